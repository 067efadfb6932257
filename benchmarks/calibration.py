"""Online calibration (rio.calibration): each radar's mount and time offset from a simulated calibration drive
with a miscalibrated rig (rio.calibration_drive: 2 deg yaw, 1 deg pitch, 2 cm lever arm wrong on every radar,
one radar 5 ms late), against the drive's length; and the odometry's drift with the true rig, the wrong rig,
and the wrong rig calibrated online. The drive starts and stops at ``--accel`` (1 m/s^2 by default; the time
offset shows only while the velocity changes, and 2 m/s^2 shows it better: benchmarks/calibration_time_offset.py).

    python benchmarks/calibration.py [--quick] [--accel 1.0]

Writes docs/results/calibration.json and docs/results/calibration.png.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rio.calibration import AXIS_KEYS, calibrate  # noqa: E402
from rio.calibration_drive import SIM_EKF, calibration_drive, estimate_errors, simulate_drive  # noqa: E402
from rio.evaluation import drift_report  # noqa: E402
from rio.odometry import RioOptions, run_rio  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two short drives, one seed")
    ap.add_argument("--accel", type=float, default=1.0, help="the drive's acceleration and braking, m/s^2")
    args = ap.parse_args(argv)
    lengths_s = (20.0, 40.0) if args.quick else (20.0, 40.0, 60.0, 90.0, 120.0)
    seeds = (1,) if args.quick else (1, 2)
    rows = []
    for duration in lengths_s:
        traj = calibration_drive(repeats=int(math.ceil(duration / 12)) + 1, accel_mps2=args.accel)
        for seed in seeds:
            imu, wrong, right = simulate_drive(traj, duration, seed)
            result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
            drift = {name: drift_report(run_rio(imu, scans, RioOptions(ekf=SIM_EKF)).trajectory, traj)
                     for name, scans in (("true_rig", right), ("wrong_rig", wrong))}
            drift["calibrated"] = drift_report(result.rio.trajectory, traj)
            per_radar = {}
            for name, r in result.radars.items():
                err = estimate_errors(result, name)
                per_radar[name] = {
                    "error": dict(zip(AXIS_KEYS, _units(err))), "sigma": dict(zip(AXIS_KEYS, _units(r.estimate.sigma))),
                    "taken": dict(zip(AXIS_KEYS, map(bool, r.accepted)))}
            rows.append({"duration_s": duration, "seed": seed, "distance_m": drift["true_rig"]["distance_m"],
                         "radars": per_radar,
                         "drift": {k: {"ate_rmse_m": v["ate_rmse_m"], "final_drift_m": v["final_drift_m"]}
                                   for k, v in drift.items()}})
            print(f"{duration:5.0f} s seed {seed}: yaw error {max(abs(p['error']['yaw']) for p in per_radar.values()):.3f} deg, "
                  f"lever {max(abs(p['error']['lever_x']) + abs(p['error']['lever_y']) for p in per_radar.values()):.1f} mm, "
                  f"time offset {max(abs(p['error']['time_offset']) for p in per_radar.values()):.2f} ms; ATE true "
                  f"{drift['true_rig']['ate_rmse_m'] * 1e3:.1f} mm, wrong {drift['wrong_rig']['ate_rmse_m'] * 1e3:.1f} mm, "
                  f"calibrated {drift['calibrated']['ate_rmse_m'] * 1e3:.1f} mm")
    out = {"units": {"roll": "deg", "pitch": "deg", "yaw": "deg", "lever_x": "mm", "lever_y": "mm", "lever_z": "mm",
                     "time_offset": "ms"},
           "scenario": "rio.calibration_drive: 2 deg yaw, 1 deg pitch, 2 cm lever arm wrong on each radar; left_rear 5 ms "
                       f"late; starts and stops at {args.accel:g} m/s^2",
           "accel_mps2": args.accel, "load_average_1min": os.getloadavg()[0], "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "calibration.json").write_text(json.dumps(out, indent=2))
    plot(rows, RESULTS / "calibration.png")
    print(f"wrote {RESULTS / 'calibration.json'} and calibration.png")
    return 0


def _units(values) -> list[float]:
    """[7] in deg, deg, deg, mm, mm, mm, ms."""
    v = np.asarray(values, float)
    return [float(x) for x in np.concatenate([np.degrees(v[:3]), v[3:6] * 1e3, v[6:] * 1e3])]


def plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(17, 4))
    durations = sorted({r["duration_s"] for r in rows})
    for ax, keys, unit, tolerance in ((axes[0], ("yaw", "pitch"), "deg", 0.2), (axes[1], ("lever_x", "lever_y"), "mm", 5.0),
                                      (axes[2], ("time_offset",), "ms", 0.5)):
        for key in keys:
            err = [np.max([abs(p["error"][key]) for r in rows if r["duration_s"] == d for p in r["radars"].values()])
                   for d in durations]
            sig = [np.max([p["sigma"][key] for r in rows if r["duration_s"] == d for p in r["radars"].values()])
                   for d in durations]
            line, = ax.plot(durations, err, "o-", label=f"{key}: largest error")
            ax.plot(durations, sig, "--", color=line.get_color(), label=f"{key}: largest sigma")
        ax.axhline(tolerance, color="k", lw=0.8, ls=":", label="tolerance")
        ax.set_yscale("log")
        ax.set_xlabel("calibration drive (s)")
        ax.set_ylabel(unit)
        ax.legend(fontsize=7)
    axes[0].set_title("mount rotation (pitch: not taken, a floor robot cannot show it)", fontsize=9)
    axes[1].set_title("lever arm in the plane", fontsize=9)
    axes[2].set_title("time offset (one radar 5 ms late)", fontsize=9)
    ax = axes[3]
    for key, marker in (("true_rig", "o"), ("wrong_rig", "s"), ("calibrated", "^")):
        ate = [np.mean([r["drift"][key]["ate_rmse_m"] * 1e3 for r in rows if r["duration_s"] == d]) for d in durations]
        ax.plot(durations, ate, marker + "-", label=key.replace("_", " "))
    ax.set_xlabel("drive (s)")
    ax.set_ylabel("ATE RMSE (mm)")
    ax.set_title("odometry drift with and without calibration", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
