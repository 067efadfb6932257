"""`sarbot export`: a recording as MCAP, read back with the mcap reader, message for message."""

import base64
import dataclasses
import importlib
import json
import subprocess
import sys

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
