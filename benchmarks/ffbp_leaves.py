"""Where the FFBP leaf kernel's time goes (imaging/ffbp_leaves.py), on one thread.

The case: benchmarks/ffbp.py's 2 m aperture with the default plan; 16 consecutive leaves from its middle.

* ``full``: the kernel itself (``imaging.ffbp_leaves._polar_leaves_kernel``, prefetching the rows
  PREFETCH_AHEAD profiles ahead);
* ``hot_rows``: the kernel itself with every leaf on the same 64 profiles, whose rows stay in cache: its time
  without waiting on memory;
* the parts, from a copy of the kernel's block (``_block`` below) with parts switched off: ``copy_full`` (all
  of it, as the kernel: it must time as ``full``, ``copy_over_kernel``), ``no_prefetch``, ``prefetch_ahead_N``
  (N = 1, 2, 4, 8 profiles ahead), ``geometry`` (the points' bins and phases only, no gather) and
  ``gather_accumulate`` (the gather and the accumulation only, the first profile's bins for all);
* ``direct_cartesian``: the direct kernel (imaging.backprojection, serial) on the same profiles onto a
  compact Cartesian grid of a leaf's size, the figure the leaves were compared with.

Times are nanoseconds a backprojection (profile x point), the best of interleaved rounds, with the load
average recorded: memory contention from other processes slows the parts that wait on memory.

Why the parts need a copy: the kernel's prefetch distance is a compile-time constant and it has no switch to
leave out its geometry or its gather; switches in its inner loop, for a benchmark, would be branches in the
hot loop of every image. The copy is checked against the kernel's image before it is timed, and timed beside
it (``copy_over_kernel``), so that a change to one and not the other shows. It leaves out what the case never
takes: reference ranges, and the exact quotient where the series would not converge for a receiver.

    python benchmarks/ffbp_leaves.py [--quick]

Writes docs/results/ffbp_leaves.json (``ffbp_leaves_quick.json`` with --quick).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from backprojection import make_case  # noqa: E402
from ffbp import load_text  # noqa: E402

from imaging.backprojection import (_G, _TWO_PI, BLOCK, _gather_pairs_accumulate, _gather_planar_accumulate,  # noqa: E402
                                    backproject, guarded_rows)
from imaging.bin_gather import PERMUTE_GATHER  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402
from imaging.core.constants import SPEED_OF_LIGHT_MPS  # noqa: E402
from imaging.core.prefetch import prefetch  # noqa: E402
from imaging.factorized_backprojection import FactorizedOptions, _slice, plan_factorized  # noqa: E402
from imaging.ffbp_leaves import PREFETCH_AHEAD, _offsets_from_centre, _place_polar, _polar_leaves_kernel, image_leaves  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402

RESULTS = ROOT / "docs" / "results"
FULL, GEOMETRY, GATHER = 0, 1, 2


@numba.njit(fastmath=True, nogil=True)
def _block(rows, r0, inv_dr, k, tx, rx, linear, z, p0, p1, g, na, g0, nb, out, part, ahead):
    """imaging.ffbp_leaves._leaf_block (no reference ranges) with ``part`` FULL, GEOMETRY (bins and phases, no
    gather) or GATHER (gather and accumulate at the first profile's bins), prefetching ``ahead`` profiles
    ahead (0: not)."""
    hi = np.float64(rows.shape[1] - 2)
    inv32 = np.float32(inv_dr)
    k_turns32 = np.float32(k / _TWO_PI)
    h = z - g[2]
    r_min = g[7]
    i_first = g0 // na
    r_first = g[7] + i_first * g[8]
    ex = np.empty(nb, np.float32)
    ey = np.empty(nb, np.float32)
    ez = np.empty(nb, np.float32)
    two_r = np.empty(nb, np.float32)
    inv_r = np.empty(nb, np.float32)
    inv_r2 = np.empty(nb, np.float32)
    r_bins = np.empty(nb, np.float32)
    for i in range(nb):
        row = (g0 + i) // na
        r = g[7] + row * g[8]
        alpha = g[9] + ((g0 + i) % na) * g[10]
        b = math.sqrt(max(r * r * (1.0 - alpha * alpha) - h * h, 0.0)) / r
        ex[i] = np.float32(alpha * g[3] + b * g[5])
        ey[i] = np.float32(alpha * g[4] + b * g[6])
        ez[i] = np.float32(h / r)
        two_r[i] = np.float32(2.0 * r)
        inv_r[i] = np.float32(1.0 / r)
        inv_r2[i] = np.float32(1.0 / (r * r))
        r_bins[i] = np.float32(2.0 * (row - i_first) * g[8] * inv_dr)
    acc_re = np.zeros(nb, np.float32)
    acc_im = np.zeros(nb, np.float32)
    idx = np.zeros(nb, np.uint32)
    frac = np.zeros(nb, np.float32)
    turns = np.zeros(nb, np.float32)
    pairs = np.empty((nb, 2), np.complex64)
    planar = np.empty((4, nb), np.float32)
    da = np.empty(nb, np.float32)
    c_0, c_1, c_2, c_3, c_4, c_5 = (np.float32(_G[0]), np.float32(_G[1]), np.float32(_G[2]), np.float32(_G[3]),
                                    np.float32(_G[4]), np.float32(_G[5]))
    for p in range(p0, p1):
        pos_c = (2.0 * r_first - r0) * inv_dr + 1.0
        base = np.floor(pos_c)
        frac_c = np.float32(pos_c - base)
        lo = np.float32(-base)
        top = np.float32(hi - base)
        ibase = np.int32(base)
        turns_c = np.float32(0.0)
        if part != GATHER or p == p0:
            if p == p0 or tx[p, 0] != tx[p - 1, 0] or tx[p, 1] != tx[p - 1, 1] or tx[p, 2] != tx[p - 1, 2]:
                _offsets_from_centre(tx[p, 0] - g[0], tx[p, 1] - g[1], tx[p, 2] - g[2], r_min, ex, ey, ez, two_r,
                                     inv_r, inv_r2, da)
            s0, s1, s2 = rx[p, 0] - g[0], rx[p, 1] - g[1], rx[p, 2] - g[2]
            sb = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            b0, b1, b2, ssb = np.float32(s0), np.float32(s1), np.float32(s2), np.float32(sb * sb)
            for i in range(nb):
                num = ssb - two_r[i] * (ex[i] * b0 + ey[i] * b1 + ez[i] * b2)
                t = num * inv_r2[i]
                d = da[i] + (num * inv_r[i]) * (c_0 + t * (c_1 + t * (c_2 + t * (c_3 + t * (c_4 + t * c_5)))))
                idx[i], frac[i], turns[i] = _place_polar(d, r_bins[i], frac_c, inv32, lo, top, ibase, turns_c, k_turns32, linear)
        if ahead > 0 and p + ahead < p1:
            i_lo, i_hi = idx[0], idx[0]
            for i in range(nb):
                i_lo = min(i_lo, idx[i])
                i_hi = max(i_hi, idx[i])
            last = min(np.int64(i_hi) + 1, rows.shape[1] - 1)
            for j in range(np.int64(i_lo), last + 1, 8):
                prefetch(rows, p + ahead, j)
            prefetch(rows, p + ahead, last)
        if part == GEOMETRY:
            for i in range(nb):
                acc_re[i] += frac[i] + turns[i]
                acc_im[i] += np.float32(idx[i])
        elif linear and PERMUTE_GATHER:
            _gather_planar_accumulate(rows[p], idx, frac, turns, planar, acc_re, acc_im)
        else:
            _gather_pairs_accumulate(rows[p], idx, frac, turns, pairs, acc_re, acc_im, linear)
    for i in range(nb):
        out[i] = np.complex64(complex(acc_re[i], acc_im[i]))


@numba.njit(fastmath=True, nogil=True)
def _leaves(rows, r0, inv_dr, k, tx, rx, z, leaf_p0, leaf_p1, geometry, shape, offset, out, part, ahead):
    for leaf in range(geometry.shape[0]):
        g = geometry[leaf]
        na = shape[leaf, 1]
        n = shape[leaf, 0] * na
        for g0 in range(0, n, BLOCK):
            _block(rows, r0, inv_dr, k, tx, rx, True, z, leaf_p0[leaf], leaf_p1[leaf], g, na, g0, min(g0 + BLOCK, n) - g0,
                   out[offset[leaf] + g0:], part, ahead)


def best_of(fn, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a smaller case (for a smoke run)")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    numba.set_num_threads(1)
    frames, n_leaves, rounds = (24, 4, 2) if args.quick else (96, 16, 6)
    uptime_before = load_text()
    samples, wf, tx, rx, _ = make_case(frames, 2, 2)
    prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
    del samples
    x, y = np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002)
    options = FactorizedOptions()
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, options)
    leaves = sorted((n for n in plan.nodes() if not n.children), key=lambda n: n.start)
    mid = len(leaves) // 2
    sel = leaves[max(0, mid - n_leaves // 2): mid + n_leaves // 2]
    a, b = sel[0].start, sel[-1].stop
    sub = _slice(prof, a, b)
    rows, t_, r_ = guarded_rows(sub), np.ascontiguousarray(tx[a:b]), np.ascontiguousarray(rx[a:b])
    k = 2 * math.pi * prof.carrier_hz / SPEED_OF_LIGHT_MPS
    geometry = np.array([leaf.geometry for leaf in sel])
    shape = np.array([(leaf.nr, leaf.na) for leaf in sel], np.int64)
    sizes = shape[:, 0] * shape[:, 1]
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    p0 = np.array([leaf.start - a for leaf in sel], np.int64)
    p1 = np.array([leaf.stop - a for leaf in sel], np.int64)
    out = np.empty(int(sizes.sum()), np.complex64)
    n_bp = int(((p1 - p0) * sizes).sum())

    def variant(part, ahead, q0=p0, q1=p1):
        return lambda: _leaves(rows, sub.range_start_m, 1 / sub.range_step_m, k, t_, r_, 0.3, q0, q1, geometry, shape,
                               offset, out, part, ahead)

    def kernel(q0=p0, q1=p1):
        return lambda: _polar_leaves_kernel(rows, sub.range_start_m, 1 / sub.range_step_m, k, t_, r_, np.zeros(b - a), True,
                                            0.3, q0, q1, geometry, shape, offset, out)

    # The copy is the kernel: the same image as image_leaves (no reference ranges).
    variant(FULL, PREFETCH_AHEAD)()
    want = np.concatenate([img.ravel() for img in image_leaves(sel, sub, t_, r_, None, a, 0.3, "linear")])
    assert np.allclose(out, want, rtol=0, atol=1e-5 * np.abs(want).max()), "the benchmark's copy differs from the kernel"
    hot_p0 = np.full_like(p0, p0[0])
    hot_p1 = hot_p0 + min(64, int(p1[0] - p0[0]))
    n_hot = int(((hot_p1 - hot_p0) * sizes).sum())
    side = int(math.sqrt(sizes.mean()))
    xx, yy = np.meshgrid(np.arange(side) * 0.002 - 0.1, 2.0 + np.arange(side) * 0.002)
    cartesian = np.stack([xx, yy, np.full_like(xx, 0.3)], -1)
    n_cart = sum((leaf.stop - leaf.start) * side * side for leaf in sel)

    def direct_cartesian():
        for leaf in sel:
            s = slice(leaf.start, leaf.stop)
            backproject(_slice(prof, leaf.start, leaf.stop), tx[s], rx[s], cartesian, parallel=False)

    parts = {"full": (kernel(), n_bp), "copy_full": (variant(FULL, PREFETCH_AHEAD), n_bp), "no_prefetch": (variant(FULL, 0), n_bp),
             "geometry": (variant(GEOMETRY, 0), n_bp), "gather_accumulate": (variant(GATHER, 0), n_bp),
             "hot_rows": (kernel(hot_p0, hot_p1), n_hot),
             **{f"prefetch_ahead_{n}": (variant(FULL, n), n_bp) for n in (1, 2, 4, 8)},
             "direct_cartesian": (direct_cartesian, n_cart)}
    for fn, _ in parts.values():
        fn()  # compile, warm
    times: dict[str, list] = {name: [] for name in parts}
    for _ in range(rounds):
        for name, (fn, count) in parts.items():
            times[name].append(best_of(fn, 2) / count * 1e9)
    ns = {name: min(v) for name, v in times.items()}
    for name, v in ns.items():
        print(f"  {name:22s} {v:.2f} ns a backprojection (median {np.median(times[name]):.2f})", flush=True)
    result = {"machine": {"cores": os.cpu_count(), "numba": numba.__version__, "load_average": os.getloadavg(),
                          "uptime_before": uptime_before, "uptime_after": load_text(), "threads": 1},
              "case": {"frames": frames, "leaves": len(sel), "leaf_points": [int(s) for s in sizes[:4]],
                       "leaf_profiles": options.leaf_profiles, "prefetch_ahead": PREFETCH_AHEAD, "rounds": rounds,
                       "backprojections": n_bp, "quick": args.quick},
              "ns_per_backprojection": ns,
              "ns_per_backprojection_median": {name: float(np.median(v)) for name, v in times.items()},
              "prefetch_speedup": ns["no_prefetch"] / ns["copy_full"],
              "copy_over_kernel": ns["copy_full"] / ns["full"],
              "memory_wait_share": 1 - ns["hot_rows"] / ns["full"],
              "over_direct_cartesian": ns["full"] / ns["direct_cartesian"]}
    name = "ffbp_leaves_quick" if args.quick else "ffbp_leaves"
    write_results(name, result, started_load=started_load)
    print(f"prefetching: {result['prefetch_speedup']:.2f}x; waiting on memory: {100 * result['memory_wait_share']:.0f} % "
          f"of the kernel; {result['over_direct_cartesian']:.2f}x the direct kernel's time a backprojection")
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
