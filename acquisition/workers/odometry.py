"""The odometry worker: IMU batches and radar frames -> point clouds -> ``rio.streaming.StreamingRio`` ->
``pose`` messages; the trajectory file at the end."""

from __future__ import annotations

import collections
import dataclasses
import logging
import time

import numpy as np

from imaging.core.rig import Rig
from imaging.core.samples import iq_to_complex

from ..messages import ImuBatch, PoseBatch, PoseEnd, RadarFrameMessage
from . import Worker

log = logging.getLogger(f"sarbot.{__name__}")


@dataclasses.dataclass
class OdometryWorkerConfig:
    """``radars`` None: all of the rig's. Point clouds are made from at most ``scan_rate_hz`` frames per radar
    (ego velocity needs no more, and each costs about 10 ms); a frame that reaches the worker more than
    ``max_lag_s`` late is skipped (counted) so the odometry stays current when the machine is busy. The
    IMU is never skipped."""

    rig: Rig
    radars: list[str] | None
    trajectory_path: str
    scan_rate_hz: float = 10.0
    max_lag_s: float = 0.3


class OdometryWorker(Worker):
    drain_quiet_s = 0.5
    drain_max_s = 30.0

    def __init__(self, config: OdometryWorkerConfig, pub):
        from rio.odometry import RioOptions
        from rio.pointcloud import PointCloudConfig
        from rio.streaming import StreamingRio

        self.config = config
        self.pub = pub
        rig = config.rig
        use = set(config.radars or rig.radar_names)
        self.topics = [ImuBatch.TOPIC, *[RadarFrameMessage.topic_of(n) for n in sorted(use)]]
        self.radars = {r.name: r for r in rig.radars if r.name in use}
        self.orders = {name: np.asarray(r.waveform.tdm_tx_order()) for name, r in self.radars.items()}
        self.half_frame_ns = {name: r.waveform.frame_duration_ns // 2 for name, r in self.radars.items()}
        self.every = {name: max(1, int(round(1.0 / (r.waveform.frame_interval_s * config.scan_rate_hz))))
                      for name, r in self.radars.items()}
        self.rio = StreamingRio(RioOptions(), imu_rate_hz=rig.imu.rate_hz)
        self.pc_config = PointCloudConfig()
        self.kept: list[PoseBatch] = []
        self.seen: collections.Counter = collections.Counter()

    def _publish(self, batch) -> None:
        if len(batch):
            poses = PoseBatch(batch.time_ns, batch.position_m, batch.orientation_xyzw, batch.velocity_mps)
            self.kept.append(poses)
            self.pub.send(poses)

    def handle(self, message, live: bool) -> None:
        from rio.odometry import RadarScan
        from rio.pointcloud import detect

        if isinstance(message, ImuBatch):
            self._publish(self.rio.add_imu(message.time_ns, message.accel_mps2, message.gyro_radps))
            return
        if not isinstance(message, RadarFrameMessage) or message.radar not in self.radars or not message.frame.valid:
            return
        name, frame = message.radar, message.frame
        self.seen[name] += 1
        if self.seen[name] % self.every[name]:
            return
        if (time.time_ns() - frame.receive_ns) * 1e-9 > self.config.max_lag_s:
            self.rio.stats["scans_skipped_behind"] += 1
            return
        radar = self.radars[name]
        pc = detect(iq_to_complex(frame.iq), radar, self.orders[name], self.pc_config)
        self._publish(self.rio.add_scan(RadarScan(frame.frame_time_ns + self.half_frame_ns[name], name, radar.mount,
                                                  pc.xyz_m, pc.doppler_mps)))

    def finish(self) -> None:
        self._publish(self.rio.finish())
        self.pub.send(PoseEnd(time.time_ns()))

    def write_products(self) -> None:
        from imaging.core.trajectory import SampledTrajectory
        from imaging.io.trajectory_file import write_trajectory

        if not self.kept:
            return
        times = np.concatenate([b.time_ns for b in self.kept])
        traj = SampledTrajectory(times, np.concatenate([b.position_m for b in self.kept]),
                                 np.concatenate([b.orientation_xyzw for b in self.kept]),
                                 np.concatenate([b.velocity_mps for b in self.kept]), source="rio")
        write_trajectory(self.config.trajectory_path, traj)
        log.info("RIO: %d poses, %s; wrote %s", times.size, dict(self.rio.stats), self.config.trajectory_path)
