"""FFBP's plan against the batched planner before it (tests/reference_ffbp_plan_batched.py), alternated.

The case: benchmarks/ffbp.py's 2 m aperture (the left-front radar's 16 channels, 96 frames, 98,304 profiles)
onto 1 m x 0.6 m at 2 mm (150,000 pixels), default settings: 380 nodes. Only the plan is timed (its run is
the same: the plans are equal to the bit, which this checks too, ``same_plan_bit_for_bit``):

* ``rounds``: in one process, the planner (``plan_factorized``) and the one before alternated, which first
  alternating round by round, wall and CPU time (``time.thread_time``) of each; the ratio is taken per round
  and its median kept (a load that comes and goes hits both alike);
* ``fresh_process``: the plan as ``sarbot image`` meets it, in new processes (each loads the plan's numba
  passes from the cache as that command does, ``load_cached_kernels_lightly``, then plans five times), the two
  versions' processes alternated: the first plan (numba's start, the cache loads, first-touch pages) and the
  later ones, wall and CPU time and page faults; and ``new_prepared``: the planner in a process that first
  made its kernels ready as ``sarbot image --algorithm ffbp`` does on its start-up thread
  (``imaging.kernel_import.prepare_kernels(ffbp=True)``, not timed: it overlaps reading the recording).

The machine is shared: the load averages are in the JSON, and the lead re-runs it on the quiet machine.

    python benchmarks/ffbp_plan_versions.py [--rounds N] [--processes N] [--name NAME]

Writes docs/results/ffbp_plan_versions.json (or NAME.json).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks"), str(ROOT / "tests")]

from results_file import load_average, probe_machine, write_results  # noqa: E402
from test_ffbp_plan import BANDWIDTH_HZ, CARRIER_HZ, assert_identical_plan, track  # noqa: E402

from imaging.factorized_backprojection import plan_factorized  # noqa: E402
from reference_ffbp_plan_batched import plan_factorized_batched  # noqa: E402

#: A process's plans, as ``sarbot image`` makes them: argv[1] the case, argv[2] "new", "new_prepared" or "batched".
FRESH_PLANS = """
import json, resource, sys, time
sys.path[:0] = [sys.argv[3], sys.argv[3] + "/tests"]
import numpy as np
from imaging.numba_target import load_cached_kernels_lightly
if sys.argv[2] != "batched":
    from imaging.factorized_backprojection import plan_factorized as plan
else:
    from reference_ffbp_plan_batched import plan_factorized_batched as plan
load_cached_kernels_lightly()  # as sarbot image starts (acquisition/cli/imaging.py)
if sys.argv[2] == "new_prepared":
    from imaging import kernel_import
    kernel_import.prepare_kernels(ffbp=True)
case = np.load(sys.argv[1])
args = (case["tx"], case["rx"], case["x"], case["y"], 0.3, float(case["carrier_hz"]), float(case["bandwidth_hz"]))
rows = []
for _ in range(5):
    faults, wall, cpu = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt, time.perf_counter(), time.thread_time()
    plan(*args)
    rows.append([time.perf_counter() - wall, time.thread_time() - cpu, resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - faults])
