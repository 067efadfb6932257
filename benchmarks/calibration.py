"""Online calibration (rio.calibration): each radar's mount and time offset from a simulated calibration drive
with a miscalibrated rig (rio.calibration_drive: 2 deg yaw, 1 deg pitch, 2 cm lever arm wrong on every radar,
one radar 5 ms late), against the drive's length; and the odometry's drift (ATE) on each drive.

What "the drift equals the run with the true rig" compares (issue 35): calibration adds 7 error states per
radar to the filter, and those states change the filter by themselves, on the true rig too. So the wrong rig
calibrated online (``calibrated``) is compared with the true rig through the same filter (``true_rig_calibrated``:
``calibrate()`` with the true rig as its prior, calibration states on). The true rig without calibration states
(``true_rig``) is its own column: with it, what the extra states do by themselves.

Why the extra states change the filter: the plain Doppler fit's vertical velocity is biased in proportion to
the velocity along the boresight (``fit_bias``: errors in the detections' elevation, 3 deg, over scatterers
mostly below or above the radar), which a mount rotation about the sensor's y axis (pitch) describes. With the
calibration states on, each radar's pitch and the lever arm along z (which ``sarbot calibrate`` refuses: a floor
robot cannot show them) moved to absorb it, on the true rig as on the wrong one. rio.ego_velocity now takes
that cross-talk out (``remove_crosstalk``; benchmarks/calibration_elevation.py measures it before and after). ``true_rig_pinned`` is the true
rig with those two axes held (prior 0), ``true_rig_pitch_lever_z`` the true rig with only those two free.

The drive starts and stops at ``--accel`` (2 m/s^2 by default: the time offset shows only while the velocity
changes, benchmarks/calibration_time_offset.py).

    python benchmarks/calibration.py [--quick] [--accel 2.0]

Writes docs/results/calibration.json and docs/results/calibration.png.
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
from rio.calibration_drive import SIM_EKF, calibration_drive, estimate_errors, fits_with_truth, simulate_drive  # noqa: E402
from rio.evaluation import drift_report  # noqa: E402
from rio.odometry import RioOptions, run_rio  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RUNS = {
    "wrong_rig": "the wrong rig file, no calibration",
    "true_rig": "the true rig, no calibration (the 15-state filter)",
    "true_rig_calibrated": "calibrate() from the true rig: the same filter as calibrated, on the true rig (the reference)",
    "calibrated": "calibrate() from the wrong rig (one pass)",
    "calibrated_iterated": "calibrate(iterations=2) from the wrong rig (sarbot calibrate --iterations 2)",
    "true_rig_pinned": "calibrate() from the true rig with pitch and lever arm z held (prior 0)",
    "true_rig_pitch_lever_z": "the true rig with only pitch and lever arm z calibrated",
}


def held(axes: str) -> dict:
    """calibration_priors that hold pitch and lever z ("pitch_lever_z") or everything but them ("others")."""
    on = math.radians(3.0), 0.05, 0.01  # EkfConfig's default priors
    if axes == "pitch_lever_z":
        prior = CalibrationPrior((3.0, 0.0, 3.0), (on[1], on[1], 0.0), time_offset_sigma_s=on[2])
    else:
        prior = CalibrationPrior((0.0, 3.0, 0.0), (0.0, 0.0, on[1]), time_offset_sigma_s=0.0)
    return {name: prior for name in default_rig().radar_names}


def doppler_fit_errors(traj, scans) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per radar, over every scan the Doppler fit takes: the true sensor-frame velocity [N, 3] (m/s) and the
    fit's error along the sensor's z [N] (m/s). ``fit_bias`` and calibration_states' ``doppler_fit_slopes``
    regress the one on the other."""
    rng = np.random.default_rng(0)
    rig = default_rig()
    out = {}
    for name in rig.radar_names:
        mount = rig.radar(name).mount
        err, v = [], []
        for est, v_sensor in fits_with_truth(traj, scans, name, mount, rng):
            err.append(est.velocity_mps[2] - v_sensor[2])
            v.append(v_sensor)
        out[name] = (np.asarray(v).reshape(-1, 3), np.asarray(err))
    return out


