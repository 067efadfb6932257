"""Import a ROS bag (sensor_msgs/Imu, PointCloud2 radar scans, a radar trigger) into a recording, no ROS needed.

ROS 1 bags and ROS 2 bags (a folder with sqlite3 or MCAP storage) are read alike, through rosbags'
AnyReader.

The radar scans of the reference dataset carry zero header stamps, so each scan takes its time from the
hardware trigger that started its frame (the last trigger received before the scan, by bag record time),
on the same sensor clock as the IMU stamps; the measurement time is the middle of the frame.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.errors import FileFormatError, SarbotError
from imaging.core.rig import AntennaArray, ImuConfig, Mount, RadarConfig
from imaging.core.waveform import Waveform
from imaging.io.recording import RecordingWriter

log = logging.getLogger(f"sarbot.{__name__}")

#: PointCloud2 field name -> where sarbot needs it.
_FIELDS = ("x", "y", "z", "intensity", "velocity")


def read_calibration(path: str | Path) -> dict:
    """The dataset's calibration YAML: topics, radar lever arm and rotation (radar -> body), frame length."""
    from ruamel.yaml import YAML

    path = Path(path)
    if not path.exists():
        raise FileFormatError(f"{path}: no such calibration file")
    try:
        data = YAML(typ="safe").load(path.read_text())
    except Exception as exc:  # ruamel raises many error types for bad YAML
        raise FileFormatError(f"{path}: not valid YAML ({exc.__class__.__name__})") from None
    need = ["topic_imu", "topic_radar_scan", "topic_radar_trigger", "l_b_r_x", "l_b_r_y", "l_b_r_z",
            "q_b_r_x", "q_b_r_y", "q_b_r_z", "q_b_r_w", "radar_frame_ms"]
    missing = [k for k in need if k not in (data or {})]
    if missing:
        raise FileFormatError(f"{path}: missing {', '.join(missing)}")
    return data


def _cloud_points(msg) -> np.ndarray:
    """x, y, z, intensity, velocity of every point of a PointCloud2 (float32 fields), [N, 5]."""
    offsets = {f.name: f.offset for f in msg.fields}
    missing = [f for f in _FIELDS if f not in offsets]
    if missing:
        raise FileFormatError(f"PointCloud2 lacks fields {missing}")
    n = msg.width * msg.height
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8)[: n * msg.point_step].reshape(n, msg.point_step)
    cols = [raw[:, offsets[f]:offsets[f] + 4].copy().view("<f4" if not msg.is_bigendian else ">f4")[:, 0] for f in _FIELDS]
    return np.column_stack(cols).astype(np.float64)


