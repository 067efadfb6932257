"""The odometry worker: IMU batches and radar frames -> point clouds -> ``rio.streaming.StreamingRio`` ->
``pose`` messages; the trajectory file at the end."""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import time

import numpy as np

from imaging.core.rig import Rig

from ..messages import (
    Event,
    ImuBatch,
    MapVelocityError,
    PointCloudMessage,
    PoseBatch,
    PoseEnd,
    RadarFrameMessage,
)
from . import Worker

log = logging.getLogger(f"sarbot.{__name__}")


@dataclasses.dataclass
class OdometryWorkerConfig:
    """``radars`` None: all of the rig's. Point clouds are made from at most ``scan_rate_hz`` frames per radar
    (ego velocity needs no more, and each costs 3-5 ms of CPU: docs/results/odometry_cpu_per_scan.json). A
    worker that falls behind (a busy machine, the backlog of its warm-up) catches up in time order: more than
    ``max_lag_s`` late it takes only every k-th scan of each radar (k grows with the lag, at most
    ``max_thinning``), counted in health and as events. It never leaves out every scan: the filter would
    drift on the IMU alone. The IMU is never left out. The filter waits for each radar
    (``StreamingRio.radar_seen``) unless no frame of it has come for ``radar_silence_s``."""

    rig: Rig
    radars: list[str] | None
    trajectory_path: str
    scan_rate_hz: float = 10.0
    max_lag_s: float = 0.3
    max_thinning: int = 8
    radar_silence_s: float = 2.0
    publish_points: bool = False  # each scan's detections on points/<radar> (for the live view)
    #: Estimate every radar's mount and time offset online (rio.ekf's calibration states): in health every
    #: second and in the trajectory file's /calibration at the end.
    calibrate: bool = False
    #: Take the strip map's velocity errors (``map/velocity_error``, rio.map_feedback) into the filter and
    #: learn the radars' Doppler scale from them. The strip-map worker's endpoint must be among ``endpoints``.
    map_feedback: bool = False
    map_endpoint: str | None = None


