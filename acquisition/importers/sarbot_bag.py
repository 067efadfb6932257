"""A ROS 2 bag that ``sarbot export --ros2`` wrote, back into a recording (docs/export.md).

Each ``sarbot_msgs/msg/RadarFrame`` carries its radar (waveform, TX order, antenna positions, mount), so the
bag alone gives the recording: raw frames bit for bit with their times, counters and validity, the IMU
(``/imu``), CAN (``/can``), triggers (``/trigger``), events (``/events``) and the truth (``/truth``). What the
bag has no field for is made up plainly: host receive times are the sensor times, IMU counters count the
samples, the truth's velocity is the derivative of its positions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imaging.core.errors import FileFormatError, SarbotError
from imaging.core.rig import AntennaArray, ImuConfig, Mount, RadarConfig
from imaging.core.trajectory import SampledTrajectory
from imaging.core.waveform import Waveform
from imaging.io.recording import RecordingWriter

from ..exporters.ros2_bag import CAN_FRAME, RADAR_FRAME, TRIGGER, sarbot_typestore

#: rcl_interfaces/msg/Log level -> the recording's level names
_LEVEL_NAMES = {10: "debug", 20: "info", 30: "warning", 40: "error", 50: "fatal"}


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _reader(bag_path: Path):
    from rosbags.highlevel import AnyReader

    if not bag_path.exists():
        raise FileFormatError(f"{bag_path}: no such bag")
    try:
        reader = AnyReader([bag_path], default_typestore=sarbot_typestore())
        reader.open()
    except Exception as exc:  # rosbags raises many types for what is not a bag
        raise FileFormatError(f"{bag_path}: not a readable ROS bag ({exc})") from None
    return reader


def is_sarbot_bag(bag_path: str | Path) -> bool:
    """Whether the bag holds sarbot's raw frames (``sarbot_msgs/msg/RadarFrame``)."""
    reader = _reader(Path(bag_path))
    try:
        return any(c.msgtype == RADAR_FRAME for c in reader.connections)
    finally:
        reader.close()


def radar_from_frame(name: str, msg) -> RadarConfig:
    """The radar a RadarFrame describes."""
    n_tx, n_rx = len(msg.tx_positions_m), len(msg.rx_positions_m)
    wf = Waveform(f0_hz=msg.f0_hz, bandwidth_hz=msg.bandwidth_hz, chirp_duration_s=msg.chirp_duration_s,
                  chirp_interval_s=msg.chirp_interval_s, chirps_per_frame=int(msg.chirps),
                  frame_interval_s=msg.frame_interval_s, sample_rate_hz=msg.sample_rate_hz, n_tx=n_tx, n_rx=n_rx)
    if list(msg.tdm_tx_order) != wf.tdm_tx_order():
        raise FileFormatError(f"radar {name}: TX order {list(msg.tdm_tx_order)[:8]}... is not chirp k by TX k mod {n_tx}, "
                              "the only order a recording holds")
    if (wf.samples_per_chirp, n_rx) != (int(msg.samples), int(msg.rx)):
        raise FileFormatError(f"radar {name}: {msg.samples} samples x {msg.rx} RX per chirp, but its waveform gives "
                              f"{wf.samples_per_chirp} x {n_rx}")
    t, r = msg.mount.translation, msg.mount.rotation
    return RadarConfig(name, wf,
                       AntennaArray(np.array([[p.x, p.y, p.z] for p in msg.tx_positions_m]),
                                    np.array([[p.x, p.y, p.z] for p in msg.rx_positions_m])),
                       Mount(np.array([t.x, t.y, t.z]), np.array([r.x, r.y, r.z, r.w])))


