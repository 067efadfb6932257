"""`sarbot export`: a recording as MCAP, read back with the mcap reader, message for message."""

import base64
import dataclasses
import importlib
import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from mcap.reader import make_reader
from test_round_trip import make_source

from imaging.io.recording import Recording

CLI = [sys.executable, "-m", "acquisition.cli"]


def decode(schema, message) -> dict:
    """A message as a dict, decoded by the official definition of its schema: Foxglove's protobuf schemas
    from ``foxglove-schemas-protobuf`` (re-encoding it must give the same bytes: nothing unknown, nothing
    lost), sarbot's JSON messages by the JSON schema the file carries (``jsonschema``), strictly parsed."""
    from google.protobuf.json_format import MessageToDict

    if schema.encoding == "protobuf":
        assert schema.name.startswith("foxglove.")
        name = schema.name.removeprefix("foxglove.")
        msg = getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)()
        msg.ParseFromString(message.data)
        assert msg.SerializeToString() == message.data
        return MessageToDict(msg, preserving_proto_field_name=True, use_integers_for_enums=True,
                             always_print_fields_with_no_presence=True)
    import jsonschema

    assert schema.encoding == "jsonschema"
    body = json.loads(message.data, parse_constant=lambda c: pytest.fail(f"not JSON: {c}"))
    jsonschema.validate(body, json.loads(schema.data))
    return body


def stamp_ns(timestamp) -> int:
    """A decoded foxglove timestamp (RFC 3339 text from protobuf's JSON form) or sarbot's {sec, nsec}."""
    if isinstance(timestamp, dict):
        return timestamp["sec"] * 1_000_000_000 + timestamp["nsec"]
    from google.protobuf.timestamp_pb2 import Timestamp

    t = Timestamp()
    t.FromJsonString(timestamp)
    return t.seconds * 1_000_000_000 + t.nanos


