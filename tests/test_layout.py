"""The house rules of the layout: what a driver process imports, and adding a wire format without touching
the daemon, replay or the command line."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from acquisition.workers import Worker, WorkerSpec

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT.parent / "shared" / "data" / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg"

CHILD_IMPORTS = """
import multiprocessing as mp
import sys

if __name__ == "__main__":
    from acquisition.daemon import Setup, process_specs
    from acquisition.processes import free_port
    from drivers.can_driver import CanConfig
    from drivers.radar.link import RadarLink
    from imaging.core.rig import default_rig

    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    stop.set()  # each driver starts, imports what it needs, and returns at once
    link = RadarLink("left_front", free_port(), **{link_kwargs})
    setup = Setup(default_rig(), [link], imu_port="/nonexistent/imu", can=CanConfig("virtual", "importtime"))
    spec = next(s for s in process_specs(setup, stop) if s.role == sys.argv[1])
    print("=== child", flush=True, file=sys.stderr)
    proc = ctx.Process(target=spec.target, args=spec.args)
    proc.start()
    proc.join(60)
    sys.exit(proc.exitcode)
"""


@pytest.mark.parametrize("role, link_kwargs", [
    ("radar.left_front", {}),
    ("radar.left_front", {"wire_format": "DCA1000", "options": {"cfg": str(CFG)}}),
    ("imu", {}),
    ("can", {}),
], ids=["radar-SRF1", "radar-DCA1000", "imu", "can"])
def test_driver_processes_import_neither_h5py_nor_matplotlib(tmp_path, role, link_kwargs):
    """``python -X importtime`` of the daemon's own driver process, started the way the daemon starts it
    (spawn, the same target and arguments): the child's import lines follow the marker."""
    script = tmp_path / "child_imports.py"
    script.write_text(CHILD_IMPORTS.replace("{link_kwargs}", repr(link_kwargs)))
    run = subprocess.run([sys.executable, "-X", "importtime", str(script), role], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    child = run.stderr.split("=== child", 1)[1]
    modules = {line.rsplit("|", 1)[-1].strip() for line in child.splitlines() if line.startswith("import time:")}
    assert "drivers.radar.udp" in modules or role != "radar.left_front"  # the child's imports are really here
    assert "numpy" in modules
    heavy = sorted(m for m in modules if m.split(".")[0] in ("h5py", "matplotlib"))
    assert not heavy, f"{role} imports {heavy}"


# -- a wire format defined here, recorded through `sarbot record` -------------------------------------------
TOY_MAGIC = b"TOY!"


class ToyStream:
    """A made-up format: one datagram per frame, ``TOY! | u32 counter | u64 time_ns | int16 I/Q``."""

    wire_format = "TOY1"

    def __init__(self, shape):
        self.shape = shape
        self.counters = type("ToyCounters", (), {})()
        self.counters.malformed = 0
        self.counters.datagrams = 0

    def feed(self, datagram: bytes, receive_ns: int):
        from drivers.radar.stream import RadarFrame

        self.counters.datagrams += 1
        if not datagram.startswith(TOY_MAGIC):
            self.counters.malformed += 1
            return []
        counter = int.from_bytes(datagram[4:8], "little")
        t_ns = int.from_bytes(datagram[8:16], "little")
        iq = np.frombuffer(datagram[16:], "<i2").reshape(self.shape)
        return [RadarFrame(counter, t_ns, receive_ns, True, 0, iq)]

    def flush(self):
        return []


def toy_encode(frame_counter: int, frame_time_ns: int, iq: np.ndarray) -> list[bytes]:
    return [TOY_MAGIC + frame_counter.to_bytes(4, "little") + frame_time_ns.to_bytes(8, "little")
            + np.ascontiguousarray(iq, "<i2").tobytes()]


def toy_open_stream(waveform, settings, radar_id):
    return ToyStream((waveform.chirps_per_frame, waveform.n_rx, waveform.samples_per_chirp, 2))


def toy_open_encoder(radar_id):
    return toy_encode


def test_a_wire_format_registered_here_records_through_sarbot_record(tmp_path):
    from acquisition import cli
    from acquisition.processes import free_port
    from drivers.radar import registry
    from imaging.io.recording import Recording

    registry.register(registry.WireFormat("TOY1", "a test's own format", toy_open_stream, toy_open_encoder))
    rig = tmp_path / "rig.toml"
    rig.write_text(textwrap.dedent("""
        [radar.toy]
        mount_yaw_deg = 90.0
        [radar.toy.waveform]
        chirps_per_frame = 8
        sample_rate_hz = 200e3
        frame_interval_s = 0.01
        n_tx = 2
        n_rx = 2
    """))
    port = free_port(socket.SOCK_DGRAM)
    shape = (8, 2, 36, 2)
    rng = np.random.default_rng(5)
    frames = [rng.integers(-2000, 2000, shape, dtype=np.int16) for _ in range(12)]
    t0 = 1_700_000_000_000_000_000

    def send():
        time.sleep(4.0)  # the daemon spawns its driver, which imports this module to find the format
        encode = registry.get("TOY1").open_encoder(0)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for k, iq in enumerate(frames):
                for d in encode(100 + k, t0 + k * 10_000_000, iq):
                    s.sendto(d, ("127.0.0.1", port))
                time.sleep(0.01)

    sender = threading.Thread(target=send)
    sender.start()
    code = cli.main(["record", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", f"toy={port},format=TOY1",
                     "--duration", "7"])
    sender.join()
    assert code == 0
    (path,) = (tmp_path / "out").glob("*.h5")
    with Recording(path) as rec:
        assert rec.wire_format("toy") == "TOY1"
        np.testing.assert_array_equal(rec.adc_iq("toy"), np.stack(frames))
        np.testing.assert_array_equal(rec.frame_counter("toy"), 100 + np.arange(12))
        np.testing.assert_array_equal(rec.frame_time_ns("toy"), t0 + np.arange(12) * 10_000_000)
        assert rec.valid("toy").all()


def test_an_unknown_wire_format_is_a_clear_error(tmp_path, capsys):
    from acquisition import cli

    rig = tmp_path / "rig.toml"
    rig.write_text("[radar.left]\n")
    code = cli.main(["record", "--config", str(rig), "-o", str(tmp_path), "--radar", "left=50001,format=NOPE"])
    err = capsys.readouterr().err
    assert code == 2
    assert "format=NOPE" in err and "'NOPE' is not a known wire format" in err and "SRF1" in err
    assert "Traceback" not in err


# -- device control: a hook of the wire format, not a branch on its name --------------------------------------
class ToyControl:
    """What a made-up format's device control would bring up (``acquisition.devices.DeviceBringUp`` takes it)."""

    def __init__(self, radar: str, port: int, device: str):
        self.radar, self.data_port, self.device = radar, port, device


def toy_cli_option(text: str) -> dict:
    name, _, device = text.partition("=")
    if not device.startswith("/dev/"):
        raise ValueError("expected NAME=/dev/DEVICE")
    return {"device": device}


def toy_controls(link, settings: dict) -> list:
    return [ToyControl(link.name, link.port, settings["device"])]


def test_a_wire_format_brings_its_own_devices_up(tmp_path, monkeypatch):
    """``--radar-cli`` on a radar of a format registered here: the format reads the option and says what to drive;
    on a format without device control it is a clear error naming the formats that take it."""
    from acquisition.cli import build_parser
    from acquisition.cli.daemon import record_setup
    from drivers.radar import registry
    from imaging.core.errors import SarbotError

    toy = registry.WireFormat("TOY2", "a test's format with a device", toy_open_stream, toy_open_encoder,
                              control_options={"--radar-cli": toy_cli_option}, controls=toy_controls)
    monkeypatch.setitem(registry._registered, "TOY2", toy)  # registered for this test only
    rig = tmp_path / "rig.toml"
    rig.write_text("[radar.toy]\n[radar.plain]\n")

    def setup_of(*extra):
        return record_setup(build_parser().parse_args(["record", "--config", str(rig), "-o", str(tmp_path),
                                                       "--radar", "toy=50001,format=TOY2", "--radar", "plain=50002",
                                                       *extra]))

    assert setup_of().controls == []
    (control,) = setup_of("--radar-cli", "toy=/dev/ttyTOY").controls
    assert (control.radar, control.data_port, control.device) == ("toy", 50001, "/dev/ttyTOY")
    with pytest.raises(SarbotError, match=r"--radar-cli 'toy=COM3': expected NAME=/dev/DEVICE"):
        setup_of("--radar-cli", "toy=COM3")
    with pytest.raises(SarbotError, match=r"--radar-cli plain: not a DCA1000 or TOY2 radar of this recording.*TOY2 radars: toy"):
        setup_of("--radar-cli", "plain=/dev/ttyTOY")


# -- a worker of one's own, started by `sarbot run` ------------------------------------------------------------
class ToyWorker(Worker):
    """Made up here: says, as its product, which process it ran in and how many messages it handled."""

    topics = ["imu"]

    def __init__(self, config, publisher):
        self.path = Path(config)
        self.handled = 0

    def handle(self, message, live):
        self.handled += 1

    def write_products(self):
        self.path.write_text(f"{os.getpid()} {self.handled}")


def toy_workers(setup, run) -> list:
    """The factory: one toy worker whose product goes beside the run's trajectory and map."""
    return [WorkerSpec("toy", ToyWorker, str(run.out_dir / f"toy_{run.stamp}.txt"))]


def test_a_worker_registered_here_is_started_by_sarbot_run(tmp_path):
    """A Worker subclass and its factory, defined in this test and registered: `sarbot run` starts it in a process
    of its own beside the odometry and the map, with no change to the pipeline or the command line; unregistered,
    the run's own factories are left."""
    from acquisition import cli
    from acquisition.processes import free_port
    from acquisition.workers import registry

    registry.register("toy", toy_workers)
    try:
        code = cli.main(["-q", "run", "--config", str(ROOT / "imaging/rigs/default.toml"), "-o", str(tmp_path),
                         "--radar", f"left_front={free_port(socket.SOCK_DGRAM)}", "--imu-port", str(tmp_path / "no_imu"),
                         "--duration", "3"])
    finally:
        registry.unregister("toy")
    assert code == 0
    assert registry.names() == ["rio", "stripmap", "view"]
    (product,) = tmp_path.glob("toy_*.txt")
    pid, handled = map(int, product.read_text().split())
    assert pid != os.getpid() and handled >= 0  # a process of its own, which ran to its end
