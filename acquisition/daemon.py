"""The acquisition daemon: one process per device and per worker, the recorder in the supervising process.

``record`` starts a radar driver process per radar link, an IMU driver process, a CAN driver process and
any workers (odometry, strip map), records everything on the bus, restarts a process that dies (and
writes that to /events), publishes health on the bus and to systemd, and stops on SIGINT/SIGTERM, after
``duration_s``, or on a full disk. The recorder lives in the supervisor: if it dies, the whole unit is
restarted by systemd.
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing as mp
import signal
import threading
import time
from pathlib import Path

import numpy as np

from drivers.can_driver import CanConfig
from drivers.radar import timestamping
from drivers.radar.link import RadarLink
from drivers.radar.timestamping import StampChoice
from imaging.core.errors import SarbotError
from imaging.core.rig import Rig

from .bus import BusPublisher
from .devices import DeviceBringUp
from .driver_loops import can_process, imu_process, imu_role, radar_process
from .messages import ClockState, Health, Latency, LoggedEvent, WorkerState
from .processes import ProcessSpec, bus_endpoint, release_free_heap
from .ptp import PtpMonitor, PtpPoller
from .recorder import DiskFullError, Recorder
from .sdnotify import UNIT_STOP_TIMEOUT_ENV, notify, unit_stop_timeout_s, watchdog_interval_s
from .workers import WorkerSpec, stop_needs_s, worker_process

log = logging.getLogger(f"sarbot.{__name__}")

#: A process that dies sooner than this after its start is restarted with a growing delay.
MIN_UPTIME_S = 10.0
#: After the stop, how long the recorder takes in what the drivers flush on their way out, s (within the
#: workers' ``worker_stop_timeout_s``, which counts from the same moment).
DRIVER_DRAIN_S = 3.0
#: How long a killed worker is waited for before the recording is closed, s.
KILL_WAIT_S = 5.0


@dataclasses.dataclass
class Setup:
    """What the daemon runs: the rig, one link per radar, the IMU port (and those of IMUs on radar mounts,
    by radar), the CAN bus, recorder settings, and the workers."""

    rig: Rig
    radars: list[RadarLink]
    imu_port: str | None = None
    can: CanConfig | None = None
    radar_imu_ports: dict[str, str] = dataclasses.field(default_factory=dict)
    flush_interval_s: float = 0.5
    split_bytes: int | None = None
    split_s: float | None = None
    min_free_bytes: int = 64_000_000
    health_interval_s: float = 2.0
    health_endpoint: str | None = None
    #: After the stop, how long the workers may take to drain, finish and write their products (their own
    #: budgets are cut to fit: ``workers.stop_budgets``). A worker still running then gets SIGTERM and writes
    #: what it has; one still running ``worker_hurry_timeout_s`` after that is killed (its products lost).
    worker_stop_timeout_s: float = 60.0
    worker_hurry_timeout_s: float = 15.0
    warm_up_timeout_s: float = 300.0
    workers: list[WorkerSpec] = dataclasses.field(default_factory=list)
    #: Devices to bring up once the drivers listen, and down before they stop (``TiRadarControl``).
    controls: list = dataclasses.field(default_factory=list)
    control_listen_timeout_s: float = 30.0
    #: radar -> a shared integer (``multiprocessing`` Value) its driver writes the UDP port it bound to, for a
    #: link on port 0 (the system picks the port at bind: nothing can take it between choosing and binding).
    #: Made by ``process_specs`` where not given; a restarted driver binds the same port again.
    bound_ports: dict = dataclasses.field(default_factory=dict)
    #: linuxptp's ptp4l management socket to watch (the host's PTP state into health, /ptp and /events);
    #: None: not watched.
    ptp4l_socket: str | None = None
    ptp_interval_s: float = 1.0
    phc2sys_log: str | None = None  # a file phc2sys's -m output goes to: its offset into health and /ptp

    @classmethod
    def for_devices(cls, rig_path, links: list[RadarLink], imu_port: str | None = None,
                    radar_imu_ports: dict[str, str] | None = None, can: CanConfig | None = None,
                    device_options: dict[str, list[str]] | None = None, **settings) -> "Setup":
        """The setup of ``sarbot record`` and ``run`` from plain values: the rig from ``rig_path`` with each
        linked radar's waveform as its link says (a TI .cfg fixes what the radar sends; the rig, where it
        sits), the devices checked against the rig, and the devices to bring up from ``device_options``
        (option -> values, ``acquisition.devices.device_controls``). ``settings``: the other fields
        (``split_bytes``, ``health_endpoint``, ...). SarbotError naming what is wrong.
        """
        from imaging.core.rig import AntennaArray, load_rig

        from .devices import device_controls

        radar_imu_ports = dict(radar_imu_ports or {})
        rig = load_rig(rig_path)
        radars = {r.name: r for r in rig.radars}
        check_links_distinct(links)
        for link in links:
            if link.name not in radars:
                raise SarbotError(f"radar {link.name}: no such radar in {rig_path} (radars: {', '.join(rig.radar_names)})")
            wf = link.waveform(radars[link.name].waveform)
            if wf != radars[link.name].waveform:
                radars[link.name] = dataclasses.replace(radars[link.name], waveform=wf, array=AntennaArray.uniform_tdm(wf))
        rig = Rig(tuple(radars.values()), rig.imu)
        for name, port in radar_imu_ports.items():
            if name not in radars:
                raise SarbotError(f"--radar-imu {name}={port}: no such radar in {rig_path} (radars: {', '.join(rig.radar_names)})")
            if radars[name].imu is None:
                raise SarbotError(f"--radar-imu {name}={port}: {rig_path} declares no IMU on radar {name}; add a "
                                  f"[radar.{name}.imu] table with its rate_hz (its axes are the radar's)")
        if not links and not imu_port and not radar_imu_ports and can is None:
            raise SarbotError("nothing to record: give --radar NAME=[HOST:]PORT, --dca1000 NAME=[HOST:]PORT:CFG, --imu-port DEVICE, "
                              "--radar-imu NAME=DEVICE and/or --can")
        return cls(rig, list(links), imu_port, can, radar_imu_ports=radar_imu_ports,
                   controls=device_controls(links, device_options or {}), **settings)


def check_links_distinct(links: list[RadarLink]) -> None:
    """SarbotError for a radar given twice, or two radars on one address (the second would never bind)."""
    names: set[str] = set()
    addresses: dict[tuple[str, int], str] = {}
    for link in links:
        if link.name in names:
            raise SarbotError(f"radar {link.name}: given twice (one --radar or --dca1000 per radar)")
        names.add(link.name)
        where = (link.host, link.port)
        if link.port and where in addresses:
            raise SarbotError(f"radar {link.name}: {link.host}:{link.port} is radar {addresses[where]}'s already "
                              "(one UDP port per radar)")
        addresses[where] = link.name


def choose_receive_stamps(links: list[RadarLink]) -> tuple[list[RadarLink], dict[str, StampChoice]]:
    """Each link with its receive stamps decided ("hardware" or "software", ``drivers.radar.timestamping``)
    before any driver starts, so the recorder can say them from the file's start, and "hardware" demanded
    where the card cannot stamp is a SarbotError now (naming the interface and what it lacks), not a driver
    restarted for ever. The driver demands what was decided."""
    choices = {}
    for link in links:
        try:
            choices[link.name] = timestamping.choose_receive_stamps(link.host, link.source, link.receive_stamps)
        except SarbotError as exc:
            raise SarbotError(f"radar {link.name}: {exc}") from None
    return [dataclasses.replace(link, receive_stamps=choices[link.name].source) for link in links], choices


def check_radar_addresses(links: list[RadarLink]) -> None:
    """Bind each radar's UDP address once, before any driver starts: an address this host does not have (or
    cannot listen on at all) is said now and stops the run (SarbotError), instead of a driver that dies and is
    restarted for ever while nothing is recorded. A port another program holds is left to the driver's
    restarts with back-off (the holder may let go); the driver binds the address again itself."""
    import errno
    import socket

    for link in links:
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:  # as the driver's (UdpReceiver)
                sock.bind((link.host, link.port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                continue
            if exc.errno == errno.EADDRNOTAVAIL:
                why = f"{link.host} is not an address of this host (see `ip addr`; the radar's network, e.g. 192.168.33.x)"
            else:
                why = f"cannot listen on UDP {link.host}:{link.port} ({exc.strerror or exc})"
            raise SarbotError(f"radar {link.name}: {why}") from None


def open_health_publisher(endpoint: str | None) -> BusPublisher:
    """The health publisher on ``endpoint`` (default: loopback, a port the system picks at bind); SarbotError
    naming the endpoint when it cannot be bound."""
    import zmq

    try:
        return BusPublisher(endpoint or "tcp://127.0.0.1:0")
    except zmq.ZMQError as exc:
        raise SarbotError(f"--health-endpoint {endpoint}: cannot publish there ({exc.strerror})") from None


def stop_lasts_s(setup: Setup) -> float:
    """The longest the daemon's stop lasts with workers, s: the drivers' drain or the workers' stop timeout
    (both count from the stop), their hurry timeout, and the wait for a killed worker; the recording is closed
    right after."""
    return max(DRIVER_DRAIN_S, setup.worker_stop_timeout_s) + setup.worker_hurry_timeout_s + KILL_WAIT_S


def check_stop_timeouts(setup: Setup) -> None:
    """SarbotError for a negative stop timeout; a warning for each worker whose own stop budgets (draining,
    finishing, writing) do not fit in ``worker_stop_timeout_s``: they are cut to fit, and more is left out; and
    one where the whole stop (``stop_lasts_s``) does not fit in the unit's ``TimeoutStopSec``, when the daemon is
    told it (``sdnotify.unit_stop_timeout_s``): systemd would kill what still runs, the recorder included."""
    for name in ("worker_stop_timeout_s", "worker_hurry_timeout_s"):
        if not getattr(setup, name) >= 0:
            raise SarbotError(f"{name}: must be 0 s or more, got {getattr(setup, name)}")
    for w in setup.workers:
        needs = stop_needs_s(w.worker)
        if needs > setup.worker_stop_timeout_s:
            log.warning("%s: its stop takes up to %.0f s (draining %.0f s, finishing %.0f s, writing %.0f s), more than "
                        "worker_stop_timeout_s (%.0f s): draining and finishing are cut to fit", w.role, needs,
                        w.worker.drain_max_s, w.worker.finish_max_s, w.worker.write_reserve_s, setup.worker_stop_timeout_s)
    if not setup.workers:  # the stop is the drivers' drain alone
        return
    try:
        unit_s = unit_stop_timeout_s()
    except ValueError as exc:
        log.warning("%s; the stop's fit in the unit's TimeoutStopSec is not checked", exc)
        return
    if unit_s is not None and stop_lasts_s(setup) > unit_s:
        log.warning("the stop may last %.0f s (worker_stop_timeout_s %g s + worker_hurry_timeout_s %g s + %g s for a "
                    "killed worker), more than the unit's TimeoutStopSec (%g s): systemd would kill what still runs, "
                    "the recorder included; raise TimeoutStopSec (and %s) or lower --worker-stop-timeout or "
                    "--worker-hurry-timeout", stop_lasts_s(setup), setup.worker_stop_timeout_s,
                    setup.worker_hurry_timeout_s, KILL_WAIT_S, unit_s, UNIT_STOP_TIMEOUT_ENV)


def stop_processes(procs: dict, specs: dict, setup: Setup, stopped_at: float, record_event) -> None:
    """Join the daemon's child processes after the stop (``stopped_at``, monotonic s): a driver gets 2 s, then
    is killed; the workers share ``worker_stop_timeout_s`` from the stop, then each still running gets SIGTERM
    (it hurries: writes what it has) and ``worker_hurry_timeout_s`` more before it is killed. Each hurry and
    kill is logged and goes to /events through ``record_event(time_ns, source, level, message)``."""
    for role, proc in procs.items():
        if not specs[role].worker:
            proc.join(2)
            if proc.is_alive():
                log.error("%s did not stop in time; killed", role)
                proc.kill()
    workers = {role: proc for role, proc in procs.items() if specs[role].worker}
    stop_by = stopped_at + setup.worker_stop_timeout_s
    hurried: dict[str, float] = {}
    while True:
        alive = {role: proc for role, proc in workers.items() if proc.is_alive()}
        now = time.monotonic()
        for role in hurried.keys() - alive.keys():
            message = (f"{role} stopped {now - hurried.pop(role):.1f} s after SIGTERM (exit code {workers[role].exitcode}), "
                       "its products written with what it had")
            log.warning("%s", message)
            record_event(time.time_ns(), role, "warning", message)
        if not alive:
            return
        for role, proc in alive.items():
            if role not in hurried and now >= stop_by:
                message = (f"{role} still running {now - stopped_at:.1f} s after the stop (worker_stop_timeout_s "
                           f"{setup.worker_stop_timeout_s:g} s); SIGTERM: it writes what it has")
                log.warning("%s", message)
                record_event(time.time_ns(), role, "warning", message)
                proc.terminate()
                hurried[role] = now
            elif role in hurried and now >= hurried[role] + setup.worker_hurry_timeout_s:
                message = (f"{role} did not stop {setup.worker_hurry_timeout_s:g} s after SIGTERM either; killed, "
                           "its products lost")
                log.error("%s", message)
                record_event(time.time_ns(), role, "error", message)
                proc.kill()
                proc.join(KILL_WAIT_S)
                del workers[role], hurried[role]
        next(iter(alive.values())).join(0.05)


def process_specs(setup: Setup, stop) -> list[ProcessSpec]:
    """The daemon's child processes for ``setup``: drivers first, then the workers, which subscribe to them."""
    specs, frame_duration_ns = [], {}
    for link in setup.radars:
        endpoint = bus_endpoint(f"radar.{link.name}")
        waveform = link.waveform(setup.rig.radar(link.name).waveform)
        frame_duration_ns[link.name] = waveform.frame_duration_ns
        bound = None
        if link.port == 0:
            bound = setup.bound_ports.setdefault(link.name, mp.get_context("spawn").Value("i", 0))
        specs.append(ProcessSpec(f"radar.{link.name}", radar_process, (link, waveform, endpoint, stop, bound), endpoint))
    radar_endpoints = [s.endpoint for s in specs]
    # The robot's IMU, then those on radar mounts (radar None: the robot's).
    imus = ([(None, setup.imu_port)] if setup.imu_port else []) + list(setup.radar_imu_ports.items())
    for radar, port in imus:
        endpoint = bus_endpoint(imu_role(radar))
        # Outlives the IMU process: a restarted driver takes the trigger's PTP time and tick from it.
        clock_reference = mp.get_context("spawn").Array("q", 3)
        specs.append(ProcessSpec(imu_role(radar), imu_process,
                                 (port, endpoint, radar_endpoints, stop, clock_reference, frame_duration_ns, radar),
                                 endpoint))
    if setup.can is not None:
        endpoint = bus_endpoint("can")
        specs.append(ProcessSpec("can", can_process, (setup.can, endpoint, stop), endpoint))
    driver_endpoints = [s.endpoint for s in specs]
    for w in setup.workers:
        specs.append(ProcessSpec(w.role, worker_process, (w, driver_endpoints, stop, radar_endpoints,
                                                          setup.worker_stop_timeout_s), w.endpoint, worker=True))
    return specs


