"""The autofocus decision by consistency: the track error estimated from the lower and from the upper half
of the band must agree before it is applied (imaging.autofocus.consistency), on passes synthesised with an
error unlike the paper's (imaging.sim.autofocus_scenes)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from imaging import metrics
from imaging.autofocus import AutofocusOptions, backproject_blocks, estimate_track_error
from imaging.autofocus.consistency import consistency_of, half_band_blocks, split_band
from imaging.autofocus.estimate import select_pixels
from imaging.autofocus.subapertures import group_images
from imaging.autofocus.weak_point import detect_point, point_check
from imaging.core.errors import ConfigError
from imaging.core.track_error import TrackError
from imaging.sim.autofocus_scenes import INDEPENDENT_ERROR, NO_ERROR, RANGE_M, synthesise_pass


def correlation(a, b):
    a, b = np.abs(a).ravel(), np.abs(b).ravel()
    a, b = a - a.mean(), b - b.mean()
    return float(a @ b / np.sqrt((a @ a) * (b @ b)))


def width_m(img, p):
    a = metrics.analyze_target(img, p.x_m, p.y_m, (0.0, 1.0, 0.0), near_m=(0.0, RANGE_M), radius_m=0.03, half_length_m=0.08)
    return a["cross_range"]["half_power_width_m"]


def test_half_bands_image_a_point_where_the_full_band_does():
    """Each half of the chirp's samples, compressed on its own, puts a point target at the same pixel with
    the same phase as the whole band (within 0.05 rad), at its own carrier 2 GHz apart."""
    p = synthesise_pass("point", NO_ERROR, 60.0, 3)
    blk = p.blocks[0]
    lower, upper = split_band(blk.profiles)
    assert upper.carrier_hz - lower.carrier_hz == pytest.approx(2e9, rel=1e-3)
    assert lower.range_step_m == pytest.approx(2 * blk.profiles.range_step_m, rel=1e-3)
    peaks = []
    for prof in (blk.profiles, lower, upper):
        img = backproject_blocks([dataclasses.replace(blk, profiles=prof)], p.points_m)
        iy, ix = np.unravel_index(np.abs(img).argmax(), img.shape)
        peaks.append((iy, ix, np.angle(img[iy, ix])))
    assert peaks[1][:2] == peaks[0][:2] == peaks[2][:2]
    assert abs(peaks[1][2] - peaks[0][2]) < 0.05 and abs(peaks[2][2] - peaks[0][2]) < 0.05


def test_consistency_separates_a_common_track_error_from_independent_fits():
    """Pairs of independent estimates of nothing pass at about the stated 1 % (white noise) and at most a
    few percent (random walks, most power in a few bins); one track error under two independent noises
    passes, and an estimate to apply that departs from it is refused."""
    rng = np.random.default_rng(11)
    t = np.arange(256.0)
    white = sum(consistency_of(t, rng.standard_normal(256), rng.standard_normal(256))[0].passed for _ in range(400))
    walks = sum(consistency_of(t, np.cumsum(rng.standard_normal(256)), np.cumsum(rng.standard_normal(256)))[0].passed
                for _ in range(400))
    assert white / 400 <= 0.03 and walks / 400 <= 0.06
    x = 3.0 * rng.standard_normal(256)  # a track error with a value of its own in every group
    a, b = x + rng.standard_normal(256), x + rng.standard_normal(256)
    c, agreed = consistency_of(t, a, b, x)
    assert c.scope == "per-group" and c.applied_agrees and agreed is not None and c.margin_db > 10.0
    assert c.uncertainty_m == pytest.approx(np.sqrt(0.5), rel=0.2)  # rms of half the difference of unit noises
    c, agreed = consistency_of(t, a, b, -x)
    assert c.passed and not c.applied_agrees and agreed is None
    # A bend and a vibration under noise twice their size: group by group nothing agrees, the smooth part
    # does, and only that part is given back to apply.
    x = 0.5 * np.sin(t / 10.0) + 0.5 * ((t - 128.0) / 128.0) ** 3
    a, b = x + rng.standard_normal(256), x + rng.standard_normal(256)
    c, agreed = consistency_of(t, a, b, 0.5 * (a + b))
    assert c.scope == "smooth" and c.ratio < c.critical_ratio and agreed is not None
    line_free = x - np.polyval(np.polyfit(t, x, 1), t)
    # The smooth part holds a few of the noise's 256 dimensions: it is far closer to the track error than
    # the average of the two estimates (0.71 rms of noise).
    assert np.sqrt(np.mean((agreed - line_free) ** 2)) < 0.3 * np.sqrt(0.5)


@pytest.mark.parametrize("error", [NO_ERROR, INDEPENDENT_ERROR], ids=["error-free", "erroneous"])
def test_clutter_is_never_moved_from_the_true_image(error):
    """Diffuse clutter only (four scatterers per resolution cell, 15 dB over the noise): by default, whatever
    the contrast gate says, the image is never further from the true image (formed on the true track)
    than without autofocus; the consistency is reported."""
    p = synthesise_pass("clutter", error, 15.0, 4)
    plain = backproject_blocks(p.blocks, p.points_m)
    truth = backproject_blocks(p.true_blocks, p.points_m)
    for gate_db in (20.0, 0.0):
        result = estimate_track_error(lambda: p.blocks, plain, p.points_m, AutofocusOptions(min_contrast_db=gate_db))
        img = backproject_blocks(p.blocks, p.points_m, result.track_error) if result.applied else plain
        assert result.consistency is not None
        assert correlation(img, truth) >= correlation(plain, truth) - 1e-9


def test_a_strong_point_target_with_a_track_error_is_focused_by_default():
    """A point target at 32 dB image SNR with the independent error (drift, a 6.1 Hz vibration, a 2 % scale
    error): the half-band estimates agree and the default decision focuses it to the true image's width
    within 5 %; the contrast decision stays available."""
    p = synthesise_pass("point", INDEPENDENT_ERROR, 32.0, 1)
    plain = backproject_blocks(p.blocks, p.points_m)
    truth_w = width_m(backproject_blocks(p.true_blocks, p.points_m), p)
    result = estimate_track_error(lambda: p.blocks, plain, p.points_m, AutofocusOptions())
    assert result.applied and result.consistency.passed and result.consistency.margin_db > 0
    focused = backproject_blocks(p.blocks, p.points_m, result.track_error)
    assert abs(width_m(plain, p) / truth_w - 1) > 0.05
    assert width_m(focused, p) == pytest.approx(truth_w, rel=0.05)
    with pytest.raises(ConfigError, match="decision"):
        AutofocusOptions(decision="sharpest")


def test_a_weak_point_target_with_a_track_error_is_focused_by_default():
    """A point target at 14 dB image SNR with the independent error: the half-band estimates disagree (at
    11 dB per half they fit the noise), but the brightest pixel is detected as a point and both halves fit
    its phase history one bend, so the default decision focuses it to the true image's width within 5 %
    (plain: 1.11x)."""
    p = synthesise_pass("point", INDEPENDENT_ERROR, 14.0, 1)
    plain = backproject_blocks(p.blocks, p.points_m)
    truth_w = width_m(backproject_blocks(p.true_blocks, p.points_m), p)
    result = estimate_track_error(lambda: p.blocks, plain, p.points_m, AutofocusOptions())
    c = result.consistency
    assert result.applied and c.scope == "point" and c.margin_db > 0 and c.as_attrs()["autofocus_consistent"] == 1
    assert c.ratio < c.critical_ratio and c.smooth_ratio < c.smooth_critical_ratio  # the halves disagreed
    assert abs(width_m(plain, p) / truth_w - 1) > 0.05
    focused = backproject_blocks(p.blocks, p.points_m, result.track_error)
    assert width_m(focused, p) == pytest.approx(truth_w, rel=0.05)
    # The fit is the point's bend, not its noise: its peak is not raised above the true image's.
    assert np.abs(focused).max() <= 1.02 * np.abs(backproject_blocks(p.true_blocks, p.points_m)).max()


def test_the_weak_point_fit_leaves_an_error_free_point_as_it_is():
    """An error-free point target at 14 dB: detected, and both halves fit it one (noise-sized) bend; the
    fit applied moves its width and peak by under 1 % (the Cramer-Rao bound of a detected point's
    two-parameter fit is a few tenths of a radian)."""
    p = synthesise_pass("point", NO_ERROR, 14.0, 1)
    plain = backproject_blocks(p.blocks, p.points_m)
    options = AutofocusOptions()
    pixels = select_pixels(plain, p.points_m, options)
    span = (float(p.blocks[0].time_s.min()), float(p.blocks[0].time_s.max()))
    g = group_images(p.blocks, pixels, options.groups, span)
    halves = tuple(group_images(half_band_blocks(p.blocks, h), pixels, options.groups, span) for h in (0, 1))
    check = point_check(g, halves, options.false_alarm)
    assert check.detected and check.passed
    assert 2 * g.k * np.sqrt(np.mean(check.displacement_m ** 2)) < 0.3
    # Without a track error the fit is noise: within its stated (Cramer-Rao) uncertainty.
    assert np.sqrt(np.mean(check.displacement_m ** 2)) < 3 * check.uncertainty_m
    fitted = backproject_blocks(p.blocks, p.points_m, TrackError(g.time_s, check.displacement_m, "entropy"))
    assert width_m(fitted, p) == pytest.approx(width_m(plain, p), rel=0.01)
    assert np.abs(fitted).max() == pytest.approx(np.abs(plain).max(), rel=0.01)


def test_a_point_is_detected_above_the_brightest_speckle_at_the_stated_rate():
    """The detection threshold ln(N / alpha) on N pixels of exponential speckle (clutter or noise) lets
    through at most alpha of speckle-only images, and takes a pixel 3 dB above the threshold for a point;
    pixels nothing was integrated into (0) are no background."""
    rng = np.random.default_rng(5)
    false_alarms = 0
    for _ in range(2000):
        _, contrast, threshold = detect_point(rng.exponential(1.0, 4096), 0.01)
        false_alarms += contrast > threshold
    assert false_alarms / 2000 <= 0.015
    power = np.concatenate([rng.exponential(1.0, 4096), np.zeros(4096)])
    power[17] = 2.0 * math.log(4096 / 0.01)
    pixel, contrast, threshold = detect_point(power, 0.01)
    assert pixel == 17 and threshold == pytest.approx(math.log(4096 / 0.01)) and contrast > threshold


def test_pga_whose_full_band_departs_from_its_agreeing_halves_applies_their_common_part(tmp_path):
    """The paper-vibration scene at 1.0 m (benchmarks/autofocus.py's longest aperture): PGA's half-band
    estimates agree group by group, but its full-band estimate departs from them (its error at the aperture's
    ends), so the consistency decision refused it and the image stayed at -2.5 dB. What the two disjoint halves
    agree on is applied instead: the peak comes within 0.5 dB of the known vibration's image."""
    from imaging.core.geometry import Vibration
    from imaging.core.grid import Grid
    from imaging.core.track_error import TrackError
    from imaging.image_formation import ImagingOptions, focus_image, form_image
    from imaging.io.recording import Recording
    from imaging.sim.scene import load_scene
    from imaging.sim.simulator import simulate_recording

    vibration = Vibration(3.83, 0.319e-3, 0.7)
    scene = dataclasses.replace(load_scene("paper_vibration"), vibration=vibration, duration_s=4.0)
    path = tmp_path / "vibration.h5"
    simulate_recording(scene, path)
    grid = Grid.from_ranges((-0.15, 0.15, 0.001), (1.9, 2.1, 0.002), 0.3)
    one_pair = ImagingOptions(tx=(0,), rx=(0,))
    with Recording(path) as rec:
        origin = int(rec.frame_time_ns("left_front")[0])
        known = TrackError.of_vibration(vibration, np.arange(0.0, 4.5, 0.0005), scene.start_time_ns, origin)
        mid = scene.start_time_ns + int((0.75 - 0.15) / 0.4 * 1e9)  # the radar abreast the target
        window = (mid - int(1.0 / 0.8 * 1e9), mid + int(1.0 / 0.8 * 1e9))
        args = (rec, "left_front", grid, scene.trajectory)
        best = form_image(*args, options=one_pair, time_window_ns=window, track_error=known)
        plain = form_image(*args, options=one_pair, time_window_ns=window)
        focused = focus_image(*args, options=one_pair, time_window_ns=window, autofocus=AutofocusOptions(method="pga", groups=256))

    def peak_db(img):
        return 20 * np.log10(np.abs(img.image).max())

    assert peak_db(plain) - peak_db(best) < -2.0
    assert focused.attrs["autofocus_applied"] == 1
    assert focused.attrs["autofocus_consistency_scope"] == "per-group"
    assert focused.track_error.model["kind"] == "half-band common part"
    assert peak_db(focused) - peak_db(best) > -0.5
