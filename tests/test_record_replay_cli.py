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


def run_cli(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "acquisition.cli", *args], capture_output=True, text=True, timeout=timeout)


def replay_into_record(tmp_path, src, rig, radar_imu: bool = False) -> tuple[str, str]:
    """`sarbot replay` of ``src`` at 2x into `sarbot record` with the rig file ``rig``, as separate processes:
    radar "left" over UDP, the IMU on a pty and, with ``radar_imu``, the left radar's own IMU on another.
    Both must exit 0; returns the replay's output and the recording's path."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    links = [tmp_path / "imu_tty"]
    replay_args = ["replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--imu-link", str(links[0])]
    record_args = ["record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                   "--imu-port", str(links[0])]
    if radar_imu:
        links.append(tmp_path / "left_imu_tty")
        replay_args += ["--radar-imu-link", f"left={links[1]}"]
        record_args += ["--radar-imu", f"left={links[1]}"]
    cmd = [sys.executable, "-m", "acquisition.cli"]
    replay = subprocess.Popen([*cmd, *replay_args, "--speed", "2", "--start-delay", "4"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 10
    while not all(link.exists() for link in links) and time.monotonic() < deadline:
        time.sleep(0.05)
    record = subprocess.run([*cmd, *record_args, "--duration", "9"], capture_output=True, text=True, timeout=60)
    out, err = replay.communicate(timeout=30)
    assert replay.returncode == 0, err
    assert record.returncode == 0, record.stderr
    return out, record.stdout.split("wrote ")[-1].strip()


def test_replay_into_record(tmp_path):
    src = tmp_path / "source.h5"
    iq, imu = make_source(src)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    _, path = replay_into_record(tmp_path, src, rig)
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


def test_an_imu_on_a_radar_mount_is_replayed_and_recorded_sample_for_sample(tmp_path):
    """`replay --radar-imu-link` and `record --radar-imu`: the radar's own IMU on a pty of its own, its samples
    in /radar/left/imu on the same time base as the robot's IMU, and no second trigger."""
    from imaging.core.rig import load_rig

    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML + "[radar.left.imu]\nrate_hz = 1000.0\n")
    src = tmp_path / "source.h5"
    iq, imu = make_source(src, rig=load_rig(rig))
    with Recording(src) as source:
        want = source.radar_imu("left")
    assert want is not None and want["time_ns"][0] == imu.time_ns[0]
    out, path = replay_into_record(tmp_path, src, rig, radar_imu=True)
    assert "and the IMU, the IMU on left" in out
    with Recording(path) as again:
        np.testing.assert_array_equal(again.file["radar/left/adc"][()], iq)
        np.testing.assert_array_equal(again.imu()["time_ns"], imu.time_ns)
        got = again.radar_imu("left")
        assert got is not None
        assert again.imu_sample_count("left") == got["time_ns"].size and again.imu_sample_count() == imu.time_ns.size
        for key in ("time_ns", "gyro_radps", "accel_mps2"):
            np.testing.assert_array_equal(got[key], want[key], err_msg=key)
        assert again.radar("left").imu.rate_hz == 1000.0
        assert again.file["radar/left/imu"].attrs["clock_drift_ppm"] == pytest.approx(-5e5, rel=0.05)  # replayed at 2x
        assert again.triggers().tolist() == [int(imu.time_ns[0])]  # the radar's IMU marks the same trigger: no second
        messages = [m.decode() for m in again.file["events/message"][()]]
        assert all(m.startswith("serial port lost") for m in messages), messages
    import json

    info = json.loads(run_cli("info", path, "--json").stdout)["radars"]["left"]["imu"]
    assert info["samples"] == want["time_ns"].size and info["nominal_rate_hz"] == 1000.0 and info["counter_gaps"] == 0
    assert "its own IMU: " in run_cli("info", path).stdout


def test_a_radar_imu_the_rig_or_the_recording_lacks_is_one_line(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)  # no [radar.left.imu]
    res = run_cli("record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar-imu", f"left={tmp_path / 'tty'}",
                  "--duration", "1")
    assert res.returncode != 0 and "Traceback" not in res.stderr
    assert "declares no IMU on radar left" in res.stderr and "[radar.left.imu]" in res.stderr
    res = run_cli("record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar-imu", "left")
    assert res.returncode != 0 and "--radar-imu 'left': expected NAME=PATH" in res.stderr
    res = run_cli("run", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", "left=50001", "--imu-port",
                  str(tmp_path / "imu"), "--map-imu-aided", "--duration", "1")
    assert res.returncode == 2 and "--map-imu-aided: no mapped radar has an IMU of its own" in res.stderr
    src = tmp_path / "source.h5"
    make_source(src)
    res = run_cli("replay", str(src), "--radar-imu-link", f"left={tmp_path / 'left_imu'}", "--speed", "0")
    assert res.returncode != 0 and "Traceback" not in res.stderr
    assert "no samples of an IMU on radar left" in res.stderr
    assert not (tmp_path / "left_imu").exists()