class HealthMonitor:
    """Frames/s per radar, IMU rate, losses and clock state over the last interval, from the recorder's counts."""

    def __init__(self, recorder: Recorder, endpoints: dict[str, str], worker_roles: list[str] = ()):
        self.recorder = recorder
        self.endpoints = endpoints
        self.worker_roles = list(worker_roles)
        self._last = (time.monotonic(), dict(recorder.frames), recorder.imu_samples)

    def sample(self, restarts: int, sensors_idle_s: float = 0.0) -> Health:
        rec = self.recorder
        t0, frames, imu_n = self._last
        now = time.monotonic()
        dt = max(now - t0, 1e-9)
        lat = np.asarray(rec.latencies_ns, float) * 1e-6
        rec.latencies_ns.clear()
        report = Health(
            frames_per_s={n: (rec.frames[n] - frames.get(n, 0)) / dt for n in rec.frames},
            imu_hz=(rec.imu_samples - imu_n) / dt,
            can_frames=rec.can_frames,
            bus_lost=rec.bus_lost,
            wire_events=rec.wire_events,
            invalid_frames=dict(rec.invalid_frames),
            restarts=restarts,
            latency_ms=Latency(float(np.percentile(lat, 50)), float(np.percentile(lat, 99)), float(lat.max()))
            if lat.size else None,
            endpoints=self.endpoints,
            clock=ClockState(dict(rec.ptp_locked), bool(rec.triggers_seen), rec.imu_drift_ppm),
            ptp=rec.ptp_status,
            receive_delay={n: d for n, d in ((n, r.stats()) for n, r in rec.receive_delay.items()) if d is not None},
            unlocked_frames=dict(rec.unlocked_frames),
            receive_stamp=dict(rec.receive_stamps),
            nic_unstamped=dict(rec.nic_unstamped),
            workers={role: rec.worker_states.get(role) or WorkerState(role, False, 0.0, {}) for role in self.worker_roles},
            sensors_idle_s=sensors_idle_s,
            conditions=dict(rec.conditions),
            imu_samples_lost=rec.imu_samples_lost,
            time_ns=time.time_ns(),
        )
        self._last = (now, dict(rec.frames), rec.imu_samples)
        return report

    @property
    def warm(self) -> bool:
        """Every worker has said it is warm."""
        states = self.recorder.worker_states
        return all(role in states and states[role].warm for role in self.worker_roles)


