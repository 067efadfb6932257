"""The odometry's speed against earlier commits, interleaved on one drive: where rio.json's halving came from
and what the fix gives back.

rio.json re-run quiet at cbf4ca9 had the odometry at 47-58x real time on the hall drives against 106-116x
quoted at fae5f5c. Each version here is a tree of its own (``git archive COMMIT``, a numba cache of its own;
``HEAD`` is this checkout) run by a worker process of its own that loads the drive once and compiles first;
the workers then take turns (the order reversed every round), so a load that changes during the run falls on
all versions alike, and each round gives every version's time as a ratio to the first version's. The drive
is benchmarks/odometry.py's hall drive (``--laps``, 1 by default: one lap, 56 s, simulated once here), with
all four radars and with one (left_front). The trajectories of the versions are compared with the last
one's (same drive, same options): a pure speed-up leaves them equal to rounding.

    python benchmarks/odometry_speed.py [--versions fae5f5c,ac0c048,HEAD] [--rounds 5] [--laps 1]

Writes docs/results/odometry_speed.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from odometry_versions import version_tree  # each commit's packages in a tree of its own
from results_file import load_average, probe_machine, write_results

ROOT = Path(__file__).resolve().parents[1]
VERSIONS = {
    "fae5f5c": "rio.json's 106-116x (the filter before the standstill, calibration and strapdown changes)",
    "ac0c048": "main before this fix (rio.json's 47-58x at cbf4ca9 has the same filter)",
    "HEAD": "this checkout",
}
CASES = {"four_radars": None, "one_radar": "left_front"}

#: A version's worker (sys.argv: tree, recording, radars or "", trajectory file): loads the drive, runs the
#: odometry once to compile, then on every "run" line times it and answers with JSON.
WORKER = r'''
import json, logging, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
logging.basicConfig(level=logging.ERROR)
from imaging.io.recording import Recording
from rio.odometry import RioOptions, imu_from_recording, run_rio, scans_from_recording
radars = tuple(sys.argv[3].split(",")) if sys.argv[3] else None
with Recording(sys.argv[2]) as rec:
    imu, scans = imu_from_recording(rec), scans_from_recording(rec, radars)
res = run_rio(imu, scans, RioOptions())
np.savez(sys.argv[4], position_m=res.trajectory.position_m, velocity_mps=res.trajectory.velocity_mps,
         radar_updates=res.stats.get("radar_updates", 0), zero_velocity_updates=res.stats.get("zero_velocity_updates", 0))
print(json.dumps({"duration_s": (imu.time_ns[-1] - imu.time_ns[0]) * 1e-9}), flush=True)
for line in sys.stdin:
    t = time.perf_counter()
    run_rio(imu, scans, RioOptions())
    print(json.dumps({"elapsed_s": time.perf_counter() - t}), flush=True)
'''


def simulate(laps: int, path: Path) -> None:
    sys.path.insert(0, str(ROOT))
    from odometry import long_drive

    from imaging.sim.simulator import simulate_recording

    simulate_recording(long_drive(laps, seed=10), path, overwrite=True)


def time_case(versions: list[str], trees: dict, recording: Path, radars: str | None, rounds: int, tmp: Path) -> dict:
    """Every version's times on one case, interleaved, and its trajectory against the last version's."""
    workers, duration = {}, {}
    runner = tmp / "worker.py"
    runner.write_text(WORKER)
    for v in versions:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / f"numba_{v}"))
        workers[v] = subprocess.Popen([sys.executable, str(runner), str(trees[v]), str(recording), radars or "",
                                       str(tmp / f"trajectory_{v}_{radars}.npz")],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=tmp)
    for v in versions:  # one at a time: each compiles (or loads its cache) before the timing starts
        line = workers[v].stdout.readline()
        if not line:
            raise SystemExit(f"{v}: the worker failed (run it by hand for its traceback)")
        duration[v] = json.loads(line)["duration_s"]
    elapsed: dict[str, list[float]] = {v: [] for v in versions}
    for r in range(rounds):
        for v in versions if r % 2 == 0 else versions[::-1]:
            workers[v].stdin.write("run\n")
            workers[v].stdin.flush()
            elapsed[v].append(json.loads(workers[v].stdout.readline())["elapsed_s"])
        print(f"round {r}: " + ", ".join(f"{v} {elapsed[v][-1]:.2f} s" for v in versions), flush=True)
    for w in workers.values():
        w.stdin.close()
        w.wait()
    reference = np.load(tmp / f"trajectory_{versions[-1]}_{radars}.npz")
    rows = []
    for v in versions:
        times = np.array(elapsed[v])
        traj = np.load(tmp / f"trajectory_{v}_{radars}.npz")
        same_length = traj["position_m"].shape == reference["position_m"].shape
        rows.append({
            "version": v, "what": VERSIONS.get(v, ""), "elapsed_s": times.tolist(),
            "median_elapsed_s": float(np.median(times)),
            "realtime_multiple": float(duration[v] / np.median(times)),
            # per round, this version's time over the first version's: the load falls on both alike
            "time_ratio_to_first": float(np.median(times / np.array(elapsed[versions[0]]))),
            "radar_updates": int(traj["radar_updates"]), "zero_velocity_updates": int(traj["zero_velocity_updates"]),
            f"max_position_difference_to_{versions[-1]}_m":
                float(np.abs(traj["position_m"] - reference["position_m"]).max()) if same_length else None,
            f"max_velocity_difference_to_{versions[-1]}_mps":
                float(np.abs(traj["velocity_mps"] - reference["velocity_mps"]).max()) if same_length else None,
        })
    return {"radars": radars or "all four", "duration_s": duration[versions[0]], "versions": rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--versions", default=",".join(VERSIONS), help="commits, HEAD for this checkout (last: the reference)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--laps", type=int, default=1)
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    versions = args.versions.split(",")
    out: dict = {"laps": args.laps, "rounds": args.rounds, "cases": {}}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        recording = tmp / "drive.h5"
        simulate(args.laps, recording)
        trees = {v: version_tree(v, tmp) for v in versions}
        for case, radars in CASES.items():
            out["cases"][case] = time_case(versions, trees, recording, radars, args.rounds, tmp)
    out["load_average_1min"] = os.getloadavg()[0]
    path = write_results("odometry_speed", out, started_load=started_load)
    print(f"wrote {path}")
    for case, res in out["cases"].items():
        for row in res["versions"]:
            print(f"{case} {row['version']}: {row['realtime_multiple']:.1f}x real time, "
                  f"{row['time_ratio_to_first']:.2f}x the time of {versions[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
