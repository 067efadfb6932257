"""Does the odometry's velocity error settle after the robot starts moving, and how long does it take? What a
map tile would read over a span begun some time after the start, on simulated drives (rio.feedback_drive:
2 s standing, then straight at 0.4 m/s, the radars' Doppler 2 % low), the odometry alone (no map).

    python benchmarks/map_feedback_settling.py [--seeds 0 1 2 3 4 5] [--length-m 3.0] [--live-seeds 1 3 4]

For each drive and each span of 1.5 s (a map tile's) begun ``begin_s`` after the odometry's horizontal speed
reached 0.1 m/s (``MapFeedbackConfig.scale_min_speed_mps``): a parabola fitted to the odometry's position error
along the track (truth minus odometry) gives the velocity error at the span's centre (what a tile reads) and
its acceleration (how much that error changes over the span, which a tile cannot see and a scale does not
make); the velocity error relative to the speed, less the truth's scale error (1 / 0.98 - 1), is what that
span would teach the Doppler scale beyond the truth, were the tile exact. With the filter the unit tests
use (``SIM_EKF``) and the live odometry worker's (``EkfConfig()``); and on the live test's drive
(tests/test_map_feedback_live.py: its scene simulated with other noise seeds, the radars' chirp interval 2 %
short) as the live odometry worker makes it: point clouds from the raw frames with the daemon's rig, 10 scans a
second a radar, ``EkfConfig()``. Writes docs/results/map_feedback_settling.json. Takes about 4 minutes.
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

from imaging.core.trajectory import SampledTrajectory  # noqa: E402
from rio.calibration_drive import SIM_EKF  # noqa: E402
from rio.ekf import EkfConfig  # noqa: E402
from rio.feedback_drive import T0, simulate_feedback_drive  # noqa: E402
from rio.map_feedback import MapFeedbackConfig  # noqa: E402
from results_file import load_average, write_results  # noqa: E402
from rio.odometry import RioOptions  # noqa: E402
from rio.streaming import StreamingRio  # noqa: E402

SPAN_S = 1.5
BEGINS_S = np.arange(0.0, 4.01, 0.25)
TRUE_SCALE_ERROR = 1 / 0.98 - 1


def odometry(drive, ekf: EkfConfig) -> SampledTrajectory:
    """The streaming odometry over the drive's IMU and scans, fed a quarter second at a time (as the loop)."""
    rio = StreamingRio(RioOptions(ekf=ekf), imu_rate_hz=400.0)
    t_imu, acc, gyr = drive.imu
    scans = sorted(drive.scans, key=lambda s: s.time_ns)
    poses, i, j, t = [], 0, 0, T0
    while t < t_imu[-1]:
        t += int(0.25e9)
        while j < len(scans) and scans[j].time_ns <= t:
            poses.append(rio.add_scan(scans[j]))
            j += 1
        k = int(np.searchsorted(t_imu, t, side="right"))
        poses.append(rio.add_imu(t_imu[i:k], acc[i:k], gyr[i:k]))
        i = k
    poses.append(rio.finish())
    return SampledTrajectory.from_batches(poses)


def live_odometry(seed: int) -> tuple[SampledTrajectory, SampledTrajectory]:
    """The live test's drive simulated with noise seed ``seed`` (acquisition.studies.map_feedback_live), and the
    odometry as the live worker makes it from its raw frames; returns (truth, odometry)."""
    from acquisition.studies.map_feedback_live import RADARS, live_drive_inputs

    from imaging.core.rig import default_rig

    rig = default_rig()
    with tempfile.TemporaryDirectory() as tmp:
        inputs = live_drive_inputs(seed, Path(tmp), frames=False)
    t_imu, acc, gyr = inputs.imu
    rio = StreamingRio(RioOptions(calibration_priors={n: p for n, p in rig.calibration_priors().items() if n in RADARS}),
                       imu_rate_hz=rig.imu.rate_hz)
    poses, i = [], 0
    for scan in inputs.scans:
        k = int(np.searchsorted(t_imu, scan.time_ns, side="right"))
        if k > i:
            poses.append(rio.add_imu(t_imu[i:k], acc[i:k], gyr[i:k]))
            i = k
        poses.append(rio.add_scan(scan))
    poses.append(rio.add_imu(t_imu[i:], acc[i:], gyr[i:]))
    poses.append(rio.finish())
    return inputs.truth, SampledTrajectory.from_batches(poses)


