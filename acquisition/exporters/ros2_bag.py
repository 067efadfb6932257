"""A recording as a ROS 2 bag (rosbags; sqlite3 or MCAP storage), for ros2 bag play and the ROS tools.

Topics: ``/radar/<name>/adc`` (``sarbot_msgs/msg/RadarFrame``: header, frame counter, validity, shape and
the int16 I/Q samples; its definition is stored in the bag), ``/radar/<name>/points``
(``sensor_msgs/msg/PointCloud2``: x, y, z, doppler, snr as float32, in the radar's frame), ``/imu``
(``sensor_msgs/msg/Imu``), ``/truth`` (``geometry_msgs/msg/PoseStamped``, frame ``world``). Stamps are
the recording's sensor times.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imaging.core.errors import SarbotError

from . import POINT_FIELDS, detection_scans

RADAR_FRAME = "sarbot_msgs/msg/RadarFrame"
RADAR_FRAME_MSG = """std_msgs/Header header
uint32 frame_counter
bool valid
uint32 chirps
uint32 rx
uint32 samples
int16[] iq
"""


def export_ros2(recording: str | Path, output: str | Path, storage: str = "mcap", progress=None) -> dict[str, int]:
    """Write ``recording`` as a ROS 2 bag folder ``output`` (which must not exist); messages per topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from imaging.io.recording import Recording

    output = Path(output)
    if output.exists():
        raise SarbotError(f"{output}: exists already (a ROS 2 bag is a new folder; remove it or give another name)")
    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    if storage not in plugins:
        raise SarbotError(f"--storage {storage}: expected mcap or sqlite3")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(RADAR_FRAME_MSG, RADAR_FRAME))
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]

    def header(t_ns: int, frame_id: str):
        return Header(stamp=Time(sec=int(t_ns) // 1_000_000_000, nanosec=int(t_ns) % 1_000_000_000), frame_id=frame_id)

    counts: dict[str, int] = {}
    with Recording(recording) as rec, Writer(output, version=8, storage_plugin=plugins[storage]) as bag:
        connections = {}

        def write(topic: str, msgtype: str, t_ns: int, msg) -> None:
            if topic not in connections:
                connections[topic] = bag.add_connection(topic, msgtype, typestore=ts)
                counts[topic] = 0
            bag.write(connections[topic], int(t_ns), ts.serialize_cdr(msg, msgtype))
            counts[topic] += 1

        total = sum(rec.n_frames(n) for n in rec.radar_names)
        done = 0
        for name in rec.radar_names:
            times, counters, valid = rec.frame_time_ns(name), rec.frame_counter(name), rec.valid(name)
            if rec.has_adc(name):
                for k in range(times.size):
                    iq = np.ascontiguousarray(rec.adc_iq(name, slice(k, k + 1))[0], dtype=np.int16)
                    msg = T[RADAR_FRAME](header=header(times[k], name), frame_counter=int(counters[k]),
                                         valid=bool(valid[k]), chirps=iq.shape[0], rx=iq.shape[1], samples=iq.shape[2],
                                         iq=iq.reshape(-1))
                    write(f"/radar/{name}/adc", RADAR_FRAME, times[k], msg)
                    done += 1
                    if progress:
                        progress(done, total)
            if rec.has_detections(name):
                _points(write, T, header, rec, name)
        imu = rec.imu()
        if imu is not None:
            Imu, Vec, Quat = T["sensor_msgs/msg/Imu"], T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
            unknown = np.array([-1.0] + [0.0] * 8)  # orientation not estimated (REP 145)
            for t, g, a in zip(imu["time_ns"], imu["gyro_radps"], imu["accel_mps2"]):
                write("/imu", "sensor_msgs/msg/Imu", t,
                      Imu(header=header(t, "imu"), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                          orientation_covariance=unknown, angular_velocity=Vec(x=float(g[0]), y=float(g[1]), z=float(g[2])),
                          angular_velocity_covariance=np.zeros(9),
                          linear_acceleration=Vec(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                          linear_acceleration_covariance=np.zeros(9)))
        truth = rec.truth()
        if truth is not None:
            Pose, PoseStamped = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseStamped"]
            Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
            for t, p, q in zip(truth.time_ns, truth.position_m, truth.orientation_xyzw):
                write("/truth", "geometry_msgs/msg/PoseStamped", t,
                      PoseStamped(header=header(t, "world"),
                                  pose=Pose(position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                            orientation=Quat(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))))
    return counts


def _points(write, T, header, rec, name: str) -> None:
    PointCloud2, PointField = T["sensor_msgs/msg/PointCloud2"], T["sensor_msgs/msg/PointField"]
    fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate(POINT_FIELDS)]
    for t, pts in detection_scans(rec, name):
        write(f"/radar/{name}/points", "sensor_msgs/msg/PointCloud2", t,
              PointCloud2(header=header(t, name), height=1, width=len(pts), fields=fields, is_bigendian=False,
                          point_step=20, row_step=20 * len(pts), data=pts.view(np.uint8).reshape(-1), is_dense=True))
