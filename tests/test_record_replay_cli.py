"""`sarbot replay` into `sarbot record`, as separate processes: the recording comes back sample for sample."""

import subprocess
import sys
import time

import numpy as np
import pytest
from test_round_trip import make_source

from imaging.io.recording import Recording

RIG_TOML = """
[imu]
rate_hz = 400.0
[radar.left]
mount_translation_m = [0.15, 0.2, 0.3]
mount_yaw_deg = 90.0
waveform = { chirps_per_frame = 32 }
"""


def test_replay_into_record(tmp_path):
    src = tmp_path / "source.h5"
    iq, imu = make_source(src)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    link = tmp_path / "imu_tty"
    cmd = [sys.executable, "-m", "acquisition.cli"]
    replay = subprocess.Popen([*cmd, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--imu-link", str(link),
                               "--speed", "2", "--start-delay", "4"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 10
    while not link.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    record = subprocess.run([*cmd, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                             "--imu-port", str(link), "--duration", "9"], capture_output=True, text=True, timeout=60)
    out, err = replay.communicate(timeout=30)
    assert replay.returncode == 0, err
    assert record.returncode == 0, record.stderr
    path = record.stdout.split("wrote ")[-1].strip()
    with Recording(path) as again:
        np.testing.assert_array_equal(again.file["radar/left/adc"][()], iq)
        assert again.valid("left").all()
        got = again.imu()
        np.testing.assert_array_equal(got["time_ns"], imu.time_ns)
        np.testing.assert_array_equal(got["gyro_radps"], imu.gyro_radps.astype(np.float32))
        assert again.triggers().tolist() == [int(imu.time_ns[0])]
        # The IMU clock against the host clock, estimated by the driver and kept with the samples: the replay
        # runs at 2x, so a host second holds two IMU seconds: host rate / IMU rate - 1 = -0.5 (-5e5 ppm).
        assert again.file["imu"].attrs["clock_drift_ppm"] == pytest.approx(-5e5, rel=0.05)
        # No loss; at most the note that the emulated IMU went away when the replay ended.
        messages = [m.decode() for m in again.file["events/message"][()]]
        assert all(m.startswith("serial port lost") for m in messages), messages


def test_record_bad_config_is_one_line(tmp_path):
    bad = tmp_path / "rig.toml"
    bad.write_text("[radar.left]\nwaveform = { n_tx = 0 }\n")
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "record", "--config", str(bad), "-o", str(tmp_path),
                          "--radar", "left=40000"], capture_output=True, text=True)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "radar.left.waveform.n_tx" in res.stderr


def test_a_killed_driver_is_restarted_and_nothing_received_intact_is_lost(tmp_path):
    import os
    import signal
    import socket

    src = tmp_path / "source.h5"
    iq, _ = make_source(src, n_frames=120)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cmd = [sys.executable, "-m", "acquisition.cli"]
    record = subprocess.Popen([*cmd, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                               "--duration", "12"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3)
    replay = subprocess.Popen([*cmd, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--speed", "1"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(2.5)
    children = [int(p) for t in os.listdir(f"/proc/{record.pid}/task")
                for p in open(f"/proc/{record.pid}/task/{t}/children").read().split()]
    radar_pids = [p for p in children if "spawn" in open(f"/proc/{p}/cmdline").read()]
    assert radar_pids
    os.kill(radar_pids[0], signal.SIGKILL)
    replay.communicate(timeout=30)
    out, err = record.communicate(timeout=60)
    assert record.returncode == 0, err
    with Recording(out.split("wrote ")[-1].strip()) as again:
        messages = [m.decode() for m in again.file["events/message"][()]]
        assert any(m.startswith("radar.left exited with code -9; restarted") for m in messages), messages
        counters = again.file["radar/left/frame_counter"][()]
        adc = again.file["radar/left/adc"][()]
        valid = again.valid("left")
        assert 60 < counters.size < 120  # frames sent while the driver was down are gone ...
        for k, c in enumerate(counters):  # ... and every frame recorded is its source frame (or marked invalid)
            if valid[k]:
                np.testing.assert_array_equal(adc[k], iq[c])


def test_sd_notify_ready_status_and_a_watchdog_fed_only_while_data_flows(tmp_path):
    """A real AF_UNIX datagram socket stands in for systemd's notify socket."""
    import os
    import socket

    src = tmp_path / "source.h5"
    make_source(src, n_frames=60)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    notify_path = str(tmp_path / "notify")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(notify_path)
    listener.settimeout(0.2)
    env = {**os.environ, "NOTIFY_SOCKET": notify_path, "WATCHDOG_USEC": "1000000"}
    cmd = [sys.executable, "-m", "acquisition.cli"]
    record = subprocess.Popen([*cmd, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                               "--duration", "9"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(2.5)
    replay = subprocess.run([*cmd, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--speed", "1"],
                            capture_output=True, text=True, timeout=30)  # 3 s of data, then silence
    assert replay.returncode == 0
    messages = []  # (time, text)
    deadline = time.monotonic() + 20
    while record.poll() is None and time.monotonic() < deadline:
        try:
            messages.append((time.monotonic(), listener.recv(4096).decode()))
        except socket.timeout:
            pass
    record.communicate(timeout=30)
    listener.close()
    texts = [m for _, m in messages]
    assert texts[0] == "READY=1" and texts[-1] == "STOPPING=1"
    assert any(t.startswith("STATUS=left") and "frames/s" in t for t in texts)
    dogs = [t for t, m in messages if m == "WATCHDOG=1"]
    assert dogs, texts
    # Fed while frames arrived, not in the silence after the replay ended (the last seconds of the run).
    assert messages[-1][0] - dogs[-1] > 1.5
