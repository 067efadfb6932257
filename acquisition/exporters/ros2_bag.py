"""A recording as a ROS 2 bag (rosbags; sqlite3 or MCAP storage), for ros2 bag play and the ROS tools.

Topics (docs/export.md), every stamp the recording's sensor time:

- ``/tf_static`` (``tf2_msgs/msg/TFMessage``): base_link -> each radar's frame and -> ``imu`` (the mounts);
- ``/radar/<name>/adc`` (``sarbot_msgs/msg/RadarFrame``): a raw frame with its waveform, TX order, antenna
  positions and mount, so it can be imaged from the bag alone (``sarbot import-bag`` reads it back);
- ``/radar/<name>/points`` (``sensor_msgs/msg/PointCloud2``): x, y, z, doppler, snr as float32, radar frame;
- ``/imu`` (``sensor_msgs/msg/Imu``), ``/can`` (``can_msgs/msg/Frame``), ``/trigger``
  (``sarbot_msgs/msg/Trigger``), ``/events`` (``rcl_interfaces/msg/Log``), ``/truth``
  (``geometry_msgs/msg/PoseStamped``, frame ``world``);
- with ``trajectories``: ``/odom`` (``nav_msgs/msg/Odometry``, world -> base_link) and ``/tf`` from the first.

The ``sarbot_msgs`` definitions are the interface package's own ``.msg`` files (ros/sarbot_msgs in the
repository, carried in the wheel), registered with rosbags' type system: one copy of each definition.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from imaging.core.errors import SarbotError

from . import POINT_FIELDS, detection_scans, event_sensor_times_ns, sensor_clock_offset_ns, sensor_span_ns

log = logging.getLogger(f"sarbot.{__name__}")

#: The interface package ros/sarbot_msgs (a link to it inside this package, so installs carry it).
SARBOT_MSGS_DIR = Path(__file__).resolve().parent / "sarbot_msgs"
#: ROS 2 bag storage plug-ins (``--storage``)
STORAGES = ("mcap", "sqlite3")
RADAR_FRAME = "sarbot_msgs/msg/RadarFrame"
TRIGGER = "sarbot_msgs/msg/Trigger"
CAN_FRAME = "can_msgs/msg/Frame"
#: can_msgs/msg/Frame (ros-drivers' ros_canopen), which rosbags' stores do not carry.
CAN_FRAME_MSG = """std_msgs/Header header
uint32 id
bool is_rtr
bool is_extended
bool is_error
uint8 dlc
uint8[8] data
"""
#: rcl_interfaces/msg/Log levels
_LOG_LEVELS = {"debug": 10, "info": 20, "warning": 30, "error": 40, "fatal": 50}
_CAN_EXTENDED_ID = 0x7FF  # identifiers above this are 29-bit (extended) frames


def _latched_qos():
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, QosTime(0, 0),
               QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


def sarbot_typestore():
    """rosbags' ROS 2 Humble types with ``sarbot_msgs`` (from its .msg files) and ``can_msgs/msg/Frame``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for path in sorted((SARBOT_MSGS_DIR / "msg").glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"sarbot_msgs/msg/{path.stem}"))
    if RADAR_FRAME not in types:
        raise SarbotError(f"{SARBOT_MSGS_DIR}: the sarbot_msgs interface package is missing (a broken install?)")
    types.update(get_types_from_msg(CAN_FRAME_MSG, CAN_FRAME))
    ts.register(types)
    return ts


