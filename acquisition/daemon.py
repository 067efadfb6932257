"""The acquisition daemon: one process per device, the recorder in the supervising process.

``record`` starts a radar driver process per radar (UDP -> SRF1 frames -> bus) and an IMU driver process
(serial -> samples -> bus), records everything on the bus, restarts a driver that dies (and writes that to
/events), and stops on SIGINT/SIGTERM or after ``duration_s``. ``replay`` sends a recording back through
emulated hardware: SRF1 datagrams on UDP, Xbus bytes on a pseudo-terminal.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import socket
import threading
import time
from pathlib import Path


from imaging.recording import Recording
from imaging.rig import Rig

from .sdnotify import notify, watchdog_interval_s

log = logging.getLogger("sarbot.daemon")


def free_tcp_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


def _radar_main(name: str, shape, host: str, port: int, endpoint: str, stop) -> None:
    from drivers.udp import UdpReceiver

    from .bus import BusPublisher
    from .pipeline import radar_driver_loop

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the supervisor decides when to stop
    rx = UdpReceiver(host, port)
    pub = BusPublisher(endpoint)
    try:
        radar_driver_loop(rx, name, tuple(shape), pub, stop)
    finally:
        rx.close()
        pub.close()


def _imu_main(port: str, endpoint: str, radar_endpoints: list[str], stop) -> None:
    from drivers.imu import ImuDriver

    from .bus import BusPublisher, BusSubscriber
    from .pipeline import publish_imu_samples

    signal.signal(signal.SIGINT, signal.SIG_IGN)
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
                msg = sub.receive(timeout_ms=0)
                if msg is not None:
                    trigger_time = int(msg.header["frame_time_ns"])
                    driver.set_trigger_time(trigger_time)
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
            publish_imu_samples(pub, samples)
    finally:
        if driver is not None:
            driver.close()
        pub.close()
        if sub is not None:
            sub.close()


def record(rig: Rig, out_dir: Path, radar_ports: dict[str, int], imu_port: str | None, duration_s: float | None = None,
           host: str = "127.0.0.1", flush_interval_s: float = 0.5, health_interval_s: float = 2.0) -> Path:
    """Run drivers and recorder until a signal or ``duration_s``; returns the recording's path."""
    from .recorder import Recorder

    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / time.strftime("recording_%Y%m%dT%H%M%S.h5")
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    specs = {}
    for name, port in radar_ports.items():
        wf = rig.radar(name).waveform
        shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)
        specs[f"radar.{name}"] = (_radar_main, (name, shape, host, port, free_tcp_endpoint(), stop))
    radar_endpoints = [args[4] for _, args in specs.values()]
    if imu_port:
        specs["imu"] = (_imu_main, (imu_port, free_tcp_endpoint(), radar_endpoints, stop))
    endpoints = radar_endpoints + ([specs["imu"][1][1]] if imu_port else [])
    procs = {}
    for role, (target, args) in specs.items():
        procs[role] = ctx.Process(target=target, args=args, name=role, daemon=True)
        procs[role].start()
    recorder = Recorder(path, rig, endpoints, flush_interval_s=flush_interval_s)
    stopping = threading.Event()

    def on_signal(signum, frame):
        stopping.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    t_end = time.monotonic() + duration_s if duration_s else None
    restarts = 0
    notify("READY=1")
    watchdog_s = watchdog_interval_s()
    last_health = last_watchdog = time.monotonic()
    counts_before = (dict(recorder.frames), recorder.imu_samples)
    flowing = False
    try:
        while not stopping.is_set() and (t_end is None or time.monotonic() < t_end):
            if recorder.step(timeout_ms=50):
                flowing = True
            now = time.monotonic()
            if now - last_health >= health_interval_s:
                frames, imu_n = counts_before
                rates = {n: (recorder.frames[n] - frames.get(n, 0)) / (now - last_health) for n in recorder.frames}
                imu_rate = (recorder.imu_samples - imu_n) / (now - last_health)
                lost = sum(st.missed for st in recorder.sub.stats.values())
                status = ", ".join(f"{n} {r:.1f} frames/s" for n, r in rates.items()) + f", IMU {imu_rate:.0f} Hz, bus lost {lost}, restarts {restarts}"
                log.info("health: %s", status)
                notify(f"STATUS={status}")
                counts_before = (dict(recorder.frames), recorder.imu_samples)
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
    finally:
        for proc in procs.values():
            proc.join(2)
            if proc.is_alive():
                proc.kill()
        recorder.close()
        for s, h in old.items():
            signal.signal(s, h)
    log.info("recorded %s (%s frames, %d IMU samples, %d driver restarts)", path, recorder.frames, recorder.imu_samples, restarts)
    return path


def replay(path: Path, radar_targets: dict[str, tuple[str, int]], imu_link: str | None, speed: float | None,
           start_delay_s: float = 0.0) -> dict:
    """Send a recording through emulated hardware; returns what was sent."""
    from .pipeline import imu_emulator, replay_radar

    with Recording(path) as rec:
        emu = None
        if imu_link:
            emu = imu_emulator(rec, speed=speed)
            link = Path(imu_link)
            if link.is_symlink() or link.exists():
                link.unlink()
            link.symlink_to(emu.port)
        time.sleep(start_delay_s)
        if emu is not None:
            emu.start()
        sent = {}
        threads = []
        for name, address in radar_targets.items():
            t = threading.Thread(target=lambda n=name, a=address: sent.__setitem__(n, replay_radar(rec, n, a, speed)))
            threads.append(t)
            t.start()
        for t in threads:
            t.join()
        if emu is not None:
            emu.done.wait()
            time.sleep(0.5)  # let the reader drain the pty
            emu.close()
            Path(imu_link).unlink(missing_ok=True)
    return sent
