"""Larger kernel blocks (issue 34, the one-antenna pass): what a block of 512 or 1,024 points instead of 256
does to the range-offset forms and to the kernel's speed.

The per-(block, profile) table (imaging/block_profiles.py) costs the same per block whatever its size, so a
block four times larger divides its share by four; but a larger block has a larger radius, and the range
offsets' series (imaging/range_offsets.py) holds within SERIES_TOLERANCE_M only beyond a distance that grows
with it (``series_min_distance``: about r^(7/6)). Below it a (block, profile) falls back to the square roots
(FORM_RX_ROOT), which cost a square root and a division per pixel and antenna.

Two parts, on the kernel_versions benchmark's two cases (the benchmark case: 16 frames of the left-front radar,
16 channels; the one-antenna pass: 4,096 chirps of TX 0 / RX 0; both onto 256 x 256 pixels of 1/256 m, scene
1.5-2.5 m from the track):

``forms``  for each block shape (columns, points) the share of (block, profile) pairs per range-offset form,
           with the series' tolerance as it is and at MIDPOINT_PHASE_RAD / k (the midpoint form's, -100 dB);
``speed``  the production kernel (``imaging.backprojection.backproject``) with each block shape in turn
           (``patch_shape`` replaced; the kernel takes the block as an argument, nothing recompiles),
           alternating in one process, CPU time and wall time, 1 and 2 threads; each shape's SER against
           the exact matched filter. The ratio is the 256-point block's CPU time over the shape's, the
           median over rounds.

    python benchmarks/block_sizes.py [--rounds N] [--series-tolerance M] [--name NAME]

``--series-tolerance`` compiles the kernel afresh (a numba cache of its own) with SERIES_TOLERANCE_M set to M
metres. Writes docs/results/block_sizes.json (NAME.json with ``--name``), with the load average: the machine
is shared.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: (columns, points) of the block shapes compared; the first is the kernel's own for this grid.
SHAPES = ((16, 256), (32, 512), (16, 512), (32, 1024))
FORM_NAMES = {1: "folded", 2: "gradient", 3: "two_series", 4: "rx_series", 5: "rx_root"}


def series_min_distance_m(radius_m: float, tolerance_m: float) -> float:
    """``imaging.range_offsets.series_min_distance`` for another tolerance (the same bisection, in Python)."""
    from imaging.range_offsets import _G_NEXT

    def applies(u: float) -> bool:
        t = (2.0 * u * radius_m + radius_m * radius_m) / (u * u)
        return t < 0.5 and u * _G_NEXT * t ** 7 <= tolerance_m

    lo, hi = radius_m, 8.0 * radius_m
    while not applies(hi):
        lo, hi = hi, 2.0 * hi
    while hi - lo > 1e-7 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if applies(mid) else (mid, hi)
    return hi


def form_shares(tx, rx, grid, width: int, points: int, k: float, tolerance_m: float) -> tuple[dict, float]:
    """Share of (block, profile) pairs per form for blocks of ``points`` walked ``width`` columns wide, with the
    series' tolerance ``tolerance_m``; and the largest block radius (metres)."""
    import numpy as np

    from imaging import block_profiles as bpf
    from imaging.patches import SUB_PATCH, patch_order
    from imaging.range_offsets import FOLD_GRADIENT_MAX, MIDPOINT_PHASE_RAD

    flat = grid.reshape(-1, 3)[patch_order(grid.shape[:-1], width, points, SUB_PATCH)]
    n_p = tx.shape[0]
    groups = bpf.profile_rows(tx, rx, np.zeros(n_p), 0, n_p)
    table, ints = np.empty(bpf.TABLE_SIZE, np.float32), np.empty(bpf.INT_TABLE_SIZE, np.int32)
    counts = np.zeros(bpf.FORM_MASK + 1, np.int64)
    worst = 0.0
    for b0 in range(0, flat.shape[0], points):
        p = flat[b0:b0 + points]
        c = 0.5 * (p.min(axis=0) + p.max(axis=0))
        d = (p - c).astype(np.float32)
        radius = math.sqrt(float((d * d).sum(axis=1).max()))
        worst = max(worst, radius)
        u_one = series_min_distance_m(radius, tolerance_m)
        u_mid = series_min_distance_m(radius * (1.0 + 0.5 * FOLD_GRADIENT_MAX), tolerance_m)
        for g in range(groups.shape[0]):
            n_q = min(bpf.TABLE_PROFILES, n_p - g * bpf.TABLE_PROFILES)
            bpf.block_profile_table(c[0], c[1], c[2], radius, u_one, u_mid, groups[g], n_q, 0.0, 1.0, 1e9, k,
                                    MIDPOINT_PHASE_RAD / k, table, ints)
            np.add.at(counts, ints[bpf.CODE:bpf.CODE + n_q] & bpf.FORM_MASK, 1)
    total = counts.sum()
    return {name: float(counts[code] / total) for code, name in FORM_NAMES.items()}, worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--series-tolerance", type=float, default=None, help="SERIES_TOLERANCE_M for the kernel, metres")
    ap.add_argument("--name", default="block_sizes")
    args = ap.parse_args()
    tmp = None
    if args.series_tolerance is not None:
        # The kernel's constants are frozen when numba compiles it: a cache of its own, compiled afresh.
        tmp = tempfile.TemporaryDirectory()
        os.environ["NUMBA_CACHE_DIR"] = tmp.name
    sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
    import numba
    import numpy as np

    import imaging.range_offsets as ro

    if args.series_tolerance is not None:
        ro.SERIES_TOLERANCE_M = args.series_tolerance
    import imaging.backprojection as bp
    from backprojection import make_case, ser_db
    from kernel_versions import cpu_hz, current_commit, uptime
    from peers import one_antenna_case
    from results_file import load_average, probe_machine, write_results

    from imaging.core.constants import SPEED_OF_LIGHT_MPS
    from imaging.range_compression import range_compress

    started_load, uptime_before = load_average(), uptime()
    probe_machine()  # the VM's speed before; write_results probes after
    hz = cpu_hz() or float("nan")
    own_shape = bp.patch_shape
    result = {"commit": current_commit(), "rounds": args.rounds, "series_tolerance_m": ro.SERIES_TOLERANCE_M,
              "cpu_hz": hz, "shapes": [list(s) for s in SHAPES]}
    makers = {"one_antenna": lambda: one_antenna_case(4096, 256, 256), "benchmark": lambda: make_case(16, 256, 256)}
    try:
        for name, make in makers.items():
            samples, wf, tx, rx, grid = make()
            prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, guarded=True)
            k = 2.0 * math.pi * prof.carrier_hz / SPEED_OF_LIGHT_MPS
            work = tx.shape[0] * grid.shape[0] * grid.shape[1]
            case = result[name] = {"backprojections": work, "forms": {}, "ser_db": {}, "threads": {}}
            for tol_name, tol in (("series_tolerance", ro.SERIES_TOLERANCE_M),
                                  ("midpoint_tolerance", ro.MIDPOINT_PHASE_RAD / k)):
                for width, points in SHAPES:
                    shares, radius = form_shares(tx, rx, grid, width, points, k, tol)
                    case["forms"].setdefault(tol_name, {"tolerance_m": tol})[f"{width}x{points // width}"] = {
                        "radius_m": radius, **shares}
                    print(f"{name}, tolerance {tol:.2e} m, {width}x{points // width}: radius {radius:.4f} m, "
                          + ", ".join(f"{f} {v:.3f}" for f, v in shares.items()), flush=True)
            exact = bp.backproject(prof, tx, rx, grid[::8, ::8], mode="exact")

            def run(shape):
                bp.patch_shape = lambda _grid, shape=shape: shape
                try:
                    return bp.backproject(prof, tx, rx, grid)
                finally:
                    bp.patch_shape = own_shape

            for width, points in SHAPES:
                case["ser_db"][f"{width}x{points // width}"] = ser_db(run((width, points))[::8, ::8], exact)
            for threads in (1, 2):
                numba.set_num_threads(threads)
                cpu = {s: [] for s in SHAPES}
                wall = {s: [] for s in SHAPES}
                for _ in range(args.rounds):
                    for shape in SHAPES:
                        c, t = time.process_time(), time.perf_counter()
                        run(shape)
                        cpu[shape].append(time.process_time() - c)
                        wall[shape].append(time.perf_counter() - t)
                base = SHAPES[0]
                case["threads"][threads] = {f"{w}x{p // w}": {
                    "cpu_speedup_median": statistics.median(b / s for b, s in zip(cpu[base], cpu[(w, p)])),
                    "wall_speedup_median": statistics.median(b / s for b, s in zip(wall[base], wall[(w, p)])),
                    "cycles_per_backprojection_best": min(cpu[(w, p)]) * hz / work,
                    "cycles_per_backprojection_median": statistics.median(cpu[(w, p)]) * hz / work,
                } for w, p in SHAPES}
                for key, r in case["threads"][threads].items():
                    print(f"{name}, {threads} thread(s), {key}: CPU time {r['cpu_speedup_median']:.3f}x the 16x16 "
                          f"block's speed (wall {r['wall_speedup_median']:.3f}x), "
                          f"{r['cycles_per_backprojection_median']:.2f} cycles per backprojection (median), "
                          f"SER {case['ser_db'][key]:.2f} dB", flush=True)
    finally:
        if tmp is not None:
            tmp.cleanup()
    result["machine"] = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                         "load_average": os.getloadavg(), "uptime_before": uptime_before, "uptime_after": uptime(),
                         "avx512_permute_gather": bool(getattr(sys.modules["imaging.bin_gather"], "PERMUTE_GATHER"))}
    print(f"load average {result['machine']['load_average'][0]:.2f}; "
          f"wrote {write_results(args.name, result, started_load=started_load)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
