"""The acquisition daemon: one process per device and per worker, the recorder in the supervising process.

``record`` starts a radar driver process per radar (UDP -> SRF1 or DCA1000 frames -> bus), an IMU driver
process (serial -> samples -> bus), a CAN driver process (python-can -> frames -> bus) and any workers
(RIO, strip map), records everything on the bus, restarts a process that dies (and writes that to /events),
publishes health on the bus and to systemd, and stops on SIGINT/SIGTERM, after ``duration_s``, or on a full
disk. The recorder lives in the supervisor: if it dies, the whole unit is restarted by systemd.
``replay`` sends a recording back through emulated hardware: SRF1 or DCA1000 datagrams on UDP, Xbus bytes
on a pseudo-terminal, CAN frames on a python-can bus.
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing as mp
import os
import signal
import socket
import threading
import time
from pathlib import Path

import numpy as np

from drivers.can_driver import CanConfig
from drivers.radar_stream import WIRE_FORMATS
from drivers.ti_cfg import TiRadarConfig
from imaging.core.errors import ConfigError, SarbotError
from imaging.core.rig import Rig
from imaging.io.recording import Recording

from .recorder import DiskFullError
from .sdnotify import notify, watchdog_interval_s

log = logging.getLogger("sarbot.daemon")


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A loopback port free at the moment of asking (TCP by default, or socket.SOCK_DGRAM)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_tcp_endpoint() -> str:
    return f"tcp://127.0.0.1:{free_port()}"


@dataclasses.dataclass(frozen=True)
class RadarLink:
    """Where a radar's datagrams arrive and in which wire format (``ti_cfg`` for DCA1000)."""

    name: str
    port: int
    host: str = "127.0.0.1"
    wire_format: str = "SRF1"
    ti_cfg: TiRadarConfig | None = None

    def __post_init__(self) -> None:
        if self.wire_format not in WIRE_FORMATS:
            raise ConfigError(f"radar.{self.name}.wire_format", f"{self.wire_format!r} is not one of {WIRE_FORMATS}")
        if self.wire_format == "DCA1000" and self.ti_cfg is None:
            raise ConfigError(f"radar.{self.name}.ti_cfg", "a DCA1000 radar needs its TI .cfg file")
        if not 0 < self.port < 65536:
            raise ConfigError(f"radar.{self.name}.port", f"{self.port} is not a UDP port")


@dataclasses.dataclass
class Setup:
    """What the daemon runs: the rig, one link per radar, the IMU port, the CAN bus, recorder settings,
    and optional workers (``role -> (function, extra args[, endpoint])``, each started as
    ``function(driver_endpoints, endpoint, *extra, stop)``)."""

    rig: Rig
    radars: list[RadarLink]
    imu_port: str | None = None
    can: CanConfig | None = None
    flush_interval_s: float = 0.5
    split_bytes: int | None = None
    split_s: float | None = None
    min_free_bytes: int = 64_000_000
    health_interval_s: float = 2.0
    health_endpoint: str | None = None
    worker_stop_timeout_s: float = 60.0
    workers: dict = dataclasses.field(default_factory=dict)


