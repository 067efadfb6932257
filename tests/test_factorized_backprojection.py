"""Fast factorized backprojection: its interpolator, its kernels against numpy, its image against the direct
kernel's (straight, bent and vibrating tracks), its error bound and its refusals."""

import numpy as np
import pytest

from imaging.backprojection import backproject
from imaging.core.geometry import Vibration, antenna_track, chirp_times_ns
from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns, StraightLine
from imaging.factorized_backprojection import (
    FactorizedOptions,
    _slice,
    _to_plane,
    backproject_factorized,
    plan_factorized,
    run_factorized,
)
from imaging.ffbp_interpolation import _tap_offsets, interpolation_error, interpolation_rms_error, interpolation_table
from imaging.ffbp_leaves import image_leaves
from imaging.ffbp_merge import _merge_rows
from imaging.range_compression import range_compress
from imaging.sim.simulator import simulate_frames
from imaging.sim.targets import PointTarget

from reference_backprojection import backproject_reference

TARGETS = [(0.0, 2.0), (-0.2, 2.1), (0.25, 1.8), (0.1, 2.3), (-0.3, 1.7)]


def pass_case(n_frames: int, trajectory=None, vibration=None, seed=0):
    """The left-front radar driving at 0.4 m/s past five point targets at about 2 m: all 16 channels."""
    radar = default_rig().radar("left_front")
    wf = radar.waveform
    traj = trajectory or StraightLine(start_m=(-0.15 - 0.4 * n_frames * wf.frame_interval_s / 2, -0.2, 0.0), speed_mps=0.4)
    ft = np.arange(n_frames, dtype=np.int64) * int(wf.frame_interval_s * 1e9)
    targets = [PointTarget((x, y, 0.3)) for x, y in TARGETS]
    adc = simulate_frames(radar, traj, targets, ft, vibration=vibration, snr_db=10.0, rng=np.random.default_rng(seed))
    times = chirp_times_ns(ft, wf.chirps_per_frame, wf.chirp_interval_s).ravel()
    track = antenna_track(radar, traj, times, np.tile(wf.tdm_tx_order(), n_frames), vibration=vibration)
    prof = range_compress(adc.reshape(-1, wf.samples_per_chirp), wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
    return prof, np.repeat(track.tx_m, wf.n_rx, axis=0), track.rx_m.reshape(-1, 3)


def error_db(image, reference) -> float:
    return float(20 * np.log10(np.linalg.norm(image - reference) / np.linalg.norm(reference)))


def direct(prof, tx, rx, x, y, z=0.3):
    xx, yy = np.meshgrid(x, y)
    return backproject(prof, tx, rx, np.stack([xx, yy, np.full_like(xx, z)], -1))


@pytest.mark.parametrize("taps,oversample", [(4, 3.0), (6, 2.0), (8, 2.0)])
def test_the_interpolator_reconstructs_tones_within_its_stated_error(taps, oversample):
    """Any tone inside the band the grid is oversampled for, at any position: the error is within
    interpolation_error, and the error is not far from it either (the bound is tight, not decorative)."""
    rng = np.random.default_rng(taps)
    table = interpolation_table(taps, oversample).astype(np.float64)
    t = _tap_offsets(taps)
    f = rng.uniform(-0.5 / oversample, 0.5 / oversample, 400)
    pos = rng.uniform(0, 1, 400)
    w = table[(pos * (table.shape[0] - 1) + 0.5).astype(int)]
    got = (w * np.exp(2j * np.pi * f[:, None] * t[None, :])).sum(axis=1)
    err = np.abs(got - np.exp(2j * np.pi * f * pos))
    assert err.max() <= interpolation_error(taps, oversample) * 1.0001
    assert err.max() > 0.2 * interpolation_error(taps, oversample)
    assert interpolation_rms_error(taps, oversample) < interpolation_error(taps, oversample)
    assert np.allclose(table.sum(axis=1), 1.0, atol=interpolation_error(taps, oversample))  # passes DC


def sample_reference(px, py, z, d, g, tab_r, tab_a):
    """numpy version of the merge and pixel kernels' sampling: the demodulated polar image d of the subaperture g
    interpolated at the plane points (px, py, z); returns (values, |p - c|)."""
    taps, nf = tab_r.shape[1], tab_r.shape[0] - 1
    dx, dy, dz = px - g[0], py - g[1], z - g[2]
    rc = np.sqrt(dx ** 2 + dy ** 2 + dz ** 2)
    fr = (rc - g[7]) / g[8]
    fa = ((dx * g[3] + dy * g[4]) / rc - g[9]) / g[10]
    i0 = np.floor(fr).astype(int) - taps // 2 + 1
    j0 = np.floor(fa).astype(int) - taps // 2 + 1
    inside = (i0 >= 0) & (j0 >= 0) & (i0 + taps <= d.shape[0]) & (j0 + taps <= d.shape[1])
    wr = tab_r[((fr - np.floor(fr)) * nf + 0.5).astype(int)]
    wa = tab_a[((fa - np.floor(fa)) * nf + 0.5).astype(int)]
    out = np.zeros(px.shape, complex)
    for a in range(taps):
        for b in range(taps):
            v = d[np.clip(i0 + a, 0, d.shape[0] - 1), np.clip(j0 + b, 0, d.shape[1] - 1)]
            out += np.where(inside, v * wr[..., a] * wa[..., b], 0)
    return out, rc


def to_plane_reference(x, y, z, d, g, k, tab_r, tab_a):
    """numpy version of _to_plane: interpolate the demodulated polar image at each pixel, restore the phase."""
    xx, yy = np.meshgrid(x, y)
    out, rc = sample_reference(xx, yy, z, d, g, tab_r, tab_a)
    return out * np.exp(-2j * k * rc)


def test_the_merge_kernel_matches_numpy():
    """A parent's grid from its two children (random demodulated images): each child interpolated at the
    parent's grid points, its phase re-referenced from the child's centre to the parent's."""
    prof, tx, rx = pass_case(2)
    x, y = np.linspace(-0.3, 0.3, 61), np.linspace(1.8, 2.2, 37)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=256))
    parent = next(n for n in plan.nodes() if n.children)
    o, k, z = plan.options, plan.wavenumber, 0.3
    tab_r, tab_a = interpolation_table(o.taps, o.oversample_range), interpolation_table(o.taps, o.oversample_angle)
    rng = np.random.default_rng(3)
    got = np.zeros((parent.nr, parent.na), np.complex64)
    want = np.zeros((parent.nr, parent.na), complex)
    r = (parent.r0_m + parent.dr_m * np.arange(parent.nr))[:, None]
    alpha = (parent.a0 + parent.da * np.arange(parent.na))[None, :]
    _, b = parent.plane_points(r, alpha, z)
    on_plane = (r * r * (1 - alpha * alpha) - (z - parent.centre_m[2]) ** 2) > 0
    points = parent.polar_points(z)
    for child in parent.children:
        d = (rng.standard_normal((child.nr, child.na)) + 1j * rng.standard_normal((child.nr, child.na))).astype(np.complex64)
        _merge_rows(got, 0, parent.nr, parent.geometry, d, child.geometry, z, k, tab_r, tab_a)
        v, rc = sample_reference(points[..., 0], points[..., 1], z, d, child.geometry, tab_r, tab_a)
        want += np.where(on_plane, v * np.exp(-2j * k * (rc - r)), 0)
    assert np.count_nonzero(want) > 0.5 * want.size  # the children cover most of the parent's grid
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-5 * np.abs(want).max())


