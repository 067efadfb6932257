"""What online calibration buys the image: point targets seen by each radar while the robot sets off into a
turn on the simulated calibration drive (rio.calibration_drive: every mount 2 deg yaw, 1 deg pitch, 2 cm lever
arm wrong in the rig file, one radar 5 ms late), raw frames along the true track, imaged by backprojection
(rio.calibration_imaging) on what each odometry run believes: the truth, the true rig's odometry, the wrong
rig's odometry, the wrong rig calibrated online (its trajectory, refined mounts and time offset), and the true
rig's odometry with the wrong mounts and clock (the rig file's cost to the image alone); and the calibrated
run's images with the late radar's frames placed at their stamps (sarbot's imaging applies no time offset yet).

    python benchmarks/calibration_stripmap.py [--quick]

Writes docs/results/calibration_stripmap.json and docs/results/calibration_stripmap.png.
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
from rio.calibration import calibrate  # noqa: E402
from rio.calibration_drive import SIM_EKF, calibration_drive, simulate_drive  # noqa: E402
from rio.calibration_imaging import (Aperture, compare_runs, place_targets, runs_of,  # noqa: E402
                                     turning_aperture_starts_ns)
from rio.odometry import RioOptions, run_rio  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RUNS = ("truth", "true_rig", "wrong_rig", "calibrated", "calibrated_clock_ignored", "wrong_mount_true_odometry")
FRAMES = 12  # 0.62 s: the robot speeds up from a stop and turns


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two apertures of one radar")
    args = ap.parse_args(argv)
    started_load = load_average()
    duration_s, seed = 90.0, 1
    traj = calibration_drive()
    imu, wrong, right = simulate_drive(traj, duration_s, seed)
    result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
    true_rig = run_rio(imu, right, RioOptions(ekf=SIM_EKF)).trajectory
    wrong_rig = run_rio(imu, wrong, RioOptions(ekf=SIM_EKF)).trajectory
    # after the calibration has settled (half the drive), up to the drive's end
    starts = turning_aperture_starts_ns(traj, T0 + int(40e9), T0 + int((duration_s - 2) * 1e9))
    radars = ["left_rear"] if args.quick else default_rig().radar_names
    starts = starts[:2] if args.quick else starts[:6]
    rows, example = [], None
    for name in radars:
        radar = default_rig().radar(name)
        runs = runs_of(name, traj, true_rig, wrong_rig, result)
        for k, start in enumerate(starts):
            frames = int(start) + np.arange(FRAMES, dtype=np.int64) * 52_000_000
            aperture = Aperture(radar, frames, place_targets(radar, traj, int(frames[FRAMES // 2])))
            keep = example is None
            q = compare_runs(aperture, traj, runs, seed=k, keep_images=keep)
            if keep:
                example = {run: q[run][1]["patch"] for run in q}
                example["title"] = (f"radar {name}, {(start - T0) * 1e-9:.1f} s into the drive: the target at 1.5 m "
                                    f"({FRAMES} frames from a stop into a turn)")
                for run in q:
                    for t in q[run]:
                        t.pop("patch", None)
            yaw_rate = traj.sample(frames[FRAMES // 2:FRAMES // 2 + 1]).angular_velocity_body_radps[0, 2]
            rows.append(_row(name, (start - T0) * 1e-9, float(yaw_rate), q))
            r = rows[-1]
            print(f"{name:11s} {r['start_s']:5.1f} s: peak against the true rig: calibrated "
                  f"{r['calibrated']['peak_db_worst']:+.2f} dB, wrong rig {r['wrong_rig']['peak_db_mean']:+.2f} dB; "
                  f"width calibrated {r['calibrated']['width_ratio_worst']:.3f}x, wrong {r['wrong_rig']['width_ratio_mean']:.3f}x")
    out = {"scenario": "rio.calibration_drive (90 s, seed 1): every radar's mount 2 deg yaw, 1 deg pitch, 2 cm lever "
                       "arm wrong in the rig file, left_rear 5 ms late; 3 point targets at 1.0, 1.5, 2.0 m per "
                       f"aperture of {FRAMES} frames ({FRAMES * 0.052:.2f} s) from a stop into a turn; "
                       "backprojection, 4 chirps of a TX pre-summed",
           "measure": "peak: the highest pixel's amplitude, dB against the image on the true rig's odometry; width: "
                      "diameter of a disc of the main lobe's area above -3 dB, as a ratio to the true rig's; PSLR: "
                      "cross-range cut; offset: the peak from where the run expects the target relative to the robot",
           "summary": _summary(rows), "load_average_1min": os.getloadavg()[0], "rows": rows}
    write_results("calibration_stripmap", out, started_load=started_load)
    plot(example, rows, RESULTS / "calibration_stripmap.png")
    print(json.dumps(out["summary"], indent=2))
    print(f"wrote {RESULTS / 'calibration_stripmap.json'} and calibration_stripmap.png")
    return 0


def _row(radar: str, start_s: float, yaw_rate_radps: float, q: dict) -> dict:
    """One aperture: per run the peak (dB) and width (ratio) against the true rig's, worst and mean over the
    targets, its PSLR and offset."""
    ref = q["true_rig"]
    row = {"radar": radar, "start_s": round(start_s, 3), "yaw_rate_radps": round(yaw_rate_radps, 3)}
    for run in (r for r in RUNS if r in q):
        peak_db = [20 * math.log10(t["peak"] / r["peak"]) for t, r in zip(q[run], ref)]
        width = [t["width_m"] / r["width_m"] for t, r in zip(q[run], ref)]
        row[run] = {"peak_db_mean": float(np.mean(peak_db)), "peak_db_worst": float(max(peak_db, key=abs)),
                    "width_ratio_mean": float(np.mean(width)), "width_ratio_worst": float(max(width, key=lambda w: abs(w - 1))),
                    "width_mm_mean": float(np.mean([t["width_m"] for t in q[run]]) * 1e3),
                    "cross_range_pslr_db_mean": _mean([t["cross_range_pslr_db"] for t in q[run]]),
                    "offset_mm_mean": float(np.mean([t["offset_m"] for t in q[run]]) * 1e3)}
    return row


def _mean(values) -> float | None:
    """The mean of those that are not None (a cut without a side lobe has no PSLR); None if none is."""
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _summary(rows: list[dict]) -> dict:
    """Over every aperture and target: how far each run is from the true rig's image."""
    out = {"apertures": len(rows)}
    for run in RUNS[2:]:
        rows_with = [r for r in rows if run in r]
        if not rows_with:
            continue
        out[run] = {"apertures": len(rows_with), "peak_db_worst": max((r[run]["peak_db_worst"] for r in rows_with), key=abs),
                    "peak_db_mean": float(np.mean([r[run]["peak_db_mean"] for r in rows_with])),
                    "width_change_worst": max((r[run]["width_ratio_worst"] - 1 for r in rows_with), key=abs),
                    "width_change_mean": float(np.mean([r[run]["width_ratio_mean"] for r in rows_with]) - 1),
                    "cross_range_pslr_db_mean": _mean([r[run]["cross_range_pslr_db_mean"] for r in rows_with]),
                    "offset_mm_mean": float(np.mean([r[run]["offset_mm_mean"] for r in rows_with]))}
    out["true_rig"] = {"cross_range_pslr_db_mean": _mean([r["true_rig"]["cross_range_pslr_db_mean"] for r in rows]),
                       "offset_mm_mean": float(np.mean([r["true_rig"]["offset_mm_mean"] for r in rows])),
                       "peak_db_mean_against_truth": float(np.mean([-r["truth"]["peak_db_mean"] for r in rows]))}
    return out


