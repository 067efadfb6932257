"""The odometry benchmark's accuracy figures with the filter of earlier commits, on the same recordings: which
change moved them.

The midpoint strapdown (f53ede5) was blamed for rio.json's figures getting worse (final drift 0.031 -> 0.043 %
on the 7-lap drive, the real bag's loop end 0.32 -> 0.43 m), but rio.json had last been run at fae5f5c, and
other changes to the filter came in between. Each version here is a tree of its own (``git archive COMMIT``,
with a numba cache of its own) whose ``rio.odometry.run_rio`` runs, in a process of its own, on recordings
simulated once by this checkout (the simulator's output has not changed since: the filter of 044b123 gives
rio.json's fae5f5c figures on them) and on the real bag imported once:

- ``044b123``: before the standstill changes (the filter rio.json measured at fae5f5c);
- ``1b9f9b5``: the IMU's stillness over 0.1 s, a tight zero-velocity update, zero-rate updates every 2 s of
  a standstill, the accelerometer bias along gravity from the static start;
- ``7744ef7``: the tight zero-velocity update only in a stop after driving;
- ``a6d4858``: the last commit before the midpoint strapdown;
- ``this checkout``;
- ``HEAD+loose_stop``: this checkout with the stops' tight zero-velocity update (0.002 m/s, 1b9f9b5) as loose
  as the radar's (0.02 m/s).

    python benchmarks/odometry_versions.py [--recordings DIR] [--versions C1,C2,...] [--quick]

``--recordings DIR`` keeps the simulated drives there and reuses them (their simulation takes 5-10 minutes
each). Writes docs/results/odometry_versions.json (``--quick``: the real bag only, 044b123 and this checkout,
to odometry_versions_quick.json).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from results_file import load_average, write_results

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
BAG = ROOT.parent / "shared" / "data" / "ti_mmwave_rospkg_demo"
VERSIONS = {
    "044b123": "before the standstill changes (the filter of rio.json at fae5f5c)",
    "1b9f9b5": "standstill: IMU stillness over 0.1 s, tight zero-velocity update, zero-rate updates every 2 s",
    "7744ef7": "the tight zero-velocity update only in a stop after driving",
    "a6d4858": "the last commit before the midpoint strapdown",
    "HEAD": "this checkout (the midpoint strapdown)",
    "HEAD+loose_stop": "this checkout, the stops' zero-velocity update at 0.02 m/s (the radar's) instead of 0.002 m/s",
}
#: Filter settings a version runs with (EkfConfig fields), beside its commit's defaults.
SETTINGS = {"HEAD+loose_stop": {"still_zero_velocity_sigma_mps": 0.02}}

#: Runs in a version's tree (sys.path[0]): the odometry on one recording, its figures as JSON on stdout.
RUNNER = r'''
import dataclasses, json, logging, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
logging.basicConfig(level=logging.ERROR)
from imaging.io.recording import Recording
from rio.ekf import EkfConfig
from rio.odometry import RioOptions, imu_from_recording, run_rio, scans_from_recording
path, case, settings = sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
radars = ("left_front",) if case == "one_radar" else None
with Recording(path) as rec:
    imu, scans = imu_from_recording(rec), scans_from_recording(rec, radars)
    truth = rec.truth() if case != "real_bag" else None
if case == "real_bag":
    settings["radar_velocity_sigma_floor_mps"] = 0.1
options = RioOptions(ekf=dataclasses.replace(EkfConfig(), **settings))
res = run_rio(imu, scans, options)
out = {"radar_updates": int(res.stats.get("radar_updates", 0))}
if truth is None:
    p = res.trajectory.position_m
    out["end_to_start_horizontal_m"] = float(np.linalg.norm(p[-1, :2] - p[0, :2]))
else:
    from rio.evaluation import drift_report
    rep = drift_report(res.trajectory, truth)
    out.update({k: float(rep[k]) for k in ("final_drift_percent", "ate_rmse_m", "final_yaw_error_deg")})
print(json.dumps(out))
'''


def summary(commit: str, cases: dict) -> dict:
    """One row of the results table: the figures rio.json quotes, flat, and every case's output under ``cases``."""
    row = {"commit": commit, "what": VERSIONS.get(commit, "")}
    for case in ("7_laps", "10_laps"):
        if case in cases:
            row[f"{case}_drift_percent"] = cases[case]["final_drift_percent"]
            row[f"{case}_ate_m"] = cases[case]["ate_rmse_m"]
    if "7_laps" in cases:
        row["7_laps_yaw_deg"] = cases["7_laps"]["final_yaw_error_deg"]
    if "one_radar" in cases:
        row["one_radar_drift_percent"] = cases["one_radar"]["final_drift_percent"]
    if "real_bag" in cases:
        row["real_bag_end_to_start_m"] = cases["real_bag"]["end_to_start_horizontal_m"]
        row["real_bag_radar_updates"] = cases["real_bag"]["radar_updates"]
    return {**row, "settings": SETTINGS.get(commit, {}), "cases": cases}