def import_bag(bag_path: str | Path, calib_path: str | Path, output: str | Path, radar_name: str = "radar",
               overwrite: bool = False, progress=None) -> dict:
    """Convert the bag (a ROS 1 ``.bag`` file or a ROS 2 bag folder) into a recording with /imu, /trigger and
    the radar's /detections."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    calib = read_calibration(calib_path)
    bag_path = Path(bag_path)
    if not bag_path.exists():
        raise FileFormatError(f"{bag_path}: no such bag")
    # Types the bag does not define itself (ROS 2 bags without message definitions) are taken as Humble's.
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    imu_t, gyro, acc = [], [], []
    triggers = []  # (record time, stamp ns)
    scans = []  # (record time, points)
    try:
        reader = AnyReader([bag_path], default_typestore=typestore)
        reader.open()
    except Exception as exc:
        raise FileFormatError(f"{bag_path}: not a readable ROS 1 or ROS 2 bag ({exc.__class__.__name__}: {exc})") from None
    try:
        topics = {c.topic for c in reader.connections}
        for key in ("topic_imu", "topic_radar_scan", "topic_radar_trigger"):
            if calib[key] not in topics:
                raise FileFormatError(f"{bag_path}: topic {calib[key]} ({key}) not in the bag (topics: {', '.join(sorted(topics))})")
        wanted = [c for c in reader.connections if c.topic in (calib["topic_imu"], calib["topic_radar_scan"], calib["topic_radar_trigger"])]
        total = sum(c.msgcount for c in wanted)
        for i, (conn, t_rec, raw) in enumerate(reader.messages(connections=wanted)):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == calib["topic_imu"]:
                imu_t.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                gyro.append((msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z))
                acc.append((msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z))
            elif conn.topic == calib["topic_radar_trigger"]:
                triggers.append((t_rec, msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec))
            else:
                scans.append((t_rec, _cloud_points(msg)))
            if progress is not None and i % 2000 == 0:
                progress(i, total)
    finally:
        reader.close()
    if not imu_t or not scans or not triggers:
        raise SarbotError(f"{bag_path}: needs IMU, radar scans and triggers; found {len(imu_t)}, {len(scans)}, {len(triggers)}")
    imu_t = np.asarray(imu_t, np.int64)
    order = np.argsort(imu_t, kind="stable")
    imu_t, gyro, acc = imu_t[order], np.asarray(gyro)[order], np.asarray(acc)[order]
    trig_rec = np.array([t for t, _ in triggers], np.int64)
    trig_stamp = np.array([s for _, s in triggers], np.int64)
    half_frame_ns = int(float(calib["radar_frame_ms"]) * 1e6 / 2)

    # The calibration's rotation is that of TI's native radar frame (y along boresight, x right); the
    # point clouds come in the ROS convention sarbot uses too (x along boresight, y left). The two differ
    # by +90 deg about z. (Checked on the data: with it, the radar velocities agree with the IMU and the
    # boresight points front-right, as the trigger topic "radar_right" says; without it, two thirds of
    # the radar updates fail the filter's gate.)
    q_native = Rotation.from_quat([calib["q_b_r_x"], calib["q_b_r_y"], calib["q_b_r_z"], calib["q_b_r_w"]])
    ros_to_native = Rotation.from_euler("z", 90.0, degrees=True)
    mount = Mount(np.array([calib["l_b_r_x"], calib["l_b_r_y"], calib["l_b_r_z"]], float),
                  (q_native * ros_to_native).as_quat())
    rate = float(calib.get("radar_rate", 10))
    # A point-cloud radar: the waveform is not known from the bag; these values only describe its frame timing.
    wf = Waveform(f0_hz=60e9, bandwidth_hz=4e9, chirp_duration_s=60e-6, chirp_interval_s=float(calib["radar_frame_ms"]) * 1e-3 / 64,
                  chirps_per_frame=64, frame_interval_s=1.0 / rate, sample_rate_hz=4e6, n_tx=1, n_rx=1)
    radar = RadarConfig(radar_name, wf, AntennaArray(np.zeros((1, 3)), np.zeros((1, 3))), mount)
    imu_rate = float(1e9 / np.median(np.diff(imu_t)))
    imu_cfg = ImuConfig(rate_hz=imu_rate)
    frame_times, host, det = [], [], []
    skipped = 0
    for k, (t_rec, pts) in enumerate(scans):
        j = int(np.searchsorted(trig_rec, t_rec, side="right")) - 1
        if j < 0:
            skipped += 1
            continue
        frame_times.append(trig_stamp[j])
        host.append(t_rec)
        det.append((len(frame_times) - 1, trig_stamp[j] + half_frame_ns, pts))
    if skipped:
        log.warning("%d radar scan(s) before the first trigger were left out", skipped)
    with RecordingWriter(output, [radar], imu=imu_cfg, truth=False, wire_format="ros_pointcloud2",
                         detections=[radar_name], overwrite=overwrite,
                         radar_attrs={radar_name: {"receive_stamp": "none"}}) as w:
        w.append_trigger(trig_stamp, [calib["topic_radar_trigger"]] * trig_stamp.size)
        w.append_scans(radar_name, np.asarray(frame_times, np.int64), np.arange(len(frame_times)), np.asarray(host, np.int64))
        for scan, t_mid, pts in det:
            w.append_detections(radar_name, np.full(len(pts), t_mid), np.full(len(pts), scan), pts[:, :3], pts[:, 4],
                                10 * np.log10(np.maximum(pts[:, 3], 1e-3)))
        # Host receive times are not in the bag for the IMU; the sensor stamps stand in.
        w.append_imu(imu_t, gyro, acc, np.arange(imu_t.size), imu_t)
    if progress is not None:
        progress(total, total)
    return {"imu_samples": int(imu_t.size), "scans": len(det), "triggers": int(trig_stamp.size), "imu_rate_hz": imu_rate}
