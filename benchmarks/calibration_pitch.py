"""Does a sideways radar's pitch converge now, and why is roll's standard deviation a little small (issue 35)?

The pitch (rotation about the sensor's y, the array's axis) shows only in the vertical velocity: a velocity vx
along the boresight becomes vz = -vx sin(t). A floor robot gives a sideways radar vx only from w x l while it
turns (0.15 m of lever arm along the boresight's normal here). The roll (about the boresight) shows in the same vertical
velocity, from the velocity vy along the array: vz = vy sin(r). Both were refused / suspect while the Doppler
fit's vertical velocity was biased; rio.ego_velocity.remove_crosstalk took that bias out.

Per radar and drive, from calibrate() on the miscalibrated rig (rio.calibration_drive: 2 deg yaw, 1 deg pitch,
2 cm lever arm, one radar 5 ms late) and on the true rig through the same filter:

- pitch and roll: error, standard deviation, taken or not; the NEES over radar-drives;
- the information bound: the standard deviation the Doppler fits' own covariances (plus the filter's floor)
  allow on the true scans, sum over scans of d^T C^-1 d with d the velocity change per radian, for pitch alone
  and for pitch and roll together (what the filter can reach if nothing else were unknown);
- the Doppler fit's vertical error per m/s along x and along y (least squares on both), the z NEES per scan,
  and the variance of 20-scan means against white noise's (1 if independent, as the filter takes them): the
  candidates for roll's over-confidence.

Drives: ``curves`` (rio.calibration_drive.CURVES, the calibration drive of benchmarks/calibration.py, starts and
stops at 2 m/s^2), ``tight_turns`` (TIGHT_TURNS: circles at 3 rad/s both ways between short straights) and
``straight`` (tests/test_calibration.py's straight drive).

    python benchmarks/calibration_pitch.py [--quick] [--seeds 1 2 3]

Writes docs/results/calibration_pitch.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import PathWithTurns  # noqa: E402
from imaging.sim.scene import DEFAULT_START_TIME_NS as T0  # noqa: E402
from rio.calibration import CalibrationLimits, calibrate  # noqa: E402
from rio.calibration_drive import CURVES, SIM_EKF, TIGHT_TURNS, calibration_drive, estimate_errors, fits_with_truth, simulate_drive  # noqa: E402
from rio.odometry import RioOptions  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
OPTIONS = RioOptions(ekf=SIM_EKF)


def drive(kind: str, duration_s: float) -> PathWithTurns:
    if kind == "straight":  # tests/test_calibration.py's: 8 m with three stops
        return PathWithTurns(segments=[("straight", 8.0)], start_m=(0, 0, 0), speed_mps=0.6, accel_mps2=1.0,
                             start_delay_s=2.0, stops=((2.0, 0.5), (4.0, 0.5), (6.0, 0.5)), t0_ns=T0)
    segments = {"curves": CURVES, "tight_turns": TIGHT_TURNS}[kind]
    repeats = 2
    while True:
        traj = calibration_drive(segments, repeats=repeats, accel_mps2=2.0)
        if traj.duration_s >= duration_s + 1.0:
            return traj
        repeats += 1


def fit_statistics(traj, scans, block: int = 20) -> dict[str, dict]:
    """Per radar over the true scans: the information bound on roll and pitch, the fit's vertical error per
    m/s along x and y, its z NEES (against the fit's covariance plus the filter's floor) and the variance of
    ``block``-scan means of the normalised z error against white noise's."""
    rng = np.random.default_rng(0)
    rig = default_rig()
    floor2 = SIM_EKF.radar_velocity_sigma_floor_mps ** 2
    out = {}
    for name in rig.radar_names:
        mount = rig.radar(name).mount
        info = np.zeros((2, 2))
        v_all, ez, z = [], [], []
        for est, v in fits_with_truth(traj, scans, name, mount, rng):
            cov = est.covariance + np.eye(3) * floor2
            # the velocity's change per radian of roll and pitch (the filter's H: skew(v) on the rotation error)
            d = np.column_stack([np.cross(v, [1.0, 0.0, 0.0]), np.cross(v, [0.0, 1.0, 0.0])])
            info += d.T @ np.linalg.solve(cov, d)
            v_all.append(v)
            ez.append(est.velocity_mps[2] - v[2])
            z.append(ez[-1] / math.sqrt(cov[2, 2]))
        v_all, ez, z = np.asarray(v_all), np.asarray(ez), np.asarray(z)
        slope = np.linalg.lstsq(v_all[:, :2], ez, rcond=None)[0]
        blocks = z[:z.size // block * block].reshape(-1, block).mean(axis=1)
        # a drive that never turns gives the pitch no information: no bound (None)
        joint = np.linalg.inv(info) if np.linalg.cond(info) < 1e8 else np.full((2, 2), np.nan)
        out[name] = {"pitch_bound_alone_deg": _deg_or_none(1 / math.sqrt(info[1, 1]) if info[1, 1] > NO_INFORMATION else math.nan),
                     "pitch_bound_with_roll_deg": _deg_or_none(math.sqrt(joint[1, 1])),
                     "roll_bound_with_pitch_deg": _deg_or_none(math.sqrt(joint[0, 0])),
                     "rms_velocity_along_boresight_mps": float(np.sqrt(np.mean(v_all[:, 0] ** 2))),
                     "fit_z_per_x": float(slope[0]), "fit_z_per_y": float(slope[1]),
                     # a vertical error k vy is a roll of -k rad to the filter (velocity change v x e_x = (0, vz, -vy))
                     "roll_the_fit_error_stands_for_deg": math.degrees(-slope[1]),
                     "fit_z_nees": float(np.mean(z ** 2)),
                     f"fit_z_block{block}_variance_ratio": float(blocks.var() * block / np.mean(z ** 2))}
    return out


#: Less information than this (rad^-2: a bound wider than 30 deg) is none: a drive that never turned.
NO_INFORMATION = math.radians(30.0) ** -2


def _deg_or_none(rad: float) -> float | None:
    return None if not math.isfinite(rad) or rad > math.radians(30.0) else math.degrees(rad)


def _text(value: float | None) -> str:
    return "none" if value is None else f"{value:.3f}"


def drive_row(kind: str, duration_s: float, seed: int) -> dict:
    started = time.perf_counter()
    traj = drive(kind, duration_s)
    imu, wrong, right = simulate_drive(traj, duration_s, seed)
    result = calibrate(imu, wrong, OPTIONS)
    reference = calibrate(imu, right, OPTIONS)
    fits = fit_statistics(traj, right)
    radars = {}
    for name, r in result.radars.items():
        err = estimate_errors(result, name)
        ref = reference.radars[name]
        ref_err = estimate_errors(reference, name, late_stamps=False)
        radars[name] = {"pitch_error_deg": math.degrees(err[1]), "pitch_sigma_deg": math.degrees(r.estimate.sigma[1]),
                        "pitch_taken": bool(r.accepted[1]),
                        "pitch_refusal": r.reasons.get("pitch", ""),
                        "roll_error_deg": math.degrees(err[0]), "roll_sigma_deg": math.degrees(r.estimate.sigma[0]),
                        "true_rig_pitch_error_deg": math.degrees(ref_err[1]),
                        "true_rig_pitch_sigma_deg": math.degrees(ref.estimate.sigma[1]),
                        "true_rig_roll_error_deg": math.degrees(ref_err[0]),
                        "true_rig_roll_sigma_deg": math.degrees(ref.estimate.sigma[0]),
                        **fits[name]}
    return {"drive": kind, "duration_s": duration_s, "seed": seed, "turning_s": result.drive.turning_s,
            "radars": radars, "wall_time_s": time.perf_counter() - started}


def summary(rows: list[dict]) -> dict:
    out = {}
    for kind in dict.fromkeys(r["drive"] for r in rows):
        for duration in sorted({r["duration_s"] for r in rows if r["drive"] == kind}):
            ps = [p for r in rows if r["drive"] == kind and r["duration_s"] == duration for p in r["radars"].values()]
            turning = [r["turning_s"] for r in rows if r["drive"] == kind and r["duration_s"] == duration]
            group = [r for r in rows if r["drive"] == kind and r["duration_s"] == duration]
            sigma = float(np.mean([p["pitch_sigma_deg"] for p in ps]))
            bounds = [p["pitch_bound_alone_deg"] for p in ps if p["pitch_bound_alone_deg"] is not None]
            out[f"{kind}_{duration:.0f}s"] = {
                "radar_drives": len(ps), "turning_s_mean": float(np.mean(turning)),
                "pitch_sigma_deg_mean": sigma,
                # the pitch's information grows with the time spent turning (at the drive's rate of turn)
                "pitch_sigma_times_sqrt_turning_s": sigma * math.sqrt(np.mean(turning)),
                "turning_s_for_pitch_sigma_0_1_deg": (sigma * math.sqrt(np.mean(turning)) / 0.1) ** 2 if np.mean(turning) > 0 else None,
                # the same drive, as long as it takes to turn that long
                "drive_s_for_pitch_sigma_0_1_deg": (duration * (sigma / 0.1) ** 2) if np.mean(turning) > 0 else None,
                "pitch_bound_alone_deg_mean": float(np.mean(bounds)) if bounds else None,
                "pitch_largest_error_deg": float(max(abs(p["pitch_error_deg"]) for p in ps)),
                "pitch_nees": float(np.mean([(p["pitch_error_deg"] / p["pitch_sigma_deg"]) ** 2 for p in ps])),
                "pitch_taken": sum(p["pitch_taken"] for p in ps),
                "pitch_taken_largest_error_deg": max([abs(p["pitch_error_deg"]) for p in ps if p["pitch_taken"]], default=None),
                # the same drive over seeds: an error that repeats with the drive's geometry, not with the noise
                "roll_error_seed_mean_deg": {name: float(np.mean([r["radars"][name]["roll_error_deg"] for r in group]))
                                             for name in group[0]["radars"]},
                "roll_the_fit_error_stands_for_seed_mean_deg": {
                    name: float(np.mean([r["radars"][name]["roll_the_fit_error_stands_for_deg"] for r in group]))
                    for name in group[0]["radars"]},
                "roll_sigma_deg_mean": float(np.mean([p["roll_sigma_deg"] for p in ps]))}
    every = [p for r in rows if r["drive"] != "straight" for p in r["radars"].values()]
    z_roll = np.array([p["roll_error_deg"] / p["roll_sigma_deg"] for p in every])
    z_roll_true = np.array([p["true_rig_roll_error_deg"] / p["true_rig_roll_sigma_deg"] for p in every])
    roll = np.array([p["roll_error_deg"] for p in every])
    stands_for = np.array([p["roll_the_fit_error_stands_for_deg"] for p in every])
    out["turning_drives"] = {
        "radar_drives": len(every),
        "pitch_nees": float(np.mean([(p["pitch_error_deg"] / p["pitch_sigma_deg"]) ** 2 for p in every])),
        "pitch_sigma_over_bound_alone_mean": float(np.mean([p["pitch_sigma_deg"] / p["pitch_bound_alone_deg"] for p in every])),
        "roll_nees": float(np.mean(z_roll ** 2)), "roll_nees_true_rig": float(np.mean(z_roll_true ** 2)),
        "roll_error_mean_deg": float(roll.mean()), "roll_error_mean_standard_error_deg": float(roll.std() / math.sqrt(roll.size)),
        "roll_error_over_sigma_mean": float(z_roll.mean()),
        "roll_largest_error_over_sigma": float(np.abs(z_roll).max()),
        "roll_wrong_minus_true_rig_largest_deg": float(max(abs(p["roll_error_deg"] - p["true_rig_roll_error_deg"]) for p in every)),
        "roll_sigma_over_bound_mean": float(np.mean([p["roll_sigma_deg"] / p["roll_bound_with_pitch_deg"] for p in every])),
        "roll_error_correlation_with_the_fit_error": float(np.corrcoef(roll, stands_for)[0, 1]),
        "roll_the_fit_error_stands_for_deg_range": [float(stands_for.min()), float(stands_for.max())],
        "fit_z_nees_mean": float(np.mean([p["fit_z_nees"] for p in every])),
        "fit_z_block20_variance_ratio_mean": float(np.mean([p["fit_z_block20_variance_ratio"] for p in every])),
        "per_radar_roll_error_mean_deg": {name: float(np.mean([r["radars"][name]["roll_error_deg"] for r in rows
                                                               if r["drive"] != "straight"]))
                                          for name in rows[0]["radars"]}}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one 40 s drive of each kind, one seed")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--out", type=Path, default=RESULTS / "calibration_pitch.json")
    args = ap.parse_args(argv)
    if args.quick:
        plan, seeds = [("tight_turns", 40.0), ("curves", 40.0), ("straight", 22.0)], args.seeds[:1]
    else:
        plan = [("tight_turns", 40.0), ("curves", 40.0), ("tight_turns", 90.0), ("curves", 120.0), ("tight_turns", 180.0),
                ("straight", 22.0)]
        seeds = args.seeds
    started = time.perf_counter()
    started_load = load_average()
    load = [os.getloadavg()[0]]
    rows = []
    for kind, duration in plan:
        for seed in seeds:
            rows.append(drive_row(kind, duration, seed))
            load.append(os.getloadavg()[0])
            r = rows[-1]
            print(f"{kind} {duration:.0f} s seed {seed} (turning {r['turning_s']:.0f} s): pitch (error, sigma, bound) deg "
                  + ", ".join(f"({p['pitch_error_deg']:+.3f}, {p['pitch_sigma_deg']:.3f}, {_text(p['pitch_bound_alone_deg'])}"
                              f"{', taken' if p['pitch_taken'] else ''})" for p in r["radars"].values())
                  + "; roll (error, sigma) " + ", ".join(f"({p['roll_error_deg']:+.3f}, {p['roll_sigma_deg']:.3f})"
                                                        for p in r["radars"].values())
                  + f"; {r['wall_time_s']:.0f} s", flush=True)
    limits = CalibrationLimits()
    out = {"what": __doc__.split("\n\n")[0], "drives": {"curves": CURVES, "tight_turns": TIGHT_TURNS,
                                                        "straight": "8 m, stops at 2, 4, 6 m"},
           "limits": {"rotation_sigma_deg": limits.rotation_sigma_deg, "min_speed_across_mps": limits.min_speed_across_mps},
           "prior_rotation_sigma_deg": math.degrees(SIM_EKF.calibration_rotation_sigma_rad),
           "summary": summary(rows), "rows": rows,
           "load_average_1min": load, "wall_time_s": time.perf_counter() - started}
    write_results(args.out.stem, out, started_load=started_load, folder=args.out.parent)
    print(json.dumps(out["summary"], indent=1))
    print(f"wrote {args.out} in {out['wall_time_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
