"""FFBP's plan, built a step of the tree at a time (``imaging.ffbp_placement``), is the plan the node-at-a-time
builder made (tests/reference_ffbp_plan.py): the same trees, roots and grid sizes, the same geometry to float
rounding, so the same image. On the benchmark's 2 m aperture, straight, bent, vibrating and stopping tracks, a
ragged profile count, a plane below the track, a strip map's rotated footprint and a plan that goes direct."""

import numpy as np
import pytest

import imaging.factorized_backprojection as ffbp
import reference_ffbp_plan
import reference_ffbp_plan_batched
from imaging.core.geometry import Vibration, antenna_track, chirp_times_ns
from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns, StraightLine
from imaging.factorized_backprojection import FactorizedOptions, plan_factorized, run_factorized
from imaging.range_compression import range_compress
from reference_ffbp_plan import plan_factorized_reference
from reference_ffbp_plan_batched import plan_factorized_batched
from test_factorized_backprojection import direct, error_db, pass_case

RADAR = default_rig().radar("left_front")
WF = RADAR.waveform
_PROFILE = range_compress(np.ones((1, WF.samples_per_chirp), complex), WF.f0_hz, WF.frequency_step_hz, oversample=8, guarded=True)
CARRIER_HZ, BANDWIDTH_HZ = _PROFILE.carrier_hz, _PROFILE.bandwidth_hz


def track(n_frames: int, trajectory=None, vibration=None):
    """TX and RX positions of the left-front radar's 16 channels on a 0.4 m/s pass (as pass_case, no echoes)."""
    traj = trajectory or StraightLine(start_m=(-0.15 - 0.4 * n_frames * WF.frame_interval_s / 2, -0.2, 0.0), speed_mps=0.4)
    ft = np.arange(n_frames, dtype=np.int64) * int(WF.frame_interval_s * 1e9)
    times = chirp_times_ns(ft, WF.chirps_per_frame, WF.chirp_interval_s).ravel()
    t = antenna_track(RADAR, traj, times, np.tile(WF.tdm_tx_order(), n_frames), vibration=vibration)
    return np.repeat(t.tx_m, WF.n_rx, axis=0), t.rx_m.reshape(-1, 3)


def assert_same_plan(new, old):
    def nodes(plan):
        return sorted(plan.nodes(), key=lambda n: (n.start, n.stop))

    assert [(r.start, r.stop, r.direct) for r in new.roots] == [(r.start, r.stop, r.direct) for r in old.roots]
    a_nodes, b_nodes = nodes(new), nodes(old)
    assert len(a_nodes) == len(b_nodes)
    for a, b in zip(a_nodes, b_nodes):
        assert (a.start, a.stop, a.level, a.nr, a.na, a.direct, len(a.children)) == \
               (b.start, b.stop, b.level, b.nr, b.na, b.direct, len(b.children)), (a.start, a.stop)
        # centre, axis, normal, r0, dr, a0, da: rounding apart (sums in another order), nothing more.
        np.testing.assert_allclose(a.geometry, b.geometry, rtol=1e-11, atol=1e-12)
    assert new.cost() == old.cost()
    assert new.error_bound_db == old.error_bound_db and new.levels == old.levels


def both(*args, **kwargs):
    return plan_factorized(*args, **kwargs), plan_factorized_reference(*args, **kwargs)


def test_the_benchmarks_2_m_aperture_gets_the_same_plan():
    """benchmarks/ffbp.py's case: 96 frames (2 m, 98304 profiles) onto 1 m x 0.6 m at 2 mm, default settings:
    4 roots of 6 levels, 380 nodes, all alike."""
    tx, rx = track(96)
    x, y = np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002)
    new, old = both(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ)
    assert len(new.roots) == 4 and new.levels == 6 and sum(1 for _ in new.nodes()) == 380
    assert_same_plan(new, old)


def _stop_track():
    """Standing still for two frames mid-pass (every phase centre of those leaves repeats per channel)."""
    tx, rx = track(12)
    tx, rx = tx.copy(), rx.copy()
    tx[2048:4096], rx[2048:4096] = tx[2048], rx[2048]
    return tx, rx


