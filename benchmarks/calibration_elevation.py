"""The Doppler fit's vertical-velocity bias from elevation noise (issue 35), and what removing it does to the
calibration: the fit on measured directions (``elevation_sigma_deg`` 0, the old fit) against the fit with the
vertical cross-talk removed (rio.ego_velocity.remove_crosstalk, for 3 deg of elevation and 1 deg of azimuth
noise: the default), and where it is cheap to run, the alternative not taken: the corrected score (every
moment of the fit noise-corrected, ``corrected_score_fit``), unbiased too but noisier.

1. ``mechanism``: synthetic detections with known directions, elevation spread and angle noise (the simulated
   radar's: 3 deg elevation, 1 deg azimuth, 0.02 m/s Doppler), moving along the boresight: the fits' mean
   vertical error per m/s against ``fit_gain``'s prediction, for many detections (the limit the prediction is
   for) and for a scan's worth.
2. ``drives``: the calibration drives (rio.calibration_drive, as benchmarks/calibration.py, a subset of its
   lengths and seeds): per radar the Doppler fit's z error per m/s along x on the true scans, roll's error and
   sigma of ``calibrate()`` from the wrong rig (NEES over radars and drives), the pitch and lever z that
   ``calibrate()`` from the true rig settles at (the bias they absorb), and calibrated / true-rig-calibrated
   ATE. The two fits alternate per drive in one process.
3. ``odometry`` (``--odometry``): what the fit does to the odometry without calibration states, on
   benchmarks/odometry.py's quick drive (one lap of the hall) and on the real hand-held bag (ATE and drift;
   the bag: its end against its start).

    python benchmarks/calibration_elevation.py [--lengths 40 60] [--seeds 1 2] [--mechanism-only] [--odometry]

Writes docs/results/calibration_elevation.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imaging.core.rig import default_rig  # noqa: E402
from rio.calibration import calibrate  # noqa: E402
from rio.calibration_drive import SIM_EKF, calibration_drive, estimate_errors, fits_with_truth, simulate_drive  # noqa: E402
from rio.ego_velocity import EgoStatus, EgoVelocity, EgoVelocityConfig, direction_moments, fit_gain, sensor_velocity  # noqa: E402
from rio.evaluation import drift_report  # noqa: E402
from rio.odometry import RioOptions  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
FITS = {"measured_directions": dataclasses.replace(EgoVelocityConfig(), elevation_sigma_deg=0.0, azimuth_sigma_deg=0.0),
        "crosstalk_removed": EgoVelocityConfig()}
#: The synthetic detections and the odometry also run the rejected alternative.
ALTERNATIVE = "corrected_score"


def corrected_score_fit(xyz_m, doppler_mps, config: EgoVelocityConfig = EgoVelocityConfig(), rng=None) -> EgoVelocity:
    """The alternative to remove_crosstalk: refit the plain fit's inliers with every moment noise-corrected
    (the true directions' sum of u u^T estimated from the measured ones, the mean's attenuation undone) and a
    sandwich covariance; the plain fit where that would leave the geometry indefinite or ill-conditioned."""
    est = sensor_velocity(xyz_m, doppler_mps, FITS["measured_directions"], rng)
    r = np.linalg.norm(xyz_m, axis=1)
    if est.status is not EgoStatus.OK or np.ptp(xyz_m[:, 2]) < 1e-6:
        return est
    u_in, d_in = xyz_m[est.inliers] / r[est.inliers, None], doppler_mps[est.inliers]
    m, inv_gain = direction_moments(u_in, math.radians(config.elevation_sigma_deg), math.radians(config.azimuth_sigma_deg), -1)
    w = np.linalg.eigvalsh(m)
    if w[0] <= 0 or w[-1] / w[0] > config.max_condition:
        return est
    m_inv = np.linalg.inv(m)
    v = m_inv @ (inv_gain * (u_in.T @ -d_in))
    residual = u_in @ v + d_in
    sigma = max(config.min_sigma_mps, math.sqrt(residual @ residual / max(u_in.shape[0] - 3, 1)))
    sandwich = m_inv @ (inv_gain[:, None] * (u_in.T @ u_in) * inv_gain[None, :]) @ m_inv
    return dataclasses.replace(est, velocity_mps=v, covariance=sigma ** 2 * sandwich, sigma_mps=sigma)


def fit_of(name: str):
    """(xyz, doppler, rng) -> EgoVelocity for a fit's name."""
    if name == ALTERNATIVE:
        return lambda xyz, dop, rng=None: corrected_score_fit(xyz, dop, EgoVelocityConfig(), rng)
    return lambda xyz, dop, rng=None: sensor_velocity(xyz, dop, FITS[name], rng)