def test_the_pixel_kernel_matches_numpy():
    prof, tx, rx = pass_case(2)
    x, y = np.linspace(-0.5, 0.5, 61), np.linspace(1.5, 2.5, 37)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=2048))
    root = plan.roots[0]
    rng = np.random.default_rng(1)
    d = (rng.standard_normal((root.nr, root.na)) + 1j * rng.standard_normal((root.nr, root.na))).astype(np.complex64)
    o = plan.options
    tab_r, tab_a = interpolation_table(o.taps, o.oversample_range), interpolation_table(o.taps, o.oversample_angle)
    got = np.zeros((y.size, x.size), complex)
    _to_plane(got, x, y, 0.3, d, root.geometry, plan.wavenumber, tab_r, tab_a)
    want = to_plane_reference(x, y, 0.3, d, root.geometry, plan.wavenumber, tab_r, tab_a)
    assert np.abs(want).min() > 0  # every pixel inside the root's grid
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-5 * np.abs(want).max())


@pytest.mark.parametrize("mode", ["linear", "nearest"])
def test_the_leaf_kernel_matches_numpy(mode):
    """A run of consecutive leaves in one call (imaging.ffbp_leaves) against plain numpy: each leaf's
    profiles backprojected onto its polar grid, demodulated by exp(+j k 2 r); reference ranges included,
    and the profiles handed over from a later first profile than 0."""
    prof, tx, rx = pass_case(2)
    x, y = np.linspace(-0.5, 0.5, 61), np.linspace(1.5, 2.5, 37)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=128))
    leaves = sorted((n for n in plan.nodes() if not n.children), key=lambda n: n.start)[3:6]
    a, b = leaves[0].start, leaves[-1].stop
    r_ref = np.random.default_rng(2).uniform(0, 0.05, tx.shape[0])
    got = image_leaves(leaves, _slice(prof, a, b), tx[a:b], rx[a:b], r_ref[a:b], a, 0.3, mode)
    for leaf, img in zip(leaves, got):
        s = slice(leaf.start, leaf.stop)
        want = backproject_reference(_slice(prof, leaf.start, leaf.stop), tx[s], rx[s], leaf.polar_points(0.3),
                                     reference_range_m=r_ref[s], mode=mode)
        want = want * np.exp(2j * plan.wavenumber * (leaf.r0_m + leaf.dr_m * np.arange(leaf.nr)))[:, None]
        assert img.shape == (leaf.nr, leaf.na) and img.dtype == np.complex64
        assert np.abs(want).max() > 0
        if mode == "nearest":
            # The kernel's geometry is float32 (about 1e-6 bins): where a profile's position is within 1e-5 bins of
            # half a bin, nearest may take the other bin, as the direct kernel's float32 blocks may.
            pts = leaf.polar_points(0.3).reshape(-1, 1, 3)
            dr = np.linalg.norm(pts - tx[s], axis=2) + np.linalg.norm(pts - rx[s], axis=2) - r_ref[s]
            pos = (dr - prof.range_axis_m[0]) / prof.range_step_m
            tie = (np.abs(pos - np.floor(pos) - 0.5) < 1e-5).any(axis=1).reshape(img.shape)
            assert tie.mean() < 0.01
            img, want = img[~tie], want[~tie]
        np.testing.assert_allclose(img, want, rtol=0, atol=1e-4 * np.abs(want).max())


