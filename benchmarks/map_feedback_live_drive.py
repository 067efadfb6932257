"""The Doppler scale the map teaches on the live test's drive, offline: without and with ``scale_settle_s``.

    python benchmarks/map_feedback_live_drive.py [--seeds 0 1 3] [--settle-s 0 1.5]

The live test's drive (tests/test_map_feedback_live.py: its scene simulated with noise seed ``seed``, the
radars' chirp interval 2 % short, so the daemon's Doppler reads 2 % low) run as the live daemon runs it, but in
one process and in time (rio.feedback_drive.run_feedback_loop): the odometry on point clouds made from the raw
frames with the daemon's rig (10 scans a second a radar, the live worker's filter, ``EkfConfig()``), the
refocusing map on its poses, each set of tiles refocused together fed back as it comes. Per seed and
``scale_settle_s``: the scale learnt and its sigma against the truth (1 / 0.98 - 1 = +20408 ppm), and each
measurement as the filter met it, with its truth (rio.map_feedback_truth). Writes
docs/results/map_feedback_live_drive.json. About a minute a run on a quiet machine, 3-7 at a load of 6-8.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import rio.feedback_drive as feedback_drive  # noqa: E402
from rio.ekf import EkfConfig  # noqa: E402
from rio.map_feedback import MapFeedbackConfig  # noqa: E402
from results_file import load_average, write_results  # noqa: E402
from rio.map_feedback_truth import measurement_truths  # noqa: E402
from acquisition.studies.map_feedback_live import TRUE_SCALE_PPM, live_drive_inputs  # noqa: E402


def live_drive(seed: int, tmp: Path) -> tuple[feedback_drive.FeedbackDrive, int]:
    """The live test's drive with noise seed ``seed``, as rio.feedback_drive's loop takes it
    (acquisition.studies.map_feedback_live.live_drive_inputs); and its first IMU time."""
    inputs = live_drive_inputs(seed, tmp)
    return feedback_drive.FeedbackDrive(inputs.truth, inputs.imu, inputs.scans, inputs.frames, np.zeros((0, 3)),
                                        inputs.duration_s), inputs.start_ns


def run(drive, start_ns: int, settle_s: float) -> dict:
    # the loop runs the live worker's filter and starts at the recording's first IMU sample
    saved = feedback_drive.SIM_EKF, feedback_drive.T0
    feedback_drive.SIM_EKF, feedback_drive.T0 = EkfConfig(), start_ns
    try:
        result = feedback_drive.run_feedback_loop(drive, True, feedback_config=MapFeedbackConfig(scale_settle_s=settle_s))
    finally:
        feedback_drive.SIM_EKF, feedback_drive.T0 = saved
    fb = result.feedback
    truths = {t.measurement.time_ns: t for t in measurement_truths(result.tile_sets, drive.truth, result.trajectory)}
    updates = []
    for u in fb.updates:
        t = truths.get(u.measurement.time_ns)
        updates.append({"line": u.line(), "time_s": (u.measurement.time_ns - start_ns) * 1e-9,
                        "measured_mps": u.measurement.velocity_error_mps, "sigma_mps": u.measurement.sigma_mps,
                        "true_mps": None if t is None else t.true_mps, "exact_mps": None if t is None else t.exact_mps})
    scale_ppm = (fb.doppler_scale - 1) * 1e6
    return {"scale_ppm": scale_ppm, "scale_sigma_ppm": fb.scale_sigma * 1e6,
            "scale_error_sigmas": (scale_ppm - TRUE_SCALE_PPM) / (fb.scale_sigma * 1e6),
            "taken": len(fb.measurements), "settling_not_taken": fb.settling_not_taken,
            "spanning_update": fb.spanning_update, "refused": fb.rejected, "updates": updates}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 3])
    ap.add_argument("--settle-s", type=float, nargs="*", default=[0.0, 1.5])
    args = ap.parse_args(argv)
    out = {"scenario": "the live test's drive (tests/test_map_feedback_live.py) with noise seeds "
                       f"{args.seeds}, odometry from raw frames and the refocusing map in time, offline",
           "truth_scale_ppm": TRUE_SCALE_PPM, "runs": {}}
    started_load = load_average()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            drive, start_ns = live_drive(seed, Path(tmp))
            for settle in args.settle_s:
                row = run(drive, start_ns, settle)
                out["runs"][f"seed {seed}, scale_settle_s {settle}"] = row
                print(f"seed {seed}, scale_settle_s {settle}: scale {row['scale_ppm']:+.0f} +- {row['scale_sigma_ppm']:.0f} "
                      f"ppm ({row['scale_error_sigmas']:+.2f} sigma from the truth), {row['taken']} taken", flush=True)
    out["summary"] = {f"scale_settle_s {s}": {
        "scale_ppm": [out["runs"][f"seed {seed}, scale_settle_s {s}"]["scale_ppm"] for seed in args.seeds],
        "scale_sigma_ppm": [out["runs"][f"seed {seed}, scale_settle_s {s}"]["scale_sigma_ppm"] for seed in args.seeds]}
        for s in args.settle_s}
    out["seconds"] = time.perf_counter() - t0
    out["load_average"] = list(os.getloadavg())
    path = write_results("map_feedback_live_drive", out, started_load=started_load)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