def record(setup: Setup, out_dir: Path, duration_s: float | None = None, on_health=None,
           until: threading.Event | None = None, path: Path | None = None) -> list[Path]:
    """Run drivers, workers and the recorder until SIGINT/SIGTERM, ``duration_s`` or ``until`` is set;
    returns the files written (``path``, or a time-stamped name in ``out_dir``). ``on_health`` is called
    with every ``Health`` report.

    Raises DiskFullError (after stopping everything and closing the file) when the disk fills up, and
    HardwareError when a device of ``setup.controls`` refuses to come up (the run stops; the file keeps
    what came before and the device's answer in /events).
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SarbotError(f"{out_dir}: cannot create the recordings folder ({exc.strerror})") from None
    path = path or out_dir / time.strftime("recording_%Y%m%dT%H%M%S.h5")
    check_radar_addresses(setup.radars)
    check_stop_timeouts(setup)
    links, stamp_choices = choose_receive_stamps(setup.radars)
    setup = dataclasses.replace(setup, radars=links)
    health_pub = open_health_publisher(setup.health_endpoint)
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    specs = {s.role: s for s in process_specs(setup, stop)}

    def start(spec: ProcessSpec):
        proc = ctx.Process(target=spec.target, args=spec.args, name=spec.role, daemon=True)
        proc.start()
        return proc

    procs = {role: start(spec) for role, spec in specs.items()}
    log.info("health on %s", health_pub.endpoint)
    # Every event written to /events is published again beside health: a viewer sees what the file holds.
    recorder = Recorder(path, setup.rig, [s.endpoint for s in specs.values()], flush_interval_s=setup.flush_interval_s,
                        wire_formats={link.name: link.wire_format for link in setup.radars},
                        split_bytes=setup.split_bytes, split_s=setup.split_s, min_free_bytes=setup.min_free_bytes,
                        frame_endpoints=[s.endpoint for role, s in specs.items() if role.startswith("radar.")],
                        on_event=lambda e: health_pub.send(LoggedEvent(e.time_ns, e.source, e.level, e.message)),
                        receive_stamps={name: c.source for name, c in stamp_choices.items()},
                        receive_stamp_notes={name: c.line() for name, c in stamp_choices.items()})
    for name, choice in stamp_choices.items():
        log.info("radar %s: %s", name, choice.line())
        if choice.source == "hardware":  # the receive delay is now on the card's clock: said where it is read
            recorder.record_event(time.time_ns(), f"radar.{name}", "info", choice.line())
    stopping = threading.Event()

    def on_signal(signum, frame):
        stopping.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    t_end = time.monotonic() + duration_s if duration_s else None
    restarts = 0
    watchdog_s = watchdog_interval_s()
    started = last_health = last_watchdog = last_trim = time.monotonic()
    monitor = HealthMonitor(recorder, {role: s.endpoint for role, s in specs.items()}, [w.role for w in setup.workers])
    # READY once the workers have compiled their kernels: until then the pipeline would fall behind.
    ready = False
    last_data, sensor_count = time.monotonic(), 0
    started_at = {role: time.monotonic() for role in procs}
    quick_failures = dict.fromkeys(procs, 0)
    restart_at: dict[str, float] = {}  # roles waiting out their backoff
    disk_full = None
    stopped_at = None  # when the stop was set: the workers' stop timeout counts from it
    devices = DeviceBringUp(setup.controls, setup.control_listen_timeout_s).start()
    ptp = PtpPoller(PtpMonitor(setup.ptp4l_socket), setup.ptp_interval_s, setup.phc2sys_log).start() \
        if setup.ptp4l_socket else None
    try:
        try:
            while not stopping.is_set() and (t_end is None or time.monotonic() < t_end) and not (until and until.is_set()):
                recorder.step(timeout_ms=50)
                devices.drain(recorder.record_event)
                for t_ns, status, events in ptp.drain() if ptp else ():
                    recorder.record_ptp(status, events, t_ns)
                if devices.failed.is_set():
                    break
                now = time.monotonic()
                count = (sum(recorder.frames.values()) + recorder.imu_samples + sum(recorder.radar_imu_samples.values())
                         + recorder.can_frames)
                if count != sensor_count:
                    last_data, sensor_count = now, count
                if not ready and (monitor.warm or now - started > setup.warm_up_timeout_s):
                    if not monitor.warm:
                        log.warning("workers not warm after %.0f s; ready anyway", now - started)
                    log.info("ready after %.1f s", now - started)
                    notify("READY=1")
                    ready = True
                if now - last_health >= setup.health_interval_s:
                    report = monitor.sample(restarts, now - last_data)
                    status = report.line()
                    log.info("health: %s", status)
                    notify(f"STATUS={status}")
                    health_pub.send(report)
                    if on_health is not None:
                        on_health(report)
                    last_health = now
                # The recorder's queue grows while the disk or the CPU is short (up to 500 frames a radar):
                # give the memory back after, or it stays with the process (188 MB in a four-radar soak).
                if now - last_trim >= 1.0:
                    release_free_heap()
                    last_trim = now
                # The watchdog says this loop runs: a hung daemon stops feeding it and systemd restarts it.
                # Sensors that send nothing are not the daemon's fault: health says they are idle, and
                # restarting would not bring them back.
                if watchdog_s and now - last_watchdog >= watchdog_s:
                    notify("WATCHDOG=1")
                    last_watchdog = now
                for role, proc in list(procs.items()):
                    if role in restart_at:
                        if now >= restart_at[role]:
                            del restart_at[role]
                            procs[role], started_at[role] = start(specs[role]), now
                        continue
                    if not proc.is_alive():
                        # A process that dies at start (a port taken, a device missing) would otherwise be
                        # restarted over and over as fast as it can die: back off, 0.5 s doubling to 30 s.
                        lived = now - started_at[role]
                        quick_failures[role] = quick_failures[role] + 1 if lived < MIN_UPTIME_S else 0
                        delay = min(0.5 * 2 ** (quick_failures[role] - 1), 30.0) if quick_failures[role] else 0.0
                        restarts += 1
                        message = (f"{role} exited with code {proc.exitcode} after {lived:.1f} s; restarting"
                                   + (f" in {delay:.1f} s" if delay else ""))
                        recorder.record_event(time.time_ns(), role, "error", message)
                        log.warning("%s", message)
                        restart_at[role] = now + delay
            notify("STOPPING=1")
            devices.stop(recorder.record_event)  # the radars stop sending before their drivers stop listening
            stop.set()
            stopped_at = time.monotonic()
            deadline = time.monotonic() + DRIVER_DRAIN_S
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
        def record_event_if_possible(*event):  # a full disk must not keep the devices running
            try:
                recorder.record_event(*event)
            except Exception:  # noqa: BLE001 - logged already by DeviceBringUp
                pass

        devices.stop(record_event_if_possible)
        if ptp is not None:
            ptp.stop()
        stop.set()
        # Workers finish their products (trajectory, map) after the drivers stop; a late one is hurried, then killed.
        stop_processes(procs, specs, setup, stopped_at or time.monotonic(), record_event_if_possible)
        recorder.close()
        health_pub.close()
        for s, h in old.items():
            signal.signal(s, h)
    log.info("recorded %s (%s frames, %d IMU samples%s, %d CAN frames, %d restarts)", ", ".join(map(str, recorder.paths)),
             recorder.frames, recorder.imu_samples,
             "".join(f", {n} from the IMU on {radar}" for radar, n in recorder.radar_imu_samples.items()),
             recorder.can_frames, restarts)
    if disk_full is not None:
        raise disk_full
    if devices.error is not None:
        raise devices.error
    return recorder.paths