def test_ffbp_blocks_long_against_the_aperture_are_warned_of(tmp_path, caplog):
    """A block's travel at --max-speed beyond 1/8 of the aperture: said before the run starts; within it, not."""
    from acquisition import cli
    from acquisition.cli.daemon import record_setup, run_workers

    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    for aperture, warned in (("0.3", True), ("2.0", False)):
        caplog.clear()
        args = cli.build_parser().parse_args(["run", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", "left=50001",
                                              "--imu-port", str(tmp_path / "imu"), "--map-algorithm", "ffbp",
                                              "--map-aperture", aperture, "--map-ffbp-block", "8", "--max-speed", "0.5"])
        with caplog.at_level("WARNING", logger="sarbot"):
            _, _, config = run_workers(record_setup(args), args, tmp_path / "out", "t")
        assert config.algorithm == "ffbp" and config.ffbp_block_frames == 8
        said = [r.getMessage() for r in caplog.records if "FFBP block" in r.getMessage()]
        assert bool(said) == warned, said
        if warned:
            assert "8 frames spans 0.21 m at 0.50 m/s, more than 1/8 of the 0.30 m aperture" in said[0]


def test_map_max_thinning_reaches_the_map_worker(tmp_path):
    from acquisition import cli
    from acquisition.cli.daemon import record_setup, run_workers
    from acquisition.workers.stripmap import MAX_THINNING

    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    for options, thinning in (([], MAX_THINNING), (["--map-max-thinning", "1"], 1), (["--map-max-thinning", "8"], 8)):
        args = cli.build_parser().parse_args(["run", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar",
                                              "left=50001", "--imu-port", str(tmp_path / "imu"), *options])
        setup = record_setup(args)
        run_workers(setup, args, tmp_path / "out", "t")
        assert [w.config.max_thinning for w in setup.workers if w.role == "stripmap"] == [thinning]


@pytest.mark.parametrize("options, says", [
    (["--map-algorithm", "ffbp", "--map-refocus", "pga"], "--map-algorithm (algorithm): ffbp images blocks of frames and cannot refocus"),
    (["--map-algorithm", "ffbp", "--map-range", "0:3"], "--map-range (range_min_m): must be positive with ffbp"),
    (["--map-algorithm", "ffbp", "--map-ffbp-block", "0"], "--map-ffbp-block (ffbp_block_frames): must be 1 to 256, got 0"),
    (["--map-aperture", "-1"], "--map-aperture (aperture_m): must be positive"),
    (["--map-max-thinning", "3"], "--map-max-thinning 3: must be 1, 2, 4, 8, ... (1: image every frame)"),
    (["--map-max-thinning", "0"], "--map-max-thinning 0: must be 1, 2, 4, 8, ..."),
])
def test_a_bad_map_setting_names_the_option(tmp_path, options, says):
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    res = run_cli("run", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", "left=50001", "--imu-port",
                  str(tmp_path / "imu"), *options, "--duration", "1")
    assert res.returncode == 2 and says in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())  # nothing started


def test_the_worker_stop_options_reach_the_running_daemon(tmp_path):
    """`sarbot run` as a real process, told by its unit a TimeoutStopSec (SARBOT_TIMEOUT_STOP_S) that its stop
    does not fit in: the running daemon's warnings at the start carry the stop and hurry timeouts given on the
    command line, its workers' budgets cut to the stop timeout; the run ends as asked."""
    import os
    import socket

    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "run", "--config", str(rig), "-o", str(tmp_path / "out"),
                          "--radar", f"left={port}", "--imu-port", str(tmp_path / "imu"), "--worker-stop-timeout", "20",
                          "--worker-hurry-timeout", "12", "--duration", "1"], capture_output=True, text=True, timeout=600,
                         env={**os.environ, "SARBOT_TIMEOUT_STOP_S": "30"})
    assert res.returncode == 0, res.stderr
    assert ("the stop may last 37 s (worker_stop_timeout_s 20 s + worker_hurry_timeout_s 12 s + 5 s for a killed worker), "
            "more than the unit's TimeoutStopSec (30 s)") in res.stderr, res.stderr
    assert "rio: its stop takes up to 32 s (draining 30 s, finishing 0 s, writing 2 s), more than worker_stop_timeout_s (20 s)" \
        in res.stderr, res.stderr
    assert "stripmap: its stop takes up to 45 s" in res.stderr and "more than worker_stop_timeout_s (20 s)" in res.stderr


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
        assert any(m.startswith("radar.left exited with code -9 after") and "; restarting" in m for m in messages), messages
        counters = again.file["radar/left/frame_counter"][()]
        adc = again.file["radar/left/adc"][()]
        valid = again.valid("left")
        assert 60 < counters.size < 120  # frames sent while the driver was down are gone ...
        for k, c in enumerate(counters):  # ... and every frame recorded is its source frame (or marked invalid)
            if valid[k]:
                np.testing.assert_array_equal(adc[k], iq[c])


