"""What the calibration states do to the odometry by themselves (issue 35): on the true rig, calibration
off against calibration on, and each group of calibration axes freed alone (the others held at the truth,
prior 0), on the 120 s simulated calibration drives of benchmarks/calibration.py. Per run: the ATE and how
far each freed axis moved from the truth; per drive: the Doppler fit's vertical-velocity error per m/s along
the boresight and along the array, which a mount pitch and roll would describe.

    python benchmarks/calibration_states.py [--quick]

Writes docs/results/calibration_states.json.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imaging.core.rig import CalibrationPrior, default_rig  # noqa: E402
from rio.calibration import AXIS_KEYS, calibrate  # noqa: E402
from rio.calibration_drive import SIM_EKF, calibration_drive, estimate_errors, simulate_drive  # noqa: E402
from rio.evaluation import drift_report  # noqa: E402
from rio.odometry import RioOptions, run_rio  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
from calibration import _units, doppler_fit_errors  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
#: Calibration axes freed together (indices into rio.calibration.AXIS_KEYS).
GROUPS = {"roll": (0,), "pitch": (1,), "yaw": (2,), "lever_xy": (3, 4), "lever_z": (5,), "time_offset": (6,)}
DEFAULT_SIGMA = np.array([3.0, 3.0, 3.0, 0.05, 0.05, 0.05, 0.01])  # deg, m, s: EkfConfig's priors


def freeing(axes) -> dict:
    """calibration_priors with only ``axes`` free (the filter's default prior) and the others held."""
    s = np.where(np.isin(np.arange(7), axes), DEFAULT_SIGMA, 0.0)
    prior = CalibrationPrior(tuple(s[0:3]), tuple(s[3:6]), time_offset_sigma_s=float(s[6]))
    return {name: prior for name in default_rig().radar_names}


def doppler_fit_slopes(traj, scans) -> dict[str, dict[str, float]]:
    """Per radar, the Doppler fit's error along the sensor's z per m/s of true velocity along its x (what a
    mount rotation about y, the pitch, describes: 0.017 for 1 deg) and along its y (a rotation about x, the
    roll): a least-squares fit of the error on both through every scan the fit takes."""
    out = {}
    for name, (v, err) in doppler_fit_errors(traj, scans).items():
        slope = np.linalg.lstsq(v[:, :2], err, rcond=None)[0]
        out[name] = {"z_per_x": float(slope[0]), "z_per_y": float(slope[1])}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one short drive")
    ap.add_argument("--accel", type=float, default=2.0, help="the drive's acceleration and braking, m/s^2")
    ap.add_argument("--out", type=Path, default=RESULTS, help="folder for calibration_states.json")
    args = ap.parse_args(argv)
    started_load = load_average()
    lengths_s, seeds = ((20.0,), (1,)) if args.quick else ((120.0,), (1, 2))
    started = time.perf_counter()
    rows = []
    for duration in lengths_s:
        traj = calibration_drive(repeats=int(math.ceil(duration / 12)) + 1, accel_mps2=args.accel)
        for seed in seeds:
            imu, _, right = simulate_drive(traj, duration, seed)
            off = drift_report(run_rio(imu, right, RioOptions(ekf=SIM_EKF)).trajectory, traj)["ate_rmse_m"]
            row = {"duration_s": duration, "seed": seed, "ate_off_mm": off * 1e3}
            moved = {}
            for group, axes in {"all": tuple(range(7)), **GROUPS}.items():
                result = calibrate(imu, right, RioOptions(ekf=SIM_EKF, calibration_priors=freeing(axes)))
                ate = drift_report(result.rio.trajectory, traj)["ate_rmse_m"]
                row[f"ratio_{group}"] = ate / off
                err = {n: _units(estimate_errors(result, n, late_stamps=False)) for n in result.radars}
                moved[group] = {AXIS_KEYS[i]: [err[n][i] for n in sorted(err)] for i in axes}
            row["moved_from_truth"] = moved
            row["doppler_fit_slopes"] = doppler_fit_slopes(traj, right)
            rows.append(row)
            print(f"{duration:5.0f} s seed {seed}: ATE off {off * 1e3:.2f} mm; on / off: "
                  + ", ".join(f"{g} {row[f'ratio_{g}']:.3f}" for g in ("all", *GROUPS)), flush=True)
    long = [r for r in rows if r["duration_s"] == max(lengths_s)]
    out = {"scenario": f"rio.calibration_drive on the true rig (no mount or clock wrong), starts and stops at {args.accel:g} "
                       "m/s^2; SIM_EKF",
           "compares": "ratio_GROUP: ATE RMSE with the calibration states of GROUP free (default priors: 3 deg, 5 cm, "
                       "10 ms; the others held at the truth) over the ATE without calibration states ('all': "
                       "every axis free, what calibrate() runs)",
           "moved_from_truth": "each freed axis's final estimate minus the truth per radar (sorted by name): deg, mm, ms",
           "doppler_fit_slopes": "per radar, the Doppler fit's error along the sensor's z per m/s of true velocity "
                                 "along its x (a 1 deg pitch: 0.017) and along its y (a 1 deg roll: 0.017)",
           "accel_mps2": args.accel, "load_average_1min": os.getloadavg()[0],
           "wall_time_s": time.perf_counter() - started,
           "summary": {f"longest_ratio_{g}": [min(r[f"ratio_{g}"] for r in long), max(r[f"ratio_{g}"] for r in long)]
                       for g in ("all", *GROUPS)},
           "rows": rows}
    write_results("calibration_states", out, started_load=started_load, folder=args.out)
    print(f"wrote {args.out / 'calibration_states.json'} in {out['wall_time_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
