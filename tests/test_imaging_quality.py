"""End-to-end image quality on simulated passes: widths against theory, peak position, far from the
origin, vibration side lobes and their inverse, integration gain."""

import numpy as np
import pytest
from conftest import LEFT_FRONT_OFFSET, R0, RADAR, point_pass

from imaging import metrics
from imaging.core.geometry import Vibration
from imaging.core.grid import Grid
from imaging.image_formation import ImagingOptions, form_image
from imaging.io.recording import Recording
from imaging.sim.scene import DEFAULT_START_TIME_NS
from imaging.sim.simulator import simulate_recording

ONE_CHANNEL = ImagingOptions(tx=(0,), rx=(0,))  # a monostatic aperture, as the theory assumes


def image_aperture(rec, aperture_m, speed, grid, origin=(0.0, 0.0), options=ONE_CHANNEL, duration_s=None):
    duration_s = duration_s or (0.5 / speed + 0.2)
    t_mid = DEFAULT_START_TIME_NS + int(duration_s / 2 * 1e9)
    half = int(aperture_m / (2 * speed) * 1e9)
    return form_image(rec, RADAR, grid, options=options, time_window_ns=(t_mid - half, t_mid + half))


@pytest.mark.parametrize("speed", [0.4, 1.0])
@pytest.mark.parametrize("aperture_m", [0.05, 0.1, 0.2, 0.34])
def test_half_power_widths_match_theory(pass_recordings, speed, aperture_m):
    dx, dy = 0.001, 0.002
    grid = Grid.from_ranges((-0.12, 0.12, dx), (R0 - 0.12, R0 + 0.12, dy), LEFT_FRONT_OFFSET[2])
    with Recording(pass_recordings[speed]) as rec:
        img = image_aperture(rec, aperture_m, speed, grid)
    a = metrics.analyze_target(img.image, img.x_m, img.y_m, img.attrs["look_direction"])
    la = img.attrs["aperture_length_m"]
    assert la == pytest.approx(aperture_m, rel=0.05)
    theory_x = metrics.cross_range_resolution_theory_m(img.wavelength_m, R0, la)
    theory_r = metrics.range_resolution_theory_m(img.attrs["bandwidth_hz"], "hann")
    assert a["cross_range"]["half_power_width_m"] == pytest.approx(theory_x, rel=0.05)
    assert a["range"]["half_power_width_m"] == pytest.approx(theory_r, rel=0.05)
    # Peak within one pixel of the truth (0, r0).
    iy, ix = a["peak_index"]
    assert abs(img.x_m[ix] - 0.0) <= dx and abs(img.y_m[iy] - R0) <= dy
    # Rectangular aperture: first side lobe at -13.3 dB; Hann in range: about -31.5 dB.
    assert a["cross_range"]["pslr_db"] == pytest.approx(-13.26, abs=1.0)
    assert a["range"]["pslr_db"] < -28.0


@pytest.mark.parametrize("window, pslr_db", [("taylor", -35.0), ("hann", -31.5), ("hamming", -42.7)])
def test_a_tapered_aperture_lowers_the_side_lobes_and_widens_the_main_lobe_as_its_theory_says(pass_recordings, window,
                                                                                              pslr_db):
    """Each profile weighted by the window at its phase centre's place along the aperture: the cross-range
    cut is the window's transform (its design side lobes; its width factor, e.g. 1.34x for Taylor), where
    the untapered aperture gives the sinc (-13.3 dB, the test above)."""
    from imaging.io.image_file import read_image, write_image

    grid = Grid.from_ranges((-0.12, 0.12, 0.001), (R0 - 0.12, R0 + 0.12, 0.002), LEFT_FRONT_OFFSET[2])
    with Recording(pass_recordings[0.4]) as rec:
        img = image_aperture(rec, 0.2, 0.4, grid, options=ImagingOptions(tx=(0,), rx=(0,), aperture_window=window))
        plain = image_aperture(rec, 0.2, 0.4, grid)
    a = metrics.analyze_target(img.image, img.x_m, img.y_m, img.attrs["look_direction"])
    la = img.attrs["aperture_length_m"]
    theory = metrics.cross_range_resolution_theory_m(img.wavelength_m, R0, la, window)
    assert a["cross_range"]["half_power_width_m"] == pytest.approx(theory, rel=0.05)
    assert a["cross_range"]["pslr_db"] == pytest.approx(pslr_db, abs=3.0)
    # Range is untouched: the same width as the untapered image's.
    b = metrics.analyze_target(plain.image, plain.x_m, plain.y_m, plain.attrs["look_direction"])
    assert a["range"]["half_power_width_m"] == pytest.approx(b["range"]["half_power_width_m"], rel=0.01)
    assert a["cross_range"]["half_power_width_m"] > 1.2 * b["cross_range"]["half_power_width_m"]
    # The file says which taper, and analyze's theory allows for it.
    path = write_image(pass_recordings[0.4].parent / f"taper_{window}.h5", img)
    back = read_image(path)
    assert back.attrs["aperture_window"] == window
    result = metrics.compare_with_theory(dict(a), back.image, back.x_m, back.y_m, back.attrs, back.wavelength_m)
    assert result["cross_range"]["ratio_to_theory"] == pytest.approx(1.0, abs=0.05)