def plot(example: dict, rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(18, 4.4))
    ref = np.abs(example["true_rig"]["image"]).max()
    for ax, run, title in zip(axes[:3], ("true_rig", "wrong_rig", "calibrated"),
                              ("true rig's odometry and mounts", "wrong rig file, no calibration",
                               "wrong rig file, calibrated online")):
        p = example[run]
        x, y = (p["x_m"] - p["expected_m"][0]) * 100, (p["y_m"] - p["expected_m"][1]) * 100
        db = 20 * np.log10(np.abs(p["image"]) / ref + 1e-12)
        im = ax.imshow(db, origin="lower", extent=(x[0], x[-1], y[0], y[-1]), vmin=-30, vmax=0, cmap="viridis")
        ax.plot(0, 0, "w+", ms=12)
        ax.set_title(f"{title}\npeak {db.max():+.1f} dB", fontsize=9)
        ax.set_xlabel("x from the expected place (cm)")
    axes[0].set_ylabel("y (cm)")
    fig.colorbar(im, ax=axes[2], label="dB against the true rig's peak")
    ax = axes[3]
    for run, marker in (("calibrated", "^"), ("wrong_rig", "s"), ("wrong_mount_true_odometry", "x"),
                        ("calibrated_clock_ignored", "v")):
        ax.plot([r[run]["width_ratio_mean"] for r in rows if run in r], [r[run]["peak_db_mean"] for r in rows if run in r],
                marker, label=run.replace("_", " "))
    ax.axhspan(-1, 1, color="g", alpha=0.1)
    ax.axvspan(0.95, 1.05, color="g", alpha=0.1)
    ax.set_xlabel("main-lobe width / true rig's")
    ax.set_ylabel("peak against the true rig (dB)")
    ax.set_title(f"every aperture ({len(rows)}; green: 1 dB, 5 %)", fontsize=9)
    ax.legend(fontsize=8)
    fig.suptitle(example["title"], fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
