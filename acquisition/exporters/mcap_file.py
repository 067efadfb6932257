"""A recording as MCAP, written by foxglove-sdk: Foxglove's own schemas wherever one exists, JSON with a
JSON schema for what has none. See docs/export.md.

Topics, every message at its sensor (PTP) time (``log_time``, ns), events included:

- ``/tf_static`` (``foxglove.FrameTransforms``): base_link -> each radar's frame (its mount) and -> ``imu``,
  once, at the recording's start;
- ``/tf`` (``foxglove.FrameTransforms``): world -> base_link at each pose of the first ``trajectories`` file
  (the odometry), else of the recording's ``/truth``;
- ``/radar/<name>/adc`` (``sarbot.RadarFrame``, JSON): one raw frame, int16 I/Q as base64, its shape
  ``[chirps, rx, samples, 2]``, frame counter, validity and the radar's description (waveform, TX order,
  antenna positions, mount: enough to image it from the file alone);
- ``/radar/<name>/points`` (``foxglove.PointCloud``): a scan's detections (x, y, z, doppler, snr, float32);
- ``/imu`` (``sarbot.Imu``, JSON), ``/can`` (``sarbot.CanFrame``, JSON), ``/trigger`` (``sarbot.Trigger``,
  JSON), ``/events`` (``foxglove.Log``);
- ``/truth`` (``foxglove.PoseInFrame``, frame ``world``) where the recording has it;
- with ``maps``: ``/map`` (``foxglove.Grid``, frame ``world``): each SAR image as float32 dB, 0 dB at its
  peak, stamped at the recording's end; a volume by its brightest voxel per column;
- with ``trajectories``: ``/pose`` (``foxglove.PoseInFrame``): each pose of an odometry trajectory.

With several maps or trajectories, each topic gets the file's stem: ``/map/stripmap_demo``.
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from imaging.core import strict_json
from imaging.core.errors import SarbotError

from . import (
    POINT_FIELDS,
    detection_scans,
    event_sensor_times_ns,
    grid_db,
    radar_description,
    sensor_clock_offset_ns,
    sensor_span_ns,
)

_STAMP = {"type": "object", "description": "sensor (PTP) time", "required": ["sec", "nsec"],
          "properties": {"sec": {"type": "integer", "minimum": 0},
                         "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}
_VEC3 = {"type": "object", "required": ["x", "y", "z"], "properties": {k: {"type": "number"} for k in "xyz"}}
_BYTES = {"type": "string", "contentEncoding": "base64"}
_NUMBER_LIST = {"type": "array", "items": {"type": "number"}}

#: The JSON schemas of sarbot's own MCAP messages (those Foxglove has no schema for), as documented in
#: docs/export.md; the file carries each as its channel's ``jsonschema``.
JSON_SCHEMAS = {
    "sarbot.RadarFrame": {
        "description": "One raw FMCW frame of one radar with what it takes to image it",
        "required": ["timestamp", "radar", "frame_counter", "valid", "shape", "dtype", "waveform", "data"],
        "properties": {
            "timestamp": _STAMP, "radar": {"type": "string", "description": "the radar's name and TF frame"},
            "frame_counter": {"type": "integer", "description": "the sensor's own frame counter (uint32)"},
            "valid": {"type": "boolean", "description": "false where datagrams were lost (zero-filled)"},
            "shape": {"type": "array", "items": {"type": "integer"}, "description": "[chirps, rx, samples, 2]"},
            "dtype": {"type": "string", "enum": ["int16le"]},
            "waveform": {
                "type": "object", "description": "see docs/signal-model.md",
                "required": ["f0_hz", "bandwidth_hz", "slope_hz_per_s", "chirp_duration_s", "chirp_interval_s",
                             "sample_rate_hz", "chirps_per_frame", "n_tx", "n_rx", "frame_interval_s",
                             "tdm_tx_order", "tx_positions_m", "rx_positions_m", "mount"],
                "properties": {
                    **{k: {"type": "number"} for k in ("f0_hz", "bandwidth_hz", "slope_hz_per_s", "chirp_duration_s",
                                                       "chirp_interval_s", "sample_rate_hz", "frame_interval_s")},
                    **{k: {"type": "integer"} for k in ("chirps_per_frame", "n_tx", "n_rx")},
                    "tdm_tx_order": {"type": "array", "items": {"type": "integer"}, "description": "TX of each chirp"},
                    "tx_positions_m": {"type": "array", "items": _NUMBER_LIST, "description": "[n_tx][x, y, z], radar frame"},
                    "rx_positions_m": {"type": "array", "items": _NUMBER_LIST, "description": "[n_rx][x, y, z], radar frame"},
                    "mount": {"type": "object", "description": "radar -> base_link",
                              "properties": {"translation_m": _NUMBER_LIST, "rotation_xyzw": _NUMBER_LIST}}}},
            "data": {**_BYTES, "description": "int16 little-endian I/Q, row-major in the order of shape"}}},
    "sarbot.Imu": {
        "description": "One IMU sample in the IMU's frame (imu)",
        "required": ["timestamp", "angular_velocity", "linear_acceleration", "counter"],
        "properties": {"timestamp": _STAMP, "angular_velocity": {**_VEC3, "description": "rad/s"},
                       "linear_acceleration": {**_VEC3, "description": "specific force, m/s^2"},
                       "counter": {"type": "integer", "description": "the IMU's sample counter"}}},
    "sarbot.CanFrame": {
        "description": "One frame of the robot base's CAN bus",
        "required": ["timestamp", "id", "dlc", "data"],
        "properties": {"timestamp": _STAMP, "id": {"type": "integer", "description": "arbitration id"},
                       "dlc": {"type": "integer", "minimum": 0, "maximum": 64}, "data": _BYTES}},
    "sarbot.Trigger": {
        "description": "The acquisition trigger that starts the radars' frames",
        "required": ["timestamp", "source"],
        "properties": {"timestamp": _STAMP, "source": {"type": "string", "description": "who saw it"}}},
}
_LOG_LEVELS = {"debug": "Debug", "info": "Info", "warning": "Warning", "error": "Error", "fatal": "Fatal"}


def _stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns) // 1_000_000_000, "nsec": int(t_ns) % 1_000_000_000}


def _xyz(v) -> dict:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


class _Out:
    """The SDK's MCAP sink and one channel per topic, all in a context of their own (nothing else logs to it)."""

    def __init__(self, path: Path):
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.context = foxglove.Context()
        self.writer = foxglove.open_mcap(path, allow_overwrite=True, context=self.context,
                                         writer_options=MCAPWriteOptions(compression=MCAPCompression.Zstd,
                                                                         profile=""))
        self.channels: dict = {}
        self.counts: dict[str, int] = {}

    def typed(self, topic: str, channel_class, message, t_ns: int) -> None:
        """``message`` (a foxglove.messages object) on a channel of Foxglove's schema."""
        if topic not in self.channels:
            self.channels[topic] = channel_class(topic, context=self.context)
            self.counts[topic] = 0
        self.channels[topic].log(message, log_time=int(t_ns))
        self.counts[topic] += 1

    def json(self, topic: str, schema: str, message: dict, t_ns: int) -> None:
        """``message`` as strict JSON on a channel of sarbot's JSON schema ``schema``."""
        import foxglove

        if topic not in self.channels:
            body = {"title": schema, "type": "object", **JSON_SCHEMAS[schema]}
            self.channels[topic] = foxglove.Channel(
                topic, message_encoding="json", context=self.context,
                schema=foxglove.Schema(name=schema, encoding="jsonschema", data=strict_json.dumps(body).encode()))
            self.counts[topic] = 0
        self.channels[topic].log(strict_json.dumps(message, separators=(",", ":")).encode(), log_time=int(t_ns))
        self.counts[topic] += 1

    def close(self) -> None:
        self.writer.close()


