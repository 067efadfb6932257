"""The live view: the run on the Foxglove WebSocket protocol (``foxglove-sdk``), for Foxglove or any client.

Clients may speak ``foxglove.sdk.v1`` (Foxglove, the SDK) or ``foxglove.websocket.v1`` (Lichtblick, npm's
``@foxglove/ws-protocol``): see ``view_protocols``.

``sarbot run --view [HOST:]PORT`` adds this worker. It subscribes to the strip map's tiles, the odometry's
poses, the daemon's health and every event, and serves:

- ``/map`` (``foxglove.Grid``, frame ``world``): the strip map's magnitude in dB (float32 field ``db``,
  0 dB at the brightest pixel so far), the whole mosaic, re-sent when tiles changed (at most
  ``map_rate_hz``); a mosaic of more than ``max_cells`` pixels is sent coarser (the brightest of each
  k x k block), so a long drive does not flood the connection;
- ``/pose`` (``foxglove.PoseInFrame``) and ``/tf`` (``foxglove.FrameTransforms``: world -> base_link, and
  base_link -> each radar by its mount), the newest odometry pose at most ``pose_rate_hz``;
- ``/radar/<name>/points`` (``foxglove.PointCloud``, frame ``<name>``): the detections the odometry made of
  each scan (x, y, z, doppler as float32);
- ``/imu`` (JSON: gyro rad/s, specific force m/s^2), the newest sample at most ``pose_rate_hz``;
- ``/health`` (JSON: the daemon's health report and its one-line summary) and ``/events``
  (``foxglove.Log``): every event the recording's /events gets, as the daemon publishes them.

Loopback by default: the map and the robot's position are not for the whole network unless asked.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from imaging.core import strict_json

from ..exporters import grid_db
from ..messages import Event, Health, ImuBatch, LoggedEvent, MapTile, PointCloudMessage, PoseBatch
from . import Worker

log = logging.getLogger(f"sarbot.{__name__}")

_LEVELS = ("debug", "info", "warning", "error", "fatal")


@dataclasses.dataclass
class ViewWorkerConfig:
    host: str
    port: int
    map_endpoint: str
    pose_endpoint: str
    health_endpoint: str
    map_rate_hz: float = 2.0
    pose_rate_hz: float = 20.0
    max_cells: int = 2_000_000
    #: radar name -> (translation [3] m, rotation xyzw [4]) in the body frame, for /tf
    mounts: dict = dataclasses.field(default_factory=dict)


def parse_view_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); loopback when no host is given."""
    from imaging.core.errors import SarbotError

    host, _, port = text.rpartition(":")
    host = host or "127.0.0.1"
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise SarbotError(f"--view {text!r}: expected [HOST:]PORT with a port in 1..65535")
    return host, int(port)


