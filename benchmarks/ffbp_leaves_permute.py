"""FFBP's leaves with the permute gather (imaging/bin_gather.py) against the scalar gather, alternated in one run.

The case: benchmarks/ffbp.py's 2 m aperture with the default plan. Both leaf kernels are compiled in this
process from imaging/ffbp_leaves.py's source, with ``PERMUTE_GATHER`` True (what a CPU with AVX-512 runs) and
False (the scalar gather of before), and alternated round by round (a load that comes and goes hits both
alike; the ratio is taken per round, its median kept):

* ``leaves``: 16 consecutive leaves from the pass's middle on one thread (benchmarks/ffbp_leaves.py's case),
  nanoseconds a backprojection;
* ``run``: FFBP's whole run (``run_factorized``, leaves, merges and pixels) on 2 threads;
* ``groups``: how many groups of 16 consecutive grid points of those leaves the permutes took (their bins within
  the window) out of all, counted by the same gather over every profile;
* the images of both are compared (``same_image_bit_for_bit``).

    python benchmarks/ffbp_leaves_permute.py [--quick]

Writes docs/results/ffbp_leaves_permute.json (``ffbp_leaves_permute_quick.json`` with --quick).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import types
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from backprojection import make_case  # noqa: E402
from ffbp import load_text  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

import imaging.ffbp_leaves as fl  # noqa: E402
from imaging.bin_gather import LANES, PERMUTE_GATHER, gather_planar  # noqa: E402
from imaging.factorized_backprojection import FactorizedOptions, _slice, plan_factorized, run_factorized  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def _copy(f, name: str, **globals_):
    return types.FunctionType(f.__code__, dict(f.__globals__, **globals_), name, f.__defaults__, f.__closure__)


def leaf_kernel(permute: bool, gather_accumulate=None):
    """imaging.ffbp_leaves' kernel compiled here with the permute gather or without (as on a CPU without
    AVX-512); with ``gather_accumulate``, that in place of the permute path's gather-and-accumulate."""
    tag = "_permute" if permute else "_scalar_gather"
    extra = {} if gather_accumulate is None else {"_gather_planar_accumulate": gather_accumulate}
    block = numba.njit(fastmath=True, nogil=True)(_copy(fl._leaf_block.py_func, "_leaf_block" + tag,
                                                        PERMUTE_GATHER=permute, **extra))
    return numba.njit(fastmath=True, nogil=True)(_copy(fl._polar_leaves_kernel.py_func, "_polar_leaves_kernel" + tag,
                                                       _leaf_block=block))