def export_mcap(recording: str | Path, output: str | Path, overwrite: bool = False, progress=None, maps=(),
                trajectories=()) -> dict[str, int]:
    """Write ``recording`` (and the image files ``maps``, the trajectory files ``trajectories``) as MCAP to
    ``output``; returns the number of messages per topic."""
    from foxglove.channels import FrameTransformsChannel, GridChannel, LogChannel, PoseInFrameChannel
    from foxglove.messages import Log, LogLevel

    from imaging.io.image_file import read_image
    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import read_trajectory

    output = Path(output)
    if output.exists() and not overwrite:
        raise SarbotError(f"{output}: exists already (use --overwrite to replace it)")
    if output.suffix.lower() != ".mcap":
        raise SarbotError(f"{output}: give a .mcap file name")
    images = {_topic("/map", p, maps): read_image(p) for p in maps}  # unreadable files fail before any writing
    tracks = {_topic("/pose", p, trajectories): read_trajectory(p) for p in trajectories}
    partial = output.with_name(output.name + ".partial")
    with Recording(recording) as rec:
        span = sensor_span_ns(rec)
        start_ns = span[0] if span else 0
        end_ns = max([int(rec.frame_time_ns(n)[-1]) for n in rec.radar_names if rec.n_frames(n)] or [start_ns])
        out = _Out(partial)
        try:
            out.typed("/tf_static", FrameTransformsChannel, _mount_transforms(rec, start_ns), start_ns)
            total = sum(rec.n_frames(n) for n in rec.radar_names)
            done = 0
            for name in rec.radar_names:
                description = radar_description(rec.radar(name), rec.tdm_tx_order(name))
                times, counters, valid = rec.frame_time_ns(name), rec.frame_counter(name), rec.valid(name)
                if rec.has_adc(name):
                    for k in range(times.size):
                        iq = np.ascontiguousarray(rec.adc_iq(name, slice(k, k + 1))[0], dtype="<i2")
                        out.json(f"/radar/{name}/adc", "sarbot.RadarFrame",
                                 {"timestamp": _stamp(times[k]), "radar": name, "frame_counter": int(counters[k]),
                                  "valid": bool(valid[k]), "shape": list(iq.shape), "dtype": "int16le",
                                  "waveform": description, "data": base64.b64encode(iq.tobytes()).decode()}, times[k])
                        done += 1
                        if progress:
                            progress(done, total)
                if rec.has_detections(name):
                    _points(out, rec, name)
            imu = rec.imu()
            if imu is not None:
                for t, g, a, c in zip(imu["time_ns"], imu["gyro_radps"], imu["accel_mps2"], imu["counter"]):
                    out.json("/imu", "sarbot.Imu", {"timestamp": _stamp(t), "angular_velocity": _xyz(g),
                                                    "linear_acceleration": _xyz(a), "counter": int(c)}, t)
            can = rec.can()
            for t, ident, dlc, data in zip(can["time_ns"], can["arbitration_id"], can["dlc"], can["data"]):
                out.json("/can", "sarbot.CanFrame", {"timestamp": _stamp(t), "id": int(ident), "dlc": int(dlc),
                                                     "data": base64.b64encode(bytes(data[:dlc])).decode()}, t)
            for t, source in zip(rec.triggers(), rec.trigger_sources()):
                out.json("/trigger", "sarbot.Trigger", {"timestamp": _stamp(t), "source": source}, t)
            events = rec.events()
            times = event_sensor_times_ns([e[0] for e in events], sensor_clock_offset_ns(rec), span,
                                          rec.events_time_base())
            for t, (_, source, level, message) in zip(times, events):
                out.typed("/events", LogChannel,
                          Log(timestamp=_foxglove_stamp(t), level=getattr(LogLevel, _LOG_LEVELS.get(level, "Info")),
                              message=message, name=source, file="", line=0), t)
            truth = rec.truth()
            if truth is not None:
                _poses(out, "/truth", truth, PoseInFrameChannel)
            for topic, track in tracks.items():
                _poses(out, topic, track, PoseInFrameChannel)
            world = next(iter(tracks.values()), truth)  # the odometry where given, else the truth
            if world is not None:
                _world_transforms(out, world, FrameTransformsChannel)
            for topic, image in images.items():
                out.typed(topic, GridChannel, grid_message(image, end_ns), end_ns)
        finally:
            out.close()
    partial.replace(output)  # a half-written file never carries the name
    return dict(out.counts)


