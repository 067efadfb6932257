"""The backprojection kernel against an earlier version of itself, timed alternately in one run.

Each version runs in a worker process of its own (numba compiles for one target per process, and the
earlier kernel ran with numba's default one), built from ``git show COMMIT:imaging/backprojection.py``, on
the same two cases, linear, 16x oversampled profiles: the backprojection benchmark's (16 frames of the
left-front radar, 16 channels, 256 x 256 pixels; ``threads`` in the JSON) and the peers benchmark's
one-antenna pass (4,096 chirps of TX 0 / RX 0 onto the same pixels; ``one_antenna``). The parent asks each worker in turn to backproject once and
report its wall time and the CPU time its threads used; the ratio is taken per round, the median over
rounds reported, for 1 and 2 threads. With ``--whole-package`` the baseline's worker takes all of ``imaging``
from COMMIT (``git archive``), not only its kernel module: for a change outside imaging/backprojection.py (the
block shapes of imaging/patches.py, the table of imaging/block_profiles.py), which the baseline's kernel would
otherwise import from the current tree. Cycles per backprojection are CPU seconds x the CPU's clock
(/proc/cpuinfo) / backprojections: what the kernel costs a core, whatever else the machine runs.

    python benchmarks/kernel_versions.py [--quick] [--baseline COMMIT] [--rounds N] [--cases one_antenna] [--name NAME]
                                         [--whole-package]

Writes docs/results/kernel_versions.json (NAME.json with ``--name``: a comparison with another baseline, or of
one case, beside the issue's). A baseline kernel that already asks for full-width vectors gets the current
kernel's target (its own would be overridden by the explicit host features given to older ones).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from results_file import load_average, probe_machine, write_results

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
#: The kernel before issue 34 (the last commit before its branch).
BASELINE = "9dd63ca"
CASES = ("benchmark", "one_antenna")

WORKER = r"""
import importlib.util, json, os, sys, time
sys.path[:0] = [{package_root!r}, {root!r}, {benchmarks!r}]
spec = importlib.util.spec_from_file_location("kernel_under_test", {module!r})
bp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bp)
import numba
import numpy as np
from backprojection import make_case, ser_db
from peers import one_antenna_case
from imaging.range_compression import range_compress
frames, px, one, wanted = {frames}, {px}, {one}, {cases!r}
cases, ser, work = {{}}, {{}}, {{}}
makers = {{"benchmark": lambda: make_case(frames, px, px), "one_antenna": lambda: one_antenna_case(one, px, px)}}
for name in wanted:
    samples, wf, tx, rx, grid = makers[name]()
    prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, guarded=True)
    exact = bp.backproject(prof, tx, rx, grid[::8, ::8], mode="exact")
    ser[name] = ser_db(bp.backproject(prof, tx, rx, grid)[::8, ::8], exact)
    work[name] = int(tx.shape[0] * px * px)
    cases[name] = (prof, tx, rx, grid)
from numba.core.registry import cpu_target
features = cpu_target.target_context.codegen()._tm_features
print(json.dumps({{"ready": True, "ser_db": ser, "work": work,
                  "prefer_256_bit_off": "-prefer-256-bit" in features}}), flush=True)
