"""The strip map's "polar" path (imaging.stripmap.polar): its numba kernels against plain numpy, and its map
against the direct kernel's within the stated error."""

import dataclasses
import math

import numpy as np
import pytest
from conftest import R0, RADAR, point_pass

from imaging import metrics
from imaging.io.recording import Recording
from imaging.sim.simulator import simulate_recording
from imaging.stripmap import StripMap, StripMapConfig
from imaging.stripmap.polar import (
    TAPS,
    FrameBeams,
    _cis,
    _extent,
    _table,
    _weights,
    beams_at_points,
    frame_beams,
    one_blas_thread,
    plane_points,
)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """The left-front radar passing a point target at 2 m, 1.2 m of travel at 0.4 m/s."""
    path = tmp_path_factory.mktemp("polar") / "pass.h5"
    simulate_recording(point_pass(0.4, duration_s=3.0), path)
    rec = Recording(path)
    yield rec, rec.radar(RADAR), rec.truth(), rec.tdm_tx_order(RADAR)
    rec.close()


def error_db(a, ref):
    return float(10 * np.log10(np.sum(np.abs(a - ref) ** 2) / np.sum(np.abs(ref) ** 2)))


def test_extent_is_numpys():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-3, 3, (500, 3)) + [0, 4, 0]
    c, u = np.array([0.1, -0.2, 0.4]), np.array([0.6, 0.8, 0.0])
    d = pts - c
    r = np.linalg.norm(d, axis=1)
    assert np.allclose(_extent(pts, c, u), (r.min(), r.max(), (d @ u / r).min(), (d @ u / r).max()))


def test_cis_is_numpys_exp():
    """The kernels' exp(j x) against numpy's to 1e-15 over a pixel's phases (up to 1e5 rad), small ones, and
    every quadrant's edges (multiples of pi / 4 either side of a rounding)."""
    import numba

    @numba.njit
    def each(x):
        out = np.empty(x.size, np.complex128)
        for i in range(x.size):
            out[i] = _cis(x[i])
        return out

    rng = np.random.default_rng(5)
    edges = np.arange(-4000, 4001) * (np.pi / 4)
    x = np.concatenate([rng.uniform(-1e5, 1e5, 100_000), rng.uniform(-4, 4, 10_000), edges,
                        np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf), [0.0, -0.0]])
    np.testing.assert_allclose(each(x), np.exp(1j * x), rtol=0, atol=1e-15)


def test_weights_are_numpys():
    """Delta_p at the nearest and farthest range on each beam's line, split into means and what is left,
    and the three weights exp(-j k d) (1, d, s), as plain numpy computes them."""
    rng = np.random.default_rng(2)
    p_n = 24
    c = np.array([0.3, -0.1, 0.5])
    u, normal = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    tx = c + rng.normal(0, 0.01, (p_n, 3))
    rx = c + rng.normal(0, 0.01, (p_n, 3))
    alpha = np.linspace(-0.3, 0.3, 7)
    z, r_near, r_far, k = 0.3, 1.0, 4.0, 1600.0
    inv_mid = 0.5 * (1 / r_near + 1 / r_far)
    out = np.empty((p_n, 3 * alpha.size), np.complex64)
    shift, shift_slope = np.empty(alpha.size), np.empty(alpha.size)
    _weights(out, shift, shift_slope, tx, rx, c, u, normal, z, alpha, r_near, r_far, inv_mid, k)

    def delta(r):
        g = plane_points(c, u, normal, np.full(alpha.size, r), alpha, z)
        assert np.allclose(g[:, 2], z)
        return (np.linalg.norm(g[None] - tx[:, None], axis=2) + np.linalg.norm(g[None] - rx[:, None], axis=2)
                - 2 * np.linalg.norm(g - c, axis=1)[None])

    near, far = delta(r_near), delta(r_far)
    base, slope = 0.5 * (near + far), (near - far) / (1 / r_near - 1 / r_far)
    assert np.allclose(shift, base.mean(axis=0)) and np.allclose(shift_slope, slope.mean(axis=0))
    d, s = base - base.mean(axis=0), slope - slope.mean(axis=0)
    e = np.exp(-1j * k * d)
    want = np.concatenate([e, e * d, e * s], axis=1)
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-6 * np.abs(want).max())


