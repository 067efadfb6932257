import numpy as np
import pytest
from reference_backprojection import backproject_reference

from imaging.backprojection import (
    BLOCK,
    PATCH,
    PHASE_ROUNDING_RAD,
    _cos_sin,
    _cos_sin_turns,
    backproject,
    max_block_extent_m,
    midpoint_form,
    patch_order,
    patch_shape,
    series_applies,
)
from imaging.range_compression import range_compress
from imaging.range_offsets import (FOLD_GRADIENT_MAX, MIDPOINT_PHASE_RAD, fold_bound_m, midpoint_remainder_bound_m,
                                   series_min_distance)

C = 299_792_458.0
F0, FSTEP, NS = 76e9, 22.75e6, 175


def synthetic_case(rng, n_profiles=96, n_points=BLOCK + 77, reference=False, centred=True, far=0.0):
    """Random bistatic antennas, scattered 3-D points, profiles of echoes from a few scatterers."""
    offset = np.array([far, -0.6 * far, 0.0])
    tx = rng.uniform(-0.5, 0.5, (n_profiles, 3)) * [1, 0.1, 0.1] + offset
    rx = tx + rng.uniform(-0.02, 0.02, (n_profiles, 3))
    scatterers = rng.uniform([-0.5, 1.5, -0.2], [0.5, 3.0, 0.2], (4, 3)) + offset
    n = np.arange(NS)
    r_ref = np.linalg.norm(tx - offset - [0, 2.2, 0], axis=1) * 2 if reference else np.zeros(n_profiles)
    samples = np.zeros((n_profiles, NS), complex)
    for s in scatterers:
        r = np.linalg.norm(tx - s, axis=1) + np.linalg.norm(rx - s, axis=1) - r_ref
        samples += np.exp(2j * np.pi / C * (F0 + FSTEP * n[None, :]) * r[:, None])
    samples += 0.1 * (rng.standard_normal(samples.shape) + 1j * rng.standard_normal(samples.shape))
    prof = range_compress(samples, F0, FSTEP, oversample=8, centred=centred, signed=reference)
    points = np.concatenate([scatterers, rng.uniform([-0.6, 1.4, -0.3], [0.6, 3.1, 0.3], (n_points - 4, 3)) + offset])
    return prof, tx, rx, points, (r_ref if reference else None)


@pytest.mark.parametrize("mode", ["nearest", "linear", "exact"])
@pytest.mark.parametrize("reference", [False, True], ids=["absolute-range", "reference-range"])
def test_kernel_matches_numpy_reference(mode, reference):
    rng = np.random.default_rng(7)
    prof, tx, rx, points, r_ref = synthetic_case(rng, reference=reference)
    got = backproject(prof, tx, rx, points, reference_range_m=r_ref, mode=mode)
    want = backproject_reference(prof, tx, rx, points, reference_range_m=r_ref, mode=mode)
    # float32 profiles, polynomial sin/cos and float32 accumulation: ~1e-6 of the image scale.
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 2e-5 * scale
    assert np.abs(want[:4]).min() > 0.5 * prof.data.shape[0]  # the scatterers focus (test is not vacuous)


def test_centred_profiles_give_the_same_image():
    rng = np.random.default_rng(1)
    plain, tx, rx, points, _ = synthetic_case(rng, centred=False)
    rng = np.random.default_rng(1)
    centred, *_ = synthetic_case(rng, centred=True)
    a = backproject(plain, tx, rx, points, mode="exact")
    b = backproject(centred, tx, rx, points, mode="exact")
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(a).max())
    # Interpolating a centred (slowly varying) profile is far more accurate than a raw one.
    err_plain = np.linalg.norm(backproject(plain, tx, rx, points, mode="linear") - a)
    err_centred = np.linalg.norm(backproject(centred, tx, rx, points, mode="linear") - a)
    assert err_centred < 0.2 * err_plain  # measured: 19 dB better