@pytest.mark.parametrize("case", ["straight", "uniform leaves", "ragged", "bend", "vibration", "stop"])
def test_tracks_get_the_same_plan(case):
    options = FactorizedOptions(leaf_profiles=256)
    if case == "bend":
        tx, rx = track(24, PathWithTurns(segments=(("arc", 4.0, 7.0),), start_m=(-0.4, -0.25, 0.0), heading_deg=-3.5, speed_mps=0.4))
    elif case == "vibration":
        tx, rx = track(24, vibration=Vibration(3.83, 0.319e-3, 0.7))
    elif case == "stop":
        tx, rx = _stop_track()
    else:
        tx, rx = track(24)
    if case == "uniform leaves":
        options = FactorizedOptions(leaf_profiles=512, leaf_oversample=None, leaf_taps=None, taps=4, oversample_range=3)
    if case == "ragged":  # leaves and nodes of many lengths, the last leaf short
        tx, rx, options = tx[:10000], rx[:10000], FactorizedOptions(leaf_profiles=384)
    x, y = np.arange(-0.4, 0.4, 0.005), np.arange(1.6, 2.4, 0.005)
    new, old = both(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, options)
    assert new.levels >= 3
    assert_same_plan(new, old)


def test_a_plane_below_the_track_and_a_rotated_footprint_get_the_same_plan():
    """The plane 0.45 m below a short track reaching far along it (a grid corner on the axis), and a strip
    map's footprint (a rotated rectangle inside the pixels' bounding box, ``outline_xy``)."""
    n_p = 2048
    centres = np.stack([np.linspace(-0.3, 0.3, n_p), np.zeros(n_p), np.full(n_p, 0.45)], 1)
    x, y = np.arange(-1.5, 1.5, 0.01), np.arange(0.5, 1.3, 0.01)
    assert_same_plan(*both(centres, centres, x, y, 0.0, CARRIER_HZ, BANDWIDTH_HZ, FactorizedOptions(leaf_profiles=128)))
    tx, rx = track(24)
    x, y = np.arange(-0.5, 0.5, 0.005), np.arange(1.5, 2.5, 0.005)
    corners = np.array([[-0.3, -0.2], [0.3, -0.2], [0.3, 0.2], [-0.3, 0.2], [-0.3, -0.2]])
    turn = np.radians(12)
    corners = corners @ np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]]) + [0.0, 2.0]
    outline = np.concatenate([a + (b - a) * np.linspace(0, 1, 32, endpoint=False)[:, None] for a, b in zip(corners[:-1], corners[1:])])
    new, old = both(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, FactorizedOptions(leaf_profiles=256), outline_xy=outline)
    assert new.levels >= 3
    assert_same_plan(new, old)


def test_a_plan_that_goes_direct_and_a_refused_image_are_as_before(monkeypatch):
    tx, rx = track(2)
    x, y = np.arange(-0.3, 0.3, 0.01), np.arange(1.7, 2.1, 0.01)
    normal = plan_factorized(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, FactorizedOptions(leaf_profiles=256))
    largest = max(n.nr * n.na for n in normal.nodes() if not n.direct)
    for module in (ffbp, reference_ffbp_plan):
        monkeypatch.setattr(module, "MAX_GRID_PER_PIXEL", 0.9 * largest / max(x.size * y.size, 4096))
    new, old = both(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, FactorizedOptions(leaf_profiles=256))
    assert new.direct_only
    assert_same_plan(new, old)
    messages = []
    for build in (plan_factorized, plan_factorized_reference):
        with pytest.raises(ValueError, match="one side of the radar's track") as refused:
            build(tx, rx, x, np.linspace(-1.0, 1.0, 20), 0.3, CARRIER_HZ, BANDWIDTH_HZ)
        messages.append(str(refused.value))
    assert messages[0] == messages[1] and "the track of profiles 0-2048 passes" in messages[0]


