"""What the axes a floor robot cannot calibrate cost (rio.calibration_unobservable): every radar's mount tilted
by 1 deg about its array's axis (the pitch of a sideways radar) and 2 cm too high in the rig file, left so
(``sarbot calibrate`` refuses both), against the true rig: the geometry (antenna shift, cone angle, Doppler),
the odometry's drift on the simulated calibration drives (rio.calibration_drive) and the strip map's point
targets where the robot sets off into a turn (rio.calibration_imaging).

    python benchmarks/calibration_unobservable.py [--quick]

Writes docs/results/calibration_unobservable.json and docs/results/calibration_unobservable.png.
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

from imaging.core.rig import default_rig  # noqa: E402
from imaging.sim.scene import DEFAULT_START_TIME_NS as T0  # noqa: E402
from rio.calibration_drive import SIM_EKF, calibration_drive, simulate_drive  # noqa: E402
from rio.calibration_imaging import Aperture, BelievedRig, compare_runs, place_targets, turning_aperture_starts_ns  # noqa: E402
from rio.calibration_unobservable import (LEVER_Z_ERROR_M, TILT_ERROR_DEG, lever_z_range_change_m,  # noqa: E402
                                          lever_z_velocity_mps, tilt_effects, tilted_mount, tilted_scans)
from rio.evaluation import drift_report  # noqa: E402
from rio.odometry import RioOptions, run_rio  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
FRAMES = 12  # 0.62 s from a stop into a turn, as benchmarks/calibration_stripmap.py


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one 60 s drive, two apertures of one radar")
    args = ap.parse_args(argv)
    started_load = load_average()
    rig = default_rig()
    geometry = {r.name: vars(tilt_effects(r)) for r in rig.radars}
    drives = ((60.0, 1),) if args.quick else ((60.0, 1), (90.0, 1), (90.0, 2), (120.0, 1))
    drift_rows, image_rows = [], []
    for duration, seed in drives:
        traj = calibration_drive(repeats=int(math.ceil(duration / 12)) + 1)
        imu, _, right = simulate_drive(traj, duration, seed)
        true_run = run_rio(imu, right, RioOptions(ekf=SIM_EKF)).trajectory
        tilted_run = run_rio(imu, tilted_scans(right), RioOptions(ekf=SIM_EKF)).trajectory
        t = traj.sample(np.arange(T0, T0 + int(duration * 1e9), 10_000_000, dtype=np.int64))
        row = {"duration_s": duration, "seed": seed,
               "lever_z_velocity_max_mps": float(lever_z_velocity_mps(t.angular_velocity_body_radps).max()),
               "yaw_rate_max_radps": float(np.abs(t.angular_velocity_body_radps[:, 2]).max())}
        for name, run in (("true_rig", true_run), ("tilted_rig", tilted_run)):
            d = drift_report(run, traj)
            row[name] = {"ate_rmse_m": d["ate_rmse_m"], "final_drift_m": d["final_drift_m"], "distance_m": d["distance_m"]}
        row["ate_ratio"] = row["tilted_rig"]["ate_rmse_m"] / row["true_rig"]["ate_rmse_m"]
        drift_rows.append(row)
        print(f"{duration:5.0f} s seed {seed}: ATE true rig {row['true_rig']['ate_rmse_m'] * 1e3:.2f} mm, tilted and raised "
              f"{row['tilted_rig']['ate_rmse_m'] * 1e3:.2f} mm ({row['ate_ratio']:.3f}x)", flush=True)
        if (duration, seed) != ((60.0, 1) if args.quick else (90.0, 1)):
            continue
        starts = turning_aperture_starts_ns(traj, T0 + int(10e9), T0 + int((duration - 2) * 1e9))
        for name in (["left_rear"] if args.quick else rig.radar_names):
            radar = rig.radar(name)
            runs = {"true_rig": (0.0, BelievedRig(true_run, radar.mount)),
                    "tilted_rig": (0.0, BelievedRig(tilted_run, tilted_mount(radar.mount)))}
            for k, start in enumerate(starts[:2] if args.quick else starts[:4]):
                frames = int(start) + np.arange(FRAMES, dtype=np.int64) * 52_000_000
                aperture = Aperture(radar, frames, place_targets(radar, traj, int(frames[FRAMES // 2])))
                q = compare_runs(aperture, traj, runs, seed=k)
                peak_db = [20 * math.log10(a["peak"] / b["peak"]) for a, b in zip(q["tilted_rig"], q["true_rig"])]
                width = [a["width_m"] / b["width_m"] for a, b in zip(q["tilted_rig"], q["true_rig"])]
                image_rows.append({"radar": name, "start_s": round((start - T0) * 1e-9, 3), "peak_db": peak_db,
                                   "width_ratio": width,
                                   "offset_mm": [a["offset_m"] * 1e3 for a in q["tilted_rig"]],
                                   "true_rig_offset_mm": [b["offset_m"] * 1e3 for b in q["true_rig"]]})
                print(f"  {name} {image_rows[-1]['start_s']:5.1f} s: peak {max(peak_db, key=abs):+.3f} dB, width "
                      f"{max(width, key=lambda w: abs(w - 1)):.4f}x", flush=True)
    peaks = [p for r in image_rows for p in r["peak_db"]]
    widths = [w for r in image_rows for w in r["width_ratio"]]
    summary = {"ate_ratio_max": max(r["ate_ratio"] for r in drift_rows),
               "ate_ratio_min": min(r["ate_ratio"] for r in drift_rows),
               "lever_z_velocity_max_mps": max(r["lever_z_velocity_max_mps"] for r in drift_rows),
               "peak_db_worst": max(peaks, key=abs), "width_change_worst": max(widths, key=lambda w: abs(w - 1)) - 1,
               "targets": len(peaks), "apertures": len(image_rows),
               "antenna_shift_max_m": max(g["antenna_shift_max_m"] for g in geometry.values()),
               "cone_angle_change_max_deg": max(g["cone_angle_change_max_deg"] for g in geometry.values()),
               "doppler_change_level_relative": geometry[rig.radar_names[0]]["doppler_change_level_relative"],
               "lever_z_range_change_at_1m_m": lever_z_range_change_m(1.0)}
    out = {"scenario": f"every radar's mount tilted {TILT_ERROR_DEG} deg about its array's axis (sensor y) and "
                       f"{LEVER_Z_ERROR_M * 100:.0f} cm too high in the rig file, not calibrated; rio.calibration_drive "
                       "drives; strip map: 3 point targets at 1.0, 1.5, 2.0 m per aperture of "
                       f"{FRAMES} frames from a stop into a turn (rio.calibration_imaging)",
           "measure": "ate_ratio: ATE RMSE of the tilted rig's odometry over the true rig's; peak_db: the target's "
                      "peak against the true rig's image; width_ratio: main-lobe width (disc of the -3 dB area) "
                      "over the true rig's",
           "summary": summary, "geometry": geometry, "drift": drift_rows, "images": image_rows,
           "load_average_1min": os.getloadavg()[0]}
    write_results("calibration_unobservable", out, started_load=started_load)
    plot(out, RESULTS / "calibration_unobservable.png")
    print(json.dumps(summary, indent=2))
    return 0


def plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    labels = [f"{r['duration_s']:.0f} s\nseed {r['seed']}" for r in out["drift"]]
    x = np.arange(len(labels))
    ax.bar(x - 0.2, [r["true_rig"]["ate_rmse_m"] * 1e3 for r in out["drift"]], 0.4, label="true rig")
    ax.bar(x + 0.2, [r["tilted_rig"]["ate_rmse_m"] * 1e3 for r in out["drift"]], 0.4,
           label=f"tilted {TILT_ERROR_DEG:g} deg, {LEVER_Z_ERROR_M * 100:.0f} cm high")
    ax.set_xticks(x, labels)
    ax.set_ylabel("ATE RMSE (mm)")
    ax.set_title("odometry drift: the axes calibration refuses, left wrong", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1]
    widths = [w for r in out["images"] for w in r["width_ratio"]]
    peaks = [p for r in out["images"] for p in r["peak_db"]]
    ax.plot(widths, peaks, "o")
    ax.axhspan(-1, 1, color="g", alpha=0.1)
    ax.axvspan(0.95, 1.05, color="g", alpha=0.1)
    ax.set_xlabel("main-lobe width / true rig's")
    ax.set_ylabel("peak against the true rig (dB)")
    ax.set_title(f"strip-map point targets ({len(peaks)}; green: 1 dB, 5 %)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