ELEVATION_SIGMA_DEG, AZIMUTH_SIGMA_DEG, DOPPLER_SIGMA_MPS = 3.0, 1.0, 0.02
#: (mean elevation, half-spread) of the synthetic scatterers, deg: a floor robot's room below the radar, a
#: room around it, one wider.
SCENES = ((-10.0, 10.0), (-5.0, 15.0), (0.0, 15.0))


def synthetic_fit_errors(n_detections: int, el_mean_deg: float, el_half_spread_deg: float, trials: int,
                         speed_mps: float = 0.6, seed: int = 1) -> dict:
    """The fits' mean error (m/s) over ``trials`` noise draws on one set of true directions, and fit_gain's
    prediction for the fit on measured directions."""
    rng = np.random.default_rng(seed)
    el = np.radians(rng.uniform(el_mean_deg - el_half_spread_deg, el_mean_deg + el_half_spread_deg, n_detections))
    az = np.radians(rng.uniform(-60, 60, n_detections))
    rng_m = rng.uniform(1.0, 8.0, n_detections)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    v = np.array([speed_mps, 0.0, 0.0])
    names = [*FITS, ALTERNATIVE]
    errors = {k: [] for k in names}
    sigmas = {k: [] for k in names}
    for _ in range(trials):
        el_m = el + np.radians(rng.normal(0, ELEVATION_SIGMA_DEG, n_detections))
        az_m = az + np.radians(rng.normal(0, AZIMUTH_SIGMA_DEG, n_detections))
        xyz = rng_m[:, None] * np.column_stack([np.cos(el_m) * np.cos(az_m), np.cos(el_m) * np.sin(az_m), np.sin(el_m)])
        doppler = -u @ v + rng.normal(0, DOPPLER_SIGMA_MPS, n_detections)
        for key in names:
            est = fit_of(key)(xyz, doppler)
            if est.status is EgoStatus.OK:
                errors[key].append(est.velocity_mps - v)
                sigmas[key].append(math.sqrt(est.covariance[2, 2]))
    predicted = (fit_gain(u, math.radians(ELEVATION_SIGMA_DEG), math.radians(AZIMUTH_SIGMA_DEG)) - np.eye(3)) @ v
    row = {"detections": n_detections, "elevation_mean_deg": el_mean_deg, "elevation_half_spread_deg": el_half_spread_deg,
           "trials": trials, "predicted_z_per_x": float(predicted[2] / speed_mps)}
    for key in names:
        e = np.asarray(errors[key])
        row[key] = {"z_per_x": float(e[:, 2].mean() / speed_mps),
                    "z_per_x_standard_error": float(e[:, 2].std() / math.sqrt(len(e)) / speed_mps),
                    "z_error_std_mps": float(e[:, 2].std()), "z_sigma_mean_mps": float(np.mean(sigmas[key]))}
    return row