def test_default_mode_accuracy_against_matched_filter():
    rng = np.random.default_rng(2)
    prof8, tx, rx, points, _ = synthetic_case(rng, n_profiles=256)
    prof = range_compress(prof8.samples * 1.0, F0, FSTEP, window="rectangular")  # already Hann-windowed; default 16x
    exact = backproject(prof, tx, rx, points, mode="exact")

    def ser_db(mode, p):
        return 20 * np.log10(np.linalg.norm(exact) / np.linalg.norm(backproject(p, tx, rx, points, mode=mode) - exact))

    assert ser_db("linear", prof) > 60.0  # the goal for the default mode
    assert ser_db("linear", prof) > ser_db("nearest", prof) + 10.0
    assert ser_db("linear", prof) > ser_db("linear", prof8) + 9.0  # error ~ bin^2: 12 dB per doubling


def grid_case(shape, far=0.0, spacing_m=0.004):
    """The synthetic case's antennas and profiles with a regular grid (``shape`` [..., ny, nx]) around its
    first scatterer: what the float32 block kernel takes."""
    prof, tx, rx, points, _ = synthetic_case(np.random.default_rng(11), far=far)
    centre = points[0]
    *layers, ny, nx = shape
    z = centre[2] + spacing_m * (np.arange(layers[0]) - layers[0] // 2) if layers else np.array([centre[2]])
    x = centre[0] + spacing_m * (np.arange(nx) - nx // 2)
    y = centre[1] + spacing_m * (np.arange(ny) - ny // 2)
    zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
    grid = np.stack([xx, yy, zz], axis=-1).reshape(*shape, 3)
    return prof, tx, rx, grid


@pytest.mark.parametrize("shape", [(40, 70), (3, 20, 30)])
@pytest.mark.parametrize("far", [0.0, 5000.0])
@pytest.mark.parametrize("mode", ["nearest", "linear"])
def test_float32_block_kernel_matches_numpy_reference_on_grids(shape, far, mode):
    prof, tx, rx, grid = grid_case(shape, far)
    flat = grid.reshape(-1, 3)
    order = patch_order(shape)
    k = 2 * np.pi * prof.carrier_hz / C
    # The grid takes the float32 kernel (compact patches), the synthetic case's scattered points do not.
    assert max_block_extent_m(*(flat[order, i] for i in range(3))) * k * 2.0 ** -24 <= PHASE_ROUNDING_RAD
    scattered = synthetic_case(np.random.default_rng(11))[3]
    assert max_block_extent_m(*(scattered[:, i] for i in range(3))) * k * 2.0 ** -24 > PHASE_ROUNDING_RAD
    got = backproject(prof, tx, rx, grid, mode=mode)
    want = backproject_reference(prof, tx, rx, grid, mode=mode)
    assert got.shape == shape
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 2e-5 * scale
    assert np.abs(want.reshape(-1)[np.argmax(np.abs(want))]) > 0.5 * prof.data.shape[0]  # the scatterer focuses


def test_patch_order_walks_squares():
    shape = (2, 37, 50)
    order = patch_order(shape)
    assert np.array_equal(np.sort(order), np.arange(2 * 37 * 50))
    iz, rest = np.divmod(order, 37 * 50)
    iy, ix = np.divmod(rest, 50)
    first = slice(0, PATCH * PATCH)
    assert (iz[first] == 0).all() and iy[first].max() < PATCH and ix[first].max() < PATCH
    # every run of BLOCK points stays within a few patches of one layer
    for b in range(0, order.size, BLOCK):
        assert np.ptp(iz[b:b + BLOCK]) == 0 or b + BLOCK > 37 * 50 * (iz[b] + 1)
    assert patch_order((5, 3)) is None and patch_order((100,)) is None
    # ... and within two patches of the grid in each direction, also where patches are narrower at an edge
    # (50 = 3 x 16 + 2 columns) and for narrow patches (8 columns x 32 rows)
    for width in (PATCH, 8):
        order = patch_order(shape, width)
        iy, ix = np.divmod(order % (37 * 50), 50)
        for b in range(0, 37 * 50 - BLOCK, BLOCK):
            if iy[b:b + BLOCK].max() < 32:  # (the last row of patches, 5 rows, is one patch 50 wide)
                assert np.ptp(ix[b:b + BLOCK]) < 2 * width
            assert np.ptp(iy[b:b + BLOCK]) < 2 * PATCH * PATCH // width


def test_patch_shape_follows_the_spacing_of_rows_and_columns():
    x, y = np.meshgrid(np.arange(40) * 0.02, np.arange(80) * 0.005)  # columns 4x as far apart as rows
    polar_like = np.stack([x, y, np.zeros_like(x)], axis=-1)
    assert patch_shape(polar_like) == (PATCH // 2, BLOCK)  # 8 columns x 32 rows: 16 cm x 16 cm
    assert patch_shape(polar_like[..., [1, 0, 2]].transpose(1, 0, 2)) == (PATCH * 2, BLOCK)
    square = np.stack([*np.meshgrid(np.arange(30) * 0.004, np.arange(20) * 0.004), np.zeros((20, 30))], axis=-1)
    assert patch_shape(square) == (PATCH, BLOCK)
    assert patch_shape(square * 10) == (PATCH // 2, BLOCK // 4)  # 4 cm pixels: 8 x 8 patches of 32 cm
    assert patch_shape(square * 100) == (4, 16)  # the smallest patches, however coarse the grid


def test_turns_sin_cos_against_numpy():
    """The float32 block kernel's (cos, sin) of 2 pi t, t in turns: polynomial error 3e-6 (100 dB under the
    image; it replaced the half-turn version, 3e-7), plus t's own float32 rounding, whole turns exact."""
    turns = np.concatenate([np.linspace(-8, 8, 10001), np.linspace(-320, 320, 4001)]).astype(np.float32)
    got = np.array([_cos_sin_turns(t) for t in turns])
    angle = 2 * np.pi * turns.astype(np.float64)
    tol = 3e-6 + np.abs(angle) * 2.0 ** -23
    assert np.all(np.abs(got[:, 0] - np.cos(angle)) < tol)
    assert np.all(np.abs(got[:, 1] - np.sin(angle)) < tol)
    small = np.abs(turns) < 8
    assert np.abs(got[small, 1] - np.sin(angle[small])).max() > 1e-7  # a polynomial, not numpy's sin


def test_far_from_origin_kernel_stays_exact():
    # The same geometry 5 km out: float64 geometry keeps the phase; only rounding of the positions differs.
    near = backproject(*synthetic_case(np.random.default_rng(4))[:4], mode="linear")
    prof, tx, rx, points, _ = synthetic_case(np.random.default_rng(4), far=5000.0)
    far = backproject(prof, tx, rx, points, mode="linear")
    assert np.abs(far - near).max() < 1e-4 * np.abs(near).max()


def test_accumulates_into_out_and_keeps_grid_shape():
    rng = np.random.default_rng(5)
    prof, tx, rx, points, _ = synthetic_case(rng, n_points=300)
    grid = points[:300].reshape(10, 30, 3)
    whole = backproject(prof, tx, rx, grid)
    assert whole.shape == (10, 30)
    out = np.zeros((10, 30), complex)
    half = prof.data.shape[0] // 2
    for sl in (slice(0, half), slice(half, None)):
        part = type(prof)(prof.data[sl], prof.range_start_m, prof.range_step_m, prof.carrier_hz, prof.f0_hz, prof.frequency_step_hz)
        backproject(part, tx[sl], rx[sl], grid, out=out)
    np.testing.assert_allclose(out, whole, atol=1e-5 * np.abs(whole).max())


def test_bad_arguments():
    rng = np.random.default_rng(6)
    prof, tx, rx, points, _ = synthetic_case(rng)
    with pytest.raises(ValueError, match="no points"):
        backproject(prof, tx, rx, np.zeros((0, 3)))
    with pytest.raises(ValueError, match="unknown backprojection mode"):
        backproject(prof, tx, rx, points, mode="cubic")
    with pytest.raises(ValueError, match="P TX and RX"):
        backproject(prof, tx[:-1], rx, points)


def test_polynomial_sin_cos_against_numpy():
    phase = np.concatenate([np.linspace(-50, 50, 10001), 1.6e7 + np.linspace(0, 7, 1001)])
    got = np.array([_cos_sin(p) for p in phase])
    np.testing.assert_allclose(got[:, 0], np.cos(phase), atol=3e-7)
    np.testing.assert_allclose(got[:, 1], np.sin(phase), atol=3e-7)


@pytest.mark.parametrize("mode", ["linear", "exact"])
def test_out_accumulates_also_into_a_non_contiguous_view(mode):
    """``out`` may be a slice of a larger image (a strided view): the result lands in it, added to what it
    held, and nothing outside the view changes."""
    rng = np.random.default_rng(3)
    prof, tx, rx, points, _ = synthetic_case(rng, n_points=60)
    grid = points[:60].reshape(6, 10, 3)
    want = backproject(prof, tx, rx, grid, mode=mode)
    big = np.full((6, 20), 1.0 + 2.0j)
    view = big[:, ::2]
    assert not view.flags.c_contiguous
    got = backproject(prof, tx, rx, grid, mode=mode, out=view)
    assert got is view
    np.testing.assert_allclose(big[:, ::2], want + (1.0 + 2.0j), rtol=1e-12, atol=1e-9 * np.abs(want).max())
    np.testing.assert_array_equal(big[:, 1::2], 1.0 + 2.0j)
    with pytest.raises(ValueError, match="complex128 of shape"):
        backproject(prof, tx, rx, grid, mode=mode, out=np.zeros((6, 10), np.complex64))


@pytest.mark.parametrize("parallel", [True, False], ids=["parallel", "calling-thread"])
@pytest.mark.parametrize("far", [0.0, 5000.0])
@pytest.mark.parametrize("mode", ["nearest", "linear"])
def test_shared_tx_profiles_match_numpy_reference(mode, far, parallel):
    """Profiles in runs that share a TX (the RX channels of one chirp), as the float32 block kernel ranges
    that TX once per run: the same image as the numpy reference, on the parallel kernels and on the
    calling thread alone (``parallel=False``, FFBP's leaves)."""
    prof, tx, rx, grid = grid_case((40, 70), far)
    n_rx = 4
    tx = np.repeat(tx[::n_rx], n_rx, axis=0)[: tx.shape[0]]  # runs of 4 profiles with one TX, the RX apart
    assert np.array_equal(tx[1], tx[0]) and not np.array_equal(tx[n_rx], tx[0])
    got = backproject(prof, tx, rx, grid, mode=mode, parallel=parallel)
    want = backproject_reference(prof, tx, rx, grid, mode=mode)
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 2e-5 * scale
    # the same numbers either way: the block kernel's arithmetic does not depend on the threads
    other = backproject(prof, tx, rx, grid, mode=mode, parallel=not parallel)
    np.testing.assert_allclose(got, other, rtol=0, atol=1e-6 * scale)


def test_scattered_points_and_exact_mode_on_the_calling_thread():
    """The float64 kernel and the matched filter, on the calling thread: the same as the parallel ones."""
    prof, tx, rx, points, _ = synthetic_case(np.random.default_rng(5))
    for mode in ("linear", "exact"):
        a = backproject(prof, tx, rx, points, mode=mode, parallel=False)
        b = backproject(prof, tx, rx, points, mode=mode)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(b).max())
        want = backproject_reference(prof, tx, rx, points, mode=mode)
        assert np.abs(a - want).max() < 2e-5 * np.abs(want).max()


def test_full_width_vectors_where_the_cpu_has_avx512():
    """A fresh process that imports the kernels compiles for 512-bit vectors on an AVX-512 CPU (LLVM's
    prefer-256-bit tuning off), for numba's default elsewhere; an explicit NUMBA_CPU_FEATURES is kept."""
    import json
    import os
    import subprocess
    import sys

    import llvmlite.binding as llvm

    code = ("import json, os; import imaging.backprojection as b; "
            "print(json.dumps([os.environ.get('NUMBA_CPU_FEATURES'), b.compiled_target()]))")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME")}
    features, target = json.loads(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                                  check=True).stdout)
    host = llvm.get_host_cpu_features()
    if host.get("avx512f"):
        assert features.endswith(",-prefer-256-bit") and target["prefer_256_bit_off"] and target["vector_bits"] == 512
    else:
        assert features is None and not target["prefer_256_bit_off"]
    mine = host.flatten()
    features, target = json.loads(subprocess.run([sys.executable, "-c", code], env={**env, "NUMBA_CPU_FEATURES": mine},
                                                 capture_output=True, text=True, check=True).stdout)
    assert features == mine and not target["prefer_256_bit_off"]


@pytest.mark.parametrize("distance_m", [0.12, 2.0], ids=["near-square-root", "series"])
@pytest.mark.parametrize("far", [0.0, 5000.0])
def test_range_offsets_by_series_and_by_square_root_match_numpy_reference(distance_m, far):
    """The float32 block kernel's two forms of a pixel's range offset: g's Taylor series where the block is
    small against its distance from the antenna, the square root beside the antenna; each against the
    numpy reference, near the origin and 5 km out."""
    prof, tx, rx, grid = grid_case((48, 48), far)
    # Move the antennas so that the grid's centre is distance_m away from their centre.
    centre = grid[24, 24]
    shift = centre - [0.0, distance_m, 0.0] - tx.mean(axis=0)
    tx, rx = tx + shift, rx + shift
    radius = np.sqrt(2) * PATCH / 2 * 0.004
    u_n = np.linalg.norm(centre - tx, axis=1)
    assert all(series_applies(u, radius) for u in u_n) == (distance_m > 1.0)
    assert any(series_applies(u, radius) for u in u_n) == (distance_m > 1.0)
    # Echoes of a scatterer at the grid's centre, from the moved antennas.
    r = np.linalg.norm(tx - centre, axis=1) + np.linalg.norm(rx - centre, axis=1)
    n = np.arange(NS)
    prof = range_compress(np.exp(2j * np.pi / C * (F0 + FSTEP * n[None, :]) * r[:, None]), F0, FSTEP, oversample=8)
    got = backproject(prof, tx, rx, grid)
    want = backproject_reference(prof, tx, rx, grid)
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 2e-5 * scale
    assert abs(want[24, 24]) > 0.5 * prof.data.shape[0]  # the scatterer focuses (not vacuous)


def test_compact_and_wide_blocks_in_one_call_match_numpy_reference():
    """Each block of points takes the float32 or the float64 geometry by its own extent: one compact block
    (float32) and one scattered over metres (float64) in one call, each as the numpy reference."""
    prof, tx, rx, grid = grid_case((40, 70))
    compact = grid.reshape(-1, 3)[patch_order((40, 70))][:BLOCK]
    scattered = synthetic_case(np.random.default_rng(11))[3][:BLOCK]
    points = np.concatenate([compact, scattered])
    k = 2 * np.pi * prof.carrier_hz / C
    assert max_block_extent_m(*(compact[:, i] for i in range(3))) * k * 2.0 ** -24 <= PHASE_ROUNDING_RAD
    assert max_block_extent_m(*(scattered[:, i] for i in range(3))) * k * 2.0 ** -24 > PHASE_ROUNDING_RAD
    for parallel in (True, False):
        got = backproject(prof, tx, rx, points, parallel=parallel)
        want = backproject_reference(prof, tx, rx, points)
        for part in (slice(0, BLOCK), slice(BLOCK, None)):
            assert np.abs(got[part] - want[part]).max() < 2e-5 * np.abs(want[part]).max()


def midpoint_delta_m(g, tx, rx):
    """|g - tx| + |g - rx| - 2 |g - m|, m the antennas' midpoint: what the midpoint form leaves out."""
    m = 0.5 * (tx + rx)
    return np.linalg.norm(g - tx, axis=-1) + np.linalg.norm(g - rx, axis=-1) - 2 * np.linalg.norm(g - m, axis=-1)


def test_midpoint_remainder_and_fold_bounds_hold_and_are_close():
    """The bounds on delta's departure from its linear part over a block and on folding that linear part
    into the series' numerator (imaging/range_offsets.py), against both computed in float64 on the bounding
    sphere of random blocks: never exceeded, and not loose (within 2x and 5x for some), from half-baselines
    of 1 to 50 mm and blocks 0.1 to 5 m away."""
    rng = np.random.default_rng(12)
    ratios, fold_ratios = [], []
    for _ in range(400):
        distance, half, radius = rng.uniform(0.1, 5.0), rng.uniform(0.001, 0.05), rng.uniform(0.005, 0.1)
        if distance <= 2 * (radius + half):
            continue
        unit = rng.normal(size=(3, 3))
        unit /= np.linalg.norm(unit, axis=1, keepdims=True)
        centre, m, e = np.zeros(3), -distance * unit[0], half * unit[1]
        tx, rx = m + e, m - e
        d = rng.normal(size=(2000, 3))
        d *= radius / np.linalg.norm(d, axis=1, keepdims=True)
        u_tx, u_rx, u_m = centre - tx, centre - rx, centre - m
        gradient = u_tx / np.linalg.norm(u_tx) + u_rx / np.linalg.norm(u_rx) - 2 * u_m / np.linalg.norm(u_m)
        remainder = midpoint_delta_m(centre + d, tx, rx) - midpoint_delta_m(centre, tx, rx) - d @ gradient
        bound = midpoint_remainder_bound_m(distance, radius, half)
        if bound > 1e-11:  # far above float64's rounding of the ranges
            ratios.append(np.abs(remainder).max() / bound)
        # delta's gradient folded into the series' numerator: 2 sqrt(A^2 + |c - m| e.d) - 2 A against 2 A + e.d
        a = np.linalg.norm(u_m + d, axis=1)
        eps = d @ gradient
        folded = 2 * np.sqrt(a * a + distance * eps) - 2 * a
        fold, x = fold_bound_m(distance, radius, np.abs(gradient).sum())
        if x <= 0.5 and fold > 1e-11:
            fold_ratios.append(np.abs(folded - eps).max() / fold)
    assert len(ratios) > 300 and len(fold_ratios) > 100
    assert max(ratios) <= 1.0 and max(fold_ratios) <= 1.0
    assert max(ratios) > 0.5 and max(fold_ratios) > 0.2
    assert midpoint_remainder_bound_m(0.05, 0.04, 0.02) == np.inf  # the block reaches the antennas
    # the least distance of the series, found once per block: the condition holds there, not just before it
    for radius in (0.001, 0.0424, 0.3):
        u = series_min_distance(radius)
        assert series_applies(u, radius) and not series_applies(u * (1 - 1e-6), radius)
        assert series_applies(3 * u, radius)


def one_antenna_pass(baseline_m, far=0.0, n_profiles=64, shape=(48, 48), spacing_m=0.004):
    """A pass of one TX/RX pair ``baseline_m`` apart (each profile its own TX) along x, 2 m from a grid
    around a scatterer; near the origin or ``far`` metres out."""
    offset = np.array([far, -0.6 * far, 0.0])
    tx = np.stack([np.linspace(-0.5, 0.5, n_profiles), np.zeros(n_profiles), np.zeros(n_profiles)], axis=1) + offset
    rx = tx + np.asarray(baseline_m)
    ny, nx = shape
    centre = offset + [0.1, 2.0, 0.3]
    xx, yy = np.meshgrid(centre[0] + spacing_m * (np.arange(nx) - nx // 2), centre[1] + spacing_m * (np.arange(ny) - ny // 2))
    grid = np.stack([xx, yy, np.full_like(xx, centre[2])], axis=-1)
    r = np.linalg.norm(tx - centre, axis=1) + np.linalg.norm(rx - centre, axis=1)
    n = np.arange(NS)
    prof = range_compress(np.exp(2j * np.pi / C * (F0 + FSTEP * n[None, :]) * r[:, None]), F0, FSTEP, oversample=8)
    return prof, tx, rx, grid


@pytest.mark.parametrize("far", [0.0, 5000.0])
@pytest.mark.parametrize(("baseline_m", "form"), [((0.0, 0.0, 0.0), 1), ((0.004, 0.0, 0.0), 1), ((0.007, 0.0, 0.0), 2),
                                                  ((0.3, 0.0, 0.0), 0)],
                         ids=["monostatic-folded", "4mm-folded", "7mm-gradient-per-pixel", "wide-two-series"])
def test_one_antenna_pass_midpoint_forms_match_numpy_reference(baseline_m, form, far):
    """A one-antenna pass (no TX shared), every (block, profile) in one form (``midpoint_form``): one series
    on the antennas' midpoint per pixel with delta's gradient folded into it (monostatic, 4 mm apart), or
    added per pixel (7 mm), or the two series where the bound allows neither (0.3 m apart: the midpoint
    form would be 0.01 rad off there); each the numpy reference's image, near and 5 km out."""
    prof, tx, rx, grid = one_antenna_pass(baseline_m, far)
    k = 2 * np.pi * prof.carrier_hz / C
    # Every block is a 16 x 16 patch; its points lie within this radius of its centre.
    radius = np.hypot(7.5, 7.5) * 0.004
    patches = grid.reshape(3, PATCH, 3, PATCH, 3).transpose(0, 2, 1, 3, 4).reshape(9, -1, 3)
    centres = 0.5 * (patches.min(axis=1) + patches.max(axis=1))
    u_series = series_min_distance(radius * (1 + 0.5 * FOLD_GRADIENT_MAX))
    forms = {midpoint_form(*(c - t), np.linalg.norm(c - t), *(c - r), np.linalg.norm(c - r), radius,
                           0.5 * np.linalg.norm(t - r), u_series, MIDPOINT_PHASE_RAD / k)[0]
             for c in centres for t, r in zip(tx, rx)}
    assert forms == {form}
    if form == 1 and baseline_m[0] > 0.0:  # delta's gradient is there to fold (not vacuous)
        c, t, r = centres[0], tx[0], rx[0]
        e = (c - t) / np.linalg.norm(c - t) + (c - r) / np.linalg.norm(c - r) - 2 * (c - 0.5 * (t + r)) / np.linalg.norm(c - 0.5 * (t + r))
        assert np.linalg.norm(e) > 1e-6
    got = backproject(prof, tx, rx, grid)
    want = backproject_reference(prof, tx, rx, grid)
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 2e-5 * scale
    assert abs(want[24, 24]) > 0.5 * prof.data.shape[0]  # the scatterer focuses (not vacuous)
    assert MIDPOINT_PHASE_RAD <= 0.1 * PHASE_ROUNDING_RAD


def test_block_profile_table_equals_the_per_profile_values():
    """The per-(block, profile) table the kernel reads (imaging/block_profiles.py), computed for all profiles
    at once, against the values the kernel computed per profile inside its loop: the centre's bin and phase,
    the form (``midpoint_form`` for a TX alone, else the RX's series or square root; the TX's offsets where
    its TX is new) and each form's coefficients. Random blocks 0.05-3 m from the antennas (square roots and
    series), chirps of one or three RX on one TX, baselines of 0 to 300 mm, near and 5 km out."""
    import math

    from imaging import block_profiles as bpt
    rng = np.random.default_rng(34)
    n = 150  # more than one group of TABLE_PROFILES
    k = 2 * np.pi * 77e9 / C
    r0, inv_dr, hi = -0.3, 1.0 / 0.0047, 2800.0
    tol_m = MIDPOINT_PHASE_RAD / k
    forms_seen = set()
    for trial in range(40):
        far = 5000.0 if trial % 2 else 0.0
        offset = np.array([far, -0.6 * far, 0.0])
        # Chirps: each TX position held by 1 or 3 consecutive profiles (RX channels)
        per_tx = rng.choice([1, 3], size=n)
        tx_pos = rng.uniform(-0.5, 0.5, (n, 3)) * [1, 0.1, 0.1] + offset
        tx = np.repeat(tx_pos, per_tx, axis=0)[:n]
        baseline = rng.choice([0.0, 0.004, 0.007, 0.3]) * rng.uniform(0.5, 1.0)
        rx = tx + rng.normal(size=(n, 3)) * baseline / math.sqrt(3)
        r_ref = rng.uniform(0, 3, n) * (trial % 3 == 0)
        radius = rng.uniform(0.01, 0.05)
        centre = offset + [0.0, rng.choice([0.05, 0.3, 2.0, 3.0]), 0.3]
        groups = bpt.profile_rows(tx, rx, r_ref, 0, n)
        u_one, u_mid = bpt.block_series_distances(radius)
        assert u_one == series_min_distance(radius)
        assert u_mid == series_min_distance(radius * (1 + 0.5 * FOLD_GRADIENT_MAX))
        for g in range(groups.shape[0]):
            q0 = g * bpt.TABLE_PROFILES
            n_q = min(bpt.TABLE_PROFILES, n - q0)
            table = np.full(bpt.TABLE_SIZE, np.nan, np.float32)
            ints = np.zeros(bpt.INT_TABLE_SIZE, np.int32)
            bpt.block_profile_table(*centre, radius, u_one, u_mid, groups[g], n_q, r0, inv_dr, hi, k, tol_m, table, ints)
            for j in range(n_q):
                p, t = q0 + j, table
                new_tx = j == 0 or np.any(tx[p] != tx[p - 1])
                alone = new_tx and not (j + 1 < n_q and np.all(tx[p + 1] == tx[p]))
                ua_v, ub_v = centre - tx[p], centre - rx[p]
                ua, ub = np.linalg.norm(ua_v), np.linalg.norm(ub_v)
                dr_c = ua + ub - r_ref[p]
                pos_c = (dr_c - r0) * inv_dr + 1.0
                base = math.floor(pos_c)
                assert ints[bpt.IBASE + j] == base
                assert abs(t[bpt.FRAC_C + j] - (pos_c - base)) < 1e-6
                assert t[bpt.LO + j] == np.float32(-base) and t[bpt.TOP + j] == np.float32(hi - base)
                turns = k * dr_c / (2 * np.pi)
                assert abs(t[bpt.TURNS_C + j] - (turns - math.floor(turns + 0.5))) < 1e-6 + 1e-16 * abs(turns)
                half = 0.5 * np.linalg.norm(tx[p] - rx[p])
                form, c0, c1, c2, e0, e1, e2, inv_m = (midpoint_form(*ua_v, ua, *ub_v, ub, radius, half, u_mid, tol_m)
                                                       if alone else (0,) * 8)
                code = ints[bpt.CODE + j]
                got = code & bpt.FORM_MASK
                forms_seen.add(int(got))
                if form:
                    assert got == form
                    assert np.allclose([t[bpt.V0 + j], t[bpt.V1 + j], t[bpt.V2 + j]], [c0, c1, c2], rtol=1e-6, atol=1e-6)
                    assert np.allclose([t[bpt.E0 + j], t[bpt.E1 + j], t[bpt.E2 + j]], [e0, e1, e2], rtol=1e-6, atol=1e-9)
                    assert np.allclose([t[bpt.SV0 + j], t[bpt.SV1 + j]], [2 * inv_m, inv_m * inv_m], rtol=1e-6)
                    continue
                a_series, b_series = ua >= u_one, ub >= u_one
                assert series_applies(ua, radius) == a_series and series_applies(ub, radius) == b_series
                if alone and a_series and b_series:
                    assert got == bpt.FORM_TWO_SERIES
                else:
                    assert got == (bpt.FORM_RX_SERIES if b_series else bpt.FORM_RX_ROOT)
                    assert bool(code & bpt.NEW_TX_OFFSETS) == new_tx and bool(code & bpt.TX_SERIES) == a_series
                assert np.allclose([t[bpt.V0 + j], t[bpt.V1 + j], t[bpt.V2 + j]], 2 * ua_v, rtol=1e-6)
                assert np.allclose([t[bpt.B0 + j], t[bpt.B1 + j], t[bpt.B2 + j]], 2 * ub_v, rtol=1e-6)
                assert np.allclose([t[bpt.SV0 + j], t[bpt.SV1 + j], t[bpt.SB0 + j], t[bpt.SB1 + j]],
                                   [1 / ua, 1 / ua ** 2, 1 / ub, 1 / ub ** 2], rtol=1e-6)
                assert np.allclose([t[bpt.A_N + j], t[bpt.A_N2 + j], t[bpt.B_N + j], t[bpt.B_N2 + j]],
                                   [ua, ua ** 2, ub, ub ** 2], rtol=1e-6)
    # every form occurs (not vacuous)
    assert forms_seen == {bpt.FORM_FOLDED, bpt.FORM_GRADIENT, bpt.FORM_TWO_SERIES, bpt.FORM_RX_SERIES, bpt.FORM_RX_ROOT}


def test_block_profile_table_compiles_without_masked_stores():
    """The table's loop stores every row plainly: a choice around a stored value (``table[V0 + j] =
    np.float32(a if c else b)``) had LLVM store it twice under complementary masks, ``vmaskmovps`` on AVX2,
    slow on AMD's cores. The optimised IR has no ``llvm.masked.store`` (on a CPU without AVX, where none is
    legal, this holds trivially)."""
    from imaging import block_profiles as bpt
    prof = np.zeros(bpt.PROFILE_TABLE_SIZE)
    table = np.zeros(bpt.TABLE_SIZE, np.float32)
    ints = np.zeros(bpt.INT_TABLE_SIZE, np.int32)
    bpt.block_profile_table(0.0, 1.0, 0.0, 0.04, 0.5, 0.5, prof, 4, 0.0, 200.0, 100.0, 1600.0, 1e-9, table, ints)
    llvm_ir = bpt.block_profile_table.inspect_llvm(bpt.block_profile_table.signatures[0])
    assert "for.body" in llvm_ir or "define" in llvm_ir  # the IR itself, not an empty string
    assert "llvm.masked.store" not in llvm_ir
