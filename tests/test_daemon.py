"""The daemon as a user runs it (`sarbot replay` into `sarbot record`, separate processes): DCA1000 and CAN
through emulated hardware, files split by time, health on the bus, and the faults the issue lists: the
recorder killed with SIGKILL and a full disk."""

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zmq
from conftest import SHARED_DATA
from test_record_replay_cli import RIG_TOML
from test_round_trip import make_source

from acquisition.bus import BusSubscriber
from acquisition.messages import Health
from acquisition.processes import free_port, free_ports, free_tcp_endpoint
from drivers.radar.ti_cfg import load_ti_cfg
from imaging.core.rig import AntennaArray, Mount, RadarConfig
from imaging.core.trajectory import PathWithTurns
from imaging.io.recording import Recording, RecordingWriter
from imaging.sim.robot_base_can import simulate_base_can
from imaging.sim.scene import DEFAULT_START_TIME_NS

CLI = [sys.executable, "-m", "acquisition.cli"]
CFG = SHARED_DATA / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg"


def make_dca1000_source(path, n_frames=20):
    cfg = load_ti_cfg(CFG)
    wf = cfg.waveform()
    radar = RadarConfig("iwr", wf, AntennaArray.uniform_tdm(wf), Mount.from_yaw([0.1, 0.2, 0.3], 90.0))
    ft = DEFAULT_START_TIME_NS + np.arange(n_frames, dtype=np.int64) * int(wf.frame_interval_s * 1e9)
    iq = np.random.default_rng(7).integers(-2000, 2000, (n_frames, 32, 4, 256, 2), dtype=np.int16)
    traj = PathWithTurns(segments=[("straight", 1.0)], speed_mps=0.4, t0_ns=DEFAULT_START_TIME_NS)
    base = simulate_base_can(traj, ft[0], ft[-1], trigger_time_ns=int(ft[0]))
    with RecordingWriter(path, [radar], adc_dtype="int16", wire_format="DCA1000") as w:
        w.append_frames("iwr", iq, ft, np.arange(n_frames), ft)
        w.append_can(base["time_ns"], base["arbitration_id"], base["dlc"], base["data"])
    return iq, base