def test_profiles_in_blocks_give_the_same_image():
    """Profiles handed over as a list of blocks (as ``sarbot image`` holds them), one boundary inside a leaf:
    the same image as from one block of all of them."""
    prof, tx, rx = pass_case(4)
    x, y = np.arange(-0.3, 0.3, 0.01), np.arange(1.7, 2.2, 0.01)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=256))
    assert plan.levels >= 2 and not plan.direct_only
    n = tx.shape[0]
    blocks = [_slice(prof, 0, 1024), _slice(prof, 1024, 1500), _slice(prof, 1500, n)]
    whole = run_factorized(plan, prof, tx, rx)
    np.testing.assert_allclose(run_factorized(plan, blocks, tx, rx), whole, rtol=0, atol=1e-6 * np.abs(whole).max())


@pytest.fixture(scope="module")
def straight_pass():
    return pass_case(24)


def test_it_equals_the_direct_kernel_to_its_error_estimate(straight_pass):
    """A 0.5 m aperture of all 16 channels onto 1 m x 0.6 m at 4 mm: merged over several levels, the image
    is the direct kernel's within -40 dB, near the plan's estimate and under its bound."""
    prof, tx, rx = straight_pass
    x, y = np.arange(-0.5, 0.5, 0.004), np.arange(1.6, 2.2, 0.004)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=256))
    assert plan.levels >= 4
    img = run_factorized(plan, prof, tx, rx)
    ref = direct(prof, tx, rx, x, y)
    err = error_db(img, ref)
    assert err < -40.0
    assert err < plan.error_bound_db
    assert abs(err - plan.error_estimate_db) < 8.0, (err, plan.error_estimate_db)
    # Every target where the direct image has it, at the same peak within 0.1 dB.
    mag, mag_ref = np.abs(img), np.abs(ref)
    for tx_, ty in TARGETS:
        if 1.6 <= ty < 2.2:
            win = (slice(*np.searchsorted(y, [ty - 0.03, ty + 0.03])), slice(*np.searchsorted(x, [tx_ - 0.03, tx_ + 0.03])))
            assert abs(20 * np.log10(mag[win].max() / mag_ref[win].max())) < 0.1
    cost = plan.cost()
    assert cost["direct_backprojections"] == tx.shape[0] * x.size * y.size
    assert cost["leaf_backprojections"] < cost["direct_backprojections"] / 10


@pytest.mark.parametrize("options,limit_db", [(FactorizedOptions(taps=8, leaf_taps=8, leaf_oversample=2.0), -55.0),
                                              (FactorizedOptions(taps=4, oversample_range=3, oversample_angle=3), -40.0)])