def test_the_image_is_the_same():
    """A 0.5 m pass onto 0.8 m x 0.5 m at 4 mm: the image of either plan is the other's to float32 rounding,
    and its error against the direct kernel the same to 0.01 dB."""
    prof, tx, rx = pass_case(24)
    x, y = np.arange(-0.4, 0.4, 0.004), np.arange(1.7, 2.2, 0.004)
    new, old = both(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions(leaf_profiles=256))
    img_new, img_old = run_factorized(new, prof, tx, rx), run_factorized(old, prof, tx, rx)
    np.testing.assert_allclose(img_new, img_old, rtol=0, atol=1e-5 * np.abs(img_old).max())
    ref = direct(prof, tx, rx, x, y)
    assert error_db(img_new, ref) < -40.0
    assert abs(error_db(img_new, ref) - error_db(img_old, ref)) < 0.01


_FAULTS_OF_A_PLAN = """
import json, resource, sys
import numpy as np
from imaging.factorized_backprojection import plan_factorized
with np.load(sys.argv[1]) as case:  # (an npz reads an array anew at every access)
    args = (case["tx"], case["rx"], case["x"], case["y"], 0.3, float(case["carrier_hz"]), float(case["bandwidth_hz"]))
faults = []
for _ in range(3):
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    plan_factorized(*args)
    faults.append(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)
print(json.dumps(faults))
"""