def _die_with_parent(role: str = "") -> None:
    """A driver whose supervisor died (SIGKILL, OOM) must not keep the port or the device busy. The
    process is also named after its role, so top and ps say which is which."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        if role:
            libc.prctl(15, ctypes.c_char_p(f"sarbot-{role}"[:15].encode()), 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the supervisor decides when to stop
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))


def _radar_main(link: RadarLink, shape, endpoint: str, stop) -> None:
    from drivers.radar_stream import Dca1000Stream, Srf1Stream
    from drivers.udp import UdpReceiver

    from .bus import BusPublisher
    from .pipeline import radar_driver_loop

    _die_with_parent(link.name)
    stream = Dca1000Stream(link.ti_cfg) if link.wire_format == "DCA1000" else Srf1Stream(tuple(shape))
    rx = UdpReceiver(link.host, link.port)
    pub = BusPublisher(endpoint)
    try:
        radar_driver_loop(rx, link.name, stream, pub, stop)
    finally:
        rx.close()
        pub.close()


def _can_main(config: CanConfig, endpoint: str, stop) -> None:
    from drivers.can_driver import CanDriver

    from .bus import BusPublisher
    from .pipeline import can_driver_loop

    _die_with_parent("can")
    pub = BusPublisher(endpoint)
    driver = CanDriver(config.open(), trigger_id=config.trigger_id)
    try:
        can_driver_loop(driver, pub, stop)
    finally:
        driver.close()
        pub.close()


def _imu_main(port: str, endpoint: str, radar_endpoints: list[str], stop) -> None:
    from drivers.imu import ImuDriver

    from .bus import BusPublisher, BusSubscriber
    from .pipeline import publish_imu_samples

    _die_with_parent("imu")
    import serial

    pub = BusPublisher(endpoint)
    # The hardware trigger marks the first chirp: its PTP time is the first radar frame's time.
    sub = BusSubscriber(radar_endpoints, topics=["radar/"]) if radar_endpoints else None
    trigger_time = None
    trigger_sent = False
    driver = None
    try:
        while not stop.is_set():
            if driver is None:
                if not os.path.exists(port):
                    time.sleep(0.05)
                    continue
                driver = ImuDriver(port, trigger_time_ns=trigger_time)
            if sub is not None and trigger_time is None:
                msg = sub.receive(timeout_ms=0 if driver.serial.in_waiting else 20)
                if msg is not None:
                    trigger_time = int(msg.header["frame_time_ns"])
                    driver.set_trigger_time(trigger_time)
                    # Only the first frame was needed: unsubscribed, the radar streams would pile up here.
                    sub.close()
                    sub = None
            try:
                samples = driver.read()
            except (serial.SerialException, OSError) as exc:
                # The device went away (unplugged, or the emulator finished): say so, wait for it to return.
                pub.publish("event", time.time_ns(), source="imu", level="warning", message=f"serial port lost: {exc}")
                driver.close()
                driver = None
                time.sleep(0.2)
                continue
            if not trigger_sent and driver.clock.trigger_ticks is not None and driver.clock.trigger_time_ns is not None:
                pub.publish("trigger", driver.clock.trigger_time_ns, source="imu_syncin")
                trigger_sent = True
            publish_imu_samples(pub, samples, driver.clock.drift_ppm())
    finally:
        if driver is not None:
            driver.close()
        pub.close()
        if sub is not None:
            sub.close()


class Health:
    """Frames/s per radar, IMU rate, losses and clock state over the last interval, from the recorder's counts."""

    def __init__(self, recorder, endpoints: dict[str, str]):
        self.recorder = recorder
        self.endpoints = endpoints
        self._last = (time.monotonic(), dict(recorder.frames), recorder.imu_samples)

    def sample(self, restarts: int) -> dict:
        rec = self.recorder
        t0, frames, imu_n = self._last
        now = time.monotonic()
        dt = max(now - t0, 1e-9)
        lat = np.asarray(rec.latencies_ns, float) * 1e-6
        rec.latencies_ns.clear()
        report = {
            "frames_per_s": {n: (rec.frames[n] - frames.get(n, 0)) / dt for n in rec.frames},
            "imu_hz": (rec.imu_samples - imu_n) / dt,
            "can_frames": rec.can_frames,
            "bus_lost": sum(st.missed for st in rec.sub.stats.values()),
            "wire_events": rec.wire_events,
            "invalid_frames": dict(rec.invalid_frames),
            "restarts": restarts,
            "latency_ms": {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                           "max": float(lat.max())} if lat.size else None,
            "endpoints": self.endpoints,
            "clock": {"ptp_locked": dict(rec.ptp_locked), "trigger_seen": bool(rec.triggers_seen),
                      "imu_drift_ppm": rec.imu_drift_ppm},
        }
        self._last = (now, dict(rec.frames), rec.imu_samples)
        return report

    @staticmethod
    def line(report: dict) -> str:
        parts = [f"{n} {r:.1f} frames/s" for n, r in report["frames_per_s"].items()]
        parts.append(f"IMU {report['imu_hz']:.0f} Hz")
        drift = report["clock"]["imu_drift_ppm"]
        parts.append(f"IMU drift {drift:+.1f} ppm" if drift is not None else "IMU drift unknown")
        locks = report["clock"]["ptp_locked"]
        unlocked = [n for n, ok in locks.items() if not ok]
        if locks:
            parts.append("PTP unlocked: " + ", ".join(unlocked) if unlocked else "PTP locked")
        if report["latency_ms"]:
            parts.append(f"latency p50 {report['latency_ms']['p50']:.1f} ms, p99 {report['latency_ms']['p99']:.1f} ms")
        parts.append(f"invalid frames {sum(report['invalid_frames'].values())}, wire events {report['wire_events']}, "
                     f"bus lost {report['bus_lost']}, restarts {report['restarts']}")
        return ", ".join(parts)