def drive_fit_errors(traj, scans, config: EgoVelocityConfig, block: int = 20) -> dict[str, dict]:
    """Per radar over the true scans: the Doppler fit's z error per m/s along x (least-squares line), the z
    error's NEES against the fit's own variance, and the variance of its mean over ``block`` consecutive scans
    against white noise's (1 if the scans' errors are independent, as the filter takes them)."""
    rng = np.random.default_rng(0)
    rig = default_rig()
    out = {}
    for name in rig.radar_names:
        mount = rig.radar(name).mount
        err, vx, normalised = [], [], []
        for est, v_sensor in fits_with_truth(traj, scans, name, mount, rng, config):
            err.append(est.velocity_mps[2] - v_sensor[2])
            vx.append(v_sensor[0])
            normalised.append(err[-1] / math.sqrt(est.covariance[2, 2]))
        vx, err, z = np.asarray(vx), np.asarray(err), np.asarray(normalised)
        blocks = z[:z.size // block * block].reshape(-1, block).mean(axis=1)
        out[name] = {"z_per_x": float(vx @ err / (vx @ vx)), "z_nees": float(np.mean(z ** 2)),
                     f"z_block{block}_variance_ratio": float(blocks.var() * block / np.mean(z ** 2))}
    return out


def drive_row(duration_s: float, seed: int, config: EgoVelocityConfig, accel_mps2: float) -> dict:
    traj = calibration_drive(repeats=int(math.ceil(duration_s / 12)) + 1, accel_mps2=accel_mps2)
    imu, wrong, right = simulate_drive(traj, duration_s, seed)
    options = RioOptions(ekf=SIM_EKF, ego=config)
    started = time.perf_counter()
    result = calibrate(imu, wrong, options)
    reference = calibrate(imu, right, options)
    ate = {"calibrated": drift_report(result.rio.trajectory, traj)["ate_rmse_m"],
           "true_rig_calibrated": drift_report(reference.rio.trajectory, traj)["ate_rmse_m"]}
    radars = {}
    for name, r in result.radars.items():
        err = estimate_errors(result, name)
        ref_err = estimate_errors(reference, name, late_stamps=False)
        radars[name] = {"roll_error_deg": math.degrees(err[0]), "roll_sigma_deg": math.degrees(r.estimate.sigma[0]),
                        "true_rig_calibrated_roll_error_deg": math.degrees(ref_err[0]),
                        "true_rig_calibrated_roll_sigma_deg": math.degrees(reference.radars[name].estimate.sigma[0]),
                        "true_rig_calibrated_pitch_deg": math.degrees(ref_err[1]),
                        "true_rig_calibrated_lever_z_mm": ref_err[5] * 1e3,
                        "yaw_error_deg": math.degrees(err[2]), "yaw_sigma_deg": math.degrees(r.estimate.sigma[2])}
    return {"duration_s": duration_s, "seed": seed, "radars": radars, "ate_rmse_m": ate,
            "ate_ratio_calibrated_to_true_rig_calibrated": ate["calibrated"] / ate["true_rig_calibrated"],
            "fit_errors": drive_fit_errors(traj, right, config), "wall_time_s": time.perf_counter() - started}


def odometry_rows(seeds=(10, 11, 12)) -> dict:
    """benchmarks/odometry.py's one-lap drive (its quick form's seed 10, and more seeds) and the real bag
    through each fit, alternating. The alternative is put in the odometry's place of sensor_velocity (the
    odometry has no switch for a fit that is not rio's)."""
    import contextlib
    import logging
    import tempfile
    from unittest import mock

    from acquisition.importers.bag import import_bag
    from benchmarks.odometry import long_drive, run
    from imaging.sim.simulator import simulate_recording
    from rio.ekf import EkfConfig

    logging.basicConfig(level=logging.ERROR)
    names = [*FITS, ALTERNATIVE]
    out = {k: {"hall_1_lap": []} for k in names}

    def fitted_by(key):
        if key == ALTERNATIVE:
            return mock.patch("rio.odometry.sensor_velocity", lambda xyz, dop, config, rng: corrected_score_fit(xyz, dop, config, rng))
        return contextlib.nullcontext()

    def options(key, **kw):
        return RioOptions(ego=FITS.get(key, EgoVelocityConfig()), **kw)

    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            drive = Path(tmp) / f"drive1_{seed}.h5"
            simulate_recording(long_drive(1, seed=seed), drive)
            for key in names:
                with fitted_by(key):
                    res, truth, _ = run(drive, options(key))
                rep = drift_report(res.trajectory, truth)
                out[key]["hall_1_lap"].append({"seed": seed, **{k: rep[k] for k in ("distance_m", "ate_rmse_m", "final_drift_m",
                                                                                   "final_drift_percent")}})
                print(key, json.dumps(out[key]["hall_1_lap"][-1]), flush=True)
        data = ROOT.parent / "shared" / "data" / "ti_mmwave_rospkg_demo"
        if data.exists():
            bag = Path(tmp) / "bag.h5"
            import_bag(data / "ti_mmwave_rospkg_demo.bag", data / "calib_ti_mmwave_rospkg_dataset.yaml", bag)
            for key in names:
                with fitted_by(key):
                    res, _, _ = run(bag, options(key, ekf=EkfConfig(radar_velocity_sigma_floor_mps=0.1)))
                p = res.trajectory.position_m
                out[key]["real_bag"] = {"radar_updates": res.stats.get("radar_updates", 0),
                                        "refused_by_gate": res.stats.get("radar_rejected_by_gate", 0),
                                        "end_to_start_horizontal_m": float(np.linalg.norm(p[-1, :2] - p[0, :2])),
                                        "end_to_start_vertical_m": float(p[-1, 2] - p[0, 2])}
                print(key, json.dumps(out[key]["real_bag"]), flush=True)
    for row in out.values():
        row["hall_1_lap_ate_rmse_m_mean"] = float(np.mean([r["ate_rmse_m"] for r in row["hall_1_lap"]]))
    return out


def summary(rows: list[dict]) -> dict:
    radars = [p for r in rows for p in r["radars"].values()]
    z2 = [(p["roll_error_deg"] / p["roll_sigma_deg"]) ** 2 for p in radars]
    z2_ref = [(p["true_rig_calibrated_roll_error_deg"] / p["true_rig_calibrated_roll_sigma_deg"]) ** 2 for p in radars]
    worst = max(radars, key=lambda p: abs(p["roll_error_deg"]))
    fits = [x for r in rows for x in r["fit_errors"].values()]
    slopes = [x["z_per_x"] for x in fits]
    pitch = [p["true_rig_calibrated_pitch_deg"] for p in radars]
    lever_z = [p["true_rig_calibrated_lever_z_mm"] for p in radars]
    ratios = [r["ate_ratio_calibrated_to_true_rig_calibrated"] for r in rows]
    return {"radar_drives": len(radars), "roll_nees": float(np.mean(z2)), "roll_nees_true_rig_calibrated": float(np.mean(z2_ref)),
            "roll_largest_error_deg": worst["roll_error_deg"], "roll_sigma_at_largest_error_deg": worst["roll_sigma_deg"],
            "roll_largest_error_over_sigma": float(max(np.sqrt(z2))),
            "fit_bias_z_per_x_range": [min(slopes), max(slopes)],
            "fit_z_nees_range": [min(x["z_nees"] for x in fits), max(x["z_nees"] for x in fits)],
            "fit_z_block20_variance_ratio_mean": float(np.mean([x["z_block20_variance_ratio"] for x in fits])),
            "true_rig_calibrated_pitch_deg_range": [min(pitch), max(pitch)],
            "true_rig_calibrated_lever_z_mm_range": [min(lever_z), max(lever_z)],
            "ate_ratio_range": [min(ratios), max(ratios)],
            "within_10_percent": sum(abs(x - 1) <= 0.1 for x in ratios), "drives": len(rows)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", type=float, nargs="+", default=[40.0, 60.0], help="drive lengths, s")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--accel", type=float, default=2.0, help="the drive's acceleration and braking, m/s^2")
    ap.add_argument("--trials", type=int, default=300, help="noise draws per synthetic scene")
    ap.add_argument("--mechanism-only", action="store_true", help="only the synthetic detections")
    ap.add_argument("--odometry", action="store_true", help="also the odometry's quick drive and the real bag")
    ap.add_argument("--odometry-only", action="store_true", help="only the odometry part (its own JSON, --out)")
    ap.add_argument("--out", type=Path, default=RESULTS / "calibration_elevation.json")
    args = ap.parse_args(argv)
    started_load = load_average()
    started = time.perf_counter()
    load = [started_load[0]]
    if args.odometry_only:
        out = {"what": "calibration_elevation.py --odometry-only: " + __doc__.split("3. ")[1].split("\n\n")[0].replace("\n", " "),
               "odometry": odometry_rows(), "load_average_1min": [load[0], os.getloadavg()[0]],
               "wall_time_s": time.perf_counter() - started}
        write_results(args.out.stem, out, started_load=started_load, folder=args.out.parent)
        print(f"wrote {args.out}")
        return 0
    mechanism = []
    for n in (600, 80):
        for el_mean, spread in SCENES:
            row = synthetic_fit_errors(n, el_mean, spread, args.trials)
            mechanism.append(row)
            print(f"{n} detections, elevation {el_mean:+.0f} +- {spread:.0f} deg: z per x predicted "
                  f"{row['predicted_z_per_x']:+.4f}; " + "; ".join(
                      f"{k} {row[k]['z_per_x']:+.4f} +- {row[k]['z_per_x_standard_error']:.4f} (z error std "
                      f"{row[k]['z_error_std_mps']:.4f} m/s)" for k in (*FITS, ALTERNATIVE)), flush=True)
    drives = {k: [] for k in FITS}
    if not args.mechanism_only:
        for duration in args.lengths:
            for seed in args.seeds:
                for key, config in FITS.items():  # alternating: the load changes alike for both
                    drives[key].append(drive_row(duration, seed, config, args.accel))
                    load.append(os.getloadavg()[0])
                    r = drives[key][-1]
                    print(f"{duration:.0f} s seed {seed} {key}: roll (error, sigma) deg "
                          + ", ".join(f"({p['roll_error_deg']:+.3f}, {p['roll_sigma_deg']:.3f})" for p in r["radars"].values())
                          + "; true rig pitch deg " + ", ".join(f"{p['true_rig_calibrated_pitch_deg']:+.2f}" for p in r["radars"].values())
                          + f"; ATE ratio {r['ate_ratio_calibrated_to_true_rig_calibrated']:.3f}; {r['wall_time_s']:.0f} s", flush=True)
    odometry = odometry_rows() if args.odometry else None
    out = {"what": __doc__.split("\n\n")[0].replace("\n", " "),
           "fits": {**{k: dataclasses.asdict(v) for k, v in FITS.items()},
                    ALTERNATIVE: "benchmarks/calibration_elevation.py corrected_score_fit (synthetic detections and odometry only)"},
           "angle_noise_deg": {"elevation": ELEVATION_SIGMA_DEG, "azimuth": AZIMUTH_SIGMA_DEG},
           "mechanism": mechanism, "accel_mps2": args.accel,
           "drives": {k: {"rows": v, "summary": summary(v)} for k, v in drives.items() if v},
           **({"odometry": odometry} if odometry else {}),
           "load_average_1min": load, "wall_time_s": time.perf_counter() - started}
    write_results(args.out.stem, out, started_load=started_load, folder=args.out.parent)
    for key, d in out["drives"].items():
        print(key, json.dumps(d["summary"]))
    print(f"wrote {args.out} in {out['wall_time_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
