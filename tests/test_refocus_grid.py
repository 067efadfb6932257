"""A strip map's refocus on pixels coarser than its cross-range resolution (imaging.stripmap.group_grid): the
track error of a wrong speed is read as the bend it is, not as a sawtooth of one-pixel ramps."""

import dataclasses

import numpy as np
import pytest

from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns
from imaging.stripmap import StripMap
from imaging.stripmap.group_grid import finer_group_images, upsampling_factors
from rio.feedback_drive import MAP_CONFIG, START_DELAY_S, simulate_feedback_drive
from rio.map_feedback import displacement_per_velocity, velocity_error_from_tiles

SPEED_MPS = 0.4
SLOW = 0.98  # the trajectory the map is imaged on: 2 % too slow, as odometry with the Doppler 2 % low


def test_group_images_on_finer_pixels_keep_each_group_s_phase():
    """A group image that is a pure phase ramp from its antenna (a far scatterer's) stays that ramp on the
    finer pixels: demodulated, interpolated, modulated back."""
    k = 2 * np.pi / 0.0039
    x = (np.arange(32) + 0.5) * 0.01
    y = 1.2 + (np.arange(32) + 0.5) * 0.01
    antenna = np.array([[0.05, 0.0, 0.0], [0.3, 0.0, 0.0]])

    def ideal(xs, ys):
        r = 2 * np.sqrt((xs[None, None, :] - antenna[:, 0, None, None]) ** 2 + (ys[None, :, None] - antenna[:, 1, None, None]) ** 2)
        return np.exp(-1j * k * r) * np.exp(-((ys[None, :, None] - 1.36) / 0.05) ** 2)

    fine, xf, yf = finer_group_images(ideal(x, y), x, y, 0.0, antenna, k, (3, 1))
    assert fine.shape == (2, 32, 96) and xf[0] == pytest.approx(0.01 / 6) and np.allclose(yf, y)
    interior = slice(3, -3)
    assert np.max(np.abs(fine - ideal(xf, yf))[:, :, interior]) < 0.02
    # 1 cm pixels, a 0.6 m aperture at 1.5 m: the squints' sines span 0.39, 2 x 0.39 x 1 cm / 3.9 mm = 2 turns
    ends = np.array([[-0.3, 0.0, 0.0], [0.3, 0.0, 0.0]])
    assert upsampling_factors(k, ends, np.array([0.0, 1.5, 0.0]), 0.01) == (3, 1)
    assert upsampling_factors(k, ends, np.array([0.0, 1.5, 0.0]), 0.003) == (1, 1)


@pytest.fixture(scope="module")
def slow_pass():
    """The feedback drive's first 1.9 m (rio.feedback_drive, seed 0: both front radars, a target each side),
    imaged 2 % slow on its 1 cm map, refocused by the entropy model."""
    drive = simulate_feedback_drive(length_m=1.9, seed=0)
    slow = PathWithTurns(segments=[("straight", 1.9 * SLOW)], speed_mps=SPEED_MPS * SLOW, accel_mps2=0.5 * SLOW,
                         start_delay_s=START_DELAY_S, t0_ns=drive.truth.t0_ns)
    rig = default_rig()
    strip = StripMap(dataclasses.replace(MAP_CONFIG, refocus="entropy"))
    frames = sorted((int(t), name, f) for name, (times, adc) in drive.frames.items() for f, t in enumerate(times))
    for t, name, f in frames:
        radar = rig.radar(name)
        strip.add_frame(radar, np.asarray(radar.waveform.tdm_tx_order()), drive.frames[name][1][f], t, slow)
    strip.refocus_pending()
    return strip, drive.targets_m


def test_a_wrong_speed_is_read_as_its_bend_on_pixels_coarser_than_the_resolution(slow_pass):
    """1 cm pixels against a 5 mm cross-range resolution. On the map's own pixels the estimate was a sawtooth
    (ramps that shift part of the aperture by a pixel, jumps of 0.55 mm between two groups, 0.4 mm rms off the
    bend of the 8 mm/s speed error: measured before the estimation grid); on the estimation grid it follows
    the bend, and the velocity fit of each tile reads the speed error."""
    strip, targets = slow_pass
    assert set(strip.refocus_geometry) == {(3, -6), (3, 5)}
    for key, geo in strip.refocus_geometry.items():
        result = strip.refocus_results[key]
        assert result.applied
        assert np.linalg.norm(geo.scatterer_m[:2] - targets[:, :2], axis=1).min() < 0.04  # 2 % of 1.1 m short
        te = result.track_error
        predicted = displacement_per_velocity(geo) @ np.array([SPEED_MPS * (1 - SLOW), 0.0])
        assert np.ptp(predicted) == pytest.approx(1.18e-3, abs=0.05e-3)
        off = te.displacement_m - predicted
        assert np.sqrt(np.mean(off ** 2)) < 0.1 * np.ptp(predicted), key
        assert np.max(np.abs(np.diff(te.displacement_m))) < 0.15e-3, key  # the bend's steepest step: 0.08 mm
        (m,) = velocity_error_from_tiles([(te, geo)])
        assert m.velocity_error_mps * np.sign(m.direction[0]) == pytest.approx(SPEED_MPS * (1 - SLOW), rel=0.15), key