for line in sys.stdin:
    threads, name = line.split()
    numba.set_num_threads(int(threads))
    c, t = time.process_time(), time.perf_counter()
    bp.backproject(*cases[name])
    print(json.dumps({{"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}}), flush=True)
"""


def uptime() -> str:
    """``uptime``'s line (the load averages): the machine is shared."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return " ".join(f"{x:.2f}" for x in os.getloadavg())


def current_commit() -> str:
    """The checkout's commit, with ``+changes`` when the kernel differs from it."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "imaging/backprojection.py"], cwd=ROOT).returncode
    return head + ("+changes" if dirty else "")


def cpu_hz() -> float | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("cpu MHz"):
                return float(line.split(":")[1]) * 1e6
    except OSError:
        pass
    return None


def start_worker(module: Path, frames: int, px: int, one: int, env: dict, cases: tuple[str, ...],
                 package_root: Path = ROOT) -> tuple[subprocess.Popen, dict]:
    """A worker for the kernel module at ``module``, importing ``imaging`` from ``package_root``."""
    code = WORKER.format(package_root=str(package_root), root=str(ROOT), benchmarks=str(ROOT / "benchmarks"),
                         module=str(module), frames=frames, px=px, one=one, cases=cases)
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=env, cwd=ROOT)
    return proc, json.loads(proc.stdout.readline())


def ask(proc: subprocess.Popen, threads: int, case: str = "benchmark") -> dict:
    proc.stdin.write(f"{threads} {case}\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--baseline", default=BASELINE, help=f"the earlier kernel's commit (default {BASELINE})")
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    ap.add_argument("--name", default=None, help="the JSON's name (default kernel_versions[_quick])")
    ap.add_argument("--whole-package", action="store_true",
                    help="the baseline's worker imports all of imaging from the baseline commit, not only its kernel")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    cases = tuple(args.cases)
    frames, px, one = (4, 128, 1024) if args.quick else (16, 256, 4096)
    rounds = args.rounds or (2 if args.quick else 6)
    uptime_before = uptime()
    with tempfile.TemporaryDirectory() as tmp:
        old_module = Path(tmp) / "backprojection_baseline.py"
        old_source = subprocess.run(["git", "show", f"{args.baseline}:imaging/backprojection.py"], cwd=ROOT,
                                    capture_output=True, text=True, check=True).stdout
        old_module.write_text(old_source)
        old_root = ROOT
        if args.whole_package:
            # The baseline commit's imaging/ in a tree of its own, first on the worker's path.
            old_root = Path(tmp) / "baseline_tree"
            old_root.mkdir()
            archive = subprocess.run(["git", "archive", args.baseline, "imaging"], cwd=ROOT, capture_output=True,
                                     check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(old_root)], input=archive, check=True)
            old_module = old_root / "imaging" / "backprojection.py"
        base_env = {k: v for k, v in os.environ.items() if k != "NUMBA_CPU_FEATURES"}
        # The earlier kernel with numba's own target, the host's features as LLVM tunes them (set explicitly,
        # so that importing the current imaging.backprojection for the case leaves them alone); a cache of
        # its own, apart from the project's.
        import llvmlite.binding as llvm

        host = llvm.get_host_cpu_features().flatten()
        old_target = {} if "prefer_full_width_vectors()" in old_source else {"NUMBA_CPU_FEATURES": host}
        old, old_info = start_worker(old_module, frames, px, one, {**base_env, **old_target,
                                                                   "NUMBA_CACHE_DIR": str(Path(tmp) / "cache")}, cases,
                                     old_root)
        # The current kernel with a cache of its own too: loaded under another module name, its cache entries
        # in the project's would be found by the next ordinary import and fail to load ("No module named
        # '<dynamic>'").
        new, new_info = start_worker(ROOT / "imaging" / "backprojection.py", frames, px, one,
                                     {**base_env, "NUMBA_CACHE_DIR": str(Path(tmp) / "cache_current")}, cases)
        hz = cpu_hz()
        per_case = {}
        try:
            for case in cases:
                work = new_info["work"][case]
                per_threads = per_case[case] = {}
                for threads in (1, 2):
                    ask(old, threads, case), ask(new, threads, case)  # warm
                    rows = [(ask(old, threads, case), ask(new, threads, case)) for _ in range(rounds)]
                    speedups = [o["wall_s"] / n["wall_s"] for o, n in rows]
                    cpu_ratio = [o["cpu_s"] / n["cpu_s"] for o, n in rows]
                    best_old = min(o["cpu_s"] for o, _ in rows)
                    best_new = min(n["cpu_s"] for _, n in rows)
                    per_threads[threads] = {
                        "speedup_wall_median": statistics.median(speedups), "speedup_wall_min": min(speedups),
                        "speedup_wall_max": max(speedups), "speedup_cpu_time_median": statistics.median(cpu_ratio),
                        "backprojections_per_s": {"baseline": work / statistics.median(o["wall_s"] for o, _ in rows),
                                                  "current": work / statistics.median(n["wall_s"] for _, n in rows)},
                        "cycles_per_backprojection": None if hz is None else {"baseline": best_old * hz / work,
                                                                              "current": best_new * hz / work},
                    }
                    r = per_threads[threads]
                    cyc = r["cycles_per_backprojection"]
                    print(f"{case}, {threads} thread(s): current kernel {r['speedup_wall_median']:.2f}x the baseline's speed "
                          f"({r['speedup_wall_min']:.2f}-{r['speedup_wall_max']:.2f}; CPU time {r['speedup_cpu_time_median']:.2f}x)"
                          + (f", {cyc['current']:.2f} cycles per backprojection against {cyc['baseline']:.2f}" if cyc else ""),
                          flush=True)
        finally:
            for proc in (old, new):
                proc.stdin.close()
                proc.wait(timeout=60)
    load = os.getloadavg()
    result = {
        "baseline_commit": args.baseline, "current_commit": current_commit(), "whole_package": args.whole_package,
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(), "cpu_hz": hz,
                    "load_average": load, "uptime_before": uptime_before, "uptime_after": uptime()},
        "full_width_vectors": {"baseline": old_info["prefer_256_bit_off"], "current": new_info["prefer_256_bit_off"]},
        "rounds": rounds,
    }
    if "benchmark" in cases:
        result.update({
            "case": {"frames": frames, "pixels": px * px, "backprojections": new_info["work"]["benchmark"],
                     "quick": args.quick},
            "ser_db": {"baseline": old_info["ser_db"]["benchmark"], "current": new_info["ser_db"]["benchmark"]},
            "threads": per_case["benchmark"]})
    if "one_antenna" in cases:
        result["one_antenna"] = {
            "profiles": one, "pixels": px * px, "backprojections": new_info["work"]["one_antenna"], "quick": args.quick,
            "ser_db": {"baseline": old_info["ser_db"]["one_antenna"], "current": new_info["ser_db"]["one_antenna"]},
            "threads": per_case["one_antenna"]}
    for case in cases:
        print(f"{case}: SER against the exact matched filter: baseline {old_info['ser_db'][case]:.2f} dB, current "
              f"{new_info['ser_db'][case]:.2f} dB")
    print(f"load average {load[0]:.2f}")
    name = args.name or ("kernel_versions_quick" if args.quick else "kernel_versions")
    print(f"wrote {write_results(name, result, started_load=started_load)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