def export_ros2(recording: str | Path, output: str | Path, storage: str = "mcap", progress=None,
                trajectories=()) -> dict[str, int]:
    """Write ``recording`` (and the odometry ``trajectories``) as a ROS 2 bag folder ``output`` (which must
    not exist); messages per topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import read_trajectory

    output = Path(output)
    if output.exists():
        raise SarbotError(f"{output}: exists already (a ROS 2 bag is a new folder; remove it or give another name)")
    plugins = dict(zip(STORAGES, (StoragePlugin.MCAP, StoragePlugin.SQLITE3)))
    if storage not in plugins:
        raise SarbotError(f"--storage {storage}: expected mcap or sqlite3")
    tracks = {("/odom" if len(trajectories) == 1 else f"/odom/{Path(p).stem}"): read_trajectory(p) for p in trajectories}
    ts = sarbot_typestore()
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vec, Quat, Point = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Point"]

    def stamp(t_ns: int):
        return Time(sec=int(t_ns) // 1_000_000_000, nanosec=int(t_ns) % 1_000_000_000)

    def header(t_ns: int, frame_id: str):
        return Header(stamp=stamp(t_ns), frame_id=frame_id)

    def transform(translation, rotation_xyzw):
        return T["geometry_msgs/msg/Transform"](translation=Vec(x=float(translation[0]), y=float(translation[1]),
                                                                z=float(translation[2])),
                                                rotation=Quat(**dict(zip("xyzw", map(float, rotation_xyzw)))))

    def stamped(t_ns: int, parent: str, child: str, translation, rotation_xyzw):
        return T["geometry_msgs/msg/TransformStamped"](header=header(t_ns, parent), child_frame_id=child,
                                                       transform=transform(translation, rotation_xyzw))

    counts: dict[str, int] = {}
    with Recording(recording) as rec, Writer(output, version=8, storage_plugin=plugins[storage]) as bag:
        connections = {}

        def write(topic: str, msgtype: str, t_ns: int, msg, latched: bool = False) -> None:
            if topic not in connections:
                # /tf_static is latched in ROS (transient local): a late subscriber still gets the mounts
                qos = [_latched_qos()] if latched else []
                connections[topic] = bag.add_connection(topic, msgtype, typestore=ts, offered_qos_profiles=qos)
                counts[topic] = 0
            bag.write(connections[topic], int(t_ns), ts.serialize_cdr(msg, msgtype))
            counts[topic] += 1

        span = sensor_span_ns(rec)
        start_ns = span[0] if span else 0
        mounts = [stamped(start_ns, "base_link", name, rec.radar(name).mount.translation_m, rec.radar(name).mount.rotation_xyzw)
                  for name in rec.radar_names]
        imu = rec.imu()
        if imu is not None and "mount_translation_m" in imu:
            mounts.append(stamped(start_ns, "base_link", "imu", imu["mount_translation_m"], imu["mount_rotation_xyzw"]))
        write("/tf_static", "tf2_msgs/msg/TFMessage", start_ns, T["tf2_msgs/msg/TFMessage"](transforms=mounts), latched=True)

        total = sum(rec.n_frames(n) for n in rec.radar_names)
        done = 0
        for name in rec.radar_names:
            radar = rec.radar(name)
            wf = radar.waveform
            described = dict(
                f0_hz=wf.f0_hz, bandwidth_hz=wf.bandwidth_hz, slope_hz_per_s=wf.slope_hz_per_s,
                chirp_duration_s=wf.chirp_duration_s, chirp_interval_s=wf.chirp_interval_s,
                sample_rate_hz=wf.sample_rate_hz, frame_interval_s=wf.frame_interval_s,
                tdm_tx_order=rec.tdm_tx_order(name).astype(np.uint8),
                tx_positions_m=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in radar.array.tx_positions_m],
                rx_positions_m=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in radar.array.rx_positions_m],
                mount=transform(radar.mount.translation_m, radar.mount.rotation_xyzw))
            times, counters, valid = rec.frame_time_ns(name), rec.frame_counter(name), rec.valid(name)
            if rec.has_adc(name):
                for k in range(times.size):
                    iq = np.ascontiguousarray(rec.adc_iq(name, slice(k, k + 1))[0], dtype=np.int16)
                    msg = T[RADAR_FRAME](header=header(times[k], name), frame_counter=int(counters[k]),
                                         valid=bool(valid[k]), **described, chirps=iq.shape[0], rx=iq.shape[1],
                                         samples=iq.shape[2], iq=iq.reshape(-1))
                    write(f"/radar/{name}/adc", RADAR_FRAME, times[k], msg)
                    done += 1
                    if progress:
                        progress(done, total)
            if rec.has_detections(name):
                _points(write, T, header, rec, name)
        if imu is not None:
            Imu = T["sensor_msgs/msg/Imu"]
            unknown = np.array([-1.0] + [0.0] * 8)  # orientation not estimated (REP 145)
            for t, g, a in zip(imu["time_ns"], imu["gyro_radps"], imu["accel_mps2"]):
                write("/imu", "sensor_msgs/msg/Imu", t,
                      Imu(header=header(t, "imu"), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                          orientation_covariance=unknown, angular_velocity=Vec(x=float(g[0]), y=float(g[1]), z=float(g[2])),
                          angular_velocity_covariance=np.zeros(9),
                          linear_acceleration=Vec(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                          linear_acceleration_covariance=np.zeros(9)))
        _can(write, T[CAN_FRAME], header, rec.can())
        for t, source in zip(rec.triggers(), rec.trigger_sources()):
            write("/trigger", TRIGGER, t, T[TRIGGER](header=header(t, "base_link"), source=source))
        events = rec.events()
        Log = T["rcl_interfaces/msg/Log"]
        times = event_sensor_times_ns([e[0] for e in events], sensor_clock_offset_ns(rec), span, rec.events_time_base())
        for t, (_, source, level, message) in zip(times, events):
            write("/events", "rcl_interfaces/msg/Log", t,
                  Log(stamp=stamp(t), level=_LOG_LEVELS.get(level, 20), name=source, msg=message, file="", function="",
                      line=0))
        truth = rec.truth()
        if truth is not None:
            Pose, PoseStamped = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseStamped"]
            for t, p, q in zip(truth.time_ns, truth.position_m, truth.orientation_xyzw):
                write("/truth", "geometry_msgs/msg/PoseStamped", t,
                      PoseStamped(header=header(t, "world"),
                                  pose=Pose(position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                            orientation=Quat(**dict(zip("xyzw", map(float, q)))))))
        for i, (topic, track) in enumerate(tracks.items()):
            _odometry(write, T, header, topic, track)
            if i == 0:
                TF = T["tf2_msgs/msg/TFMessage"]
                for t, p, q in zip(track.time_ns, track.position_m, track.orientation_xyzw):
                    write("/tf", "tf2_msgs/msg/TFMessage", t, TF(transforms=[stamped(t, "world", "base_link", p, q)]))
    return counts


def _odometry(write, T, header, topic: str, track) -> None:
    """nav_msgs/Odometry: the pose in ``world``, the velocity in ``base_link`` (as nav_msgs wants it);
    covariances unknown (zero)."""
    from scipy.spatial.transform import Rotation

    Odometry, Point, Quat, Vec = (T["nav_msgs/msg/Odometry"], T["geometry_msgs/msg/Point"],
                                  T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"])
    velocity_body = Rotation.from_quat(track.orientation_xyzw).inv().apply(track.velocity_mps)
    zero = Vec(x=0.0, y=0.0, z=0.0)
    for t, p, q, v in zip(track.time_ns, track.position_m, track.orientation_xyzw, velocity_body):
        pose = T["geometry_msgs/msg/Pose"](position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                           orientation=Quat(**dict(zip("xyzw", map(float, q)))))
        twist = T["geometry_msgs/msg/Twist"](linear=Vec(x=float(v[0]), y=float(v[1]), z=float(v[2])), angular=zero)
        write(topic, "nav_msgs/msg/Odometry", t,
              Odometry(header=header(t, "world"), child_frame_id="base_link",
                       pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                       twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36))))


def _can(write, Frame, header, can: dict) -> None:
    """can_msgs/Frame carries classic CAN (8 data bytes): a CAN FD frame with more is left out, said once."""
    too_long = 0
    for t, ident, dlc, data in zip(can["time_ns"], can["arbitration_id"], can["dlc"], can["data"]):
        if dlc > 8:
            too_long += 1
            continue
        payload = np.zeros(8, np.uint8)
        payload[:dlc] = data[:dlc]
        write("/can", CAN_FRAME, t, Frame(header=header(t, "can"), id=int(ident), is_rtr=False,
                                          is_extended=bool(ident > _CAN_EXTENDED_ID), is_error=False, dlc=int(dlc),
                                          data=payload))
    if too_long:
        log.warning("/can: %d CAN FD frame(s) with more than 8 data bytes left out (can_msgs/Frame holds 8)", too_long)


def _points(write, T, header, rec, name: str) -> None:
    PointCloud2, PointField = T["sensor_msgs/msg/PointCloud2"], T["sensor_msgs/msg/PointField"]
    fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate(POINT_FIELDS)]
    for t, pts in detection_scans(rec, name):
        write(f"/radar/{name}/points", "sensor_msgs/msg/PointCloud2", t,
              PointCloud2(header=header(t, name), height=1, width=len(pts), fields=fields, is_bigendian=False,
                          point_step=20, row_step=20 * len(pts), data=pts.view(np.uint8).reshape(-1), is_dense=True))