@numba.njit(inline="always")
def _count_groups(row, idx, frac, turns, planar, acc_re, acc_im):
    """In place of the gather and accumulation: the groups of 16 the permutes took, and all groups, added to
    the block's first point (its real and imaginary parts), which the kernel then writes out."""
    acc_re[0] += gather_planar(row, idx, planar)
    acc_im[0] += idx.size // LANES


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a smaller case (for a smoke run)")
    args = ap.parse_args()
    if not PERMUTE_GATHER:
        print("numba's target has no AVX-512 here: the leaves take the scalar gather either way", file=sys.stderr)
        return 2
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    uptime_before = load_text()
    frames, n_leaves, rounds = (24, 4, 2) if args.quick else (96, 16, 7)
    samples, wf, tx, rx, _ = make_case(frames, 2, 2)
    prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
    del samples
    x, y = np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions())
    leaves = sorted((n for n in plan.nodes() if not n.children), key=lambda n: n.start)
    mid = len(leaves) // 2
    sel = leaves[max(0, mid - n_leaves // 2): mid + n_leaves // 2]
    a, b = sel[0].start, sel[-1].stop
    sub, t_, r_ = _slice(prof, a, b), np.ascontiguousarray(tx[a:b]), np.ascontiguousarray(rx[a:b])
    n_bp = sum((leaf.stop - leaf.start) * leaf.nr * leaf.na for leaf in sel)
    kernels = {"permute": leaf_kernel(True), "scalar": leaf_kernel(False)}
    counter = leaf_kernel(True, _count_groups)

    def with_kernel(kernel, fn):
        saved = fl._polar_leaves_kernel
        fl._polar_leaves_kernel = kernel
        try:
            return fn()
        finally:
            fl._polar_leaves_kernel = saved

    def leaves_once(kernel):
        return with_kernel(kernel, lambda: fl.image_leaves(sel, sub, t_, r_, None, a, 0.3, "linear"))

    def run_once(kernel):
        return with_kernel(kernel, lambda: run_factorized(plan, prof, tx, rx))

    counts = with_kernel(counter, lambda: fl.image_leaves(sel, sub, t_, r_, None, a, 0.3, "linear"))
    permuted = sum(float(img.ravel()[g0].real) for img in counts for g0 in range(0, img.size, fl.BLOCK))
    groups = sum(float(img.ravel()[g0].imag) for img in counts for g0 in range(0, img.size, fl.BLOCK))
    same_leaves = all(np.array_equal(p, s) for p, s in zip(leaves_once(kernels["permute"]), leaves_once(kernels["scalar"])))
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    same_run = np.array_equal(run_once(kernels["permute"]), run_once(kernels["scalar"]))
    times: dict = {f"{part}_{name}": [] for part in ("leaves", "leaves_cpu", "run", "run_cpu") for name in kernels}
    for _ in range(rounds):
        numba.set_num_threads(1)
        for name, kernel in kernels.items():
            # The leaves run on this thread: its CPU time leaves out other processes' turns on the core.
            wall, cpu = math.inf, math.inf
            for _ in range(2):
                t, c = time.perf_counter(), time.thread_time()
                leaves_once(kernel)
                wall, cpu = min(wall, time.perf_counter() - t), min(cpu, time.thread_time() - c)
            times[f"leaves_{name}"].append(wall)
            times[f"leaves_cpu_{name}"].append(cpu)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        for name, kernel in kernels.items():
            t, c = time.perf_counter(), time.process_time()
            run_once(kernel)
            times[f"run_{name}"].append(time.perf_counter() - t)
            times[f"run_cpu_{name}"].append(time.process_time() - c)
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    tm = {k: np.array(v) for k, v in times.items()}
    result = {"machine": {"numba": numba.__version__, "uptime_before": uptime_before, "uptime_after": load_text()},
              "case": {"frames": frames, "leaves": len(sel), "leaf_points": [int(n.nr * n.na) for n in sel[:4]],
                       "profiles": int(tx.shape[0]), "pixels": int(x.size * y.size), "rounds": rounds,
                       "backprojections": int(n_bp), "quick": args.quick},
              "groups_permuted": int(permuted), "groups": int(groups), "groups_permuted_share": permuted / max(groups, 1),
              "same_image_bit_for_bit": {"leaves": bool(same_leaves), "run": bool(same_run)},
              "rounds_s": times,
              "leaves_ns_per_backprojection": {name: float(tm[f"leaves_{name}"].min() / n_bp * 1e9) for name in kernels},
              "leaves_speedup": float(np.median(tm["leaves_scalar"] / tm["leaves_permute"])),
              "leaves_speedup_rounds": sorted(float(v) for v in tm["leaves_scalar"] / tm["leaves_permute"]),
              "leaves_cpu_ns_per_backprojection": {name: float(tm[f"leaves_cpu_{name}"].min() / n_bp * 1e9)
                                                   for name in kernels},
              "leaves_cpu_speedup": float(np.median(tm["leaves_cpu_scalar"] / tm["leaves_cpu_permute"])),
              "leaves_cpu_speedup_rounds": sorted(float(v) for v in tm["leaves_cpu_scalar"] / tm["leaves_cpu_permute"]),
              "run_s_2_threads": {name: float(tm[f"run_{name}"].min()) for name in kernels},
              "run_speedup_2_threads": float(np.median(tm["run_scalar"] / tm["run_permute"])),
              "run_speedup_rounds": sorted(float(v) for v in tm["run_scalar"] / tm["run_permute"]),
              "run_cpu_speedup_2_threads": float(np.median(tm["run_cpu_scalar"] / tm["run_cpu_permute"])),
              "run_cpu_speedup_rounds": sorted(float(v) for v in tm["run_cpu_scalar"] / tm["run_cpu_permute"])}
    name = "ffbp_leaves_permute_quick" if args.quick else "ffbp_leaves_permute"
    write_results(name, result, started_load=started_load)
    print(f"groups of 16 permuted: {permuted:.0f} of {groups:.0f} ({100 * result['groups_permuted_share']:.1f} %); "
          f"the same image: {result['same_image_bit_for_bit']}; leaves {result['leaves_speedup']:.2f}x on 1 thread "
          f"({result['leaves_ns_per_backprojection']['scalar']:.2f} -> {result['leaves_ns_per_backprojection']['permute']:.2f} "
          f"ns a backprojection; in CPU time {result['leaves_cpu_speedup']:.2f}x), FFBP's run {result['run_speedup_2_threads']:.2f}x on 2 threads "
          f"({result['run_s_2_threads']['scalar']:.3f} -> {result['run_s_2_threads']['permute']:.3f} s; in CPU time "
          f"{result['run_cpu_speedup_2_threads']:.2f}x)")
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
