"""Worker processes of ``sarbot run``: radar-inertial odometry and the live strip map, on the bus.

Each worker is started by the daemon as ``worker(driver_endpoints, endpoint, *settings, stop)``: it
subscribes to the drivers, publishes on its own endpoint, and writes its product when told to stop.

* RIO worker: IMU batches and radar frames -> point clouds -> ``rio.streaming.StreamingRio`` -> ``pose``
  messages (time, position, orientation, velocity batches); writes the trajectory file at the end.
* Strip-map worker: radar frames, and poses from the RIO worker -> ``imaging.stripmap.StripMap``; a frame
  is imaged once the poses cover it. Publishes changed tiles (``map/tile``) and its state (``map/status``,
  with its lag behind real time), and writes the map (image schema) and a PNG at the end.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import time
from pathlib import Path

import numpy as np

from imaging.core.rig import Rig
from imaging.core.samples import iq_to_complex

log = logging.getLogger("sarbot.workers")

#: How far back the strip-map worker keeps poses (enough for frames waiting on the odometry's hold-back).
POSE_WINDOW_NS = 5_000_000_000


def rio_worker(driver_endpoints: list[str], endpoint: str, rig: Rig, radars: list[str] | None, trajectory_path: str,
               stop, scan_rate_hz: float = 10.0, max_lag_s: float = 0.3) -> None:
    """Point clouds of at most ``scan_rate_hz`` frames per radar (ego velocity needs no more, and each costs
    about 10 ms); a frame that reaches the worker more than ``max_lag_s`` late is skipped (counted) so the
    odometry stays current when the machine is busy. The IMU is never skipped."""
    from imaging.core.trajectory import SampledTrajectory
    from imaging.io.trajectory_file import write_trajectory
    from rio.odometry import RadarScan, RioOptions
    from rio.pointcloud import PointCloudConfig, detect
    from rio.streaming import StreamingRio

    from .bus import BusPublisher, BusSubscriber
    from .daemon import _die_with_parent

    _die_with_parent("rio")
    use = set(radars or rig.radar_names)
    sub = BusSubscriber(driver_endpoints, topics=["imu", *[f"radar/{n}" for n in sorted(use)]])
    pub = BusPublisher(endpoint)
    configs = {r.name: r for r in rig.radars if r.name in use}
    orders = {name: np.asarray(r.waveform.tdm_tx_order()) for name, r in configs.items()}
    half_frame = {name: r.waveform.frame_duration_ns // 2 for name, r in configs.items()}
    rio = StreamingRio(RioOptions(), imu_rate_hz=rig.imu.rate_hz)
    pc_config = PointCloudConfig()
    kept = []
    every = {name: max(1, int(round(1.0 / (r.waveform.frame_interval_s * scan_rate_hz)))) for name, r in configs.items()}
    seen = collections.Counter()

    def publish(batch) -> None:
        if len(batch):
            kept.append(batch)
            pub.publish("pose", int(batch.time_ns[0]), [batch.time_ns, batch.position_m, batch.orientation_xyzw,
                                                         batch.velocity_mps])

    def handle(msg) -> None:
        if msg.topic == "imu":
            t, gyro, accel, _, _ = msg.arrays
            publish(rio.add_imu(t, accel, gyro))
            return
        name = msg.topic.split("/", 1)[1]
        if name not in configs or not msg.header["valid"]:
            return
        seen[name] += 1
        if seen[name] % every[name]:
            return
        if (time.time_ns() - int(msg.header["receive_ns"])) * 1e-9 > max_lag_s:
            rio.stats["scans_skipped_behind"] += 1
            return
        pc = detect(iq_to_complex(msg.arrays[0]), configs[name], orders[name], pc_config)
        publish(rio.add_scan(RadarScan(int(msg.header["frame_time_ns"]) + half_frame[name], name,
                                       configs[name].mount, pc.xyz_m, pc.doppler_mps)))

    try:
        while not stop.is_set():
            msg = sub.receive(timeout_ms=50)
            if msg is not None:
                handle(msg)
        while (msg := sub.receive(timeout_ms=500)) is not None:  # what the drivers sent on their way out
            handle(msg)
        publish(rio.finish())
        pub.publish("pose/end", time.time_ns())
        time.sleep(0.2)  # let the subscribers take the last messages before the socket closes
    finally:
        if kept:
            times = np.concatenate([b.time_ns for b in kept])
            traj = SampledTrajectory(times, np.concatenate([b.position_m for b in kept]),
                                     np.concatenate([b.orientation_xyzw for b in kept]),
                                     np.concatenate([b.velocity_mps for b in kept]), source="rio")
            write_trajectory(trajectory_path, traj)
            log.info("RIO: %d poses, %s; wrote %s", times.size, dict(rio.stats), trajectory_path)
        pub.close()
        sub.close()


@dataclasses.dataclass
class StripMapStatus:
    frames_imaged: int = 0
    frames_standing_still: int = 0  # no aperture to gain: left out
    frames_skipped_invalid: int = 0
    frames_dropped_behind: int = 0
    lag_s: float = 0.0  # frame reception to imaged, the latest frame
    max_lag_s: float = 0.0
    busy_s: float = 0.0  # time spent imaging


def stripmap_worker(driver_endpoints: list[str], endpoint: str, rig: Rig, radars: list[str] | None, config,
                    pose_endpoint: str, map_path: str, stop, max_queue_s: float = 10.0) -> None:
    from imaging.core.trajectory import SampledTrajectory
    from imaging.io.image_file import write_image
    from imaging.plot import save_image_png
    from imaging.stripmap import StripMap

    from .bus import BusPublisher, BusSubscriber
    from .daemon import _die_with_parent

    _die_with_parent("stripmap")
    use = set(radars or rig.radar_names)
    # Only the radars it images: each stream is 14 MB/s the process would otherwise receive for nothing.
    sub = BusSubscriber([*driver_endpoints, pose_endpoint], topics=["pose", *[f"radar/{n}" for n in sorted(use)]])
    pub = BusPublisher(endpoint)
    configs = {r.name: r for r in rig.radars if r.name in use}
    orders = {name: np.asarray(r.waveform.tdm_tx_order()) for name, r in configs.items()}
    frame_ns = {name: r.waveform.frame_duration_ns for name, r in configs.items()}
    sm = StripMap(config)
    status = StripMapStatus()
    poses: collections.deque = collections.deque()  # batches (t, p, q, v)
    frames: collections.deque = collections.deque()  # (name, iq copy, frame time, receive time)
    changed: set = set()
    last_publish = time.monotonic()

    def add_poses(arrays) -> None:
        """Keep poses in time order; a batch that repeats times already held keeps only its newer ones."""
        t = arrays[0]
        keep = t > poses[-1][0][-1] if poses else np.ones(t.size, bool)
        if keep.any():
            poses.append(tuple(np.array(a[keep]) for a in arrays))

    def take(msg, live: bool) -> None:
        """A pose batch or a radar frame off the bus. Live, the pose window and the frame queue are kept
        bounded; when draining at the end, everything is kept for the last imaging pass."""
        if msg.topic == "pose":
            add_poses(msg.arrays)
            while live and len(poses) > 2 and poses[-1][0][-1] - poses[1][0][0] > POSE_WINDOW_NS:
                poses.popleft()
            return
        name = msg.topic.split("/", 1)[1]
        if name not in configs:
            return
        if not msg.header["valid"]:
            status.frames_skipped_invalid += 1
            return
        frames.append((name, np.array(msg.arrays[0]), int(msg.header["frame_time_ns"]), int(msg.header["receive_ns"])))
        # Never fall more than max_queue_s behind: the oldest frames go (counted).
        while live and (frames[-1][2] - frames[0][2]) * 1e-9 > max_queue_s:
            frames.popleft()
            status.frames_dropped_behind += 1

    def trajectory():
        t = np.concatenate([b[0] for b in poses])
        if t.size < 2:
            return None
        return SampledTrajectory(t, np.concatenate([b[1] for b in poses]), np.concatenate([b[2] for b in poses]),
                                 np.concatenate([b[3] for b in poses]), source="rio")

    def image_ready(final: bool = False) -> None:
        if not frames or not poses:
            return
        newest_pose = int(poses[-1][0][-1])
        traj = None
        while frames:
            name, iq, t_frame, t_recv = frames[0]
            if t_frame + frame_ns[name] > newest_pose:
                if not final:
                    return
                frames.popleft()  # never covered by the odometry: the drive ended
                continue
            frames.popleft()
            traj = traj or trajectory()
            if traj is None:
                return
            t0 = time.monotonic()
            footprint = sm.add_frame(configs[name], orders[name], iq_to_complex(iq), t_frame, traj)
            changed.update(footprint.tiles)
            status.busy_s += time.monotonic() - t0
            if footprint.skipped:
                status.frames_standing_still += 1
            else:
                status.frames_imaged += 1
            status.lag_s = (time.time_ns() - t_recv) * 1e-9
            status.max_lag_s = max(status.max_lag_s, status.lag_s)

    def publish_tiles() -> None:
        for key in sorted(changed):
            pub.publish("map/tile", 0, [sm.tiles[key].astype(np.complex64)], key=list(key), pixel_m=config.pixel_m,
                        tile_px=config.tile_px)
        changed.clear()
        pub.publish("map/status", time.time_ns(), **dataclasses.asdict(status), tiles=len(sm.tiles))

    try:
        while not stop.is_set():
            msg = sub.receive(timeout_ms=50)
            if msg is not None:
                take(msg, live=True)
            image_ready()
            if time.monotonic() - last_publish > 0.5:
                publish_tiles()
                last_publish = time.monotonic()
        # Take the frames still queued and the odometry's last poses (it says when it has sent them all).
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            msg = sub.receive(timeout_ms=200)
            if msg is None:
                continue
            if msg.topic == "pose/end":
                break
            take(msg, live=False)
        image_ready(final=True)
        publish_tiles()
    finally:
        if sm.tiles:
            img = sm.to_image({"radars": ",".join(sorted(configs)), "trajectory_source": "rio",
                               "wavelength_m": float(np.mean([r.waveform.wavelength_m for r in configs.values()])),
                               **dataclasses.asdict(status)})
            write_image(map_path, img)
            save_image_png(Path(map_path).with_suffix(".png"), img.image, img.x_m, img.y_m,
                           title=f"strip map, {status.frames_imaged} frames, aperture {config.aperture_m} m")
            log.info("strip map: %s; wrote %s", dataclasses.asdict(status), map_path)
        pub.close()
        sub.close()


def add_pipeline_workers(setup, out_dir: Path, stamp: str, config, max_speed_mps: float = 0.5,
                         map_radars: list[str] | None = None, rio_radars: list[str] | None = None, presum: int | None = None):
    """Give ``setup`` (``acquisition.daemon.Setup``) the odometry and strip-map workers.

    ``presum`` None picks the largest pre-summing whose phase spread stays within pi/4 at ``max_speed_mps``.
    Returns the trajectory path, the map path and the strip-map settings used.
    """
    from imaging.stripmap import max_presum

    from .daemon import free_tcp_endpoint

    names = [link.name for link in setup.radars]
    map_radars = map_radars or names
    if presum is None:
        presum = min(max_presum(config, setup.rig.radar(n), max_speed_mps) for n in map_radars)
    config = dataclasses.replace(config, presum=presum)
    out_dir.mkdir(parents=True, exist_ok=True)
    traj_path = out_dir / f"trajectory_{stamp}.h5"
    map_path = out_dir / f"stripmap_{stamp}.h5"
    pose_endpoint = free_tcp_endpoint()
    setup.workers = {
        "rio": (rio_worker, (setup.rig, rio_radars or names, str(traj_path)), pose_endpoint),
        "stripmap": (stripmap_worker, (setup.rig, map_radars, config, pose_endpoint, str(map_path))),
    }
    return traj_path, map_path, config
