"""Radar-inertial odometry: accuracy on long simulated drives (evaluated with evo) and speed against the
knobs that trade it (RANSAC iterations, radars used, IMU rate).

    python benchmarks/odometry.py [--quick]

Writes docs/results/rio.json and docs/results/rio.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import PathWithTurns  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.detection_simulator import DetectionModel, Person, room_scatterers  # noqa: E402
from imaging.sim.imu_simulator import ImuErrors  # noqa: E402
from imaging.sim.scene import DEFAULT_START_TIME_NS, Scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from rio.ego_velocity import EgoVelocityConfig  # noqa: E402
from rio.evaluation import drift_report  # noqa: E402
from rio.odometry import RioOptions, imu_from_recording, run_rio, scans_from_recording  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def long_drive(laps: int, seed: int) -> Scene:
    """Laps of a rounded rectangle in a 22 m x 14 m hall with clutter and people, stops every lap."""
    lap = [("straight", 8.0), ("arc", 1.5, 90.0), ("straight", 4.0), ("arc", 1.5, 90.0),
           ("straight", 8.0), ("arc", 1.5, 90.0), ("straight", 4.0), ("arc", 1.5, 90.0)]
    lap_length = 24.0 + 4 * 1.5 * np.pi / 2
    traj = PathWithTurns(segments=lap * laps, start_m=(-4.0, -3.5, 0.0), speed_mps=0.8, accel_mps2=0.4,
                         start_delay_s=3.0, stops=[(lap_length * (k + 0.5), 2.0) for k in range(laps)],
                         t0_ns=DEFAULT_START_TIME_NS)
    people = [Person((-6.0, 4.5, 1.0), (6.0, 4.5, 1.0), 1.2), Person((8.5, -5.0, 1.0), (8.5, 4.0, 1.0), 1.0)]
    return Scene(name=f"hall_{laps}_laps", rig=default_rig(), trajectory=traj, targets=[], duration_s=traj.duration_s + 3.0,
                 radars=default_rig().radar_names, imu=True, seed=seed,
                 imu_errors=ImuErrors(gyro_bias_radps=(0.002, -0.003, 0.001), accel_bias_mps2=(0.05, -0.04, 0.03)),
                 detection_model=DetectionModel(max_range_m=9.0, detection_probability=0.5),
                 static_points_m=room_scatterers(size_m=(22.0, 14.0), centre_m=(0.0, 0.0), spacing_m=0.5, clutter=100,
                                                 rng=np.random.default_rng(seed)),
                 people=people)


def evo_metrics(est, truth) -> dict:
    """APE (SE(3) alignment) and RPE per metre with evo."""
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D

    def pose_traj(t_ns, p, q_xyzw):
        return PoseTrajectory3D(positions_xyz=p, orientations_quat_wxyz=np.roll(q_xyzw, 1, axis=1), timestamps=t_ns * 1e-9)

    true = truth.sample(est.time_ns)
    ref = pose_traj(est.time_ns, true.position_m, true.orientation_xyzw)
    # APE after an SE(3) alignment (evo); the position+yaw aligned ATE comes from rio.evaluation.
    e = pose_traj(est.time_ns, est.position_m, est.orientation_xyzw)
    r, e = sync.associate_trajectories(ref, e)
    e.align(r, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((r, e))
    out = {"ape_rmse_m_se3": float(ape.get_statistic(metrics.StatisticsType.rmse))}
    e = pose_traj(est.time_ns, est.position_m, est.orientation_xyzw)
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1.0, delta_unit=metrics.Unit.meters, all_pairs=False)
    rpe.process_data((ref, e))
    out["rpe_per_metre_rmse_m"] = float(rpe.get_statistic(metrics.StatisticsType.rmse))
    return out


def run(rec_path, options: RioOptions, radars=None, every: int = 1):
    """``every``: only every n-th scan of each radar, as the live odometry worker thins them (a scan costs
    it about 10 ms of point-cloud detection on the raw frame, which the simulated point clouds skip)."""
    with Recording(rec_path) as rec:
        imu = imu_from_recording(rec)
        scans = scans_from_recording(rec, radars)
        truth = rec.truth()
    if every > 1:
        seen: dict[str, int] = {}
        kept = []
        for scan in scans:
            seen[scan.radar] = seen.get(scan.radar, -1) + 1
            if seen[scan.radar] % every == 0:
                kept.append(scan)
        scans = kept
    t = time.perf_counter()
    res = run_rio(imu, scans, options)
    elapsed = time.perf_counter() - t
    duration = (imu.time_ns[-1] - imu.time_ns[0]) * 1e-9
    return res, truth, {"realtime_multiple": duration / elapsed, "elapsed_s": elapsed, "duration_s": duration}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    logging.basicConfig(level=logging.ERROR)
    laps_list = [1] if args.quick else [7, 10]
    out: dict = {"drives": [], "knobs": []}
    plots = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, laps in enumerate(laps_list):
            scene = long_drive(laps, seed=10 + i)
            path = Path(tmp) / f"drive{laps}.h5"
            t = time.perf_counter()
            simulate_recording(scene, path)
            sim_s = time.perf_counter() - t
            if i == 0:
                run(path, RioOptions())  # warm-up: numba compiles on the first call, not to be timed
            res, truth, speed = run(path, RioOptions())
            rep = drift_report(res.trajectory, truth)
            rep.update(evo_metrics(res.trajectory, truth))
            rep.update(speed, scene=scene.name, simulation_s=sim_s, radars=4)
            out["drives"].append(rep)
            plots.append((scene.name, res.trajectory, truth))
            print(f"{scene.name}: {rep['distance_m']:.0f} m, final drift {rep['final_drift_percent']:.3f} %, "
                  f"ATE {rep['ate_rmse_m']:.3f} m ({rep['ate_rmse_percent']:.3f} %), {rep['realtime_multiple']:.0f}x real time")
            if i == 0:
                knob_path = path
        knobs = [("ransac_iterations", it, RioOptions(ego=dataclasses.replace(EgoVelocityConfig(), ransac_iterations=it)), None, 1)
                 for it in (10, 20, 40, 80)]
        knobs += [("radars", n, RioOptions(), tuple(default_rig().radar_names[:n]), 1) for n in (1, 2, 4)]
        knobs += [("imu_rate_hz", 400 // d, RioOptions(imu_decimation=d), None, 1) for d in (1, 2, 4)]
        # Scans per radar per second with all four radars (the frame rate is 19.2 Hz): the live worker's
        # cost is set by it (10 ms a scan), not by the filter's.
        frame_hz = 1.0 / default_rig().radars[0].waveform.frame_interval_s
        knobs += [("scan_rate_hz", round(frame_hz / e, 1), RioOptions(), None, e) for e in (1, 2, 4, 8)]
        for name, value, options, radars, every in knobs:
            res, truth, speed = run(knob_path, options, radars, every)
            rep = drift_report(res.trajectory, truth)
            row = {"knob": name, "value": value, **speed, "final_drift_percent": rep["final_drift_percent"],
                   "ate_rmse_percent": rep["ate_rmse_percent"]}
            out["knobs"].append(row)
            print(f"{name}={value}: {row['realtime_multiple']:.0f}x real time, drift {row['final_drift_percent']:.3f} %, "
                  f"ATE {row['ate_rmse_percent']:.3f} %")
        out["real_bag"] = real_bag(Path(tmp))
    out["load_average_1min"] = os.getloadavg()[0]  # the speeds mean little on a loaded machine
    name = "rio_quick" if args.quick else "rio"
    write_results(name, out, started_load=started_load)
    chart(plots, out["knobs"], RESULTS / f"{name}.png")
    print(f"wrote {RESULTS / (name + '.json')} and {name}.png")
    return 0


def real_bag(tmp: Path) -> dict:
    """The real hand-held recording: no ground truth, so what can be said: gate acceptance, speeds, the
    distance between where the walk started and where it ended."""
    from acquisition.importers.bag import import_bag
    from rio.ekf import EkfConfig

    data = ROOT.parent / "shared" / "data" / "ti_mmwave_rospkg_demo"
    if not data.exists():
        return {"skipped": f"{data} not found"}
    rec = tmp / "bag.h5"
    import_bag(data / "ti_mmwave_rospkg_demo.bag", data / "calib_ti_mmwave_rospkg_dataset.yaml", rec)
    res, _, speed = run(rec, RioOptions(ekf=EkfConfig(radar_velocity_sigma_floor_mps=0.1)))
    p = res.trajectory.position_m
    out = {"radar_updates": res.stats.get("radar_updates", 0), "refused_by_gate": res.stats.get("radar_rejected_by_gate", 0),
           "path_length_m": float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))),
           "end_to_start_horizontal_m": float(np.linalg.norm(p[-1, :2] - p[0, :2])),
           "end_to_start_vertical_m": float(p[-1, 2] - p[0, 2]),
           "max_speed_mps": float(np.linalg.norm(res.trajectory.velocity_mps, axis=1).max()), **speed}
    print(f"real bag: {out['radar_updates']} radar updates, {out['refused_by_gate']} refused, path {out['path_length_m']:.1f} m, "
          f"ends {out['end_to_start_horizontal_m']:.2f} m from the start horizontally, {out['end_to_start_vertical_m']:+.2f} m vertically")
    _BAG_TRACK.append(p)
    return out


_BAG_TRACK: list = []


def chart(plots, knobs, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(18, 5))
    ax = axes[0]
    for name, est, truth in plots[:1]:
        true = truth.sample(est.time_ns)
        from rio.evaluation import align_start

        p = align_start(est, truth)
        ax.plot(true.position_m[:, 0], true.position_m[:, 1], "k-", lw=2, label="truth")
        ax.plot(p[:, 0], p[:, 1], "r--", lw=1, label="RIO (start-aligned)")
        ax.set_title(name)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend()
    ax = axes[1]
    for knob, marker in (("ransac_iterations", "o"), ("radars", "s"), ("imu_rate_hz", "^"), ("scan_rate_hz", "D")):
        rows = [r for r in knobs if r["knob"] == knob]
        ax.plot([r["realtime_multiple"] for r in rows], [r["final_drift_percent"] for r in rows], marker + "-", label=knob)
        for r in rows:
            ax.annotate(str(r["value"]), (r["realtime_multiple"], r["final_drift_percent"]), xytext=(4, 3),
                        textcoords="offset points", fontsize=8)
    ax.set_xlabel("processing speed (x real time)")
    ax.set_ylabel("final drift (% of distance)")
    ax.set_title("speed against accuracy")
    ax.legend()
    ax = axes[2]
    if _BAG_TRACK:
        p = _BAG_TRACK[0]
        ax.plot(p[:, 0], p[:, 1], "b-")
        ax.plot(p[0, 0], p[0, 1], "go", label="start")
        ax.plot(p[-1, 0], p[-1, 1], "rs", label="end")
        ax.set_aspect("equal")
        ax.legend()
    ax.set_title("real hand-held recording (no ground truth)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