def test_sd_notify_ready_status_and_a_watchdog_that_tells_idle_sensors_from_a_hung_daemon(tmp_path):
    """A real AF_UNIX datagram socket stands in for systemd's notify socket. The watchdog is fed while the
    daemon runs, also when the sensors fall silent (an idle rig must not be restarted every 12 s into a
    failed unit); the silence shows in the status instead.

    Each step waits for what the daemon says (READY, the idle status, STOPPING), not for a time: on a loaded
    machine the workers' warm-up alone can take longer than a fixed sleep. The one time bound is the
    behaviour: no two watchdog messages further apart than WATCHDOG_USEC once READY is said (half of it is
    the daemon's interval; the other half is the scheduling slack a loaded machine needs)."""
    import os
    import re
    import signal
    import socket

    watchdog_s = 3.0
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
    listener.settimeout(0.1)
    env = {**os.environ, "NOTIFY_SOCKET": notify_path, "WATCHDOG_USEC": str(int(watchdog_s * 1e6))}
    cmd = [sys.executable, "-m", "acquisition.cli"]
    messages = []  # (time received, text)

    def receive_until(done, within_s: float, what: str):
        deadline = time.monotonic() + within_s
        while not done():
            try:
                messages.append((time.monotonic(), listener.recv(4096).decode()))
            except socket.timeout:  # nothing queued: the daemon must still be running
                assert time.monotonic() < deadline and record.poll() is None, f"no {what}: {[m for _, m in messages]}"

    record = subprocess.Popen([*cmd, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                               "--duration", "600"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        receive_until(lambda: "READY=1" in (m for _, m in messages), 330, "READY")  # warm-up_timeout_s 300
        replay = subprocess.Popen([*cmd, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--speed", "1"],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # 3 s of data
        receive_until(lambda: replay.poll() is not None, 120, "end of the replay")
        assert replay.returncode == 0, replay.communicate()[1]
        replay_end = time.monotonic()
        # Then silence: wait for health to call it idle, and go on for a watchdog timeout more.
        receive_until(lambda: any(t > replay_end and m.startswith("STATUS=sensors idle for") for t, m in messages),
                      120, "idle status")
        silent_until = time.monotonic() + watchdog_s
        receive_until(lambda: time.monotonic() > silent_until, 60, "end of the silence")
        record.send_signal(signal.SIGTERM)
        receive_until(lambda: messages[-1][1] == "STOPPING=1", 60, "STOPPING")
        record.communicate(timeout=60)
    finally:
        if record.poll() is None:
            record.kill()
            record.communicate()
        listener.close()
    texts = [m for _, m in messages]
    assert texts.count("READY=1") == 1 and texts[-1] == "STOPPING=1"
    ready = texts.index("READY=1")
    rates = [float(r) for m in texts[ready:] for r in re.findall(r"left ([0-9.]+) frames/s", m)]
    assert max(rates) > 5.0, texts  # the replay's 20 frames/s seen
    dogs = [t for t, m in messages[ready:] if m == "WATCHDOG=1"]
    assert len(dogs) >= 5, texts
    # Fed to the end, through the silence after the replay ended, ...
    assert messages[-1][0] - dogs[-1] < watchdog_s and np.max(np.diff([messages[ready][0], *dogs])) < watchdog_s
    # ... which health calls what it is.
    assert any(t > replay_end and m.startswith("STATUS=sensors idle for") for t, m in messages), texts


def test_nothing_is_destroyed_by_default(tmp_path):
    """``image -o`` does not replace an existing file (nor ever the recording itself); ``replay --imu-link``
    never unlinks a file that is not its own link; a replay whose IMU pty nobody reads ends with an error
    instead of hanging."""
    src = tmp_path / "source.h5"
    make_source(src, n_frames=10)
    grid = "--grid=-0.2:0.2:0.02,1.9:2.1:0.02"
    existing = tmp_path / "img.h5"
    existing.write_text("an earlier result\n")
    res = run_cli("image", str(src), "-o", str(existing), grid, "--trajectory", "truth")
    assert res.returncode == 2 and "exists already" in res.stderr and "--overwrite" in res.stderr
    assert existing.read_text() == "an earlier result\n"
    res = run_cli("image", str(src), "-o", str(src), grid, "--overwrite")
    assert res.returncode == 2 and "recording being imaged" in res.stderr
    with Recording(src) as rec:
        assert rec.n_frames("left") == 10  # the recording is intact
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me\n")
    res = run_cli("replay", str(src), "--imu-link", str(notes), "--speed", "0")
    assert res.returncode == 2 and "is not a link to a pseudo-terminal" in res.stderr
    assert notes.read_text() == "keep me\n"
    long = tmp_path / "long.h5"  # 8 s of IMU: more than the pty's buffer holds
    make_source(long, n_frames=150)
    link = tmp_path / "imu"
    res = run_cli("replay", str(long), "--imu-link", str(link), "--speed", "0", timeout=60)  # nobody reads
    assert res.returncode == 2 and "nobody reads the IMU pty" in res.stderr, res.stderr
    assert not link.exists() and not link.is_symlink()


def test_can_replays_on_the_host_clock_whatever_the_radar_clock_says(tmp_path):
    """A recording whose radar clock is three years off the host clock (a simulation recorded by `sarbot
    record`): /can was timed by the host, so replay sends it alongside the radars, not three years later."""
    from acquisition.processes import free_ports
    from imaging.core.constants import TAI_MINUS_UTC_NS
    from imaging.core.rig import rig_from_dict
    from imaging.io.recording import RecordingWriter

    rig = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 8, "sample_rate_hz": 200e3,
                                                         "frame_interval_s": 0.05}}}})
    host0 = time.time_ns()
    sensor0 = host0 - 3 * 365 * 86_400 * 1_000_000_000
    n = 10
    path = tmp_path / "rec.h5"
    with RecordingWriter(path, rig.radars, adc_dtype="int16") as w:
        w.append_frames("left", np.zeros((n, 8, 4, 36, 2), np.int16), sensor0 + np.arange(n) * 50_000_000,
                        np.arange(n), host0 + np.arange(n) * 50_000_000)
        can_t = host0 + TAI_MINUS_UTC_NS + np.arange(20) * 25_000_000
        w.append_can(can_t, np.full(20, 0x201), np.full(20, 8), np.ones((20, 8), np.uint8))
    radar_port, can_port = free_ports(2)
    res = run_cli("replay", str(path), "--radar", f"left=127.0.0.1:{radar_port}", "--can", "udp_multicast:239.74.163.2",
                  "--can-arg", f"port={can_port}", "--speed", "1", timeout=60)
    assert res.returncode == 0, res.stderr
    assert "can: 20 frames" in res.stdout