def test_a_plan_takes_few_new_pages_where_the_allocator_maps_every_large_block_afresh(tmp_path):
    """glibc maps a block above its mmap threshold afresh (new pages, a fault each) until the process has freed
    a large one, as in a fresh ``sarbot image``: the plan's cost must not hang on it. The 2 m case's plan made
    ~26 MB of nodes x points temporaries, 6,550-6,870 faults a plan with the threshold held at 128 KiB (measured
    on the code before); its served points' pass now runs a node at a time in numba, and a plan faults in its
    phase centres' columns (3 x 768 KiB, 576 pages), the image's distance from the nodes' axes (~700) and the
    grids' edges (~250): 1,630-2,050 measured."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    tx, rx = track(96)
    np.savez(tmp_path / "case.npz", tx=tx, rx=rx, x=np.arange(-0.5, 0.5, 0.002), y=np.arange(1.7, 2.3, 0.002),
             carrier_hz=CARRIER_HZ, bandwidth_hz=BANDWIDTH_HZ)
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "131072", "MALLOC_TRIM_THRESHOLD_": "131072"}
    out = subprocess.run([sys.executable, "-c", _FAULTS_OF_A_PLAN, str(tmp_path / "case.npz")], cwd=root, env=env,
                         capture_output=True, text=True, check=True).stdout
    repeats = json.loads(out)[1:]  # the first also loads the kernels
    assert max(repeats) < 3000, repeats


# -- the planner against the one before it (tests/reference_ffbp_plan_batched.py), to the bit -----------------
def assert_identical_plan(new, old):
    """Every node's profiles, level, children, direct flag, grid sizes and geometry (centre, axis, normal, r0,
    dr, a0, da) equal to the bit, the roots in the same order."""
    def walk(plan):
        return [(n.start, n.stop, n.level, n.nr, n.na, n.direct, len(n.children)) for n in plan.nodes()]

    assert [(r.start, r.stop, r.direct) for r in new.roots] == [(r.start, r.stop, r.direct) for r in old.roots]
    assert walk(new) == walk(old)  # the same traversal: the same trees, children in the same order
    for a, b in zip(new.nodes(), old.nodes()):
        assert a.geometry.tobytes() == b.geometry.tobytes(), (a.start, a.stop, a.geometry - b.geometry)
        assert type(a.nr) is int and type(a.r0_m) is float  # as before: Python numbers, not numpy scalars
    assert new.cost() == old.cost() and new.levels == old.levels


def _identical_case(case: str):
    """(args, kwargs) of plan_factorized for the cases the planner is held to the one before on."""
    x, y = np.arange(-0.4, 0.4, 0.005), np.arange(1.6, 2.4, 0.005)
    if case == "2 m aperture":
        tx, rx = track(96)
        return (tx, rx, np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002), 0.3, CARRIER_HZ, BANDWIDTH_HZ), {}
    if case == "curved track":
        tx, rx = track(24, PathWithTurns(segments=(("arc", 4.0, 7.0),), start_m=(-0.4, -0.25, 0.0), heading_deg=-3.5, speed_mps=0.4))
    elif case == "vibration":
        tx, rx = track(24, vibration=Vibration(3.83, 0.319e-3, 0.7))
    elif case == "stop":
        tx, rx = _stop_track()
    elif case == "ragged":
        tx, rx = (v[:10000] for v in track(24))
        return (tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ), {"options": FactorizedOptions(leaf_profiles=384)}
    elif case == "plane below the track":
        n_p = 2048
        centres = np.stack([np.linspace(-0.3, 0.3, n_p), np.zeros(n_p), np.full(n_p, 0.45)], 1)
        return ((centres, centres, np.arange(-1.5, 1.5, 0.01), np.arange(0.5, 1.3, 0.01), 0.0, CARRIER_HZ, BANDWIDTH_HZ),
                {"options": FactorizedOptions(leaf_profiles=128)})
    elif case == "rotated footprint":
        tx, rx = track(24)
        turn = np.radians(12)
        corners = np.array([[-0.3, -0.2], [0.3, -0.2], [0.3, 0.2], [-0.3, 0.2], [-0.3, -0.2]])
        corners = corners @ np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]]) + [0.0, 2.0]
        outline = np.concatenate([a + (b - a) * np.linspace(0, 1, 32, endpoint=False)[:, None] for a, b in zip(corners[:-1], corners[1:])])
        return ((tx, rx, np.arange(-0.5, 0.5, 0.005), np.arange(1.5, 2.5, 0.005), 0.3, CARRIER_HZ, BANDWIDTH_HZ),
                {"options": FactorizedOptions(leaf_profiles=256), "outline_xy": outline})
    else:
        raise AssertionError(case)
    return (tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ), {"options": FactorizedOptions(leaf_profiles=256)}


@pytest.mark.parametrize("case", ["2 m aperture", "curved track", "vibration", "stop", "ragged", "plane below the track",
                                  "rotated footprint"])
def test_the_plan_is_the_batched_planners_to_the_bit(case):
    """The planner that keeps the tree in arrays and frames every node in one pass makes the plan the batched
    planner made (a step of the tree a pass, Python objects throughout), bit for bit, so the same image."""
    args, kwargs = _identical_case(case)
    new, old = plan_factorized(*args, **kwargs), plan_factorized_batched(*args, **kwargs)
    assert sum(1 for _ in new.nodes()) >= 7 and not new.direct_only  # (below the track: many roots of one leaf)
    assert_identical_plan(new, old)


def test_a_plan_that_goes_direct_and_a_refused_image_are_the_batched_planners(monkeypatch):
    tx, rx = track(2)
    x, y = np.arange(-0.3, 0.3, 0.01), np.arange(1.7, 2.1, 0.01)
    options = FactorizedOptions(leaf_profiles=256)
    largest = max(n.nr * n.na for n in plan_factorized(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, options).nodes())
    for module in (ffbp, reference_ffbp_plan_batched):
        monkeypatch.setattr(module, "MAX_GRID_PER_PIXEL", 0.9 * largest / max(x.size * y.size, 4096))
    new = plan_factorized(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, options)
    assert new.direct_only
    assert_identical_plan(new, plan_factorized_batched(tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ, options))
    messages = []
    for build in (plan_factorized, plan_factorized_batched):
        with pytest.raises(ValueError, match="one side of the radar's track") as refused:
            build(tx, rx, x, np.linspace(-1.0, 1.0, 20), 0.3, CARRIER_HZ, BANDWIDTH_HZ)
        messages.append(str(refused.value))
    assert messages[0] == messages[1]


def test_the_identity_check_can_fail():
    """A plan one node of which is off by one ulp in r0 (or one sample in nr) is told apart."""
    args, kwargs = _identical_case("ragged")
    new, old = plan_factorized(*args, **kwargs), plan_factorized_batched(*args, **kwargs)
    node = next(n for n in new.nodes() if not n.children)
    node.r0_m = float(np.nextafter(node.r0_m, np.inf))
    with pytest.raises(AssertionError):
        assert_identical_plan(new, old)
    node.r0_m = float(np.nextafter(node.r0_m, -np.inf))
    assert_identical_plan(new, old)
    node.nr += 1
    with pytest.raises(AssertionError):
        assert_identical_plan(new, old)


_PLAN_AFTER_PREPARATION = """
import json, sys
import numpy as np
from imaging import kernel_import
import imaging.ffbp_placement as placement
kernel_import.prepare_kernels(ffbp=True)  # as sarbot image --algorithm ffbp does on its background thread
passes = {name: getattr(placement, name) for name in ("_moments", "_extremes", "_served_extent", "_grid_edges")}
before = {name: [str(s) for s in p.signatures] for name, p in passes.items()}
from imaging.factorized_backprojection import plan_factorized
with np.load(sys.argv[1]) as case:
    plan_factorized(case["tx"], case["rx"], case["x"], case["y"], 0.3, float(case["carrier_hz"]), float(case["bandwidth_hz"]))