def test_window_at_is_the_window_across_its_span():
    from imaging.core.windows import get_window, window_at

    for name in ("rectangular", "hann", "hamming", "taylor"):
        w = get_window(name, 64)
        # scipy's Taylor window of n samples (periodic: n + 1 symmetric ones, the last left off) samples its
        # function at cell centres, the others at cell edges
        u = (np.arange(64) + 0.5) / 65 if name == "taylor" else np.arange(64) / 64
        assert np.allclose(window_at(name, u), w, atol=1e-3), name
        u = np.linspace(0, 1, 101)
        assert np.allclose(window_at(name, u), window_at(name, 1 - u), atol=1e-6), name  # symmetric
    assert window_at("hann", np.array([-0.1, 1.1])).tolist() == [0.0, 0.0]


def test_image_five_km_from_the_origin_is_as_good(sim_dir):
    speed, duration = 0.4, 1.2
    results = {}
    for origin in [(0.0, 0.0), (4000.0, 3000.0)]:  # 5 km out
        path = sim_dir / f"origin_{origin[0]:.0f}.h5"
        simulate_recording(point_pass(speed, duration, origin=origin), path)
        grid = Grid.from_ranges((origin[0] - 0.06, origin[0] + 0.06, 0.001), (origin[1] + R0 - 0.1, origin[1] + R0 + 0.1, 0.002),
                                LEFT_FRONT_OFFSET[2])
        with Recording(path) as rec:
            img = image_aperture(rec, 0.34, speed, grid, duration_s=duration, options=ImagingOptions())
        results[origin] = img
    near, far = results.values()
    a = metrics.analyze_target(near.image, near.x_m, near.y_m, near.attrs["look_direction"])
    b = metrics.analyze_target(far.image, far.x_m, far.y_m, far.attrs["look_direction"])
    assert b["peak_m"][0] - 4000.0 == pytest.approx(a["peak_m"][0], abs=1e-4)
    assert b["peak_m"][1] - 3000.0 == pytest.approx(a["peak_m"][1], abs=1e-4)
    for cut in ("range", "cross_range"):
        assert b[cut]["half_power_width_m"] == pytest.approx(a[cut]["half_power_width_m"], rel=1e-3)
    assert b["peak_amplitude"] == pytest.approx(a["peak_amplitude"], rel=1e-3)
    corr = np.abs(np.vdot(near.image, far.image)) / (np.linalg.norm(near.image) * np.linalg.norm(far.image))
    assert corr > 0.9999


def test_vibration_side_lobes_and_their_inverse(sim_dir):
    # The reference case: a side lobe near 0.04 m cross-range at about -4.3 dB, r0 = 2 m, 0.4 m/s.
    speed, wavelength = 0.4, 0.0038445
    f_vib = metrics.vibration_frequency_hz(0.04, R0, speed, wavelength)
    a_vib = metrics.vibration_amplitude_m(-4.3, wavelength)
    duration = 3.0
    path = sim_dir / "vibration.h5"
    simulate_recording(point_pass(speed, duration, vibration=Vibration(f_vib, a_vib, 0.7)), path)
    grid = Grid.from_ranges((-0.12, 0.12, 0.0005), (R0 - 0.02, R0 + 0.02, 0.002), LEFT_FRONT_OFFSET[2])
    with Recording(path) as rec:
        # 0.6 m: 6 vibration periods, the side lobes resolved (7.7 mm width), angles within +-9 deg. Longer
        # apertures smear the side lobes (at 1.2 m the level reads 0.5 dB low, A_vib 5 % low).
        img = image_aperture(rec, 0.6, speed, grid, duration_s=duration)
    a = metrics.analyze_target(img.image, img.x_m, img.y_m, img.attrs["look_direction"])
    s, v = metrics.cut(img.image, img.x_m, img.y_m, a["peak_m"], (1.0, 0.0), 0.1, 2001)
    offset, level, sides = metrics.paired_sidelobes(s, v, min_offset_m=0.02)
    (left_off, left_db), (right_off, right_db) = sides
    assert left_off == pytest.approx(right_off, rel=0.05) and left_db == pytest.approx(right_db, abs=1.0)  # paired (leakage of the main lobe tilts them a little)
    assert offset == pytest.approx(0.04, rel=0.02)
    assert metrics.vibration_frequency_hz(offset, R0, img.attrs["speed_mps"], img.wavelength_m) == pytest.approx(f_vib, rel=0.05)
    assert metrics.vibration_amplitude_m(level, img.wavelength_m) == pytest.approx(a_vib, rel=0.05)