def test_beams_at_points_is_numpys():
    """Per pixel: TAPS beams around its angle by the tabulated kernel, each read linearly at 2 r + shift +
    shift_slope eps, main - j k eps slope, times exp(-j k (2 r + shift + shift_slope eps)) (in numpy with the
    exact phase per tap; the kernel's middle tap's shift_slope stands for all: within 1e-4 here)."""
    rng = np.random.default_rng(3)
    nb, bins, step, k = 16, 600, 0.005, 1600.0
    main = (rng.normal(size=(nb, bins)) + 1j * rng.normal(size=(nb, bins))).astype(np.complex64)
    slope = (rng.normal(size=(nb, bins)) + 1j * rng.normal(size=(nb, bins))).astype(np.complex64)
    shift = rng.normal(0, 1e-3, nb)
    shift_slope = np.full(nb, 2e-4) + rng.normal(0, 1e-8, nb)  # as across a frame's taps: well under a mrad
    turn = np.exp(-1j * k * shift).astype(np.complex64)[:, None]  # carried by the signals
    beams = FrameBeams(np.zeros(3), np.array([1.0, 0.0, 0.0]), -0.4, 0.05, 0.6, k, step,
                       np.concatenate([main * turn, slope * turn]), shift, shift_slope)
    pts = np.stack([rng.uniform(-0.2, 0.2, 200), rng.uniform(1.0, 1.4, 200), np.zeros(200)], axis=1)
    got = beams_at_points(beams, pts)
    table = _table()
    want = np.zeros(pts.shape[0], np.complex128)
    for i, g in enumerate(pts):
        r = np.linalg.norm(g)
        fa = (g[0] / r + 0.4) / 0.05
        j0 = int(math.floor(fa)) - TAPS // 2 + 1
        w = table[int((fa - math.floor(fa)) * (table.shape[0] - 1) + 0.5)]
        eps = 1 / r - 0.6
        for t in range(TAPS):
            a = j0 + t
            rr = 2 * r + shift[a] + shift_slope[a] * eps
            pos = rr / step
            b = int(pos)
            f = pos - b
            v = (main[a, b] * (1 - f) + main[a, b + 1] * f) - 1j * k * eps * (slope[a, b] * (1 - f) + slope[a, b + 1] * f)
            want[i] += w[t] * v * np.exp(-1j * k * rr)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * np.abs(want).max())


def test_one_blas_thread_keeps_the_product():
    a = np.arange(12, dtype=np.complex64).reshape(3, 4)
    with one_blas_thread():
        assert np.array_equal(a @ a.T, (a.astype(np.complex128) @ a.T.astype(np.complex128)).astype(np.complex64))


def test_a_frames_beams_give_the_direct_kernels_frame_image(drive):
    """One frame at its footprint's pixels: the beams against the direct kernel, within -45 dB (-58 to -62
    dB at the soak's scene, benchmarks/stripmap_polar.py)."""
    rec, radar, truth, order = drive
    config = StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=3.0, presum=4, algorithm="direct")
    sm = StripMap(config)
    adc, t = rec.adc(RADAR, slice(30, 31))[0], int(rec.frame_time_ns(RADAR)[30])
    profiles, tx, rx, look, _ = sm.frame_profiles(radar, order, adc, t, truth)
    samples, tx2, rx2, look2, _ = sm.frames_profiles(radar, order, [adc], [t], truth, compress=False)
    assert np.allclose(tx, tx2) and np.allclose(rx, rx2) and samples.shape == (profiles.data.shape[0], radar.waveform.samples_per_chirp)
    c, lk = (0.5 * (tx + rx))[:, :2].mean(axis=0), look.mean(axis=0)
    lk /= np.linalg.norm(lk)
    gx, gy = np.meshgrid(np.arange(-0.15, 0.15, 0.01) + c[0], np.arange(1.0, 3.0, 0.01) + c[1])
    pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, config.z_m)], axis=1)
    from imaging.backprojection import backproject

    direct = backproject(profiles, tx, rx, pts, mode="linear")
    wf = radar.waveform
    beams = frame_beams(samples, tx, rx, pts, wf.f0_hz, wf.frequency_step_hz, config.window, config.oversample, lk)
    assert error_db(beams_at_points(beams, pts), direct) < -45


def test_a_frame_holds_the_beams_its_pixels_read_and_no_more(drive):
    """The beams a frame forms are those its pixels' taps reach (each end with a beam's room for rounding), and
    reading them from ``first_beam`` gives the numbers the same beams held from beam 0 give, bit for bit."""
    rec, radar, truth, order = drive
    config = StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=3.0, presum=4)
    sm = StripMap(config)
    adc, t = rec.adc(RADAR, slice(30, 31))[0], int(rec.frame_time_ns(RADAR)[30])
    samples, tx, rx, look, _ = sm.frames_profiles(radar, order, [adc], [t], truth, compress=False)
    c, lk = (0.5 * (tx + rx))[:, :2].mean(axis=0), look.mean(axis=0)
    lk /= np.linalg.norm(lk)
    gx, gy = np.meshgrid(np.arange(-0.15, 0.15, 0.01) + c[0], np.arange(1.0, 3.0, 0.01) + c[1])
    pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, config.z_m)], axis=1)
    wf = radar.waveform
    beams = frame_beams(samples, tx, rx, pts, wf.f0_hz, wf.frequency_step_hz, config.window, config.oversample, lk)
    held = beams.signals.shape[0] // 2
    d = pts - beams.centre_m
    fa = np.floor((d @ beams.axis / np.linalg.norm(d, axis=1) - beams.alpha0) / beams.dalpha)
    lowest, highest = int(fa.min()) - TAPS // 2 + 1, int(fa.max()) + TAPS // 2
    assert beams.first_beam >= 1  # the grid's margin below, never read, is not formed
    assert 0 <= lowest - beams.first_beam <= 1 and 0 <= beams.first_beam + held - 1 - highest <= 1
    values = beams_at_points(beams, pts)
    assert np.count_nonzero(values) == pts.shape[0]
    f = beams.first_beam
    pad = np.zeros((f, beams.signals.shape[1]), np.complex64)
    from_zero = dataclasses.replace(
        beams, first_beam=0, signals=np.concatenate([pad, beams.signals[:held], pad, beams.signals[held:]]),
        shift_m=np.concatenate([np.zeros(f), beams.shift_m]), shift_slope_m=np.concatenate([np.zeros(f), beams.shift_slope_m]))
    assert np.array_equal(beams_at_points(from_zero, pts), values)