def fit_bias(traj, scans) -> dict[str, float]:
    """Per radar, the slope of the Doppler fit's error along the sensor's z against the true velocity along its
    x (boresight): a least-squares line through every scan the fit takes; 0.017 is what a 1 deg pitch gives."""
    out = {}
    for name, (v, err) in doppler_fit_errors(traj, scans).items():
        vx = np.ascontiguousarray(v[:, 0])  # contiguous: the same sums, bit for bit, as the JSON's run
        out[name] = float(vx @ err / (vx @ vx))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one short drive, one seed")
    ap.add_argument("--accel", type=float, default=2.0, help="the drive's acceleration and braking, m/s^2")
    ap.add_argument("--out", type=Path, default=RESULTS, help="folder for calibration.json and .png")
    args = ap.parse_args(argv)
    started_load = load_average()
    lengths_s = (20.0,) if args.quick else (20.0, 40.0, 60.0, 90.0, 120.0)
    seeds = (1,) if args.quick else (1, 2)
    options = RioOptions(ekf=SIM_EKF)
    started = time.perf_counter()
    rows = []
    for duration in lengths_s:
        traj = calibration_drive(repeats=int(math.ceil(duration / 12)) + 1, accel_mps2=args.accel)
        for seed in seeds:
            imu, wrong, right = simulate_drive(traj, duration, seed)
            result = calibrate(imu, wrong, options)
            reference = calibrate(imu, right, options)
            runs = {"wrong_rig": run_rio(imu, wrong, options), "true_rig": run_rio(imu, right, options),
                    "true_rig_calibrated": reference.rio, "calibrated": result.rio,
                    "calibrated_iterated": calibrate(imu, wrong, options, iterations=2).rio,
                    "true_rig_pinned": calibrate(imu, right, RioOptions(ekf=SIM_EKF, calibration_priors=held("pitch_lever_z"))).rio,
                    "true_rig_pitch_lever_z": calibrate(imu, right, RioOptions(ekf=SIM_EKF, calibration_priors=held("others"))).rio}
            drift = {k: drift_report(v.trajectory, traj) for k, v in runs.items()}
            per_radar = {}
            for name, r in result.radars.items():
                err = estimate_errors(result, name)
                ref_err = estimate_errors(reference, name, late_stamps=False)
                per_radar[name] = {
                    "error": dict(zip(AXIS_KEYS, _units(err))), "sigma": dict(zip(AXIS_KEYS, _units(r.estimate.sigma))),
                    "taken": dict(zip(AXIS_KEYS, map(bool, r.accepted))),
                    "true_rig_calibrated_error": dict(zip(AXIS_KEYS, _units(ref_err)))}
            ate = {k: v["ate_rmse_m"] for k, v in drift.items()}
            rows.append({"duration_s": duration, "seed": seed, "distance_m": drift["true_rig"]["distance_m"],
                         "radars": per_radar,
                         "drift": {k: {"ate_rmse_m": v["ate_rmse_m"], "final_drift_m": v["final_drift_m"]}
                                   for k, v in drift.items()},
                         "ate_ratio": {"calibrated_to_true_rig_calibrated": ate["calibrated"] / ate["true_rig_calibrated"],
                                       "iterated_to_true_rig_calibrated": ate["calibrated_iterated"] / ate["true_rig_calibrated"],
                                       "calibrated_to_true_rig": ate["calibrated"] / ate["true_rig"],
                                       "true_rig_calibrated_to_true_rig": ate["true_rig_calibrated"] / ate["true_rig"],
                                       "true_rig_pinned_to_true_rig": ate["true_rig_pinned"] / ate["true_rig"],
                                       "true_rig_pitch_lever_z_to_true_rig": ate["true_rig_pitch_lever_z"] / ate["true_rig"]},
                         "fit_bias_z_per_x": fit_bias(traj, right)})
            ratio = rows[-1]["ate_ratio"]
            print(f"{duration:5.0f} s seed {seed}: yaw error {max(abs(p['error']['yaw']) for p in per_radar.values()):.3f} deg, "
                  f"lever {max(abs(p['error']['lever_x']) + abs(p['error']['lever_y']) for p in per_radar.values()):.1f} mm, "
                  f"time offset {max(abs(p['error']['time_offset']) for p in per_radar.values()):.2f} ms; ATE (mm) "
                  + ", ".join(f"{k} {v * 1e3:.2f}" for k, v in ate.items())
                  + f"; calibrated / true rig calibrated {ratio['calibrated_to_true_rig_calibrated']:.3f}, "
                  f"/ true rig {ratio['calibrated_to_true_rig']:.3f}", flush=True)
    ratios = {k: [r["ate_ratio"][k] for r in rows] for k in rows[0]["ate_ratio"]}
    long = [r for r in rows if r["duration_s"] >= 90]
    out = {"units": {"roll": "deg", "pitch": "deg", "yaw": "deg", "lever_x": "mm", "lever_y": "mm", "lever_z": "mm",
                     "time_offset": "ms"},
           "scenario": "rio.calibration_drive: 2 deg yaw, 1 deg pitch, 2 cm lever arm wrong on each radar; left_rear 5 ms "
                       f"late; starts and stops at {args.accel:g} m/s^2",
           "compares": "drift: ATE RMSE (position and yaw aligned) of each run in 'runs'; the issue's 'drift equals the run "
                       "with the true rig within 10 %' is ate_ratio.calibrated_to_true_rig_calibrated (the same filter "
                       "on both rigs); calibrated_to_true_rig is against the true rig without calibration states",
           "runs": RUNS,
           "fit_bias": "Doppler fit's error along the sensor's z per m/s along its x (true scans; a 1 deg pitch: 0.017)",
           "accel_mps2": args.accel, "load_average_1min": os.getloadavg()[0],
           "wall_time_s": time.perf_counter() - started,
           "summary": {
               **{f"{k}_range": [min(v), max(v)] for k, v in ratios.items()},
               "within_10_percent_of_true_rig_calibrated": sum(abs(x - 1) <= 0.1 for x in ratios["calibrated_to_true_rig_calibrated"]),
               "within_10_percent_of_true_rig": sum(abs(x - 1) <= 0.1 for x in ratios["calibrated_to_true_rig"]),
               "drives": len(rows),
               "fit_bias_z_per_x_range": [min(min(r["fit_bias_z_per_x"].values()) for r in rows),
                                          max(max(r["fit_bias_z_per_x"].values()) for r in rows)],
               "true_rig_calibrated_pitch_deg_range_90s_up": _range(long, "pitch"),
               "true_rig_calibrated_lever_z_mm_range_90s_up": _range(long, "lever_z")},
           "rows": rows}
    write_results("calibration", out, started_load=started_load, folder=args.out)
    plot(rows, args.out / "calibration.png")
    print(f"wrote {args.out / 'calibration.json'} and calibration.png in {out['wall_time_s']:.0f} s")
    return 0