def import_sarbot_bag(bag_path: str | Path, output: str | Path, overwrite: bool = False, progress=None) -> dict[str, int]:
    """Write the sarbot bag ``bag_path`` as the recording ``output``; the number of items of each kind."""
    bag_path = Path(bag_path)
    reader = _reader(bag_path)
    try:
        frames: dict[str, list] = {}  # radar -> [(t, counter, valid, iq)]
        radars: dict[str, RadarConfig] = {}
        imu, can, triggers, events, truth, mounts = [], [], [], [], [], {}
        total = sum(c.msgcount for c in reader.connections if c.msgtype == RADAR_FRAME)
        for conn, t_ns, raw in reader.messages():
            if conn.msgtype not in (RADAR_FRAME, "sensor_msgs/msg/Imu", CAN_FRAME, TRIGGER, "rcl_interfaces/msg/Log",
                                    "geometry_msgs/msg/PoseStamped", "tf2_msgs/msg/TFMessage"):
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.msgtype == RADAR_FRAME:
                name = msg.header.frame_id
                if name not in radars:
                    radars[name] = radar_from_frame(name, msg)
                    frames[name] = []
                iq = np.asarray(msg.iq, np.int16).reshape(msg.chirps, msg.rx, msg.samples, 2)
                frames[name].append((_ns(msg.header.stamp), msg.frame_counter, msg.valid, iq))
                if progress:
                    progress(sum(map(len, frames.values())), total)
            elif conn.msgtype == "sensor_msgs/msg/Imu":
                g, a = msg.angular_velocity, msg.linear_acceleration
                imu.append((_ns(msg.header.stamp), (g.x, g.y, g.z), (a.x, a.y, a.z)))
            elif conn.msgtype == CAN_FRAME:
                can.append((_ns(msg.header.stamp), msg.id, msg.dlc, bytes(msg.data)))
            elif conn.msgtype == TRIGGER:
                triggers.append((_ns(msg.header.stamp), msg.source))
            elif conn.msgtype == "rcl_interfaces/msg/Log":
                events.append((_ns(msg.stamp), msg.name, _LEVEL_NAMES.get(msg.level, "info"), msg.msg))
            elif conn.msgtype == "geometry_msgs/msg/PoseStamped" and conn.topic == "/truth":
                p, q = msg.pose.position, msg.pose.orientation
                truth.append((_ns(msg.header.stamp), (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)))
            elif conn.topic == "/tf_static":
                for tr in msg.transforms:
                    mounts[tr.child_frame_id] = tr.transform
    finally:
        reader.close()
    if not radars:
        raise SarbotError(f"{bag_path}: holds no sarbot_msgs/msg/RadarFrame")
    imu_config = None
    if len(imu) >= 2:
        t = np.array([s[0] for s in imu], np.int64)
        mount = Mount()
        if "imu" in mounts:
            tr, r = mounts["imu"].translation, mounts["imu"].rotation
            mount = Mount(np.array([tr.x, tr.y, tr.z]), np.array([r.x, r.y, r.z, r.w]))
        imu_config = ImuConfig(rate_hz=float(1e9 / np.median(np.diff(t))), mount=mount)
    with RecordingWriter(output, list(radars.values()), imu=imu_config, adc_dtype="int16", truth=len(truth) >= 2,
                         wire_format="sarbot_msgs", overwrite=overwrite,
                         radar_attrs=dict.fromkeys(radars, {"receive_stamp": "none"})) as w:
        for name, rows in frames.items():
            t = np.array([r[0] for r in rows], np.int64)
            w.append_frames(name, np.stack([r[3] for r in rows]), t, np.array([r[1] for r in rows], np.uint32), t,
                            valid=np.array([r[2] for r in rows], bool))
        if imu_config is not None:
            t = np.array([s[0] for s in imu], np.int64)
            w.append_imu(t, np.array([s[1] for s in imu], np.float32), np.array([s[2] for s in imu], np.float32),
                         np.arange(t.size), t)
        if can:
            data = np.zeros((len(can), 64), np.uint8)
            for k, (_, _, dlc, payload) in enumerate(can):
                data[k, :dlc] = np.frombuffer(payload[:dlc], np.uint8)
            w.append_can(np.array([c[0] for c in can], np.int64), np.array([c[1] for c in can], np.uint32),
                         np.array([c[2] for c in can], np.uint8), data)
        for t, source in triggers:
            w.append_trigger(t, source)
        for row in events:
            w.append_event(*row)
        if len(truth) >= 2:
            track = SampledTrajectory([s[0] for s in truth], [s[1] for s in truth], [s[2] for s in truth])
            w.append_truth(track.sample(track.time_ns))
    return {"frames": sum(map(len, frames.values())), "imu": len(imu), "can": len(can), "triggers": len(triggers),
            "events": len(events), "truth": len(truth)}