def test_the_polar_map_is_the_direct_map_within_its_error(drive):
    """The whole pass, frame by frame and batched: the map within -45 dB of the direct kernel's, the target's
    peak in the same pixel, its cross-range width and peak side lobe as the direct map's."""
    rec, radar, truth, order = drive
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.0, range_max_m=3.0, presum=4)
    assert config.algorithm == "polar" and config.images_by_beams
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    frames = list(range(10, 50))
    maps = {}
    for name, cfg, batch in (("direct", dataclasses.replace(config, algorithm="direct"), 1), ("polar", config, 1),
                             ("polar batched", config, 4)):
        sm = StripMap(cfg)
        for a in range(0, len(frames), batch):
            ks = frames[a:a + batch]
            sm.add_frames(radar, order, [adc[k] for k in ks], [int(times[k]) for k in ks], truth)
        maps[name] = sm
    assert maps["polar"].profiles == maps["direct"].profiles and maps["polar"].tiles.keys() == maps["direct"].tiles.keys()
    ref, x, y = maps["direct"].mosaic()
    assert error_db(maps["polar"].mosaic()[0], ref) < -45
    one, batched = maps["polar"].mosaic()[0], maps["polar batched"].mosaic()[0]
    assert np.abs(batched - one).max() <= 1e-4 * np.abs(one).max()  # the same frames' beams
    got = {n: metrics.analyze_target(maps[n].mosaic()[0], x, y, (0.0, 1.0), near_m=(0.0, R0), radius_m=0.1, half_length_m=0.15)
           for n in ("direct", "polar")}
    assert got["polar"]["peak_index"] == got["direct"]["peak_index"]
    assert np.allclose(got["polar"]["peak_m"], got["direct"]["peak_m"], atol=1e-4)  # its sub-pixel fit
    assert got["polar"]["peak_amplitude"] == pytest.approx(got["direct"]["peak_amplitude"], rel=0.01)
    for cut in ("range", "cross_range"):
        assert got["polar"][cut]["pslr_db"] == pytest.approx(got["direct"][cut]["pslr_db"], abs=0.5)
        assert got["polar"][cut]["half_power_width_m"] == pytest.approx(got["direct"][cut]["half_power_width_m"], rel=0.01)
    assert maps["polar"].to_image().attrs["method"] == "stripmap-polar-linear"


def test_refocusing_and_other_modes_image_directly():
    assert not StripMapConfig(refocus="pga").images_by_beams
    assert not StripMapConfig(mode="nearest").images_by_beams
    assert StripMap(StripMapConfig(mode="exact")).config.images_by_beams is False
    assert not StripMapConfig(range_min_m=0.0).images_by_beams
    assert not StripMapConfig(beam_half_angle_deg=80.0).images_by_beams
    assert StripMapConfig(beam_half_angle_deg=70.0).images_by_beams


def test_frames_of_few_profiles_go_direct(drive):
    """Pre-summed far (a live map catching up) a frame has POLAR_MIN_PROFILES or fewer profiles: "polar"
    images it with the direct kernel (cheaper there), the same map as "direct"; one more step down it does not."""
    from imaging.stripmap.map import POLAR_MIN_PROFILES

    rec, radar, truth, order = drive
    wf = radar.waveform
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.0, range_max_m=3.0)
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    frames = list(range(20, 28))
    for presum, same in ((16, True), (8, False)):
        assert (wf.n_tx * wf.chirps_per_tx // presum * wf.n_rx <= POLAR_MIN_PROFILES) == same
        maps = []
        for alg in ("polar", "direct"):
            sm = StripMap(dataclasses.replace(config, algorithm=alg))
            sm.add_frames(radar, order, [adc[k] for k in frames], [int(times[k]) for k in frames], truth, presum=presum)
            maps.append(sm.mosaic()[0])
        assert np.array_equal(maps[0], maps[1]) == same
        assert same or error_db(maps[0], maps[1]) < -45