def _stamp(t_ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(sec=int(t_ns) // 1_000_000_000, nsec=int(t_ns) % 1_000_000_000)


class ViewWorker(Worker):
    drain_quiet_s = 0.5
    drain_max_s = 2.0

    def __init__(self, config: ViewWorkerConfig, pub):
        self.config = config
        self.pub = pub
        # Events from the daemon's one stream of them (LoggedEvent: every event the file gets, each once),
        # not from each driver and worker, whose own events miss the supervisor's (restarts, devices).
        self.topics = [MapTile.TOPIC, PoseBatch.TOPIC, Health.TOPIC, LoggedEvent.TOPIC, PointCloudMessage.TOPIC,
                       ImuBatch.TOPIC]
        self.endpoints = [config.map_endpoint, config.pose_endpoint, config.health_endpoint]
        self.tiles: dict[tuple[int, int], np.ndarray] = {}  # magnitude, float32
        self.pixel_m = self.tile_px = None
        self.map_changed = False
        self.last_map = self.last_pose_sent = 0.0
        self.pose = None  # (t, position, orientation) of the newest pose
        self.pose_changed = False
        self.server = self.bridge = None
        self.point_channels: dict = {}
        self.imu = None  # the newest sample (t, gyro, accel)
        self.last_imu_sent = 0.0
        self.sent = {"map": 0, "pose": 0, "health": 0, "events": 0, "points": 0, "imu": 0}

    def warm_up(self) -> None:
        import foxglove
        from foxglove.channels import (
            FrameTransformsChannel,
            GridChannel,
            LogChannel,
            PointCloudChannel,
            PoseInFrameChannel,
        )

        from .view_protocols import SubprotocolBridge

        # The SDK's server on a loopback port of its own; clients reach it through the bridge, which
        # accepts foxglove.websocket.v1 (Lichtblick, @foxglove/ws-protocol) besides foxglove.sdk.v1.
        self.server = foxglove.start_server(name="sarbot", host="127.0.0.1", port=0)
        self.bridge = SubprotocolBridge(self.config.host, self.config.port, self.server.port)
        self.grid_channel = GridChannel("/map")
        self.pose_channel = PoseInFrameChannel("/pose")
        self.tf_channel = FrameTransformsChannel("/tf")
        self.log_channel = LogChannel("/events")
        self.health_channel = foxglove.Channel("/health", message_encoding="json",
                                               schema={"type": "object", "title": "sarbot.Health"})
        self.imu_channel = foxglove.Channel("/imu", message_encoding="json",
                                            schema={"type": "object", "title": "sarbot.Imu"})
        for name in self.config.mounts:  # advertised from the start, so a client sees every topic at once
            self.point_channels[name] = PointCloudChannel(f"/radar/{name}/points")
        log.info("live view: Foxglove WebSocket (foxglove.sdk.v1, foxglove.websocket.v1) on ws://%s:%d",
                 self.config.host, self.bridge.port)

    def counters(self) -> dict[str, int]:
        return {f"sent_{k}": v for k, v in self.sent.items()}

    def handle(self, message, live: bool) -> None:
        if isinstance(message, MapTile):
            self.tiles[tuple(message.key)] = np.abs(message.image).astype(np.float32)
            self.pixel_m, self.tile_px = message.pixel_m, message.tile_px
            self.map_changed = True
        elif isinstance(message, PoseBatch) and len(message):
            self.pose = (int(message.time_ns[-1]), message.position_m[-1], message.orientation_xyzw[-1])
            self.pose_changed = True
        elif isinstance(message, PointCloudMessage):
            self._send_points(message)
        elif isinstance(message, ImuBatch) and len(message):
            self.imu = (int(message.time_ns[-1]), message.gyro_radps[-1], message.accel_mps2[-1])
        elif isinstance(message, Health):
            body = {**dataclasses.asdict(message), "summary": message.line()}
            self.health_channel.log(strict_json.dumps(body).encode())
            self.sent["health"] += 1
        elif isinstance(message, Event):
            from foxglove.messages import Log, LogLevel

            level = message.level if message.level in _LEVELS else "info"
            self.log_channel.log(Log(timestamp=_stamp(message.time_ns), level=getattr(LogLevel, level.capitalize()),
                                     message=message.message, name=message.source, file="", line=0))
            self.sent["events"] += 1

    def step(self) -> None:
        now = time.monotonic()
        if self.pose_changed and now - self.last_pose_sent >= 1.0 / self.config.pose_rate_hz:
            self._send_pose()
            self.last_pose_sent = now
        if self.imu is not None and now - self.last_imu_sent >= 1.0 / self.config.pose_rate_hz:
            t, g, a = self.imu
            self.imu_channel.log(strict_json.dumps({"time_ns": t, "gyro_radps": [float(v) for v in g],
                                             "accel_mps2": [float(v) for v in a]}).encode())
            self.imu, self.last_imu_sent = None, now
            self.sent["imu"] += 1
        if self.map_changed and now - self.last_map >= 1.0 / self.config.map_rate_hz:
            self._send_map()
            self.last_map = now

    def finish(self) -> None:
        if self.map_changed:
            self._send_map()
        if self.pose_changed:
            self._send_pose()

    def write_products(self) -> None:
        if self.bridge is not None:
            self.bridge.stop()
        if self.server is not None:
            self.server.stop()

    def _send_pose(self) -> None:
        from foxglove.messages import (
            FrameTransform,
            FrameTransforms,
            Pose,
            PoseInFrame,
            Quaternion,
            Vector3,
        )

        t, p, q = self.pose
        position = Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
        orientation = Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
        self.pose_channel.log(PoseInFrame(timestamp=_stamp(t), frame_id="world",
                                          pose=Pose(position=position, orientation=orientation)))
        mounts = [FrameTransform(timestamp=_stamp(t), parent_frame_id="base_link", child_frame_id=name,
                                 translation=Vector3(x=float(tr[0]), y=float(tr[1]), z=float(tr[2])),
                                 rotation=Quaternion(x=float(r[0]), y=float(r[1]), z=float(r[2]), w=float(r[3])))
                  for name, (tr, r) in self.config.mounts.items()]
        self.tf_channel.log(FrameTransforms(transforms=[FrameTransform(
            timestamp=_stamp(t), parent_frame_id="world", child_frame_id="base_link", translation=position,
            rotation=orientation), *mounts]))
        self.pose_changed = False
        self.sent["pose"] += 1

    def _send_points(self, m: PointCloudMessage) -> None:
        from foxglove.channels import PointCloudChannel
        from foxglove.messages import (
            PackedElementField,
            PackedElementFieldNumericType,
            PointCloud,
            Pose,
            Quaternion,
            Vector3,
        )

        channel = self.point_channels.get(m.radar)
        if channel is None:
            channel = self.point_channels[m.radar] = PointCloudChannel(f"/radar/{m.radar}/points")
        points = np.column_stack([np.asarray(m.xyz_m, "<f4"), np.asarray(m.doppler_mps, "<f4")]).astype("<f4")
        f32 = PackedElementFieldNumericType.Float32
        channel.log(PointCloud(
            timestamp=_stamp(m.time_ns), frame_id=m.radar,
            pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
            point_stride=16, fields=[PackedElementField(name=n, offset=4 * i, type=f32)
                                     for i, n in enumerate(("x", "y", "z", "doppler"))],
            data=points.tobytes()))
        self.sent["points"] += 1

    def _send_map(self) -> None:
        from foxglove.messages import (
            Grid,
            PackedElementField,
            PackedElementFieldNumericType,
            Pose,
            Quaternion,
            Vector2,
            Vector3,
        )

        keys = np.array(list(self.tiles))
        lo, hi = keys.min(axis=0), keys.max(axis=0)
        n = self.tile_px
        mag = np.zeros(((hi[1] - lo[1] + 1) * n, (hi[0] - lo[0] + 1) * n), np.float32)
        for (ix, iy), tile in self.tiles.items():
            mag[(iy - lo[1]) * n:(iy - lo[1] + 1) * n, (ix - lo[0]) * n:(ix - lo[0] + 1) * n] = tile
        mag, k = block_max(mag, self.config.max_cells)
        db = grid_db(mag)
        tile_m = n * self.pixel_m
        origin = Pose(position=Vector3(x=float(lo[0] * tile_m), y=float(lo[1] * tile_m), z=0.0),
                      orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
        self.grid_channel.log(Grid(
            timestamp=_stamp(time.time_ns()), frame_id="world", pose=origin, column_count=db.shape[1],
            cell_size=Vector2(x=float(k * self.pixel_m), y=float(k * self.pixel_m)), row_stride=4 * db.shape[1],
            cell_stride=4,
            fields=[PackedElementField(name="db", offset=0, type=PackedElementFieldNumericType.Float32)], data=db.tobytes()))
        self.map_changed = False
        self.sent["map"] += 1


def block_max(image: np.ndarray, max_cells: int) -> tuple[np.ndarray, int]:
    """``image`` reduced by the smallest integer factor k that leaves at most ``max_cells`` pixels, each the
    largest of its k x k block (a point target stays visible); returns the image and k."""
    k = 1
    while (-(-image.shape[0] // k)) * (-(-image.shape[1] // k)) > max_cells:
        k += 1
    if k == 1:
        return image, 1
    ny, nx = -(-image.shape[0] // k) * k, -(-image.shape[1] // k) * k
    padded = np.zeros((ny, nx), image.dtype)
    padded[:image.shape[0], :image.shape[1]] = image
    return padded.reshape(ny // k, k, nx // k, k).max(axis=(1, 3)), k