print(json.dumps(rows))
"""


def clocked(fn) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.thread_time()
    fn()
    return time.perf_counter() - wall, time.thread_time() - cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=20, help="alternated rounds in one process (default 20)")
    ap.add_argument("--processes", type=int, default=4, help="fresh processes per version (default 4)")
    ap.add_argument("--name", default="ffbp_plan_versions", help="the JSON's name under docs/results/")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    tx, rx = track(96)
    x, y = np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002)
    case = (tx, rx, x, y, 0.3, CARRIER_HZ, BANDWIDTH_HZ)
    versions = {"new": lambda: plan_factorized(*case), "batched": lambda: plan_factorized_batched(*case)}
    plans = {name: fn() for name, fn in versions.items()}  # (loads or compiles their passes)
    assert_identical_plan(plans["new"], plans["batched"])
    rows: dict = {f"{name}_{unit}": [] for name in versions for unit in ("s", "cpu_s")}
    for r in range(args.rounds):
        for name in (("new", "batched") if r % 2 == 0 else ("batched", "new")):
            wall, cpu = clocked(versions[name])
            rows[f"{name}_s"].append(wall)
            rows[f"{name}_cpu_s"].append(cpu)
    a = {k: np.array(v) for k, v in rows.items()}
    in_process = {"rounds": rows, "new_s": float(np.median(a["new_s"])), "batched_s": float(np.median(a["batched_s"])),
                  "new_cpu_s": float(np.median(a["new_cpu_s"])), "batched_cpu_s": float(np.median(a["batched_cpu_s"])),
                  "speedup_wall": float(np.median(a["batched_s"] / a["new_s"])),
                  "speedup_cpu": float(np.median(a["batched_cpu_s"] / a["new_cpu_s"]))}
    print(f"in one process, {args.rounds} rounds: plan {in_process['new_cpu_s'] * 1e3:.1f} ms CPU "
          f"({in_process['new_s'] * 1e3:.1f} ms wall) against {in_process['batched_cpu_s'] * 1e3:.1f} ms "
          f"({in_process['batched_s'] * 1e3:.1f} ms): {in_process['speedup_cpu']:.2f}x CPU, "
          f"{in_process['speedup_wall']:.2f}x wall", flush=True)
    fresh: dict = {"new": [], "batched": [], "new_prepared": []}
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "case.npz"
        np.savez(path, tx=tx, rx=rx, x=x, y=y, carrier_hz=CARRIER_HZ, bandwidth_hz=BANDWIDTH_HZ)

        def process(name: str) -> list:
            return json.loads(subprocess.run([sys.executable, "-c", FRESH_PLANS, str(path), name, str(ROOT)], cwd=ROOT,
                                             check=True, capture_output=True, text=True).stdout)

        for name in fresh:
            process(name)  # numba's cache holds both versions' passes from here on
        for p in range(args.processes):
            for name in (("new", "batched", "new_prepared") if p % 2 == 0 else ("new_prepared", "batched", "new")):
                fresh[name].append(process(name))
    summary: dict = {"processes": args.processes, "plans": fresh}
    for name, runs in fresh.items():
        first, later = np.array([run[0] for run in runs]), np.array([row for run in runs for row in run[1:]])
        summary[name] = {"first_plan_s": float(np.median(first[:, 0])), "first_plan_cpu_s": float(np.median(first[:, 1])),
                         "first_plan_faults": int(np.median(first[:, 2])), "plan_s": float(np.median(later[:, 0])),
                         "plan_cpu_s": float(np.median(later[:, 1])), "plan_faults": int(np.median(later[:, 2]))}
    for key in ("first_plan_s", "first_plan_cpu_s", "plan_s", "plan_cpu_s"):
        summary[f"speedup_{key}"] = summary["batched"][key] / summary["new"][key]
    for key in ("first_plan_s", "first_plan_cpu_s"):
        summary[f"speedup_{key}_prepared"] = summary["batched"][key] / summary["new_prepared"][key]
    print("in fresh processes: " + "; ".join(
        f"{name}: first plan {s['first_plan_s'] * 1e3:.1f} ms ({s['first_plan_cpu_s'] * 1e3:.1f} ms CPU, "
        f"{s['first_plan_faults']} faults), later {s['plan_s'] * 1e3:.1f} ms ({s['plan_cpu_s'] * 1e3:.1f} ms CPU, "
        f"{s['plan_faults']} faults)" for name, s in ((n, summary[n]) for n in ("new", "new_prepared", "batched"))), flush=True)
    result = {"case": {"aperture_m": float(np.ptp(0.5 * (tx[:, 0] + rx[:, 0]))), "profiles": int(tx.shape[0]),
                       "pixels": int(x.size * y.size), "nodes": sum(1 for _ in plans["new"].nodes())},
              "same_plan_bit_for_bit": True, "in_process": in_process, "fresh_process": summary}
    print(f"wrote {write_results(args.name, result, started_load=started_load)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
