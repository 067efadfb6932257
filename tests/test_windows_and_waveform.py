import numpy as np
import pytest

from imaging.core.config import ConfigError
from imaging.core.rig import default_rig, load_rig, rig_from_dict
from imaging.core.waveform import Waveform
from imaging.core.windows import (
    NOMINAL_WIDTH_FACTOR,
    WINDOWS,
    get_window,
    half_power_width,
    window_width_factor,
)


@pytest.mark.parametrize("name", ["rectangular", "hann"])
def test_window_width_factors_match_design(name):
    # docs/conventions.md: -3.0 dB widths of 0.88448 (rectangular) and 1.4381 (Hann) bins.
    assert window_width_factor(name) == pytest.approx(NOMINAL_WIDTH_FACTOR[name], rel=2e-4)


def test_window_factors_are_ordered_by_taper():
    f = {w: window_width_factor(w) for w in WINDOWS}
    assert f["rectangular"] < f["taylor"] < f["hamming"] < f["hann"]


def test_half_power_width_of_a_sampled_gaussian():
    x = np.linspace(-5, 5, 2001)
    sigma = 1.3
    amp = np.exp(-x**2 / (4 * sigma**2))  # power exp(-x^2 / 2 sigma^2)
    expected = 2 * sigma * np.sqrt(2 * np.log(10**0.3))
    assert half_power_width(amp, spacing=x[1] - x[0]) == pytest.approx(expected, rel=1e-4)


def test_periodic_windows():
    w = get_window("hann", 8)
    assert w[0] == 0 and w[4] == pytest.approx(1.0)


def test_reference_waveform_derived_quantities():
    wf = Waveform()
    assert wf.slope_hz_per_s == pytest.approx(4e9 / 180e-6)
    assert wf.samples_per_chirp == 175  # 977 kHz * 180 us = 175.86
    assert wf.sampled_bandwidth_hz == pytest.approx(175 * wf.slope_hz_per_s / 977e3)
    assert wf.wavelength_m == pytest.approx(299_792_458 / (76e9 + 87 * wf.frequency_step_hz))
    # docs/signal-model.md: bin k holds two-way range k * c * fs / (Nfft * slope)
    assert wf.range_bin_m(1024) == pytest.approx(299_792_458 * 977e3 / (1024 * wf.slope_hz_per_s))
    assert wf.max_range_m == pytest.approx(0.5 * 299_792_458 * 977e3 / wf.slope_hz_per_s)
    assert wf.max_unambiguous_velocity_mps == pytest.approx(wf.wavelength_m / (4 * 4 * 200e-6))
    assert wf.range_resolution_m("hann") == pytest.approx(1.4381 * 299_792_458 / (2 * wf.sampled_bandwidth_hz), rel=2e-4)
    assert wf.tdm_tx_order()[:6] == [0, 1, 2, 3, 0, 1]


@pytest.mark.parametrize(
    "override, field",
    [
        ({"n_tx": 0}, "n_tx"),
        ({"chirps_per_frame": 255}, "chirps_per_frame"),
        ({"chirp_interval_s": 100e-6}, "chirp_interval_s"),
        ({"frame_interval_s": 0.01}, "frame_interval_s"),
        ({"bandwidth_hz": -1.0}, "bandwidth_hz"),
    ],
)
def test_invalid_waveform_names_the_field(override, field):
    with pytest.raises(ConfigError) as err:
        rig_from_dict({"radar": {"front": {"waveform": override}}})
    assert err.value.field == f"radar.front.waveform.{field}"


def test_rig_errors_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match=r"radar\.a\.waveform\.f0_hz: expected a number"):
        rig_from_dict({"radar": {"a": {"waveform": {"f0_hz": "fast"}}}})
    with pytest.raises(ConfigError, match=r"radar\.a\.waveform\.chirp_time: unknown setting"):
        rig_from_dict({"radar": {"a": {"waveform": {"chirp_time": 1.0}}}})
    with pytest.raises(ConfigError, match=r"radar\.a\.mount_yaw_deg: give either"):
        rig_from_dict({"radar": {"a": {"mount_yaw_deg": 90.0, "mount_rotation_xyzw": [0, 0, 0, 1]}}})
    with pytest.raises(ConfigError, match=r"radar\.a\.mount_rotation_xyzw: is not a unit quaternion"):
        rig_from_dict({"radar": {"a": {"mount_rotation_xyzw": [0, 0, 0, 3]}}})
    bad = tmp_path / "rig.toml"
    bad.write_text("[radar.a\n")
    with pytest.raises(ConfigError, match="rig.toml.*not valid TOML"):
        load_rig(bad)


def test_default_rig_file_matches_default_rig():
    from importlib import resources

    with resources.as_file(resources.files("imaging.rigs") / "default.toml") as p:
        loaded = load_rig(p)
    built = default_rig()
    assert loaded.radar_names == built.radar_names
    for a, b in zip(loaded.radars, built.radars):
        assert a.waveform == b.waveform
        np.testing.assert_allclose(a.mount.to_body(a.array.rx_positions_m), b.mount.to_body(b.array.rx_positions_m), atol=1e-12)
    # Facing outward, perpendicular to travel (body x): boresights +-y.
    np.testing.assert_allclose([r.mount.boresight_body for r in built.radars],
                               [[0, 1, 0], [0, 1, 0], [0, -1, 0], [0, -1, 0]], atol=1e-12)
    assert [r.waveform.f0_hz for r in built.radars] == [76.0e9, 76.1e9, 76.2e9, 76.3e9]
    # Filled 16-element virtual array at lambda0/2.
    r = built.radars[0]
    virtual = (r.array.tx_positions_m[:, None, 1] + r.array.rx_positions_m[None, :, 1]).ravel()
    np.testing.assert_allclose(np.sort(virtual), np.arange(16) * r.waveform.wavelength_f0_m / 2, atol=1e-12)
