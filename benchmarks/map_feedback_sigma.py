"""Are the map's velocity measurements' sigmas honest? Each measurement (rio.map_feedback) against the truth
(rio.map_feedback_truth), on simulated feedback drives (rio.feedback_drive) over several seeds, and on a run
of the live daemon (tests/test_map_feedback_live.py, kept with --basetemp) re-imaged from its recording on
its odometry's trajectory.

    python benchmarks/map_feedback_sigma.py [--seeds 0 1 2] [--length-m 3.0] [--live DIR ...] [--tag before]

Writes docs/results/map_feedback_sigma.json (or map_feedback_sigma_TAG.json): per measurement its value, sigma,
truth, what an exact refocus would have read, and the NEES (mean squared normalised error; 1 where honest).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rio.feedback_drive import run_feedback_loop, simulate_feedback_drive  # noqa: E402
from rio.map_feedback import MapFeedbackConfig, velocity_error_from_tiles  # noqa: E402
from rio.map_feedback_truth import RESIDUAL_ONLY, measurement_truths, nees, position_error_accel_rms_mps2  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"


BEFORE = RESIDUAL_ONLY


def evaluated(tile_sets, truth, trajectory, **extra) -> list[dict]:
    """Rows of every measurement of ``tile_sets`` against the truth: as the map sends them now ("after") and
    with the sigma before this change ("before"), the tiles of a set jointly and each tile alone."""
    rows = []
    for name, config in (("before", BEFORE), ("after", MapFeedbackConfig())):
        for each_tile in (False, True):
            truths = measurement_truths(tile_sets, truth, trajectory, config, each_tile)
            rows += rows_of(truths, **extra, sigma_model=name, fit="each tile" if each_tile else "joint")
            print(f"   {name:6s} {'each tile' if each_tile else 'joint':9s}: {len(truths)} measurements, NEES "
                  f"{nees(truths):.2f}", flush=True)
    return rows


def rows_of(truths, **extra) -> list[dict]:
    return [{**extra, "span_s": t.measurement.span_s, "time_ns": t.measurement.time_ns, "radars": list(t.measurement.radars), "tiles": t.measurement.tiles,
             "direction_x": float(t.measurement.direction[0]), "measured_mps": t.measured_mps, "sigma_mps": t.sigma_mps,
             "true_mps": t.true_mps, "exact_mps": t.exact_mps, "normalised_error": t.normalised_error} for t in truths]


def driving_accel(truth, trajectory) -> list[float]:
    """The RMS acceleration of the trajectory's position error over 1.5 s windows while driving (truth
    faster than 0.3 m/s), world x, y, z (m/s^2)."""
    t = trajectory.time_ns[(trajectory.time_ns >= truth.sample(trajectory.time_ns[:1]).time_ns[0])]
    moving = t[np.linalg.norm(truth.sample(t).velocity_mps, axis=1) > 0.3]
    if moving.size < 2:
        return [float("nan")] * 3
    return [float(x) for x in position_error_accel_rms_mps2(truth, trajectory, int(moving[0]), int(moving[-1]))]


def simulated(seeds, length_m: float, config: MapFeedbackConfig) -> list[dict]:
    rows = []
    for seed in seeds:
        t0 = time.perf_counter()
        drive = simulate_feedback_drive(length_m=length_m, seed=seed)
        result = run_feedback_loop(drive, True, feedback_config=config)
        truths = measurement_truths(result.tile_sets, drive.truth, result.trajectory)
        accel = driving_accel(drive.truth, result.trajectory)
        rows += evaluated(result.tile_sets, drive.truth, result.trajectory, source="simulated", seed=seed,
                          position_error_accel_rms_mps2=accel)
        print(f"seed {seed}: {len(truths)} measurements, NEES {nees(truths):.2f}, position error accel rms "
              f"{np.round(np.array(accel) * 1e3, 1)} mm/s^2, "
              f"scale {(result.feedback.doppler_scale - 1) * 1e6:+.0f} ppm, {time.perf_counter() - t0:.0f} s", flush=True)
        for t in truths:
            print(f"   measured {t.measured_mps * 1e3:+7.2f} +- {t.sigma_mps * 1e3:5.2f}  true {t.true_mps * 1e3:+7.2f}  "
                  f"exact {t.exact_mps * 1e3:+7.2f} mm/s  ({','.join(t.measurement.radars)})", flush=True)
    return rows


def live_tile_sets(run_dir: Path, config: MapFeedbackConfig, thin: int = 1):
    """The live run's map re-imaged from its recording on its odometry's trajectory (the poses the map worker
    imaged on), each radar's tiles refocused per call as the worker does; returns (tile sets, truth,
    trajectory)."""
    from imaging.core.rig import default_rig
    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import read_trajectory
    from imaging.stripmap import StripMap

    from acquisition.studies.map_feedback_live import MAP, feedback_scene

    traj = read_trajectory(run_dir / "trajectory.h5") if (run_dir / "trajectory.h5").exists() else \
        read_trajectory(next(run_dir.glob("*traj*.h5")))
    rig = default_rig()
    strip = StripMap(MAP)
    tile_sets, used = [], set()
    with Recording(run_dir / "recording.h5") as rec:
        frames = []
        for name in rec.radar_names:
            if not rec.has_adc(name):
                continue
            times = rec.frame_time_ns(name)
            # every thin-th frame only, as the live map imaging frames thinned on a loaded machine
            frames += [(int(t), name, i) for i, t in enumerate(times) if i % thin == 0]
        frames.sort()
        for t, name, i in frames:
            if t + rig.radar(name).waveform.frame_duration_ns > traj.time_ns[-1]:
                continue
            strip.add_frame(rig.radar(name), rec.tdm_tx_order(name), rec.adc(name, slice(i, i + 1))[0], t, traj)
            fresh = [k for k in strip.refocus_geometry if k not in used and k in strip.refocus_results]
            used.update(fresh)
            tiles = [(strip.refocus_results[k].track_error, strip.refocus_geometry[k]) for k in fresh]
            if tiles:
                tile_sets.append((tiles, velocity_error_from_tiles(tiles, config)))
    return tile_sets, feedback_scene().trajectory, traj


def live(run_dirs, config: MapFeedbackConfig, thin: int = 1) -> list[dict]:
    rows = []
    for d in run_dirs:
        # the re-imaging is the slow part: kept beside the run, to evaluate another sigma model on the same tiles
        cache = Path(d) / f"tile_sets_thin{thin}.pickle"
        if cache.exists():
            tile_sets, truth, traj = pickle.loads(cache.read_bytes())
        else:
            tile_sets, truth, traj = live_tile_sets(Path(d), config, thin)
            cache.write_bytes(pickle.dumps((tile_sets, truth, traj)))
        truths = measurement_truths(tile_sets, truth, traj, config)
        accel = driving_accel(truth, traj)
        rows += evaluated(tile_sets, truth, traj, source="live" if thin == 1 else f"live, frames thinned {thin}",
                          run=str(d), position_error_accel_rms_mps2=accel)
        print(f"live {d}: {len(truths)} measurements, NEES {nees(truths):.2f}, position error accel rms "
              f"{np.round(np.array(accel) * 1e3, 1)} mm/s^2", flush=True)
        for t in truths:
            print(f"   measured {t.measured_mps * 1e3:+7.2f} +- {t.sigma_mps * 1e3:5.2f}  true {t.true_mps * 1e3:+7.2f}  "
                  f"exact {t.exact_mps * 1e3:+7.2f} mm/s  ({','.join(t.measurement.radars)})", flush=True)
    return rows


def summary(rows) -> dict:
    out = {}
    for key in sorted({(r["source"], r["sigma_model"], r["fit"]) for r in rows}):
        sel = [r for r in rows if (r["source"], r["sigma_model"], r["fit"]) == key]
        source = " ".join(key)
        e = np.array([r["normalised_error"] for r in sel])
        refocus = np.array([r["measured_mps"] - r["exact_mps"] for r in sel])
        model = np.array([r["exact_mps"] - r["true_mps"] for r in sel])
        out[source] = {"measurements": len(sel), "nees": float(np.mean(e ** 2)) if e.size else None,
                       "error_rms_mps": float(np.sqrt(np.mean([(r["measured_mps"] - r["true_mps"]) ** 2 for r in sel]))) if sel else None,
                       "sigma_rms_mps": float(np.sqrt(np.mean([r["sigma_mps"] ** 2 for r in sel]))) if sel else None,
                       "refocus_error_rms_mps": float(np.sqrt(np.nanmean(refocus ** 2))) if sel else None,
                       "model_error_rms_mps": float(np.sqrt(np.nanmean(model ** 2))) if sel else None}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    ap.add_argument("--length-m", type=float, default=3.0)
    ap.add_argument("--live", nargs="*", default=[], help="directories of live runs (recording.h5, trajectory.h5)")
    ap.add_argument("--thin", type=int, nargs="*", default=[1], help="live runs re-imaged with every k-th frame")
    ap.add_argument("--tag", default="", help="suffix of the JSON's name")
    args = ap.parse_args(argv)
    started_load = load_average()
    config = MapFeedbackConfig()
    rows = simulated(args.seeds, args.length_m, config)
    for thin in args.thin:
        rows += live(args.live, config, thin)
    out = {"scenario": f"rio.feedback_drive: {args.length_m} m straight at 0.4 m/s, Doppler 2 % low, seeds {args.seeds}; "
                       f"live runs re-imaged: {len(args.live)}",
           "config": {k: v for k, v in dataclasses.asdict(config).items()},
           "load_average": list(os.getloadavg()), "summary": summary(rows), "rows": rows}
    path = write_results(f"map_feedback_sigma_{args.tag}" if args.tag else "map_feedback_sigma", out,
                         started_load=started_load)
    print(json.dumps(out["summary"], indent=2))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