def test_more_taps_or_oversampling_buy_accuracy(straight_pass, options, limit_db):
    """8 taps on 2x grids throughout (the leaves' too), or 4 taps on 3x merged grids."""
    prof, tx, rx = straight_pass
    x, y = np.arange(-0.4, 0.4, 0.005), np.arange(1.7, 2.1, 0.005)
    img = backproject_factorized(prof, tx, rx, x, y, 0.3, options=options)
    assert error_db(img, direct(prof, tx, rx, x, y)) < limit_db


def test_coarse_leaf_grids_read_with_more_taps_cut_the_leaves_not_the_accuracy(straight_pass):
    """The leaves' grids sampled 1.5x with 8 taps (the default) against 2x with 6 taps as the merged grids: a
    quarter fewer leaf backprojections or more, the image within -41 dB of the direct one and near the plan's
    estimate. Leaf grids sampled coarser still with the same 6 taps: the error grows as the estimate says,
    which counts the leaf's interpolation apart from the merges'."""
    prof, tx, rx = straight_pass
    x, y = np.arange(-0.5, 0.5, 0.004), np.arange(1.6, 2.2, 0.004)
    ref = direct(prof, tx, rx, x, y)
    plans, errors = {}, {}
    for name, options in [("default", FactorizedOptions()), ("uniform", FactorizedOptions(leaf_oversample=None, leaf_taps=None)),
                          ("coarse", FactorizedOptions(leaf_oversample=1.3, leaf_taps=6))]:
        plans[name] = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, options)
        errors[name] = error_db(run_factorized(plans[name], prof, tx, rx), ref)
    default, uniform = plans["default"], plans["uniform"]
    assert default.cost()["leaf_backprojections"] < 0.75 * uniform.cost()["leaf_backprojections"]
    assert default.cost()["multiply_adds"] > uniform.cost()["multiply_adds"]  # 8 x 8 taps where a leaf is read
    assert errors["default"] < -41.0 and abs(errors["default"] - default.error_estimate_db) < 8.0
    assert plans["coarse"].error_estimate_db > default.error_estimate_db + 6.0
    assert errors["coarse"] > errors["default"] + 6.0 and errors["coarse"] < plans["coarse"].error_bound_db


@pytest.mark.parametrize("kind", ["bend", "vibration"])
def test_a_bent_or_vibrating_track_is_followed(kind):
    """The grids are sized from the antennas' actual spread: an arc of 4 m radius (the axis turns 7 degrees
    over the aperture) or the paper's vibration (0.32 mm at 3.83 Hz) keep the image within -40 dB."""
    n_frames = 24
    if kind == "bend":
        traj = PathWithTurns(segments=(("arc", 4.0, 7.0),), start_m=(-0.4, -0.25, 0.0), heading_deg=-3.5, speed_mps=0.4)
        prof, tx, rx = pass_case(n_frames, trajectory=traj)
    else:
        prof, tx, rx = pass_case(n_frames, vibration=Vibration(3.83, 0.319e-3, 0.7))
    x, y = np.arange(-0.4, 0.4, 0.005), np.arange(1.6, 2.4, 0.005)
    img = backproject_factorized(prof, tx, rx, x, y, 0.3, options=FactorizedOptions(leaf_profiles=256))
    assert error_db(img, direct(prof, tx, rx, x, y)) < -40.0


def test_reference_ranges_pass_through(straight_pass):
    """Motion-compensated phase histories (range relative to a scene centre per profile, as Gotcha's)
    image the same with FFBP as with the direct kernel."""
    _, tx, rx = straight_pass
    tx, rx = tx[:4096], rx[:4096]
    f0, fstep, ns, c = 76e9, 22.75e6, 175, 299_792_458.0
    r_ref = 2 * np.linalg.norm(tx - [0.0, 2.0, 0.3], axis=1)
    n = np.arange(ns)
    samples = np.zeros((tx.shape[0], ns), complex)
    for x_, y_ in TARGETS:
        s = np.array([x_, y_, 0.3])
        r = np.linalg.norm(tx - s, axis=1) + np.linalg.norm(rx - s, axis=1) - r_ref
        samples += np.exp(2j * np.pi / c * (f0 + fstep * n[None, :]) * r[:, None])
    prof = range_compress(samples, f0, fstep, oversample=8, signed=True, guarded=True)
    x, y = np.arange(-0.3, 0.3, 0.005), np.arange(1.8, 2.2, 0.005)
    xx, yy = np.meshgrid(x, y)
    ref = backproject(prof, tx, rx, np.stack([xx, yy, np.full_like(xx, 0.3)], -1), reference_range_m=r_ref)
    img = backproject_factorized(prof, tx, rx, x, y, 0.3, reference_range_m=r_ref, options=FactorizedOptions(leaf_profiles=256))
    assert np.abs(ref).max() > 0.5 * tx.shape[0]  # the targets are focused
    assert error_db(img, ref) < -40.0