def _range(rows, key: str) -> list[float]:
    values = [p["true_rig_calibrated_error"][key] for r in rows for p in r["radars"].values()]
    return [min(values), max(values)] if values else []


def _units(values) -> list[float]:
    """[7] in deg, deg, deg, mm, mm, mm, ms."""
    v = np.asarray(values, float)
    return [float(x) for x in np.concatenate([np.degrees(v[:3]), v[3:6] * 1e3, v[6:] * 1e3])]


def plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 5, figsize=(21, 4))
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
    axes[0].set_title("mount rotation (pitch: taken only after enough turning; benchmarks/calibration_pitch.py)", fontsize=9)
    axes[1].set_title("lever arm in the plane", fontsize=9)
    axes[2].set_title("time offset (one radar 5 ms late)", fontsize=9)
    ax = axes[3]
    for key, marker in (("true_rig", "o"), ("wrong_rig", "s"), ("true_rig_calibrated", "D"), ("calibrated", "^")):
        ate = [np.mean([r["drift"][key]["ate_rmse_m"] * 1e3 for r in rows if r["duration_s"] == d]) for d in durations]
        ax.plot(durations, ate, marker + "-", label=key.replace("_", " "))
    ax.set_yscale("log")
    ax.set_xlabel("drive (s)")
    ax.set_ylabel("ATE RMSE (mm), mean of the seeds")
    ax.set_title("odometry drift with and without calibration", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[4]
    x = np.array([r["duration_s"] for r in rows]) + np.array([(r["seed"] - 1.5) * 2 for r in rows])
    for key, marker, label in (("calibrated_to_true_rig_calibrated", "^", "calibrated / true rig calibrated (the issue's)"),
                               ("calibrated_to_true_rig", "o", "calibrated / true rig without calibration"),
                               ("true_rig_calibrated_to_true_rig", "D", "true rig: calibration states on / off")):
        ax.plot(x, [r["ate_ratio"][key] for r in rows], marker, label=label)
    ax.axhspan(0.9, 1.1, color="0.9", label="within 10 %")
    ax.set_xlabel("drive (s), each seed")
    ax.set_ylabel("ATE ratio")
    ax.set_title("drift against the true rig, per drive", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