def test_dca1000_and_can_replayed_into_record_split_in_parts_with_health_on_the_bus(tmp_path):
    src = tmp_path / "source.h5"
    iq, base = make_dca1000_source(src)
    rig = tmp_path / "rig.toml"
    rig.write_text("[radar.iwr]\nmount_translation_m = [0.1, 0.2, 0.3]\nmount_yaw_deg = 90.0\n")
    port, can_port = free_ports(2)
    health_endpoint = free_tcp_endpoint()
    can = ["--can", "udp_multicast:239.74.163.2", "--can-arg", f"port={can_port}"]
    ctx = zmq.Context()
    health = []
    sub = BusSubscriber(health_endpoint, topics=[Health.TOPIC], context=ctx)
    done = threading.Event()

    def listen():
        while not done.is_set():
            m = sub.receive(timeout_ms=100)
            if m is not None:
                health.append(Health.from_message(m))

    listener = threading.Thread(target=listen)
    listener.start()
    replay = subprocess.Popen([*CLI, "replay", str(src), "--radar", f"iwr=127.0.0.1:{port}", *can, "--start-delay", "4"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    record = subprocess.run([*CLI, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--dca1000",
                             f"iwr={port}:{CFG}", *can, "--split-time", "2", "--duration", "9",
                             "--health-endpoint", health_endpoint], capture_output=True, text=True, timeout=60)
    out, err = replay.communicate(timeout=30)
    done.set()
    listener.join()
    sub.close()
    ctx.term()
    assert replay.returncode == 0, err
    assert record.returncode == 0, record.stderr
    paths = [line.split("wrote ", 1)[1] for line in record.stdout.splitlines() if line.startswith("wrote ")]
    assert len(paths) >= 3  # 9 s in parts of 2 s
    adc, can_rows, frames_valid = [], [], []
    for k, p in enumerate(paths):
        with Recording(p) as part:
            assert part.file.attrs["part"] == k
            assert part.file.attrs["previous_part"] == (os.path.basename(paths[k - 1]) if k else "")
            assert part.file["radar/iwr"].attrs["wire_format"] == "DCA1000"
            assert part.radar("iwr").waveform.samples_per_chirp == 256  # the .cfg's layout, not the rig's
            adc.append(part.file["radar/iwr/adc"][()])
            frames_valid.append(part.valid("iwr"))
            can_rows.append(part.can())
            assert not part.events()
    np.testing.assert_array_equal(np.concatenate(adc), iq)
    assert np.concatenate(frames_valid).all()
    for key in ("arbitration_id", "dlc", "data"):
        np.testing.assert_array_equal(np.concatenate([c[key] for c in can_rows]), base[key])
    reports = [h for h in health if h.frames_per_s.get("iwr", 0) > 0]
    assert reports, health
    assert 5 < max(h.frames_per_s["iwr"] for h in reports) < 15  # the .cfg's 10 frames/s
    assert all(h.bus_lost == 0 and h.restarts == 0 for h in health)
    assert any(h.clock.trigger_seen for h in health)  # the CAN trigger frame


def test_record_killed_with_sigkill_keeps_what_it_flushed_and_takes_its_drivers_along(tmp_path):
    src = tmp_path / "source.h5"
    iq, _ = make_source(src, n_frames=60)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    port = free_port(socket.SOCK_DGRAM)
    replay = subprocess.Popen([*CLI, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--start-delay", "4"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    record = subprocess.Popen([*CLI, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    seen = 0
    while seen < 8 and time.monotonic() < deadline:  # kill it mid-run, once it has flushed some frames
        time.sleep(0.2)
        for path in (tmp_path / "out").glob("*.h5"):
            try:
                with Recording(path) as rec:
                    seen = rec.n_frames("left")
            except Exception:
                pass  # being created
    record.send_signal(signal.SIGKILL)
    record.wait(10)
    replay.communicate(timeout=30)
    (path,) = (tmp_path / "out").glob("*.h5")
    with Recording(path) as rec:
        n = rec.n_frames("left")
        assert 8 <= n < 60
        np.testing.assert_array_equal(rec.file["radar/left/adc"][:n], iq[:n])
    # The drivers died with their supervisor: the radar's UDP port is free again.
    deadline = time.monotonic() + 5
    while True:
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.bind(("127.0.0.1", port))
            break
        except OSError:
            assert time.monotonic() < deadline, "a driver outlived the killed daemon"
            time.sleep(0.1)


def _can_mount_tmpfs() -> list[str] | None:
    """A command prefix that runs its command in a private mount namespace where tmpfs can be mounted."""
    if shutil.which("unshare") is None:
        return None
    for prefix in (["unshare", "-m"], ["unshare", "-rm"]):
        ok = subprocess.run([*prefix, "sh", "-c", "mount -t tmpfs -o size=1M none /mnt"], capture_output=True)
        if ok.returncode == 0:
            return prefix
    return None


def test_a_full_disk_stops_recording_cleanly_and_keeps_the_file_readable(tmp_path):
    prefix = _can_mount_tmpfs()
    if prefix is None:
        pytest.skip("cannot mount a small tmpfs here (needs unshare with mount or user namespaces)")
    src = tmp_path / "source.h5"
    iq, _ = make_source(src, n_frames=60)  # 5.4 MB of frames for a 4 MB disk
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    port = free_port(socket.SOCK_DGRAM)
    disk = tmp_path / "disk"
    kept = tmp_path / "kept"
    disk.mkdir()
    kept.mkdir()
    script = (f"mount -t tmpfs -o size=4M none {disk} && "
              f"{sys.executable} -m acquisition.cli record --config {rig} -o {disk} --radar left={port} --duration 15 --min-free 1M; "
              f"rc=$?; cp {disk}/*.h5 {kept}/; exit $rc")
    replay = subprocess.Popen([*CLI, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--start-delay", "4"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    record = subprocess.run([*prefix, "sh", "-c", script], capture_output=True, text=True, timeout=60, cwd=os.getcwd())
    replay.communicate(timeout=30)
    assert record.returncode == 3, record.stderr
    assert "disk full" in record.stderr and "Traceback" not in record.stderr and "RuntimeError" not in record.stderr
    (path,) = kept.glob("*.h5")
    with Recording(path) as rec:
        n = rec.n_frames("left")
        assert 3 <= n < 60
        np.testing.assert_array_equal(rec.file["radar/left/adc"][:n], iq[:n])


def test_verbose_logging_reaches_every_driver_process(tmp_path):
    """``sarbot -v record``: debug lines of the radar driver process and the IMU driver's own module
    (``drivers.imu``, in its process) reach the terminal, each tagged with the process's role."""
    from drivers.emulators import XbusPty

    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    n = 800
    emu = XbusPty(np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)), rate_hz=400.0, speed=1.0)
    port = free_port(socket.SOCK_DGRAM)
    record = subprocess.Popen([*CLI, "-v", "record", "--config", str(rig), "-o", str(tmp_path / "out"),
                               "--radar", f"left={port}", "--imu-port", emu.port, "--duration", "6"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(3.0)  # the drivers open their ports
    emu.start()
    out, err = record.communicate(timeout=60)
    emu.close()
    assert record.returncode == 0, err
    assert "DEBUG [left] sarbot.acquisition.driver_loops: radar left: stream ended" in err
    assert "INFO [imu] sarbot.drivers.imu: IMU: trigger seen" in err


def test_a_restarted_imu_driver_records_again(tmp_path):
    """The IMU driver killed mid-run: the supervisor restarts it with the trigger's PTP time and tick it
    kept, so the new driver times the samples as before (the IMU marks only one sample with SyncIn; a
    driver without the reference recorded nothing for the rest of the run). Before the kill: the IMU is in
    the file within a flush interval of its arrival."""
    src = tmp_path / "source.h5"
    iq, imu = make_source(src, n_frames=150)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    port = free_port(socket.SOCK_DGRAM)
    link = tmp_path / "imu_tty"
    replay = subprocess.Popen([*CLI, "replay", str(src), "--radar", f"left=127.0.0.1:{port}", "--imu-link", str(link),
                               "--start-delay", "4"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    record = subprocess.Popen([*CLI, "record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"left={port}",
                               "--imu-port", str(link), "--duration", "17"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    deadline = time.monotonic() + 30
    seen, behind_s = 0, []
    while seen < 800 and time.monotonic() < deadline:  # two seconds of IMU in the file
        time.sleep(0.2)
        for path in (tmp_path / "out").glob("*.h5"):
            try:
                with Recording(path) as rec:
                    in_file = rec.imu()
                    seen = 0 if in_file is None else in_file["time_ns"].size
                    if seen:  # how far the newest sample in the file is behind its arrival at the host
                        behind_s.append((time.time_ns() - int(in_file["host_time_ns"][-1])) * 1e-9)
            except Exception:
                pass  # being created
    assert seen >= 800
    # The IMU reaches the file within about one flush interval (0.5 s) plus its 50 ms batches; a recorder
    # appending one sample per message fell 10 s behind.
    assert np.median(behind_s) < 0.8 and max(behind_s) < 2.0, behind_s
    killed = subprocess.run(["pkill", "-KILL", "-x", "sarbot-imu"])
    assert killed.returncode == 0  # the IMU driver process, by the name it gives itself
    out, err = record.communicate(timeout=60)
    replay.communicate(timeout=30)
    assert record.returncode == 0, err
    (path,) = (tmp_path / "out").glob("*.h5")
    with Recording(path) as rec:
        got = rec.imu()["time_ns"]
        assert any(e[1] == "imu" and "exited with code -9" in e[3] for e in rec.events())
    # Samples keep coming to the end of the run, on the same time base, with a gap only around the restart.
    assert got.size > 0.8 * imu.time_ns.size and got[-1] >= imu.time_ns[-40]
    assert np.isin(got, imu.time_ns).all()


def test_the_daemon_binds_port_0_publishes_the_port_and_its_bus_takes_no_tcp_port(tmp_path):
    """No port is picked as free and bound later (another process could take it between): a radar link on port
    0 is bound by its driver to a port the system picks and published in ``Setup.bound_ports``, where a sender
    (the demo's emulated radars) reads it; every bus endpoint is an ipc:// socket in a private folder."""
    import multiprocessing as mp
    import stat
    from pathlib import Path

    from acquisition.daemon import Setup, process_specs, record
    from acquisition.replay import replay
    from drivers.radar.link import RadarLink

    src = tmp_path / "source.h5"
    iq, _ = make_source(src, n_frames=20)
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG_TOML)
    setup = Setup.for_devices(rig, [RadarLink("left", 0)])
    ctx = mp.get_context("spawn")
    endpoints = [s.endpoint for s in process_specs(setup, ctx.Event())]
    assert endpoints and all(e.startswith("ipc://") for e in endpoints), endpoints
    folder = Path(endpoints[0][len("ipc://"):]).parent
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    bound = setup.bound_ports["left"]
    done, sent = threading.Event(), {}

    def send():
        try:
            sent.update(replay(src, {"left": ("127.0.0.1", bound)}, None, 2.0))
        finally:
            time.sleep(1.0)
            done.set()

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    (path,) = record(setup, tmp_path / "out", until=done, duration_s=60)
    sender.join(10)
    assert 1024 <= bound.value < 65536 and sent["left"] > 0
    with Recording(path) as rec:
        assert rec.n_frames("left") == 20
        np.testing.assert_array_equal(rec.file["radar/left/adc"][:], iq)


def test_production_code_never_picks_a_free_port_to_bind_later():
    """free_port, free_ports and free_tcp_endpoint are for tests: no module of the daemon, demo or replay
    path calls them (acquisition/processes.py only defines them, one on top of the other)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    offenders = []
    for folder in ("acquisition", "drivers", "imaging", "rio"):
        for path in (root / folder).rglob("*.py"):
            if path == root / "acquisition" / "processes.py":
                continue
            text = path.read_text()
            for name in ("free_port(", "free_ports(", "free_tcp_endpoint("):
                if name in text.replace(f"def {name}", ""):
                    offenders.append(f"{path.relative_to(root)}: {name}")
    assert offenders == [], offenders


def test_free_ports_are_distinct_and_outside_the_ephemeral_range():
    """Ports for tests come from below ip_local_port_range, where no outgoing connection takes its local port,
    and are never handed out twice in a process: three endpoints asked for one after the other all bind (a
    CI run once got the same port twice, or one a reconnecting socket had just taken, and failed to bind)."""
    from acquisition.processes import _ephemeral_range
    from acquisition.bus import BusPublisher

    low, _ = _ephemeral_range()
    ports = [free_port() for _ in range(50)] + free_ports(50) + [int(free_tcp_endpoint().rsplit(":", 1)[1]) for _ in range(50)]
    assert len(set(ports)) == len(ports)
    assert all(1024 <= p < low for p in ports)
    publishers = [BusPublisher(free_tcp_endpoint()) for _ in range(3)]
    for p in publishers:
        p.close()