def test_a_driver_that_fails_at_start_backs_off_and_says_why_in_one_line(tmp_path):
    """The radar's port is taken (another process holds it): the driver says so in one line and exits;
    the supervisor restarts it with a growing delay (0.5, 1, 2, 4 s...) instead of about 1.4 times a
    second, and records every restart."""
    import socket

    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    port = holder.getsockname()[1]
    res = run_cli("record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                  "--duration", "8")
    holder.close()
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    assert f"radar left: cannot listen on UDP 127.0.0.1:{port}" in res.stderr
    (path,) = (tmp_path / "out").glob("*.h5")
    with Recording(path) as rec:
        restarts = [e for e in rec.events() if e[1] == "radar.left" and "restarting" in e[3]]
    assert 2 <= len(restarts) <= 5, restarts  # 8 s at 1.4 restarts/s would be 11
    assert "in 0.5 s" in restarts[0][3] and "in 1.0 s" in restarts[1][3]


def test_a_replay_stopped_by_sigterm_leaves_no_sender_behind(tmp_path):
    """The radars' senders are processes of their own: a replay ended by SIGTERM (kill, systemd, a test
    harness) must take them with it, not leave them sending datagrams at a port for the rest of the laps."""
    import os
    import signal
    import socket
    from pathlib import Path

    src = tmp_path / "source.h5"
    make_source(src)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(10)
        port = rx.getsockname()[1]
        replay = subprocess.Popen([sys.executable, "-m", "acquisition.cli", "replay", str(src), "--radar",
                                   f"left=127.0.0.1:{port}", "--laps", "100"],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        rx.recv(65536)  # the sender is sending
        tasks = Path(f"/proc/{replay.pid}/task").iterdir()
        senders = {int(c) for t in tasks for c in (t / "children").read_text().split()}
        assert senders
        replay.send_signal(signal.SIGTERM)
        replay.wait(timeout=10)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and any(os.path.exists(f"/proc/{p}") and _alive(p) for p in senders):
            time.sleep(0.05)
        assert not any(os.path.exists(f"/proc/{p}") and _alive(p) for p in senders), senders
        rx.settimeout(0.5)
        while True:  # what was sent before is in the socket's buffer; nothing more comes
            try:
                rx.recv(65536)
            except TimeoutError:
                break


def _alive(pid: int) -> bool:
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