print(json.dumps([before, {name: [str(s) for s in p.signatures] for name, p in passes.items()}]))
"""


def test_the_background_preparation_loads_every_pass_a_plan_calls(tmp_path):
    """``imaging.kernel_import.prepare_kernels(ffbp=True)`` (sarbot image's start-up thread) loads the plan's
    numba passes with the very argument types a plan gives them, so that a process's first plan loads and
    compiles nothing (a pass given an axis as eigh returns it, not contiguous, would be another signature)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    tx, rx = track(12)
    np.savez(tmp_path / "case.npz", tx=tx, rx=rx, x=np.arange(-0.3, 0.3, 0.005), y=np.arange(1.8, 2.2, 0.005),
             carrier_hz=CARRIER_HZ, bandwidth_hz=BANDWIDTH_HZ)
    out = subprocess.run([sys.executable, "-c", _PLAN_AFTER_PREPARATION, str(tmp_path / "case.npz")],
                         cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, check=True).stdout
    before, after = json.loads(out)
    assert all(len(signatures) == 1 for signatures in before.values()), before
    assert after == before


def test_the_grid_edges_pass_is_the_numpy_edges_to_the_bit():
    """imaging.ffbp_placement.grid_edges (a numba pass) against the numpy broadcasts it replaced
    (tests/reference_ffbp_placement_batched.py), on random grids from 1 x 1 to 500 x 300 samples, some with
    fewer rows or columns than edge points (repeats masked), each written for two children."""
    import imaging.ffbp_placement as placement
    import reference_ffbp_placement_batched as before

    rng = np.random.default_rng(7)
    n = 40
    u = rng.normal(size=(n, 2))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    args = (rng.normal(size=(n, 3)), u, np.stack([-u[:, 1], u[:, 0]], axis=1), rng.uniform(1, 3, n), rng.uniform(1e-4, 1e-2, n),
            rng.uniform(-0.5, 0.2, n), rng.uniform(1e-4, 1e-2, n), rng.integers(1, 500, n), rng.integers(1, 300, n), 0.3)
    args[7][:4], args[8][4:8] = [1, 2, 63, 65], [1, 3, 64, 100]
    x, y, valid = placement.grid_edges(*args, copies=2)
    ex, ey, evalid = before.grid_edges(*args)
    for new, old in ((x, ex), (y, ey), (valid, evalid)):
        assert new[0::2].tobytes() == old.tobytes() and new[1::2].tobytes() == old.tobytes()
    assert 0 < valid.sum() < valid.size  # some repeats masked
