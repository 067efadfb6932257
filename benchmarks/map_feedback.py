"""The map corrects the odometry (rio.map_feedback): odometry drift and live-map sharpness with and without the
feedback, on simulated drives (rio.feedback_drive: straight at 0.4 m/s past point targets on both sides, the
radars' Doppler 2 % low, the two front radars imaging, refocus by the entropy model).

    python benchmarks/map_feedback.py [--quick]

Writes docs/results/map_feedback.json and docs/results/map_feedback.png. Per seed: the odometry's position
error along and across the track at the end and per metre driven, with and without the feedback; every
target's peak in the map as imaged (before any refocus: how a tile starts) relative to the same map imaged on
the true trajectory; the map's measurements (velocity error read, its sigma); and the filter's side alone
(``odometry_with_ideal_map``: the truth's velocity error as the measurement, every 1.6 s, 1 mm/s), as filter
updates only and with the Doppler scale learnt from them; and whether the map's sigmas are honest
(rio.map_feedback_truth: each measurement against the truth, NEES, jointly and each tile alone, with the
sigma now and with the fit's residual alone).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rio.map_feedback_truth import sigma_honesty  # noqa: E402
from rio.feedback_drive import (  # noqa: E402
    SPEED_MPS,
    odometry_with_truth_measurements,
    run_feedback_loop,
    simulate_feedback_drive,
    target_peaks_db,
)
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def drift(result, drive) -> dict:
    """Position error of the odometry at the end of the drive (along x, the track, and y), and per metre."""
    traj = result.trajectory
    truth = drive.truth.sample(traj.time_ns)
    err = traj.position_m - truth.position_m
    distance = float(np.sum(np.linalg.norm(np.diff(truth.position_m, axis=0), axis=1)))
    return {"end_along_m": float(err[-1, 0]), "end_across_m": float(err[-1, 1]),
            "along_per_m": float(abs(err[-1, 0]) / distance), "distance_m": distance,
            "velocity_error_along_mean_mps": float(np.mean((truth.velocity_mps - traj.velocity_mps)[truth.velocity_mps[:, 0] > 0.3, 0]))}


def run_seed(seed: int, length_m: float) -> dict:
    drive = simulate_feedback_drive(length_m=length_m, seed=seed)
    reference = run_feedback_loop(drive, False, trajectory=drive.truth)
    ref_db = target_peaks_db(reference.plain_map, drive.targets_m)
    row = {"seed": seed, "length_m": length_m, "targets": len(drive.targets_m)}
    # The filter's side alone: the truth's along-track velocity error every 1.6 s at 1 mm/s, as the map would
    # give it if every pair of tiles read one; as updates alone and with the Doppler scale learnt.
    ideal = {}
    for name, sigma, learn in (("none", None, False), ("updates_only", 0.001, False), ("updates_and_scale", 0.001, True)):
        error, fb = odometry_with_truth_measurements(drive, sigma, learn_scale=learn, seed=seed)
        ideal[name] = {"end_along_m": float(-error[0]), "end_across_m": float(-error[1]), "measurements": len(fb.measurements),
                       "doppler_scale": fb.doppler_scale}
    row["odometry_with_ideal_map"] = ideal
    print(f"seed {seed} ideal map: end along {ideal['none']['end_along_m'] * 1e3:+.1f} mm without, "
          f"{ideal['updates_only']['end_along_m'] * 1e3:+.1f} mm updates only, "
          f"{ideal['updates_and_scale']['end_along_m'] * 1e3:+.1f} mm with the scale", flush=True)
    for name, feedback in (("without", False), ("with", True)):
        t0 = time.perf_counter()
        result = run_feedback_loop(drive, feedback)
        peaks = target_peaks_db(result.plain_map, drive.targets_m) - ref_db
        late = drive.targets_m[:, 0] > 0.5 * length_m
        row[name] = {"drift": drift(result, drive), "peak_db": [float(p) for p in peaks],
                     "late_peak_db_mean": float(np.nanmean(peaks[late])), "seconds": time.perf_counter() - t0}
        if feedback:
            truth_v = drive.truth.sample(np.array([m.time_ns for m in result.feedback.measurements], np.int64)).velocity_mps \
                if result.feedback.measurements else np.zeros((0, 3))
            row[name]["measurements"] = [
                {"time_s": (m.time_ns - int(drive.truth.t0_ns)) * 1e-9, "direction": [float(x) for x in m.direction],
                 "velocity_error_mps": m.velocity_error_mps, "sigma_mps": m.sigma_mps, "tiles": m.tiles,
                 "radars": list(m.radars)} for m in result.feedback.measurements]
            row[name]["rejected_by_gate"] = result.feedback.rejected
            row[name]["tiles_refocused"] = len(result.refocus_map.refocus_geometry)
            row[name]["truth_speed_at_measurements_mps"] = [float(np.linalg.norm(v)) for v in truth_v]
            # each measurement against the truth: are the sigmas honest (NEES 1)? now and as they were
            row[name]["sigma_honesty"] = sigma_honesty(result.tile_sets, drive.truth, result.trajectory)
            row[name]["doppler_scale"] = result.feedback.doppler_scale
            row[name]["doppler_scale_sigma"] = result.feedback.scale_sigma
        print(f"seed {seed} {name:7s}: end along {row[name]['drift']['end_along_m'] * 1e3:+.1f} mm "
              f"({row[name]['drift']['along_per_m'] * 100:.2f} %), late peaks {row[name]['late_peak_db_mean']:+.2f} dB "
              f"vs the true trajectory, {row[name]['seconds']:.0f} s", flush=True)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one short drive")
    args = ap.parse_args(argv)
    started_load = load_average()
    seeds, length_m = ((0,), 3.0) if args.quick else ((0, 1), 4.5)
    rows = [run_seed(s, length_m) for s in seeds]
    summary = {}
    for name in ("without", "with"):
        summary[name] = {"along_per_m_mean": float(np.mean([r[name]["drift"]["along_per_m"] for r in rows])),
                         "measurements_mean": float(np.mean([len(r["with"]["measurements"]) for r in rows])) if name == "with" else 0.0,
                         "end_along_m_mean": float(np.mean([r[name]["drift"]["end_along_m"] for r in rows])),
                         "late_peak_db_mean": float(np.mean([r[name]["late_peak_db_mean"] for r in rows]))}
    honesty = {}
    for model in ("now", "residual_only"):
        for fit in ("joint", "each_tile"):
            e = [x for r in rows for x in r["with"]["sigma_honesty"][model][fit]["normalised_errors"]]
            honesty[f"{model} {fit}"] = {"measurements": len(e), "nees": float(np.mean(np.square(e))) if e else None}
    summary["sigma_honesty"] = honesty
    out = {"scenario": f"rio.feedback_drive: {length_m} m straight at {SPEED_MPS} m/s, Doppler 2 % low, targets on "
                       "both sides every 0.64 m at 1.2/1.6 m; map 0.6 m aperture, entropy refocus",
           "units": {"drift": "m, truth minus odometry is the negative of end_along_m", "peak_db": "dB against the map on the true trajectory"},
           "load_average": list(os.getloadavg()), "summary": summary, "rows": rows}
    write_results("map_feedback", out, started_load=started_load)
    plot(rows, RESULTS / "map_feedback.png")
    print(f"wrote {RESULTS / 'map_feedback.json'} and map_feedback.png")
    return 0


def plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    ax = axes[0]
    x = np.arange(len(rows))
    for k, (name, colour) in enumerate((("without", "tab:red"), ("with", "tab:green"))):
        ax.bar(x + 0.35 * k, [abs(r[name]["drift"]["end_along_m"]) * 1e3 for r in rows], 0.35, color=colour,
               label=f"{name} feedback")
    ax.set_xticks(x + 0.175, [f"seed {r['seed']}" for r in rows])
    ax.set_ylabel("odometry error along the track at the end (mm)")
    ax.set_title("drift (Doppler 2 % low)", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1]
    for name, colour in (("without", "tab:red"), ("with", "tab:green")):
        for i, r in enumerate(rows):
            ax.plot(np.arange(len(r[name]["peak_db"])), r[name]["peak_db"], "o-", color=colour, alpha=0.7,
                    label=f"{name} feedback" if i == 0 else None)
    ax.set_xlabel("target (left side, then right side, along the track)")
    ax.set_ylabel("peak as imaged, against the true trajectory (dB)")
    ax.set_title("live-map sharpness before refocus", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