def test_recording_to_mcap_and_back_sample_for_sample(tmp_path):
    src = tmp_path / "rec.h5"
    make_source(src, n_frames=12)
    out = tmp_path / "rec.mcap"
    res = subprocess.run([*CLI, "export", str(src), "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    messages: dict[str, list] = {}
    schemas = {}
    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            messages.setdefault(channel.topic, []).append((message.log_time, decode(schema, message)))
            schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
    with Recording(src) as rec:
        times, counters, iq = rec.frame_time_ns("left"), rec.frame_counter("left"), rec.adc_iq("left")
        imu, can, triggers = rec.imu(), rec.can(), rec.triggers()
    # Every message is there, counted by the file's own statistics as well.
    assert len(messages["/radar/left/adc"]) == times.size == 12
    assert len(messages["/imu"]) == imu["time_ns"].size and len(messages["/can"]) == can["time_ns"].size
    assert len(messages["/trigger"]) == triggers.size
    assert [m["source"] for _, m in messages["/trigger"]] == ["sync_box"]  # as make_source wrote it
    assert summary.statistics.message_count == sum(len(v) for v in messages.values())
    assert schemas["/radar/left/adc"] == ("sarbot.RadarFrame", "jsonschema", "json")
    # Raw frames bit for bit, with their times and counters.
    for k, (log_time, m) in enumerate(messages["/radar/left/adc"]):
        assert log_time == times[k] and m["frame_counter"] == counters[k] and m["valid"] is True
        got = np.frombuffer(base64.b64decode(m["data"]), "<i2").reshape(m["shape"])
        np.testing.assert_array_equal(got, iq[k])
        assert m["timestamp"]["sec"] * 1_000_000_000 + m["timestamp"]["nsec"] == times[k]
    # IMU samples exactly (float32 in the file, exact in JSON's float64).
    gyro = np.array([[m["angular_velocity"][a] for a in "xyz"] for _, m in messages["/imu"]])
    accel = np.array([[m["linear_acceleration"][a] for a in "xyz"] for _, m in messages["/imu"]])
    np.testing.assert_array_equal(gyro, imu["gyro_radps"].astype(np.float64))
    np.testing.assert_array_equal(accel, imu["accel_mps2"].astype(np.float64))
    np.testing.assert_array_equal([t for t, _ in messages["/imu"]], imu["time_ns"])
    can_data = [base64.b64decode(m["data"]) for _, m in messages["/can"]]
    assert can_data == [bytes(d[:n]) for d, n in zip(can["data"], can["dlc"])]
    # Never over an existing file unasked.
    again = subprocess.run([*CLI, "export", str(src), "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "exists already" in again.stderr


def test_truth_and_events_become_foxglove_poses_and_logs(tmp_path):
    from conftest import point_pass

    from imaging.sim.simulator import simulate_recording

    src = tmp_path / "pass.h5"
    simulate_recording(point_pass(1.0, duration_s=0.25), src)

    with h5py.File(src, "a") as f:  # an event as the recorder writes them
        g = f["events"]
        for key, value in (("time_ns", 1), ("source", "radar.left_front"), ("level", "error"), ("message", "lost 3")):
            g[key].resize((g[key].shape[0] + 1,))
            g[key][-1] = value
    out = tmp_path / "pass.mcap"
    res = subprocess.run([*CLI, "export", str(src), "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    with Recording(src) as rec:
        truth = rec.truth()
    with out.open("rb") as f:
        got = {}
        for schema, channel, message in make_reader(f, validate_crcs=True).iter_messages():
            got.setdefault(channel.topic, []).append((schema.name, decode(schema, message)))
    assert len(got["/truth"]) == truth.time_ns.size and got["/truth"][0][0] == "foxglove.PoseInFrame"
    p = got["/truth"][-1][1]["pose"]["position"]
    np.testing.assert_allclose([p["x"], p["y"], p["z"]], truth.position_m[-1])
    (log,) = got["/events"]
    assert log[0] == "foxglove.Log" and log[1]["level"] == 4 and log[1]["message"] == "lost 3"


def test_a_strip_map_and_a_trajectory_go_along(tmp_path):
    """The products of sarbot run beside the recording: the map as a foxglove.Grid in dB, the odometry as poses."""
    from imaging.io.image_file import SarImage, write_image
    from imaging.io.trajectory_file import write_trajectory

    src = tmp_path / "rec.h5"
    make_source(src, n_frames=4)
    rng = np.random.default_rng(2)
    x, y = np.arange(-1.0, 1.0, 0.01), np.arange(1.5, 2.5, 0.02)
    image = (rng.normal(size=(y.size, x.size)) + 1j * rng.normal(size=(y.size, x.size))).astype(np.complex64)
    image[30, 150] = 40.0
    write_image(tmp_path / "map.h5", SarImage(image, x, y, np.array([0.3]), {"wavelength_m": 0.0039}))
    with Recording(src) as rec:
        end_ns = int(rec.frame_time_ns("left")[-1])
    from imaging.core.trajectory import SampledTrajectory

    t = end_ns - np.arange(5)[::-1] * 10_000_000
    traj = SampledTrajectory(t, np.column_stack([np.linspace(0, 1, 5), np.zeros(5), np.zeros(5)]), np.tile([0, 0, 0, 1.0], (5, 1)))
    write_trajectory(tmp_path / "traj.h5", traj)
    out = tmp_path / "rec.mcap"
    res = subprocess.run([*CLI, "export", str(src), "-o", str(out), "--map", str(tmp_path / "map.h5"),
                          "--trajectory", str(tmp_path / "traj.h5")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    got = {}
    with out.open("rb") as f:
        for schema, channel, message in make_reader(f, validate_crcs=True).iter_messages():
            got.setdefault(channel.topic, []).append((schema.name, message.log_time, decode(schema, message)))
    ((schema, log_time, grid),) = got["/map"]
    assert schema == "foxglove.Grid" and log_time == end_ns and grid["column_count"] == x.size
    db = np.frombuffer(base64.b64decode(grid["data"]), "<f4").reshape(-1, grid["row_stride"] // 4)
    mag = np.abs(image)
    np.testing.assert_allclose(db, 20 * np.log10(mag / mag.max()), atol=1e-4)
    assert db[30, 150] == 0.0
    # Cell (row r, column c) is centred on (x[c], y[r]).
    corner, cell = grid["pose"]["position"], grid["cell_size"]
    assert abs(corner["x"] + 150.5 * cell["x"] - x[150]) < 1e-9
    assert abs(corner["y"] + 30.5 * cell["y"] - y[30]) < 1e-9 and corner["z"] == 0.3
    poses = got["/pose"]
    assert [lt for _, lt, _ in poses] == t.tolist() and poses[-1][2]["pose"]["position"]["x"] == 1.0
    bad = subprocess.run([*CLI, "export", str(src), "-o", str(tmp_path / "b.mcap"), "--map", str(src)],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and str(src) in bad.stderr and not (tmp_path / "b.mcap").exists()


def test_recording_to_a_ros2_bag_read_back_with_anyreader(tmp_path):
    from rosbags.highlevel import AnyReader

    src = tmp_path / "rec.h5"
    make_source(src, n_frames=6)
    out = tmp_path / "rec_bag"
    res = subprocess.run([*CLI, "export", str(src), "-o", str(out), "--ros2", "--storage", "sqlite3"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    with Recording(src) as rec:
        times, counters, iq, imu = rec.frame_time_ns("left"), rec.frame_counter("left"), rec.adc_iq("left"), rec.imu()
    got: dict[str, list] = {}
    with AnyReader([out]) as reader:  # the bag's own message definitions, the custom one included
        for conn, t, raw in reader.messages():
            got.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    assert len(got["/radar/left/adc"]) == 6 and len(got["/imu"]) == imu["time_ns"].size
    for k, (t, m) in enumerate(got["/radar/left/adc"]):
        assert t == times[k] and m.frame_counter == counters[k] and m.valid
        np.testing.assert_array_equal(np.asarray(m.iq).reshape(m.chirps, m.rx, m.samples, 2), iq[k])
        assert m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec == times[k]
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for _, m in got["/imu"]])
    np.testing.assert_array_equal(gyro, imu["gyro_radps"].astype(np.float64))
    again = subprocess.run([*CLI, "export", str(src), "-o", str(out), "--ros2"], capture_output=True, text=True)
    assert again.returncode == 2 and "exists already" in again.stderr


def test_point_clouds_in_both_formats(tmp_path):
    """A recording of detections (a point-cloud radar): each scan one foxglove.PointCloud in MCAP and one
    sensor_msgs/PointCloud2 in the ROS 2 bag, points bit for bit."""
    from rosbags.highlevel import AnyReader
    from test_round_trip import RIG

    from imaging.io.recording import RecordingWriter

    radar = RIG.radar("left")
    rng = np.random.default_rng(3)
    t0 = 1_700_000_000_000_000_000
    scans = [rng.normal(size=(n, 5)).astype(np.float32) for n in (4, 7, 1)]
    src = tmp_path / "points.h5"
    with RecordingWriter(src, [radar], imu=RIG.imu, truth=False, detections=["left"]) as w:
        w.append_scans("left", t0 + np.arange(3) * 100_000_000, np.arange(3), t0 + np.arange(3) * 100_000_000)
        for k, pts in enumerate(scans):
            t = t0 + k * 100_000_000 + 50_000_000
            w.append_detections("left", np.full(len(pts), t), np.full(len(pts), k), pts[:, :3], pts[:, 3], pts[:, 4])
    mcap_path, bag_path = tmp_path / "points.mcap", tmp_path / "points_bag"
    for out, extra in ((mcap_path, []), (bag_path, ["--ros2"])):
        res = subprocess.run([*CLI, "export", str(src), "-o", str(out), *extra], capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
    with mcap_path.open("rb") as f:
        clouds = [decode(s, m) for s, c, m in make_reader(f, validate_crcs=True).iter_messages()
                  if c.topic == "/radar/left/points"]
    with AnyReader([bag_path]) as reader:
        conns = [c for c in reader.connections if c.topic == "/radar/left/points"]
        ros = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    assert len(clouds) == len(ros) == 3
    for pts, cloud, msg in zip(scans, clouds, ros):
        got = np.frombuffer(base64.b64decode(cloud["data"]), "<f4").reshape(-1, 5)
        np.testing.assert_array_equal(got, pts)
        assert msg.width == len(pts) and msg.point_step == 20
        np.testing.assert_array_equal(np.frombuffer(bytes(msg.data), "<f4").reshape(-1, 5), pts)


def test_a_replayed_recording_exports_on_one_clock_with_its_mounts_and_official_schemas(tmp_path):
    """A replay's host clock runs 1,107 days after its sensor clock; the driver's event carries host time.
    The MCAP spans exactly the recording's sensor times, the event sits at the sensor time it happened at,
    every message decodes by Foxglove's own schemas (or sarbot's JSON schemas), CRCs check out, and
    /tf_static carries every radar's mount and the IMU's."""
    from conftest import point_pass

    from acquisition.exporters import sensor_span_ns
    from imaging.sim.simulator import simulate_recording

    src = tmp_path / "replayed.h5"
    simulate_recording(dataclasses.replace(point_pass(1.0, duration_s=0.25), imu=True), src)
    offset_ns = 1107 * 86_400 * 1_000_000_000
    with h5py.File(src, "a") as f:
        for name in f["radar"]:
            f[f"radar/{name}/host_time_ns"][...] = f[f"radar/{name}/frame_time_ns"][...] + offset_ns
        f["imu/host_time_ns"][...] = f["imu/time_ns"][...] + offset_ns
        frame_3 = int(f[f"radar/{next(iter(f['radar']))}/frame_time_ns"][3])
        g = f["events"]
        for key, value in (("time_ns", frame_3 + offset_ns), ("source", "radar.left_front"), ("level", "warning"),
                           ("message", "restarted")):
            g[key].resize((g[key].shape[0] + 1,))
            g[key][-1] = value
    with Recording(src) as rec:
        lo, hi = sensor_span_ns(rec)
        mounts = {n: rec.radar(n).mount for n in rec.radar_names}
        imu_mount = rec.imu()["mount_translation_m"]
        truth = rec.truth()
    assert hi - lo < 1_000_000_000 and lo == int(truth.time_ns[0])
    out = tmp_path / "replayed.mcap"
    res = subprocess.run([*CLI, "export", str(src), "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    got: dict[str, list] = {}
    with out.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        stats = reader.get_summary().statistics
        for schema, channel, message in reader.iter_messages():
            got.setdefault(channel.topic, []).append((schema.name, message.log_time, decode(schema, message)))
    assert (stats.message_start_time, stats.message_end_time) == (lo, hi)
    ((schema, t, log),) = got["/events"]
    assert schema == "foxglove.Log" and t == frame_3 and stamp_ns(log["timestamp"]) == frame_3
    assert log["level"] == 3 and log["name"] == "radar.left_front"
    ((schema, t, tf_static),) = got["/tf_static"]
    assert schema == "foxglove.FrameTransforms" and t == lo
    children = {tr["child_frame_id"]: tr for tr in tf_static["transforms"]}
    assert set(children) == {*mounts, "imu"} and {tr["parent_frame_id"] for tr in tf_static["transforms"]} == {"base_link"}
    for name, mount in mounts.items():
        tr = children[name]
        np.testing.assert_allclose([tr["translation"][a] for a in "xyz"], mount.translation_m)
        np.testing.assert_allclose([tr["rotation"][a] for a in "xyzw"], mount.rotation_xyzw)
    np.testing.assert_allclose([children["imu"]["translation"][a] for a in "xyz"], imu_mount)
    # /tf: world -> base_link at every pose of the truth (no odometry given), stamped on the sensor clock.
    assert [t for _, t, _ in got["/tf"]] == truth.time_ns.tolist()
    last = got["/tf"][-1][2]["transforms"][0]
    assert (last["parent_frame_id"], last["child_frame_id"]) == ("world", "base_link")
    np.testing.assert_allclose([last["translation"][a] for a in "xyz"], truth.position_m[-1])
    # Every channel's schema: Foxglove's own for what Foxglove has one for.
    schemas = {topic: rows[0][0] for topic, rows in got.items()}
    assert schemas["/truth"] == "foxglove.PoseInFrame" and schemas["/imu"] == "sarbot.Imu"
    assert all(s.startswith("foxglove.") for topic, s in schemas.items() if not topic.endswith("/adc")
               and topic not in ("/imu", "/can", "/trigger"))
    # The raw frame says all it takes to image it.
    adc = got[next(t for t in got if t.endswith("/adc"))][0][2]
    assert len(adc["waveform"]["tdm_tx_order"]) == adc["waveform"]["chirps_per_frame"] == adc["shape"][0]


REPO = Path(__file__).resolve().parents[1]


def test_sarbot_msgs_is_a_ros2_interface_package_and_the_exporter_uses_its_files():
    """ros/sarbot_msgs builds with colcon (package.xml, CMakeLists naming every .msg); the exporter's types are
    those files, not a copy."""
    from acquisition.exporters.ros2_bag import RADAR_FRAME, SARBOT_MSGS_DIR, sarbot_typestore

    package = REPO / "ros" / "sarbot_msgs"
    assert SARBOT_MSGS_DIR.resolve() == package.resolve()
    msgs = sorted(p.name for p in (package / "msg").glob("*.msg"))
    assert "RadarFrame.msg" in msgs
    cmake, xml = (package / "CMakeLists.txt").read_text(), (package / "package.xml").read_text()
    assert all(f'"msg/{m}"' in cmake for m in msgs) and "rosidl_generate_interfaces" in cmake
    assert "<name>sarbot_msgs</name>" in xml and "<member_of_group>rosidl_interface_packages</member_of_group>" in xml
    fields = [name for name, _ in sarbot_typestore().fielddefs[RADAR_FRAME][1]]
    declared = [line.split()[1] for line in (package / "msg" / "RadarFrame.msg").read_text().splitlines()
                if line.strip() and not line.startswith("#")]
    assert fields == declared
    for waveform_field in ("f0_hz", "slope_hz_per_s", "sample_rate_hz", "chirp_interval_s", "tdm_tx_order",
                           "tx_positions_m", "rx_positions_m", "mount"):
        assert waveform_field in fields


def test_a_ros2_bag_carries_mounts_triggers_can_events_and_odometry(tmp_path):
    from rosbags.highlevel import AnyReader

    from imaging.core.trajectory import SampledTrajectory
    from imaging.io.trajectory_file import write_trajectory

    src = tmp_path / "rec.h5"
    make_source(src, n_frames=6)
    with h5py.File(src, "a") as f:
        t_event = int(f["radar/left/frame_time_ns"][2])
        for key, value in (("time_ns", t_event), ("source", "radar.left"), ("level", "error"), ("message", "lost 3")):
            f["events"][key].resize((1,))
            f["events"][key][-1] = value
    with Recording(src) as rec:
        times, can, radar = rec.frame_time_ns("left"), rec.can(), rec.radar("left")
    t = times[0] + np.arange(5) * 20_000_000
    traj = SampledTrajectory(t, np.column_stack([np.linspace(0, 0.4, 5), np.zeros(5), np.zeros(5)]), np.tile([0, 0, 0, 1.0], (5, 1)))
    write_trajectory(tmp_path / "traj.h5", traj)
    out = tmp_path / "bag"
    res = subprocess.run([*CLI, "export", str(src), "-o", str(out), "--ros2", "--trajectory", str(tmp_path / "traj.h5")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    got: dict[str, list] = {}
    with AnyReader([out]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, t_ns, raw in reader.messages():
            got.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    assert types["/tf_static"] == "tf2_msgs/msg/TFMessage" and types["/can"] == "can_msgs/msg/Frame"
    assert types["/events"] == "rcl_interfaces/msg/Log" and types["/trigger"] == "sarbot_msgs/msg/Trigger"
    assert types["/odom"] == "nav_msgs/msg/Odometry" and types["/tf"] == "tf2_msgs/msg/TFMessage"
    ((_, tf_static),) = got["/tf_static"]
    (mount,) = [tr for tr in tf_static.transforms if tr.child_frame_id == "left"]
    assert mount.header.frame_id == "base_link"
    np.testing.assert_allclose([mount.transform.translation.x, mount.transform.translation.y,
                                mount.transform.translation.z], radar.mount.translation_m)
    assert [m.source for _, m in got["/trigger"]] == ["sync_box"]
    assert len(got["/can"]) == can["time_ns"].size
    for (t_ns, m), ident, dlc, data in zip(got["/can"], can["arbitration_id"], can["dlc"], can["data"]):
        assert m.id == ident and m.dlc == dlc and bytes(m.data[:dlc]) == bytes(data[:dlc])
    ((t_ns, log),) = got["/events"]
    assert t_ns == t_event and log.level == 40 and log.msg == "lost 3" and log.name == "radar.left"
    assert [t_ns for t_ns, _ in got["/odom"]] == t.tolist()
    odom = got["/odom"][-1][1]
    assert odom.child_frame_id == "base_link" and abs(odom.pose.pose.position.x - 0.4) < 1e-12
    assert abs(odom.twist.twist.linear.x - traj.velocity_mps[-1, 0]) < 1e-9
    frame = got["/radar/left/adc"][0][1]
    assert (frame.f0_hz, frame.sample_rate_hz, frame.slope_hz_per_s) == (radar.waveform.f0_hz, radar.waveform.sample_rate_hz,
                                                                         radar.waveform.slope_hz_per_s)
    assert list(frame.tdm_tx_order) == radar.waveform.tdm_tx_order()
    np.testing.assert_array_equal([[p.x, p.y, p.z] for p in frame.rx_positions_m], radar.array.rx_positions_m)
    refused = subprocess.run([*CLI, "export", str(src), "-o", str(tmp_path / "b2"), "--ros2", "--map", str(src)],
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "--map" in refused.stderr


def test_recording_to_ros2_bag_and_back_gives_the_same_image(tmp_path):
    """recording -> ROS 2 bag -> sarbot import-bag -> sarbot image: the image of the bag is the recording's,
    bit for bit (everything the imaging needs travels in the RadarFrame and /truth)."""
    from conftest import point_pass

    from imaging.io.image_file import read_image
    from imaging.io.recording import RecordingWriter
    from imaging.sim.simulator import simulate_recording

    simulate_recording(point_pass(1.0, duration_s=0.42), tmp_path / "sim.h5")
    src = tmp_path / "src.h5"  # int16 I/Q as a real radar's recording holds them
    with Recording(tmp_path / "sim.h5") as sim, RecordingWriter(src, [sim.radar(n) for n in sim.radar_names],
                                                                 adc_dtype="int16", truth=True) as w:
        for n in sim.radar_names:
            w.append_frames(n, sim.adc_iq(n), sim.frame_time_ns(n), sim.frame_counter(n), sim.host_time_ns(n))
        truth = sim.truth()
        w.append_truth(truth.sample(truth.time_ns))
    bag, back = tmp_path / "bag", tmp_path / "back.h5"
    grid = "-0.3:0.3:0.01,1.8:2.2:0.01"
    for args in (["export", str(src), "-o", str(bag), "--ros2"], ["import-bag", str(bag), "-o", str(back)],
                 ["image", str(src), "-o", str(tmp_path / "a.h5"), "--grid", grid],
                 ["image", str(back), "-o", str(tmp_path / "b.h5"), "--grid", grid]):
        res = subprocess.run([*CLI, "-q", *args], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
    with Recording(src) as a, Recording(back) as b:
        (name,) = a.radar_names
        np.testing.assert_array_equal(b.adc_iq(name), a.adc_iq(name))
        np.testing.assert_array_equal(b.frame_time_ns(name), a.frame_time_ns(name))
        ra, rb = a.radar(name), b.radar(name)
        assert ra.waveform == rb.waveform
        np.testing.assert_array_equal(rb.array.tx_positions_m, ra.array.tx_positions_m)
        np.testing.assert_array_equal(rb.mount.translation_m, ra.mount.translation_m)
    image_a, image_b = read_image(tmp_path / "a.h5").image, read_image(tmp_path / "b.h5").image
    assert np.abs(image_a).max() > 0
    np.testing.assert_array_equal(image_b, image_a)
    # A bag that is not sarbot's still needs its calibration, said in one line.
    no_calib = subprocess.run([*CLI, "import-bag", str(tmp_path / "nothing"), "-o", str(tmp_path / "c.h5")],
                              capture_output=True, text=True, timeout=120)
    assert no_calib.returncode == 2 and "nothing" in no_calib.stderr and "Traceback" not in no_calib.stderr


def test_events_move_onto_the_sensor_clock():
    """Host-clock stamps move by the sensor-minus-host offset; sensor-clock stamps stay; what lies outside the
    recording on either clock is put at its nearer end."""
    from acquisition.exporters import event_sensor_times_ns

    span = (1_000_000_000_000, 1_010_000_000_000)  # 10 s of data on the sensor clock
    offset = -95_644_800_000_000_000  # the replay runs 1,107 days after the recording
    host = [span[0] - offset + 2_000_000_000, span[1] - offset + 30_000_000_000]
    got = event_sensor_times_ns([span[0] + 5, span[1] + 1, *host, 1], offset, span)
    assert got.tolist() == [span[0] + 5, span[1], span[0] + 2_000_000_000, span[1], span[0]]
    assert event_sensor_times_ns([], offset, span).size == 0


def test_events_the_recorder_says_are_on_the_host_clock_all_move():
    """The recorder's /events say `time_base` "host": every row moves by the offset, also one that happens to
    lie within a minute of the sensor span (a short run: host UTC is only TAI-UTC, 37 s, from PTP time),
    which the guess for files that do not say leaves where it is."""
    from acquisition.exporters import event_sensor_times_ns

    span = (1_000_000_000_000, 1_100_000_000_000)  # 100 s of data on the sensor clock
    offset = 37_000_000_000  # PTP (TAI) minus the host's CLOCK_REALTIME (UTC)
    host = [span[0] - offset + 40_000_000_000, span[0] - offset + 90_000_000_000]
    assert event_sensor_times_ns(host, offset, span, "host").tolist() == [span[0] + 40_000_000_000,
                                                                         span[0] + 90_000_000_000]
    assert event_sensor_times_ns(host, offset, span).tolist() == [span[0] + 3_000_000_000, span[0] + 53_000_000_000]