def test_vibration_inverse_round_trips():
    for amp in (5e-5, 2e-4, 3.4e-4, 5e-4):
        level = metrics.vibration_sidelobe_level_db(amp, 0.0038)
        assert metrics.vibration_amplitude_m(level, 0.0038) == pytest.approx(amp, rel=1e-9)
    x = 0.04
    f = metrics.vibration_frequency_hz(x, 2.0, 0.4, 0.0038)
    assert f == pytest.approx(2 * 0.4 / 0.0038 * x / np.hypot(x, 2.0))


def test_integration_gain_is_coherent(sim_dir):
    path = sim_dir / "noisy.h5"
    speed, duration = 0.4, 1.3
    simulate_recording(point_pass(speed, duration, snr_db=-15.0, seed=11), path)
    grid = Grid.from_ranges((-0.25, 0.25, 0.004), (R0 - 0.3, R0 + 0.3, 0.006), LEFT_FRONT_OFFSET[2])
    counts, snrs = [], []
    with Recording(path) as rec:
        centre = rec.n_frames(RADAR) // 2
        for n in (1, 2, 4, 8, 16):
            frames = slice(centre - n // 2, centre - n // 2 + n)
            img = form_image(rec, RADAR, grid, frames=frames, options=ONE_CHANNEL)
            (iy, ix), _ = metrics.find_peak(img.image, img.x_m, img.y_m, near_m=(0.0, R0), radius_m=0.05)
            counts.append(n)
            snrs.append(metrics.image_snr_db(img.image, (iy, ix), (25, 40)))
    alpha, _ = metrics.fit_integration_gain(counts, snrs)
    assert 0.8 < alpha < 1.2  # coherent: SNR grows as N


def test_fit_integration_gain_recovers_exponent():
    n = np.array([1, 2, 4, 8, 16, 32])
    alpha, g0 = metrics.fit_integration_gain(n, 10 * np.log10(3.0 * n**0.62))
    assert alpha == pytest.approx(0.62) and g0 == pytest.approx(10 * np.log10(3.0))
    with pytest.raises(ValueError):
        metrics.fit_integration_gain([4, 4], [1.0, 2.0])


@pytest.mark.parametrize("options", [ImagingOptions(), ONE_CHANNEL])
def test_the_range_window_gives_the_image_of_every_bin(pass_recordings, monkeypatch, options):
    """form_image makes only the range bins the grid needs (imaging.range_window: a chirp-z transform of
    about a sixth of the bins here); its image is the one made from every bin to float32 precision (SER
    above 100 dB), on all 16 channels and on one."""
    import imaging.profiles
    import imaging.range_compression

    made = []
    compress = imaging.range_compression.range_compress

    def recorded(*args, **kwargs):
        profiles = compress(*args, **kwargs)
        made.append((kwargs.get("bins"), profiles.n_bins))
        return profiles

    grid = Grid.from_ranges((-0.3, 0.3, 0.004), (R0 - 0.3, R0 + 0.3, 0.004), LEFT_FRONT_OFFSET[2])
    monkeypatch.setattr(imaging.profiles, "range_compress", recorded)
    with Recording(pass_recordings[0.4]) as rec:
        windowed = form_image(rec, RADAR, grid, frames=slice(2, 8), options=options).image
        assert made and all(bins is not None and n_bins == bins[1] - bins[0] < 2800 / 4 for bins, n_bins in made)
        monkeypatch.setattr(imaging.profiles, "worth_it", lambda *args: False)  # every bin, as before the window
        made.clear()
        full = form_image(rec, RADAR, grid, frames=slice(2, 8), options=options).image
        assert made and all(bins is None and n_bins == 2800 for bins, n_bins in made)
    ser_db = 10 * np.log10(np.sum(np.abs(full) ** 2) / np.sum(np.abs(windowed - full) ** 2))
    assert ser_db > 100.0