def spans(truth, traj: SampledTrajectory) -> list[dict]:
    """Each span's velocity error along the track (world x, at its centre), its change over the span and what
    it would teach the scale."""
    speed = np.hypot(traj.velocity_mps[:, 0], traj.velocity_mps[:, 1])
    start_ns = int(traj.time_ns[np.argmax(speed >= MapFeedbackConfig().scale_min_speed_mps)])
    rows = []
    for begin in BEGINS_S:
        t_ns = np.round(start_ns + (begin + np.linspace(0.0, SPAN_S, 64)) * 1e9).astype(np.int64)
        error = (truth.sample(t_ns).position_m - traj.sample(t_ns).position_m)[:, 0]  # the track is world x
        t_s = (t_ns - t_ns.mean()) * 1e-9
        a, v, _ = np.polyfit(t_s, error, 2)
        centre_speed = float(traj.sample(t_ns[32:33]).velocity_mps[0, 0])
        rows.append({"begin_s": float(begin), "start_s": (start_ns - int(traj.time_ns[0])) * 1e-9,
                     "velocity_error_mps": float(v), "change_over_span_mps": float(2 * a * SPAN_S),
                     "scale_beyond_truth_ppm": float((v / centre_speed - TRUE_SCALE_ERROR) * 1e6)})
    return rows


def summary(rows: list[dict]) -> dict:
    """Per span begin: mean and RMS over the drives of the change over the span and the scale beyond truth."""
    out = {}
    for begin in BEGINS_S:
        sel = [r for r in rows if r["begin_s"] == float(begin)]
        change = np.array([r["change_over_span_mps"] for r in sel])
        beyond = np.array([r["scale_beyond_truth_ppm"] for r in sel])
        out[f"{begin:.2f}"] = {"change_over_span_mean_mps": float(change.mean()),
                               "change_over_span_rms_mps": float(np.sqrt(np.mean(change ** 2))),
                               "change_over_span_min_mps": float(change.min()), "change_over_span_max_mps": float(change.max()),
                               "scale_beyond_truth_mean_ppm": float(beyond.mean()),
                               "scale_beyond_truth_rms_ppm": float(np.sqrt(np.mean(beyond ** 2)))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--length-m", type=float, default=3.0)
    ap.add_argument("--live-seeds", type=int, nargs="*", default=[1, 3, 4])
    args = ap.parse_args(argv)
    out = {"scenario": f"rio.feedback_drive: {args.length_m} m straight at 0.4 m/s after 2 s standing, Doppler 2 % low, "
                       f"odometry only; spans of {SPAN_S} s begun begin_s after the odometry's speed reached 0.1 m/s",
           "units": {"change_over_span_mps": "how much the along-track velocity error changes over the span",
                     "scale_beyond_truth_ppm": "velocity error at the span's centre / speed, less 1/0.98 - 1"},
           "seeds": args.seeds, "live_seeds": args.live_seeds, "filters": {}}
    started_load = load_average()
    t0 = time.perf_counter()
    runs = [("SIM_EKF (unit tests, benchmarks)", SIM_EKF, args.seeds), ("EkfConfig() (the live odometry worker)", EkfConfig(), args.seeds),
            ("the live test's drive, point clouds from raw frames, EkfConfig()", None, args.live_seeds)]
    for name, ekf, seeds in runs:
        rows = []
        for seed in seeds:
            if ekf is None:
                rows += [{"seed": seed, **r} for r in spans(*live_odometry(seed))]
                continue
            drive = simulate_feedback_drive(length_m=args.length_m, seed=seed, with_frames=False)
            rows += [{"seed": seed, **r} for r in spans(drive.truth, odometry(drive, ekf))]
        if not rows:
            continue
        out["filters"][name] = {"summary": summary(rows), "rows": rows}
        print(name)
        for begin, s in out["filters"][name]["summary"].items():
            print(f"  span begun {begin} s after the start: change over the span {s['change_over_span_mean_mps'] * 1e3:+.2f} "
                  f"({s['change_over_span_min_mps'] * 1e3:+.2f} .. {s['change_over_span_max_mps'] * 1e3:+.2f}) mm/s, "
                  f"scale beyond truth {s['scale_beyond_truth_mean_ppm']:+.0f} (rms {s['scale_beyond_truth_rms_ppm']:.0f}) ppm",
                  flush=True)
    out["seconds"] = time.perf_counter() - t0
    out["load_average"] = list(os.getloadavg())
    path = write_results("map_feedback_settling", out, started_load=started_load)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