def test_what_it_cannot_image_is_refused_by_name(straight_pass):
    prof, tx, rx = straight_pass
    with pytest.raises(ValueError, match="one side of the radar's track"):
        backproject_factorized(prof, tx, rx, np.linspace(-0.5, 0.5, 20), np.linspace(-1.0, 1.0, 20), 0.3)
    with pytest.raises(ValueError, match="bandwidth"):
        backproject_factorized(prof, tx, rx, np.linspace(-0.5, 0.5, 20), np.linspace(1.5, 2.0, 20), 0.3, bandwidth_hz=-1.0)
    with pytest.raises(ValueError, match="increasing"):
        backproject_factorized(prof, tx, rx, np.linspace(0.5, -0.5, 20), np.linspace(1.5, 2.0, 20), 0.3)
    plan = plan_factorized(tx[:1024], rx[:1024], np.linspace(-0.5, 0.5, 20), np.linspace(1.5, 2.0, 20), 0.3,
                           prof.carrier_hz, prof.bandwidth_hz)
    with pytest.raises(ValueError, match="the plan is for 1024"):
        run_factorized(plan, prof, tx, rx)
    with pytest.raises(Exception, match="taps"):
        FactorizedOptions(taps=5)


def test_a_plan_whose_grids_go_astray_goes_direct(straight_pass, monkeypatch):
    """A plan asking for polar grids far beyond the pixels (a live strip map's block once asked for 7e11
    samples and died allocating them) sends every profile straight onto the pixels instead: the direct
    kernel's image, with no interpolation error to state."""
    import imaging.factorized_backprojection as ffbp

    prof, tx, rx = straight_pass
    tx, rx = tx[:2048], rx[:2048]
    x, y = np.arange(-0.3, 0.3, 0.01), np.arange(1.7, 2.1, 0.01)
    normal = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=256))
    assert not normal.direct_only and normal.levels >= 1
    largest = max(n.nr * n.na for n in normal.nodes() if not n.direct)
    monkeypatch.setattr(ffbp, "MAX_GRID_PER_PIXEL", 0.9 * largest / max(x.size * y.size, 4096))
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=256))
    assert plan.direct_only and plan.levels == 0 and plan.error_bound_db == -np.inf and plan.error_estimate_db == -np.inf
    sub = ffbp._slice(prof, 0, 2048)
    np.testing.assert_allclose(run_factorized(plan, sub, tx, rx), direct(sub, tx, rx, x, y), rtol=0, atol=1e-9 * tx.shape[0])


def test_grids_are_sized_where_they_are_needed_not_at_the_axis():
    """An image plane 0.45 m below a short track, reaching far along it at close range: the corner of the
    (range, angle) box at the nearest range and widest angle lies on the axis. The grids stay the size of
    the image (they were sized from derivatives there, which diverge) and the image is the direct one."""
    rng = np.random.default_rng(1)
    n_p = 2048
    centres = np.stack([np.linspace(-0.3, 0.3, n_p), np.zeros(n_p), np.full(n_p, 0.45)], 1)
    f0, fstep, ns, c = 77e9, 22.75e6, 175, 299_792_458.0
    x, y = np.arange(-1.5, 1.5, 0.01), np.arange(0.5, 1.3, 0.01)
    samples = np.zeros((n_p, ns), complex)
    for sx, sy in rng.uniform([-1.0, 0.6], [1.0, 1.2], (4, 2)):
        r = 2 * np.linalg.norm(centres - [sx, sy, 0.0], axis=1)
        samples += np.exp(2j * np.pi / c * (f0 + fstep * np.arange(ns)[None, :]) * r[:, None])
    prof = range_compress(samples, f0, fstep, oversample=8, guarded=True)
    plan = plan_factorized(centres, centres, x, y, 0.0, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=128))
    grids = [n.nr * n.na for n in plan.nodes() if not n.direct]
    assert grids and max(grids) < 2 * x.size * y.size
    img = run_factorized(plan, prof, centres, centres)
    assert error_db(img, direct(prof, centres, centres, x, y, z=0.0)) < -40.0