def record(setup: Setup, out_dir: Path, duration_s: float | None = None, on_health=None,
           until: threading.Event | None = None, path: Path | None = None) -> list[Path]:
    """Run drivers, workers and the recorder until SIGINT/SIGTERM, ``duration_s`` or ``until`` is set;
    returns the files written (``path``, or a time-stamped name in ``out_dir``).

    Raises DiskFullError (after stopping everything and closing the file) when the disk fills up.
    """
    from .bus import BusPublisher
    from .recorder import Recorder

    rig = setup.rig
    out_dir.mkdir(parents=True, exist_ok=True)
    path = path or out_dir / time.strftime("recording_%Y%m%dT%H%M%S.h5")
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    specs = {}
    for link in setup.radars:
        wf = rig.radar(link.name).waveform
        shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp)
        specs[f"radar.{link.name}"] = (_radar_main, (link, shape, free_tcp_endpoint(), stop))
    radar_endpoints = [args[2] for _, args in specs.values()]
    endpoints = list(radar_endpoints)
    if setup.imu_port:
        specs["imu"] = (_imu_main, (setup.imu_port, free_tcp_endpoint(), radar_endpoints, stop))
        endpoints.append(specs["imu"][1][1])
    if setup.can is not None:
        specs["can"] = (_can_main, (setup.can, free_tcp_endpoint(), stop))
        endpoints.append(specs["can"][1][1])
    driver_endpoints = list(endpoints)
    for role, (target, extra, *endpoint) in setup.workers.items():
        endpoint = endpoint[0] if endpoint else free_tcp_endpoint()
        specs[role] = (target, (driver_endpoints, endpoint, *extra, stop))
        endpoints.append(endpoint)
    procs = {}
    for role, (target, args) in specs.items():
        procs[role] = ctx.Process(target=target, args=args, name=role, daemon=True)
        procs[role].start()
    recorder = Recorder(path, rig, endpoints, flush_interval_s=setup.flush_interval_s,
                        wire_formats={link.name: link.wire_format for link in setup.radars},
                        split_bytes=setup.split_bytes, split_s=setup.split_s, min_free_bytes=setup.min_free_bytes)
    health_pub = BusPublisher(setup.health_endpoint or "tcp://127.0.0.1:0")
    log.info("health on %s", health_pub.endpoint)
    stopping = threading.Event()

    def on_signal(signum, frame):
        stopping.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    t_end = time.monotonic() + duration_s if duration_s else None
    restarts = 0
    notify("READY=1")
    watchdog_s = watchdog_interval_s()
    last_health = last_watchdog = time.monotonic()
    health = Health(recorder, dict(zip(specs, endpoints)))
    flowing = False
    disk_full = None
    try:
        try:
            while not stopping.is_set() and (t_end is None or time.monotonic() < t_end) and not (until and until.is_set()):
                if recorder.step(timeout_ms=50):
                    flowing = True
                now = time.monotonic()
                if now - last_health >= setup.health_interval_s:
                    report = health.sample(restarts)
                    status = Health.line(report)
                    log.info("health: %s", status)
                    notify(f"STATUS={status}")
                    health_pub.publish("health", time.time_ns(), **report)
                    if on_health is not None:
                        on_health(report)
                    last_health = now
                # The watchdog is fed only while data flows: a daemon alive but recording nothing gets restarted.
                if watchdog_s and flowing and now - last_watchdog >= watchdog_s:
                    notify("WATCHDOG=1")
                    last_watchdog = now
                    flowing = False
                for role, proc in list(procs.items()):
                    if not proc.is_alive():
                        restarts += 1
                        recorder.writer.append_event(time.time_ns(), role, "error",
                                                     f"{role} exited with code {proc.exitcode}; restarted")
                        log.warning("%s exited with code %s; restarting it", role, proc.exitcode)
                        target, args = specs[role]
                        procs[role] = ctx.Process(target=target, args=args, name=role, daemon=True)
                        procs[role].start()
            notify("STOPPING=1")
            stop.set()
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline:  # drain what the drivers flush on the way out
                recorder.step(timeout_ms=100)
                if not any(p.is_alive() for p in procs.values()):
                    while recorder.step(timeout_ms=200):
                        pass
                    break
        except DiskFullError as exc:
            disk_full = exc
            notify("STOPPING=1")
            notify(f"STATUS=stopped: {exc.strerror}")
            log.error("%s", exc.strerror)
    finally:
        stop.set()
        for role, proc in procs.items():
            # Workers finish their products (trajectory, map) after the drivers stop; give them time.
            proc.join(setup.worker_stop_timeout_s if role in setup.workers else 2)
            if proc.is_alive():
                log.error("%s did not stop in time; killed", role)
                proc.kill()
        recorder.close()
        health_pub.close()
        for s, h in old.items():
            signal.signal(s, h)
    log.info("recorded %s (%s frames, %d IMU samples, %d CAN frames, %d restarts)", ", ".join(map(str, recorder.paths)),
             recorder.frames, recorder.imu_samples, recorder.can_frames, restarts)
    if disk_full is not None:
        raise disk_full
    return recorder.paths


