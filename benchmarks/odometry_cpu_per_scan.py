"""The odometry worker's CPU per radar scan: a baseline commit's code against the checkout's, interleaved in one
process, fed the same messages.

    python benchmarks/odometry_cpu_per_scan.py [--baseline COMMIT] [--rounds 6] [--recording PATH] [--quick]

The drive is the demo's (``acquisition.studies.demo.demo_scene``: four radars, 10 s, 192 frames each at
19.2 Hz, the IMU at 400 Hz), simulated once into a temporary folder (``--recording``: a simulated recording
of it kept from an earlier run). Its messages are made once, in the order the bus brings them: IMU batches
of 20 samples (the IMU driver's 0.05 s) and every radar frame as int16 I/Q, each at its end.
``OdometryWorker.handle`` takes them all, then ``finish`` (the trajectory file written, as live; poses sent on
a bus with no subscriber); its warm-up is run before and not counted. Every frame's receive time is "now", so
the worker never falls behind and thins nothing: both versions make every second frame of each radar into
a scan (``scan_rate_hz`` 10) and run the same filter. The bus's receive and decoding are left out (the same
code in both). As in the worker's run loop, the C heap's free pages go back to the system once a second of
the drive (``release_free_heap``): whether an array of a few MB is served from the heap or mapped and faulted
in anew changes what a scan costs (acquisition/processes.py), and the baseline made several a scan.

The baseline's ``acquisition/workers/odometry.py``, ``rio/pointcloud.py`` and ``imaging/io/trajectory_file.py``
are loaded from git (``git show COMMIT:PATH``) as modules of their own beside the checkout's, and put in
``sys.modules`` in place of the checkout's while the baseline runs (the worker imports them inside its
methods); everything else is the checkout's. Rounds alternate which version goes first, so the machine's
load falls on both alike. CPU is the main thread's (``time.thread_time``): ZeroMQ's I/O thread is left out.
Figures: the median over rounds of the CPU per scan and per frame received, and the ratio baseline / now per
round. Beside them, each round, ``detect`` alone (each version's ``PointCloudDetector`` on the I/Q, frame by
frame in turn; a baseline before the detector: its ``detect`` on the complex frame, as its worker called it) on
every radar's first 12 frames; and once, each version's worker under cProfile: the shares of its time in the
point clouds, their FFTs, their CFAR, the filter and the poses' publishing. The two trajectory files are
compared (positions, orientations, velocities) and the point clouds of every radar's first 24 frames.

Writes docs/results/odometry_cpu_per_scan.json (``--quick``: 2 rounds, to odometry_cpu_per_scan_quick.json).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import acquisition.workers.odometry as worker_now  # noqa: E402
import imaging.io.trajectory_file as trajectory_now  # noqa: E402
import rio.pointcloud as pointcloud_now  # noqa: E402
from acquisition.bus import BusPublisher  # noqa: E402
from acquisition.messages import ImuBatch, RadarFrameMessage  # noqa: E402
from acquisition.processes import release_free_heap  # noqa: E402
from drivers.radar.stream import RadarFrame  # noqa: E402
from imaging.core.rig import Rig  # noqa: E402
from imaging.core.samples import iq_to_complex  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from git_baseline import baseline_module  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

#: main before the point clouds' CFAR went into one numba pass (wave 3m); wave 3k's baseline was 0e7a3c5.
BASELINE = "aa20a74"
#: Wave 3k's figures against its baseline 0e7a3c5 (the file this run replaces; docs/benchmark-notes.md).
EARLIER_BASELINE = {
    "baseline_commit": "0e7a3c5", "commit": "6036b0b",
    "cpu_ms_per_scan": {"baseline": 7.37, "now": 5.93}, "ratio_baseline_over_now_median": 1.30,
    "detect_alone_cpu_ms": {"baseline": 6.31, "now": 4.87}, "load": "5.2 at the start, 4.7 at the end",
}
IMU_BATCH = 20  # samples: the IMU driver's 0.05 s at 400 Hz


@contextlib.contextmanager
def modules_in_place(modules: dict):
    """``modules`` (import name -> module) in ``sys.modules`` for the block, the checkout's back after it."""
    kept = {name: sys.modules[name] for name in modules}
    sys.modules.update(modules)
    try:
        yield
    finally:
        sys.modules.update(kept)


