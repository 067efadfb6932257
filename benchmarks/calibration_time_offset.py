"""What limits the online time-offset calibration (rio.calibration) on the simulated calibration drive
(rio.calibration_drive): the Doppler fit's real velocity error against the floor the filter adds to it, and the
time offset's error and standard deviation, with the NEES of the observable axes, for the filter's settings and
drives given (the floor on the radar velocity's noise; the drive's acceleration).

    python benchmarks/calibration_time_offset.py [--quick]

Writes docs/results/calibration_time_offset.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rio.calibration import AXIS_KEYS, calibrate  # noqa: E402
from rio.calibration_drive import LATE_RADAR, SIM_EKF, calibration_drive, estimate_errors, simulate_drive  # noqa: E402
from rio.ego_velocity import sensor_velocity  # noqa: E402
from rio.odometry import RioOptions  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
OBSERVABLE = [AXIS_KEYS.index(k) for k in ("yaw", "lever_x", "lever_y", "time_offset")]


def fit_error(duration_s: float = 40.0, seed: int = 1) -> dict:
    """The ego-velocity fit's error against the true sensor velocity, per sensor axis (m/s): its standard
    deviation and the fit's own median standard deviation."""
    traj = calibration_drive(repeats=int(math.ceil(duration_s / 12)) + 1)
    _, _, right = simulate_drive(traj, duration_s, seed)
    errors, sigmas = [], []
    for s in right:
        est = sensor_velocity(s.xyz_m, s.doppler_mps)
        if not est.ok or est.velocity_mps is None:
            continue
        true = traj.sample(np.array([s.time_ns], np.int64))
        v_body = true.rotation.as_matrix()[0].T @ true.velocity_mps[0]
        v_sensor = s.mount.rotation_matrix.T @ (v_body + np.cross(true.angular_velocity_body_radps[0], s.mount.translation_m))
        errors.append(est.velocity_mps - v_sensor)
        sigmas.append(np.sqrt(np.diag(est.covariance)))
    errors, sigmas = np.array(errors), np.array(sigmas)
    return {"scans": len(errors), "error_std_mps": errors.std(axis=0).tolist(), "error_mean_mps": errors.mean(axis=0).tolist(),
            "fit_sigma_median_mps": np.median(sigmas, axis=0).tolist(),
            # the isotropic floor that, added in quadrature to the fit's own sigma, gives each axis's real error
            "floor_needed_mps": np.sqrt(np.maximum(errors.std(axis=0) ** 2 - np.median(sigmas, axis=0) ** 2, 0)).tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one 60 s drive")
    ap.add_argument("--configs", default="1.0:0.008,1.0:0.0045,2.0:0.008,2.0:0.0045",
                    help="ACCEL_MPS2:FLOOR_MPS,... the drive's acceleration and the filter's velocity floor")
    args = ap.parse_args(argv)
    started_load = load_average()
    duration_s, seeds = (60.0, (1,)) if args.quick else (120.0, (1, 2))
    configs = [tuple(float(x) for x in c.split(":")) for c in args.configs.split(",")]
    out = {"fit": fit_error(), "duration_s": duration_s, "rows": []}
    print(json.dumps(out["fit"]), flush=True)
    for accel in sorted({a for a, _ in configs}):
        traj = calibration_drive(repeats=int(math.ceil(duration_s / 12)) + 1, accel_mps2=accel)
        for seed in seeds:
            imu, wrong, _ = simulate_drive(traj, duration_s, seed)
            for _, floor in (c for c in configs if c[0] == accel):
                ekf = dataclasses.replace(SIM_EKF, radar_velocity_sigma_floor_mps=floor)
                result = calibrate(imu, wrong, RioOptions(ekf=ekf))
                radars = {}
                for name, r in result.radars.items():
                    err, sig = estimate_errors(result, name), r.estimate.sigma
                    radars[name] = {"time_offset_error_ms": float(err[6] * 1e3), "time_offset_sigma_ms": float(sig[6] * 1e3),
                                    "lever_x_error_mm": float(err[3] * 1e3), "lever_x_sigma_mm": float(sig[3] * 1e3),
                                    "nees_observable": float(np.sum((err[OBSERVABLE] / sig[OBSERVABLE]) ** 2))}
                row = {"accel_mps2": accel, "velocity_floor_mps": floor, "seed": seed, "radars": radars,
                       "time_offset_error_max_ms": max(abs(r["time_offset_error_ms"]) for r in radars.values()),
                       "nees_mean": float(np.mean([r["nees_observable"] for r in radars.values()]))}
                out["rows"].append(row)
                print(f"accel {accel} floor {floor} seed {seed}: time offset error max {row['time_offset_error_max_ms']:.3f} ms, "
                      f"sigma {np.mean([r['time_offset_sigma_ms'] for r in radars.values()]):.3f} ms, NEES "
                      f"{row['nees_mean']:.2f}, lever x error mean "
                      f"{np.mean([r['lever_x_error_mm'] for r in radars.values()]):+.2f} mm", flush=True)
    out["late_radar"] = LATE_RADAR
    out["load_average_1min"] = os.getloadavg()[0]
    write_results("calibration_time_offset", out, started_load=started_load)
    return 0


if __name__ == "__main__":
    sys.exit(main())