def version_tree(commit: str, tmp: Path) -> Path:
    """This checkout for HEAD, else the commit's packages from ``git archive`` in a directory of its own."""
    if commit.split("+")[0] == "HEAD":
        return ROOT
    tree = tmp / commit
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "rio", "imaging", "acquisition", "drivers"],
                             check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def recordings(directory: Path, simulated: bool = True) -> dict[str, Path]:
    """The 7- and 10-lap drives of benchmarks/odometry.py (simulated if not in ``directory``; none if not
    ``simulated``) and the real bag."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from odometry import long_drive

    from acquisition.importers.bag import import_bag
    from imaging.sim.simulator import simulate_recording

    out = {}
    for i, laps in enumerate((7, 10) if simulated else ()):
        path = directory / f"drive{laps}.h5"
        if not path.exists():
            part = path.with_suffix(".part.h5")
            simulate_recording(long_drive(laps, seed=10 + i), part, overwrite=True)
            part.rename(path)
        out[f"{laps}_laps"] = path
    bag = directory / "real_bag.h5"
    if not bag.exists():
        import_bag(BAG / "ti_mmwave_rospkg_demo.bag", BAG / "calib_ti_mmwave_rospkg_dataset.yaml", bag)
    out["real_bag"] = bag
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recordings", type=Path, help="keep and reuse the simulated drives here")
    ap.add_argument("--versions", default=",".join(VERSIONS))
    ap.add_argument("--quick", action="store_true", help="the real bag only, 044b123 and this checkout")
    args = ap.parse_args()
    started_load = load_average()
    versions = ["044b123", "HEAD"] if args.quick else args.versions.split(",")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        directory = args.recordings or tmp
        directory.mkdir(parents=True, exist_ok=True)
        recs = recordings(directory, simulated=not args.quick)
        runner = tmp / "runner.py"
        runner.write_text(RUNNER)
        cases = [("real_bag", recs["real_bag"])] if args.quick else \
            [("7_laps", recs["7_laps"]), ("one_radar", recs["7_laps"]), ("10_laps", recs["10_laps"]), ("real_bag", recs["real_bag"])]
        out: dict = {"versions": []}
        for commit in versions:
            tree = version_tree(commit, tmp)
            cases_out = {}
            for case, path in cases:
                run = subprocess.run([sys.executable, str(runner), str(tree), str(path), case,
                                      json.dumps(SETTINGS.get(commit, {}))], capture_output=True,
                                     text=True, cwd=tmp)
                if run.returncode != 0:
                    raise SystemExit(f"{commit} {case}: {run.stderr.strip().splitlines()[-1]}")
                cases_out[case] = json.loads(run.stdout.strip().splitlines()[-1])
                print(commit, case, cases_out[case], flush=True)
            out["versions"].append(summary(commit, cases_out))
    out["load_average_1min"] = os.getloadavg()[0]
    path = write_results("odometry_versions_quick" if args.quick else "odometry_versions", out, started_load=started_load)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
