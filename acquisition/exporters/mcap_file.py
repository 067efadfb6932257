"""A recording as MCAP (JSON messages with JSON schemas), for Foxglove and the ``mcap`` tools.

Topics, each message at its sensor time (``log_time``, ns):

- ``/radar/<name>/adc`` (``sarbot.RadarFrame``): one raw frame, int16 I/Q as base64 bytes, its shape
  ``[chirps, rx, samples, 2]``, frame counter, validity and the radar's waveform;
- ``/radar/<name>/points`` (``foxglove.PointCloud``): a scan's detections (x, y, z, doppler, snr, float32),
  where the recording has them;
- ``/imu`` (``sarbot.Imu``): one sample, gyro rad/s, specific force m/s^2, the IMU's counter;
- ``/can`` (``sarbot.CanFrame``), ``/trigger`` (``sarbot.Trigger``), ``/events`` (``foxglove.Log``);
- ``/truth`` (``foxglove.PoseInFrame``, frame ``world``) where the recording has it;
- with ``maps``: ``/map`` (``foxglove.Grid``, frame ``world``): each SAR image (a strip map, ``sarbot image``)
  as float32 dB, 0 dB at its peak, stamped at the recording's end; a volume by its brightest voxel per column;
- with ``trajectories``: ``/pose`` (``foxglove.PoseInFrame``): each pose of an odometry trajectory.

With several maps or trajectories, each topic gets the file's stem: ``/map/stripmap_demo``.
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from imaging.core import strict_json
from imaging.core.errors import SarbotError

from . import POINT_FIELDS, detection_scans, grid_db

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_BYTES = {"type": "string", "contentEncoding": "base64"}

SCHEMAS = {
    "sarbot.RadarFrame": {"timestamp": _TIME, "radar": {"type": "string"}, "frame_counter": {"type": "integer"},
                          "valid": {"type": "boolean"}, "shape": {"type": "array", "items": {"type": "integer"}},
                          "dtype": {"type": "string"}, "waveform": {"type": "object"}, "data": _BYTES},
    "foxglove.PointCloud": {"timestamp": _TIME, "frame_id": {"type": "string"},
                            "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
                            "point_stride": {"type": "integer"}, "fields": {"type": "array"}, "data": _BYTES},
    "sarbot.Imu": {"timestamp": _TIME, "angular_velocity": _VEC3, "linear_acceleration": _VEC3,
                   "counter": {"type": "integer"}},
    "sarbot.CanFrame": {"timestamp": _TIME, "id": {"type": "integer"}, "dlc": {"type": "integer"}, "data": _BYTES},
    "sarbot.Trigger": {"timestamp": _TIME, "source": {"type": "string"}},
    "foxglove.Log": {"timestamp": _TIME, "level": {"type": "integer"}, "message": {"type": "string"},
                     "name": {"type": "string"}, "file": {"type": "string"}, "line": {"type": "integer"}},
    "foxglove.Grid": {"timestamp": _TIME, "frame_id": {"type": "string"},
                      "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
                      "column_count": {"type": "integer"},
                      "cell_size": {"type": "object", "properties": {k: {"type": "number"} for k in "xy"}},
                      "row_stride": {"type": "integer"}, "cell_stride": {"type": "integer"},
                      "fields": {"type": "array"}, "data": _BYTES},
    "foxglove.PoseInFrame": {"timestamp": _TIME, "frame_id": {"type": "string"},
                             "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}},
}
#: foxglove.Log levels
_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
_FLOAT32 = 7  # foxglove.PackedElementField numeric type


def _stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns) // 1_000_000_000, "nsec": int(t_ns) % 1_000_000_000}


def _xyz(v) -> dict:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


class _Out:
    def __init__(self, stream):
        from mcap.writer import CompressionType, Writer

        self.writer = Writer(stream, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library="sarbot")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def send(self, topic: str, schema: str, t_ns: int, message: dict) -> None:
        if topic not in self.channels:
            if schema not in self.schemas:
                body = {"title": schema, "type": "object", "properties": SCHEMAS[schema]}
                self.schemas[schema] = self.writer.register_schema(schema, "jsonschema", strict_json.dumps(body).encode())
            self.channels[topic] = self.writer.register_channel(topic, "json", self.schemas[schema])
            self.counts[topic] = 0
        self.writer.add_message(self.channels[topic], log_time=int(t_ns), publish_time=int(t_ns),
                                data=strict_json.dumps(message, separators=(",", ":")).encode(), sequence=self.counts[topic])
        self.counts[topic] += 1


def export_mcap(recording: str | Path, output: str | Path, overwrite: bool = False, progress=None, maps=(),
                trajectories=()) -> dict[str, int]:
    """Write ``recording`` (and the image files ``maps``, the trajectory files ``trajectories``) as MCAP to
    ``output``; returns the number of messages per topic."""
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
    with Recording(recording) as rec, partial.open("wb") as stream:
        out = _Out(stream)
        total = sum(rec.n_frames(n) for n in rec.radar_names)
        done = 0
        for name in rec.radar_names:
            wf = rec.radar(name).waveform
            waveform = {k: getattr(wf, k) for k in ("f0_hz", "bandwidth_hz", "chirp_duration_s", "chirp_interval_s",
                                                    "sample_rate_hz", "chirps_per_frame", "n_tx", "n_rx",
                                                    "frame_interval_s")}
            times, counters, valid = rec.frame_time_ns(name), rec.frame_counter(name), rec.valid(name)
            if rec.has_adc(name):
                for k in range(times.size):
                    iq = np.ascontiguousarray(rec.adc_iq(name, slice(k, k + 1))[0], dtype="<i2")
                    out.send(f"/radar/{name}/adc", "sarbot.RadarFrame", times[k],
                             {"timestamp": _stamp(times[k]), "radar": name, "frame_counter": int(counters[k]),
                              "valid": bool(valid[k]), "shape": list(iq.shape), "dtype": "int16le",
                              "waveform": waveform, "data": base64.b64encode(iq.tobytes()).decode()})
                    done += 1
                    if progress:
                        progress(done, total)
            if rec.has_detections(name):
                _points(out, rec, name)
        imu = rec.imu()
        if imu is not None:
            for t, g, a, c in zip(imu["time_ns"], imu["gyro_radps"], imu["accel_mps2"], imu["counter"]):
                out.send("/imu", "sarbot.Imu", t, {"timestamp": _stamp(t), "angular_velocity": _xyz(g),
                                                  "linear_acceleration": _xyz(a), "counter": int(c)})
        can = rec.can()
        for t, ident, dlc, data in zip(can["time_ns"], can["arbitration_id"], can["dlc"], can["data"]):
            out.send("/can", "sarbot.CanFrame", t, {"timestamp": _stamp(t), "id": int(ident), "dlc": int(dlc),
                                                    "data": base64.b64encode(bytes(data[:dlc])).decode()})
        for t, source in zip(rec.triggers(), rec.trigger_sources()):
            out.send("/trigger", "sarbot.Trigger", t, {"timestamp": _stamp(t), "source": source})
        for t, source, level, message in rec.events():
            out.send("/events", "foxglove.Log", t, {"timestamp": _stamp(t), "level": _LEVELS.get(level, 2),
                                                    "message": message, "name": source, "file": "", "line": 0})
        truth = rec.truth()
        if truth is not None:
            _poses(out, "/truth", truth)
        for topic, track in tracks.items():
            _poses(out, topic, track)
        end_ns = max([int(rec.frame_time_ns(n)[-1]) for n in rec.radar_names if rec.n_frames(n)] or [0])
        for topic, image in images.items():
            out.send(topic, "foxglove.Grid", end_ns, grid_message(image, end_ns))
        out.writer.finish()
    partial.replace(output)  # a half-written file never carries the name
    return dict(out.counts)


def _poses(out: _Out, topic: str, trajectory) -> None:
    for t, p, q in zip(trajectory.time_ns, trajectory.position_m, trajectory.orientation_xyzw):
        out.send(topic, "foxglove.PoseInFrame", t,
                 {"timestamp": _stamp(t), "frame_id": "world",
                  "pose": {"position": _xyz(p), "orientation": dict(zip("xyzw", map(float, q)))}})


def _topic(base: str, path, paths) -> str:
    return base if len(paths) == 1 else f"{base}/{Path(path).stem}"


def grid_message(image, t_ns: int) -> dict:
    """A SarImage as a foxglove.Grid (JSON): row r, column c at (x_m[c], y_m[r]) in the world frame; a
    volume by its brightest voxel along z."""
    mag = np.abs(image.image)
    db = grid_db(mag.max(axis=0) if mag.ndim == 3 else mag)
    dx = float(image.x_m[1] - image.x_m[0]) if image.x_m.size > 1 else 1.0
    dy = float(image.y_m[1] - image.y_m[0]) if image.y_m.size > 1 else dx
    z = float(image.z_m[0]) if image.z_m is not None and np.size(image.z_m) else 0.0
    corner = {"x": float(image.x_m[0]) - dx / 2, "y": float(image.y_m[0]) - dy / 2, "z": z}
    return {"timestamp": _stamp(t_ns), "frame_id": "world",
            "pose": {"position": corner, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "column_count": int(db.shape[1]), "cell_size": {"x": dx, "y": dy}, "row_stride": 4 * int(db.shape[1]),
            "cell_stride": 4, "fields": [{"name": "db", "offset": 0, "type": _FLOAT32}],
            "data": base64.b64encode(db.tobytes()).decode()}


def _points(out: _Out, rec, name: str) -> None:
    mount = rec.radar(name).mount
    pose = {"position": _xyz(mount.translation_m), "orientation": dict(zip("xyzw", map(float, mount.rotation_xyzw)))}
    fields = [{"name": n, "offset": 4 * i, "type": _FLOAT32} for i, n in enumerate(POINT_FIELDS)]
    for t, pts in detection_scans(rec, name):
        out.send(f"/radar/{name}/points", "foxglove.PointCloud", t,
                 {"timestamp": _stamp(t), "frame_id": "base_link", "pose": pose, "point_stride": 20, "fields": fields,
                  "data": base64.b64encode(pts.tobytes()).decode()})