def _foxglove_stamp(t_ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(sec=int(t_ns) // 1_000_000_000, nsec=int(t_ns) % 1_000_000_000)


def _pose(position, orientation_xyzw):
    from foxglove.messages import Pose, Quaternion, Vector3

    return Pose(position=Vector3(**_xyz(position)), orientation=Quaternion(**dict(zip("xyzw", map(float, orientation_xyzw)))))


def _transform(t_ns: int, parent: str, child: str, translation, rotation_xyzw):
    from foxglove.messages import FrameTransform, Quaternion, Vector3

    return FrameTransform(timestamp=_foxglove_stamp(t_ns), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(**_xyz(translation)),
                          rotation=Quaternion(**dict(zip("xyzw", map(float, rotation_xyzw)))))


def _mount_transforms(rec, t_ns: int):
    """base_link -> every radar's frame (named as the radar) and -> ``imu``: the rig's mounts."""
    from foxglove.messages import FrameTransforms

    transforms = [_transform(t_ns, "base_link", name, m.translation_m, m.rotation_xyzw)
                  for name in rec.radar_names for m in [rec.radar(name).mount]]
    imu = rec.imu()
    if imu is not None and "mount_translation_m" in imu:
        transforms.append(_transform(t_ns, "base_link", "imu", imu["mount_translation_m"], imu["mount_rotation_xyzw"]))
    return FrameTransforms(transforms=transforms)


def _world_transforms(out: _Out, trajectory, channel_class) -> None:
    from foxglove.messages import FrameTransforms

    for t, p, q in zip(trajectory.time_ns, trajectory.position_m, trajectory.orientation_xyzw):
        out.typed("/tf", channel_class, FrameTransforms(transforms=[_transform(t, "world", "base_link", p, q)]), t)


def _poses(out: _Out, topic: str, trajectory, channel_class) -> None:
    from foxglove.messages import PoseInFrame

    for t, p, q in zip(trajectory.time_ns, trajectory.position_m, trajectory.orientation_xyzw):
        out.typed(topic, channel_class, PoseInFrame(timestamp=_foxglove_stamp(t), frame_id="world", pose=_pose(p, q)), t)


def _topic(base: str, path, paths) -> str:
    return base if len(paths) == 1 else f"{base}/{Path(path).stem}"


def grid_message(image, t_ns: int):
    """A SarImage as a ``foxglove.Grid``: row r, column c at (x_m[c], y_m[r]) in the world frame; a volume
    by its brightest voxel along z."""
    from foxglove.messages import Grid, PackedElementField, PackedElementFieldNumericType, Vector2

    mag = np.abs(image.image)
    db = grid_db(mag.max(axis=0) if mag.ndim == 3 else mag)
    dx = float(image.x_m[1] - image.x_m[0]) if image.x_m.size > 1 else 1.0
    dy = float(image.y_m[1] - image.y_m[0]) if image.y_m.size > 1 else dx
    z = float(image.z_m[0]) if image.z_m is not None and np.size(image.z_m) else 0.0
    corner = (float(image.x_m[0]) - dx / 2, float(image.y_m[0]) - dy / 2, z)
    return Grid(timestamp=_foxglove_stamp(t_ns), frame_id="world", pose=_pose(corner, (0.0, 0.0, 0.0, 1.0)),
                column_count=int(db.shape[1]), cell_size=Vector2(x=dx, y=dy), row_stride=4 * int(db.shape[1]),
                cell_stride=4, fields=[PackedElementField(name="db", offset=0, type=PackedElementFieldNumericType.Float32)],
                data=db.tobytes())


def _points(out: _Out, rec, name: str) -> None:
    from foxglove.channels import PointCloudChannel
    from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud

    mount = rec.radar(name).mount
    pose = _pose(mount.translation_m, mount.rotation_xyzw)
    f32 = PackedElementFieldNumericType.Float32
    fields = [PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate(POINT_FIELDS)]
    for t, pts in detection_scans(rec, name):
        out.typed(f"/radar/{name}/points", PointCloudChannel,
                  PointCloud(timestamp=_foxglove_stamp(t), frame_id="base_link", pose=pose, point_stride=20,
                             fields=fields, data=pts.tobytes()), t)