def load_drive(path: Path):
    """The rig and the drive's messages in bus order: (time, "imu", (t, gyro, accel)) and (time, "radar",
    (name, counter, frame_time_ns, iq))."""
    with Recording(path) as rec:
        radars = [rec.radar(n) for n in rec.radar_names]
        imu = rec.imu()
        frames = {r.name: (rec.frame_time_ns(r.name), rec.adc_iq(r.name)) for r in radars}
    events = []
    t = imu["time_ns"]
    for k in range(0, t.size, IMU_BATCH):
        s = slice(k, k + IMU_BATCH)
        events.append((int(t[s][-1]), 0, "imu", (t[s], imu["gyro_radps"][s], imu["accel_mps2"][s])))
    for r in radars:
        frame_time, iq = frames[r.name]
        for i in range(frame_time.size):
            events.append((int(frame_time[i]) + r.waveform.frame_duration_ns, 1, "radar",
                           (r.name, i, int(frame_time[i]), np.ascontiguousarray(iq[i]))))
    events.sort(key=lambda e: e[:2])
    return Rig(tuple(radars)), [e[2:] for e in events]


def run_worker(module, rig: Rig, events: list, trajectory_path: Path) -> dict:
    """One pass of the drive through ``module``'s OdometryWorker: CPU and wall time, scans and frames."""
    pub = BusPublisher("tcp://127.0.0.1:*")
    try:
        worker = module.OdometryWorker(module.OdometryWorkerConfig(rig, None, str(trajectory_path)), pub)
        worker.warm_up()
        cpu, wall = time.thread_time(), time.perf_counter()
        batches = 0
        for kind, data in events:
            if kind == "imu":
                t, gyro, accel = data
                message = ImuBatch(t, gyro, accel, np.zeros(t.size, np.uint32), t)
                batches += 1
                if batches % 20 == 0:  # a second of the drive: the run loop gives the free heap back as often
                    release_free_heap()
            else:
                name, counter, frame_time_ns, iq = data
                message = RadarFrameMessage(name, RadarFrame(counter, frame_time_ns, time.time_ns(), True, 0, iq))
            worker.handle(message, live=True)
        worker.finish()
        worker.write_products()
        cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
    finally:
        pub.close()
    frames = sum(worker.seen.values())
    scans = sum(n // worker.every[name] for name, n in worker.seen.items())
    return {"cpu_s": cpu, "wall_s": wall, "frames": frames, "scans": scans,
            "thinned": int(worker.rio.stats["scans_thinned_behind"]), "poses": worker.poses_written}


def compare_trajectories(a: Path, b: Path) -> dict:
    from imaging.io.trajectory_file import read_trajectory

    ta, tb = read_trajectory(a), read_trajectory(b)
    same_times = bool(np.array_equal(ta.time_ns, tb.time_ns))
    out = {"poses": [int(ta.time_ns.size), int(tb.time_ns.size)], "same_times": same_times}
    if same_times:
        for field in ("position_m", "orientation_xyzw", "velocity_mps"):
            out[f"max_abs_difference_{field}"] = float(np.max(np.abs(getattr(ta, field) - getattr(tb, field))))
    return out


def radar_frames(rig: Rig, events: list, per_radar: int) -> list:
    """(radar, int16 I/Q) of each radar's first ``per_radar`` frames, in bus order."""
    taken, out = {}, []
    for kind, data in events:
        if kind == "radar" and taken.get(data[0], 0) < per_radar:
            taken[data[0]] = taken.get(data[0], 0) + 1
            out.append((rig.radar(data[0]), data[3]))
    return out


def point_cloud_makers(pointcloud_base, rig: Rig) -> dict:
    """Per version, radar name -> a function of the int16 I/Q giving its point cloud as that version's worker
    makes it: a ``PointCloudDetector`` per radar, or (a baseline before it) ``detect`` on the complex frame."""
    makers = {}
    for version, module in (("baseline", pointcloud_base), ("now", pointcloud_now)):
        makers[version] = {}
        for r in rig.radars:
            order = np.asarray(r.waveform.tdm_tx_order())
            if hasattr(module, "PointCloudDetector"):
                makers[version][r.name] = module.PointCloudDetector(r, order).detect
            else:
                makers[version][r.name] = (lambda iq, r=r, order=order, m=module: m.detect(iq_to_complex(iq), r, order))
    return makers


def time_detect(makers: dict, frames: list, first: str) -> dict:
    """CPU per point cloud (``time.thread_time``, ms) of each version's point clouds on the same frames,
    frame by frame in turn (``first`` first), so that the machine's load falls on both alike."""
    cpu = {"baseline": 0.0, "now": 0.0}
    order = [first, "now" if first == "baseline" else "baseline"]
    for radar, iq in frames:
        for version in order:
            t = time.thread_time()
            makers[version][radar.name](iq)
            cpu[version] += time.thread_time() - t
    return {v: c / len(frames) * 1e3 for v, c in cpu.items()}


def profile_shares(module, rig: Rig, events: list, trajectory_path: Path) -> dict:
    """One pass under cProfile: the share of the worker's time (cumulative, of ``handle`` and ``finish``) in
    the point clouds, their FFTs, the filter's IMU and scan paths and the publishing of poses."""
    import cProfile
    import pstats

    profile = cProfile.Profile()
    profile.enable()
    run_worker(module, rig, events, trajectory_path)
    profile.disable()
    cumulative: dict[str, float] = {}
    for (path, _, function), row in pstats.Stats(profile).stats.items():
        key = {"detect": "point_clouds", "c2c": "ffts", "cfar_2d": "cfar", "_cfar": "cfar", "add_imu":
               "filter_imu_batches", "add_scan": "filter_scans", "_publish": "publishing_poses", "handle": "handle",
               "finish": "finish"}.get(function)
        if key and (key == "ffts" or "pointcloud" in path or "streaming" in path or "odometry" in path):
            cumulative[key] = cumulative.get(key, 0.0) + row[3]
    total = cumulative.get("handle", 0.0) + cumulative.get("finish", 0.0)
    return {k: v / total for k, v in cumulative.items() if k not in ("handle", "finish")}


def compare_point_clouds(makers: dict, events: list, per_radar: int = 24) -> dict:
    """Detections of the baseline's point clouds and the checkout's (``point_cloud_makers``) on each radar's
    first ``per_radar`` frames: whether every array is equal, and how many detections there were."""
    taken, equal, detections = {}, True, 0
    for kind, data in events:
        if kind != "radar" or taken.get(data[0], 0) >= per_radar:
            continue
        name, iq = data[0], data[3]
        taken[name] = taken.get(name, 0) + 1
        old, new = makers["baseline"][name](iq), makers["now"][name](iq)
        detections += old.xyz_m.shape[0]
        equal &= all(np.array_equal(getattr(old, f), getattr(new, f))
                     for f in ("xyz_m", "doppler_mps", "snr_db", "range_m", "azimuth_rad"))
    return {"frames": sum(taken.values()), "detections": detections, "bit_identical": bool(equal)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--recording", type=Path, help="the demo drive simulated earlier (else simulated here)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 2 rounds, to odometry_cpu_per_scan_quick.json")
    args = ap.parse_args()
    if args.quick:
        args.rounds = 2
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        recording = args.recording
        if recording is None:
            from acquisition.studies.demo import demo_scene
            from imaging.sim.simulator import simulate_recording

            recording = tmp / "demo_drive.h5"
            print("simulating the demo drive ...", flush=True)
            simulate_recording(demo_scene(), recording)
        rig, events = load_drive(recording)
        base = {
            "rio.pointcloud": baseline_module(args.baseline, "rio/pointcloud.py", "pointcloud_base"),
            "imaging.io.trajectory_file": baseline_module(args.baseline, "imaging/io/trajectory_file.py",
                                                          "trajectory_file_base"),
        }
        worker_base = baseline_module(args.baseline, "acquisition/workers/odometry.py", "odometry_base")
        versions = {"baseline": (worker_base, base), "now": (worker_now, {})}
        started_load = load_average()
        probe_machine()
        runs = {v: [] for v in versions}
        ratios, detect_ms = [], []
        frames = radar_frames(rig, events, 12)
        makers = point_cloud_makers(base["rio.pointcloud"], rig)
        for k in range(args.rounds):
            order = list(versions) if k % 2 == 0 else list(versions)[::-1]
            this = {}
            for v in order:
                module, modules = versions[v]
                with modules_in_place(modules):
                    this[v] = run_worker(module, rig, events, tmp / f"trajectory_{v}.h5")
                runs[v].append(this[v])
            ratios.append(this["baseline"]["cpu_s"] / this["now"]["cpu_s"])
            detect_ms.append(time_detect(makers, frames, order[0]))
            print(f"round {k}: " + ", ".join(f"{v} {this[v]['cpu_s'] / this[v]['scans'] * 1e3:.2f} ms CPU/scan"
                                              for v in versions) + f", baseline/now {ratios[-1]:.2f}", flush=True)
        with modules_in_place(base):
            shares = {"baseline": profile_shares(worker_base, rig, events, tmp / "trajectory_profiled.h5")}
        shares["now"] = profile_shares(worker_now, rig, events, tmp / "trajectory_profiled.h5")
        trajectories = compare_trajectories(tmp / "trajectory_baseline.h5", tmp / "trajectory_now.h5")
        point_clouds = compare_point_clouds(makers, events)
    figures = {}
    for v, rs in runs.items():
        figures[v] = {
            "cpu_ms_per_scan": statistics.median(r["cpu_s"] / r["scans"] * 1e3 for r in rs),
            "cpu_ms_per_frame_received": statistics.median(r["cpu_s"] / r["frames"] * 1e3 for r in rs),
            "wall_ms_per_scan": statistics.median(r["wall_s"] / r["scans"] * 1e3 for r in rs),
            "scans": rs[0]["scans"], "frames": rs[0]["frames"], "thinned": max(r["thinned"] for r in rs),
            "poses": rs[0]["poses"], "cpu_s_per_round": [r["cpu_s"] for r in rs],
        }
    frames_per_s = 4 * 19.2  # the soak's four radars at 1x
    result = {
        "baseline_commit": args.baseline,
        "drive": "demo_scene: four radars, 10 s, 192 frames each, IMU 400 Hz in batches of 20",
        "rounds": args.rounds,
        "versions": figures,
        "ratio_baseline_over_now_per_round": ratios,
        "ratio_baseline_over_now_median": statistics.median(ratios),
        "core_pct_at_1x_four_radars": {v: figures[v]["cpu_ms_per_frame_received"] * frames_per_s / 10 for v in figures},
        "detect_alone_cpu_ms": {v: statistics.median(d[v] for d in detect_ms) for v in ("baseline", "now")},
        "detect_alone_ratio_per_round": [d["baseline"] / d["now"] for d in detect_ms],
        "profile_shares_of_worker_time": shares,
        "trajectories": trajectories,
        "point_clouds": point_clouds,
        **({"earlier_baseline": EARLIER_BASELINE} if args.baseline == BASELINE else {}),
        "note": "CPU of the worker's thread only (thread_time), bus receive and decoding left out; the machine "
                "was shared (load in the provenance): the ratios taken in the same rounds are the figures.",
    }
    name = "odometry_cpu_per_scan" + ("_quick" if args.quick else "")
    path = write_results(name, result, started_load=started_load)
    print(f"baseline/now {result['ratio_baseline_over_now_median']:.2f}; trajectories {trajectories}; "
          f"point clouds {point_clouds}; wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