def _replay_radar_process(path: str, name: str, address, speed, go, start, results) -> None:
    from .pipeline import replay_radar

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with Recording(path) as rec:
            results.put((name, "ready"))
            go.wait()
            results.put((name, replay_radar(rec, name, tuple(address), speed, start_monotonic=start.value)))
    except Exception as exc:
        results.put((name, f"{type(exc).__name__}: {exc}"))


def replay(path: Path, radar_targets: dict[str, tuple[str, int]], imu_link: str | None, speed: float | None,
           start_delay_s: float = 0.0, can: CanConfig | None = None) -> dict:
    """Send a recording through emulated hardware: each radar's datagrams (SRF1 or DCA1000, as recorded)
    to its UDP address, the IMU as Xbus bytes on a pty that ``imu_link`` points to, and /can on a
    python-can bus. Returns what was sent ({radar: datagrams, "can": frames})."""
    from .pipeline import imu_emulator, replay_can

    with Recording(path) as rec:
        for name in radar_targets:
            if name not in rec.radar_names:
                raise SarbotError(f"--radar {name}: {path} has no such radar (radars: {', '.join(rec.radar_names)})")
        emu = None
        if imu_link:
            if rec.imu() is None:
                raise SarbotError(f"--imu-link: {path} has no IMU samples to replay")
            emu = imu_emulator(rec, speed=speed)
            link = Path(imu_link)
            if link.is_symlink() or link.exists():
                link.unlink()
            link.symlink_to(emu.port)
        can_bus = can.open() if can is not None else None
        time.sleep(start_delay_s)
        sent = {}
        failures = []

        def send_can(t0_ns):
            try:
                sent["can"] = replay_can(rec, can_bus, speed, t0_ns)
            except Exception as exc:  # reported below, after the radars finish
                failures.append(f"can: {exc}")

        # One process per radar, as on the robot: threads would share one interpreter with the IMU
        # emulator, and its 400 Hz packets would come late whenever the radars send a frame.
        ctx = mp.get_context("spawn")
        results = ctx.Queue()
        go = ctx.Event()
        start = ctx.Value("d", 0.0)  # the senders' common start (time.monotonic() is shared by all processes)
        procs = {name: ctx.Process(target=_replay_radar_process, args=(str(path), name, address, speed, go, start, results),
                                   name=f"replay.{name}", daemon=True) for name, address in radar_targets.items()}
        for proc in procs.values():
            proc.start()
        for _ in procs:
            key, value = results.get(timeout=60)
            if value != "ready":
                failures.append(f"{key}: {value}")
        start.value = time.monotonic() + 0.1
        go.set()
        can_thread = None
        if can_bus is not None:
            firsts = [int(rec.frame_time_ns(n)[0]) for n in radar_targets if rec.n_frames(n)]
            can_thread = threading.Thread(target=send_can, args=(min(firsts) if firsts else None,))
        if emu is not None:
            time.sleep(max(start.value - time.monotonic(), 0.0))
            emu.start()
        if can_thread is not None:
            can_thread.start()
        for name, proc in procs.items():
            proc.join()
            if proc.exitcode != 0:
                failures.append(f"{name}: sender exited with code {proc.exitcode}")
        for _ in procs:
            try:
                key, value = results.get(timeout=5)
            except Exception:  # queue.Empty: a sender died without a word (its exit code is reported above)
                break
            if isinstance(value, str):
                failures.append(f"{key}: {value}")
            else:
                sent[key] = value
        if can_thread is not None:
            can_thread.join()
            time.sleep(0.2)  # frames still in flight on the emulated bus
            can_bus.shutdown()
        if emu is not None:
            emu.done.wait()
            time.sleep(0.5)  # let the reader drain the pty
            emu.close()
            Path(imu_link).unlink(missing_ok=True)
    if failures:
        raise SarbotError("replay failed: " + "; ".join(failures))
    return sent