class OdometryWorker(Worker):
    drain_quiet_s = 0.5
    drain_max_s = 30.0

    def __init__(self, config: OdometryWorkerConfig, pub):
        from rio.odometry import RioOptions
        from rio.pointcloud import PointCloudConfig, PointCloudDetector
        from rio.streaming import StreamingRio

        self.config = config
        self.pub = pub
        rig = config.rig
        use = set(config.radars or rig.radar_names)
        self.topics = [ImuBatch.TOPIC, *[RadarFrameMessage.topic_of(n) for n in sorted(use)]]
        self.map_feedback = None
        if config.map_feedback:
            from rio.map_feedback import MapFeedback

            self.map_feedback = MapFeedback()
            self.topics.append(MapVelocityError.TOPIC)
            self.endpoints = [config.map_endpoint] if config.map_endpoint else []
        self.radars = {r.name: r for r in rig.radars if r.name in use}
        self.orders = {name: np.asarray(r.waveform.tdm_tx_order()) for name, r in self.radars.items()}
        self.half_frame_ns = {name: r.waveform.frame_duration_ns // 2 for name, r in self.radars.items()}
        self.every = {name: max(1, int(round(1.0 / (r.waveform.frame_interval_s * config.scan_rate_hz))))
                      for name, r in self.radars.items()}
        options = RioOptions(calibrate_extrinsics=config.calibrate, calibrate_time_offset=config.calibrate,
                             calibration_priors={n: p for n, p in rig.calibration_priors().items() if n in use})
        self.rio = StreamingRio(options, imu_rate_hz=rig.imu.rate_hz)
        self.pc_config = PointCloudConfig()
        # One detector per radar: its windows and cube buffer are made once, not on every scan.
        self.detectors = {name: PointCloudDetector(r, self.orders[name], self.pc_config)
                          for name, r in self.radars.items()}
        self.trajectory = None  # a TrajectoryWriter once the first poses come: poses go to disk, not memory
        self.poses_written = 0
        self.last_flush = time.monotonic()
        self.seen: collections.Counter = collections.Counter()
        self.behind: collections.Counter = collections.Counter()  # per radar: scans in a row more than max_lag_s late
        self.started_monotonic: float | None = None  # the first message
        self.last_frame_monotonic: dict[str, float] = {}  # per radar sending, when its last frame came
        self.silent: set[str] = set()  # radars said to be silent (the filter does not wait for them)
        self.lag_ms = 0  # of the last scan turned into a point cloud: its last datagram to now
        self.last_lag_event = 0.0
        #: Set by ``finish``: whether the hurry left the filter's last scans out (the trajectory file's
        #: ``stop_cut_short``); None while finish has not run.
        self.stop_cut_short: bool | None = None

    def warm_up(self) -> None:
        """Run the whole chain once on made-up data of the live shapes and dtypes: point clouds from a
        noise frame of every radar, a standstill for the filter's start, then scans standing and moving (the
        zero-velocity and the RANSAC paths). A throwaway filter: nothing reaches the bus."""
        from rio.odometry import RadarScan, RioOptions
        from rio.streaming import StreamingRio

        rng = np.random.default_rng(0)
        rate = self.config.rig.imu.rate_hz
        rio = StreamingRio(RioOptions(), imu_rate_hz=rate)
        n = int(round(3.0 * rate))
        t = 1_000_000_000 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)
        gyro = rng.normal(0.0, 1e-3, (n, 3)).astype(np.float32)
        accel = (np.array([0.0, 0.0, 9.80665]) + rng.normal(0.0, 1e-2, (n, 3))).astype(np.float32)
        rio.add_imu(t[: n // 2], accel[: n // 2], gyro[: n // 2])
        for k, (name, radar) in enumerate(self.radars.items()):
            wf = radar.waveform
            shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp)
            noise = rng.integers(-300, 300, (*shape, 2), dtype=np.int16)  # I/Q as the wire carries them
            pc = self.detectors[name].detect(noise)
            xyz = np.column_stack([rng.uniform(1.0, 5.0, 40), rng.uniform(-2.0, 2.0, 40), rng.uniform(-0.5, 0.5, 40)])
            unit = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
            for j, velocity in enumerate((np.zeros(3), np.array([-0.3, 0.1, 0.0]))):
                doppler = -unit @ velocity
                rio.add_scan(RadarScan(int(t[n // 2 + 40 * (2 * k + j)]), name, radar.mount,
                                       xyz.astype(pc.xyz_m.dtype), doppler.astype(pc.doppler_mps.dtype)))
        rio.add_imu(t[n // 2:], accel[n // 2:], gyro[n // 2:])
        rio.finish()

    def _publish(self, batch) -> None:
        from imaging.io.trajectory_file import TrajectoryWriter

        if len(batch):
            poses = PoseBatch(batch.time_ns, batch.position_m, batch.orientation_xyzw, batch.velocity_mps)
            self.pub.send(poses)
            if self.trajectory is None:
                self.trajectory = TrajectoryWriter(self.config.trajectory_path, "rio")
            self.trajectory.append(poses.time_ns, poses.position_m, poses.orientation_xyzw, poses.velocity_mps)
            if self.map_feedback is not None:
                self.map_feedback.note_poses(poses.time_ns, poses.velocity_mps)
            self.poses_written += len(poses)
            if time.monotonic() - self.last_flush > 5.0:
                self.trajectory.flush()
                self.last_flush = time.monotonic()

    def handle(self, message, live: bool) -> None:
        from rio.odometry import RadarScan

        now = time.monotonic()
        if self.started_monotonic is None:
            self.started_monotonic = now
        if isinstance(message, ImuBatch):
            self._note_silence(now)
            self._publish(self.rio.add_imu(message.time_ns, message.accel_mps2, message.gyro_radps))
            return
        if isinstance(message, MapVelocityError):
            if self.map_feedback is not None and self.rio.ekf is not None:
                self._take_map_measurement(message.measurement())
            return
        if not isinstance(message, RadarFrameMessage) or message.radar not in self.radars or not message.frame.valid:
            return
        name, frame = message.radar, message.frame
        self.last_frame_monotonic[name] = now
        self.silent.discard(name)
        t_scan = frame.frame_time_ns + self.half_frame_ns[name]
        self.rio.radar_seen(name, t_scan)  # also for the frames not made into scans: the filter need not wait for them
        self.seen[name] += 1
        if self.seen[name] % self.every[name]:
            return
        lag_s = (time.time_ns() - frame.receive_ns) * 1e-9
        if not self._take_scan(name, lag_s):
            return
        self.lag_ms = int(lag_s * 1e3)
        radar = self.radars[name]
        pc = self.detectors[name].detect(frame.iq)  # straight from the int16 I/Q: no complex copy
        if self.config.publish_points:
            self.pub.send(PointCloudMessage(name, t_scan, pc.xyz_m, pc.doppler_mps))
        scan = RadarScan(t_scan, name, radar.mount, pc.xyz_m, pc.doppler_mps)
        self._publish(self.rio.add_scan(self.map_feedback.correct_scan(scan) if self.map_feedback is not None else scan))

    def _take_map_measurement(self, measurement) -> None:
        """One of the map's velocity errors into the filter; what the filter made of it (its residual, sigma
        and the Doppler scale around it: ``rio.map_feedback.MapUpdate``) is logged and said on the bus (into
        /events), so an update the gate refuses can be explained afterwards."""
        feedback = self.map_feedback
        seen = len(feedback.updates)
        feedback.apply_measurements(self.rio.ekf, [measurement])
        for update in feedback.updates[seen:]:
            log.info("RIO: %s", update.line())
            self.pub.send(Event(time.time_ns(), "rio", "info" if update.accepted else "warning", update.line()))

    def _note_silence(self, now: float) -> None:
        """Radars with no frame for ``radar_silence_s`` are not waited for (said once on the bus); with none
        sending since the start, the odometry goes on from the IMU alone rather than hold its poses back."""
        limit = self.config.radar_silence_s
        for name, last in self.last_frame_monotonic.items():
            if name not in self.silent and now - last > limit:
                self.silent.add(name)
                self.rio.radar_silent(name)
                self.pub.send(Event(time.time_ns(), "rio", "warning",
                                    f"no frame of radar {name} for {now - last:.1f} s: odometry no longer waits for it"))
        waiting = self.rio.radar_watermark_ns is not None  # None from radar_silent() until a radar sends
        if not self.last_frame_monotonic and waiting and now - self.started_monotonic > limit:
            self.rio.radar_silent()
            self.pub.send(Event(time.time_ns(), "rio", "warning", f"no radar frame for "
                                f"{now - self.started_monotonic:.1f} s: odometry goes on with the IMU alone"))

    def _take_scan(self, radar: str, lag_s: float) -> bool:
        """Whether this radar's scan, ``lag_s`` late, is made into a point cloud. Late, every k-th of each
        radar is (k = lag / max_lag_s, at most max_thinning), so every radar keeps some; a thinned one is
        counted and said on the bus at most once a second (into /events)."""
        if lag_s <= self.config.max_lag_s:
            self.behind[radar] = 0
            return True
        self.behind[radar] += 1
        if (self.behind[radar] - 1) % min(self.config.max_thinning, math.ceil(lag_s / self.config.max_lag_s)) == 0:
            return True
        self.rio.stats["scans_thinned_behind"] += 1
        now = time.monotonic()
        if now - self.last_lag_event >= 1.0:
            self.pub.send(Event(time.time_ns(), "rio", "warning", f"odometry {lag_s:.1f} s behind: "
                                f"{self.rio.stats['scans_thinned_behind']} radar scans thinned out so far"))
            self.last_lag_event = now
        return False

    def counters(self) -> dict[str, int]:
        counted = {k: int(self.rio.stats[k]) for k in ("scans_thinned_behind", "scans_late") if k in self.rio.stats}
        if self.map_feedback is not None:
            counted["map_velocity_updates"] = len(self.map_feedback.measurements)
            counted["map_velocity_refused"] = self.map_feedback.rejected
            counted["map_velocity_spanning_update"] = self.map_feedback.spanning_update
            counted["map_velocity_settling"] = self.map_feedback.settling_not_taken
            counted["map_velocity_wild"] = self.map_feedback.wild_not_taken
            # The radars' Doppler scale learnt from the map, in parts per million off 1 (counters are integers).
            counted["map_doppler_scale_ppm"] = round((self.map_feedback.doppler_scale - 1.0) * 1e6)
            counted["map_doppler_scale_sigma_ppm"] = round(self.map_feedback.scale_sigma * 1e6)
        return {**counted, "lag_ms": self.lag_ms}

    def calibration(self) -> dict[str, dict]:
        if self.rio.ekf is None:
            return {}
        return {name: {"mount_translation_m": e.mount.translation_m.tolist(),
                       "mount_rotation_xyzw": e.mount.rotation_xyzw.tolist(), "time_offset_s": float(e.time_offset_s),
                       "sigma": e.sigma.tolist()} for name, e in self.rio.ekf.calibration_estimates().items()}

    def finish(self) -> None:
        """The filter's last poses out, then ``PoseEnd``. Hurried (SIGTERM: the daemon's stop timeout passed),
        the scans the filter still holds are left (its poses so far are in the trajectory file), said in a
        warning. The trajectory file says so (``stop_cut_short``); a hurry that comes once the filter is done
        leaves nothing out, and does not."""
        self.stop_cut_short = self.hurried
        if self.hurried:
            log.warning("RIO: hurried at the stop; the filter's last scans left out, %d poses written",
                        self.poses_written)
        else:
            self._publish(self.rio.finish())
        self.pub.send(PoseEnd(time.time_ns()))

    def write_products(self) -> None:
        if self.trajectory is None:
            return
        # Hurried before finish ran (SIGTERM while warming up or live): its scans were left out too.
        cut_short = self.hurried if self.stop_cut_short is None else self.stop_cut_short
        self.trajectory.close(stop_cut_short=cut_short)
        calibration = self.calibration()
        if calibration:
            from imaging.io.trajectory_file import write_calibration

            write_calibration(self.config.trajectory_path, calibration)
        log.info("RIO: %d poses, %s; wrote %s%s", self.poses_written, dict(self.rio.stats), self.config.trajectory_path,
                 " (stop_cut_short: hurried at the stop)" if cut_short else "")
