"""Replay: a recording sent back through emulated hardware, as the robot's sensors would send it.

Each radar's frames go out as datagrams of the wire format it was recorded in (looked up in
``drivers.radar.registry``) on UDP, one sender process per radar; the IMU as Xbus bytes on a
pseudo-terminal; /can on a python-can bus. The drivers cannot tell it from the real thing.
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

from drivers.can_driver import CanConfig, message_from_row
from drivers.emulators import XbusPty
from drivers.radar import registry
from drivers.radar.pcap import read_udp
from drivers.radar.udp import UdpSender
from imaging.core.constants import TAI_MINUS_UTC_NS
from imaging.core.errors import SarbotError
from imaging.io.recording import Recording

from .replay_frames import LapFrames

log = logging.getLogger(f"sarbot.{__name__}")


def _wait_until(start_monotonic: float, offset_ns: int, speed: float | None) -> None:
    """Sleep until ``offset_ns`` of recording time after ``start_monotonic``, at ``speed`` x real time (None or
    0: do not wait)."""
    if speed:
        wait = start_monotonic + offset_ns * 1e-9 / speed - time.monotonic()
        if wait > 0:
            time.sleep(wait)


def lap_duration_ns(recording: Recording, radars) -> int:
    """How long one lap of a looped replay lasts: the longest radar's span plus one frame interval, so the
    next lap's first frame comes one interval after this lap's last."""
    spans = []
    for name in radars:
        times = recording.frame_time_ns(name)
        if times.size >= 2:
            spans.append(int(times[-1] - times[0]) + int(np.median(np.diff(times))))
    return max(spans, default=0)


def replay_radar(recording: Recording, radar: str, address, speed: float | None = 1.0, radar_id: int = 0,
                 start_monotonic: float | None = None, laps: int = 1, lap_ns: int = 0) -> int:
    """Send a radar's frames to ``address`` in the wire format it was recorded in, at the recorded frame
    timing (x ``speed``; None or 0: as fast as the receiver keeps up). ``start_monotonic``: when the first
    frame goes out (time.monotonic(), which all processes of a Linux machine share), so several radars
    replayed by several processes stay in step. ``laps`` > 1 sends the frames again and again, each lap
    ``lap_ns`` later than the one before and its frame counters continuing the last. Returns the number of
    datagrams sent."""
    times = recording.frame_time_ns(radar)
    counters = recording.frame_counter(radar)
    wire_format = registry.for_replay(recording.wire_format(radar), f"{recording.path}: /radar/{radar}")
    # Packed where the format can: a frame in a few system calls, not one per datagram (drivers.radar.udp).
    encode_packed = wire_format.open_packed_encoder(radar_id) if wire_format.open_packed_encoder else None
    encode = None if encode_packed else wire_format.open_encoder(radar_id)
    frames = LapFrames(recording, radar, laps)
    sender = UdpSender()
    t0 = time.monotonic() if start_monotonic is None else start_monotonic
    sent = 0
    counters_per_lap = int(counters[-1] - counters[0]) + 1 if counters.size else 0
    try:
        for lap in range(laps):
            for k in range(times.size):
                t = int(times[k]) + lap * lap_ns
                _wait_until(t0, t - times[0], speed)
                counter = (int(counters[k]) + lap * counters_per_lap) & 0xFFFFFFFF
                iq = frames.read(lap, k)
                if encode_packed is not None:
                    sent += sender.send(encode_packed(counter, t, iq, frame_key=k), address)
                else:
                    for d in encode(counter, t, iq):
                        sender.sendto(d, address)
                        sent += 1
                if not speed:
                    time.sleep(0.0005)  # as fast as the receiver keeps up on loopback
    finally:
        sender.close()
    return sent


def replay_can(recording: Recording, bus, speed: float | None = 1.0, t0_ns: int | None = None) -> int:
    """Send /can frames on a python-can bus with their recorded spacing (x ``speed``). ``t0_ns`` is the
    recording time that maps to now (default: the first frame); returns the number sent."""
    rows = recording.can()
    if rows["time_ns"].size == 0:
        return 0
    t_ref = rows["time_ns"][0] if t0_ns is None else t0_ns
    start = time.monotonic()
    for t, ident, dlc, data in zip(rows["time_ns"], rows["arbitration_id"], rows["dlc"], rows["data"]):
        _wait_until(start, t - t_ref, speed)
        bus.send(message_from_row(ident, dlc, data))
    return int(rows["time_ns"].size)


def replay_pcap(path, address, dst_port: int, speed: float | None = 1.0) -> int:
    """Send the UDP payloads of a capture to ``dst_port`` in it on to ``address``, with their captured spacing."""
    datagrams = [d for d in read_udp(path) if d.dst_port == dst_port]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        start = time.monotonic()
        for d in datagrams:
            _wait_until(start, d.time_ns - datagrams[0].time_ns, speed)
            sock.sendto(d.payload, address)
    return len(datagrams)


def imu_emulator(recording: Recording, speed: float | None = 1.0, laps: int = 1, lap_ns: int = 0,
                 radar: str | None = None) -> XbusPty:
    """An Xsens IMU on a pty replaying the recording's /imu (or with ``radar`` the IMU on that radar's mount,
    /radar/<radar>/imu); the first sample carries the trigger. With ``laps`` > 1 each lap lasts ``lap_ns``:
    the samples of one lap, cut or padded with the last sample (the drive ends at rest) to the lap's length,
    so the IMU's clock keeps in step with the radars'."""
    if radar is None:
        imu = recording.imu()
        rate = float(imu["rate_hz"])
    else:
        imu = recording.radar_imu(radar)
        rate = recording.radar(radar).imu.rate_hz
    gyro, accel = imu["gyro_radps"], imu["accel_mps2"]
    if laps > 1:
        n = int(round(lap_ns * 1e-9 * rate))
        take = np.minimum(np.arange(n), len(gyro) - 1)
        gyro, accel = np.tile(gyro[take], (laps, 1)), np.tile(accel[take], (laps, 1))
    return XbusPty(gyro, accel, rate_hz=rate, trigger_index=0, speed=speed, start_counter=int(imu["counter"][0]))


def _radar_sender_process(path: str, name: str, address, speed, go, start, results, laps: int, lap_ns: int) -> None:
    from .processes import die_with_parent

    die_with_parent(f"replay-{name}")  # a replay stopped by SIGTERM took none of its senders with it
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with Recording(path) as rec:
            results.put((name, "ready"))
            go.wait()
            results.put((name, replay_radar(rec, name, tuple(address), speed, start_monotonic=start.value, laps=laps,
                                            lap_ns=lap_ns)))
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which names the radar
        results.put((name, f"{type(exc).__name__}: {exc}"))


def _link_to_pty(link: Path, option: str) -> None:
    """Make way for a link to an emulator's pty at ``link``: only a link an earlier replay left (to a
    pseudo-terminal) is replaced; never a real file."""
    if link.exists() or link.is_symlink():
        if not (link.is_symlink() and os.readlink(link).startswith("/dev/pts/")):
            raise SarbotError(f"{option} {link}: exists and is not a link to a pseudo-terminal; give a path that does not exist")
        link.unlink()


#: Longest the emulated devices wait for ``DevicesHeld.go`` or ``DevicesHeld.release``, s.
MAX_HOLD_S = 900.0


@dataclasses.dataclass
class DevicesHeld:
    """Events (``multiprocessing`` ones, for a replay in a process of its own) that keep the emulated devices
    plugged in around the sending, as a robot's are: the IMU's pty and the CAN bus are up before anything is
    sent, and the sending waits for ``go`` (the reader is ready); ``sent`` is set once everything is sent;
    the devices stay until ``release`` is set (the reader has stopped), so that a reader started first and
    stopped last sees neither a missing device nor one unplugged. Each wait lasts ``MAX_HOLD_S`` at most."""

    go: object
    sent: object
    release: object


#: How long ``bound_port`` waits for a driver to bind, s.
BIND_WAIT_S = 60.0


def bound_port(port) -> int:
    """A target's UDP port: a number, or a shared integer (``multiprocessing`` Value) a driver that bound port 0
    writes its port to (``acquisition.daemon.Setup.bound_ports``), read once it is there."""
    if isinstance(port, int):
        return port
    deadline = time.monotonic() + BIND_WAIT_S
    while not port.value:
        if time.monotonic() > deadline:
            raise SarbotError(f"a radar driver did not bind its port within {BIND_WAIT_S:g} s")
        time.sleep(0.05)
    return int(port.value)


def replay(path: Path, radar_targets: dict[str, tuple[str, int]], imu_link: str | None, speed: float | None,
           start_delay_s: float = 0.0, can: CanConfig | None = None, laps: int = 1,
           radar_imu_links: dict[str, str] | None = None, held: DevicesHeld | None = None) -> dict:
    """Send a recording through emulated hardware: each radar's datagrams (in the wire format it was
    recorded in) to its UDP address, the IMU as Xbus bytes on a pty that ``imu_link`` points to (and each
    IMU on a radar's mount on a pty of its own, ``radar_imu_links``: radar -> link), and /can on
    a python-can bus. ``laps`` > 1: the drive again and again, back to back, times and counters
    continuing (a soak test; the drive should end where and as it started, at rest). ``held``: the devices
    up before the sending and after it until released (``DevicesHeld``); a target's port may be a driver's
    bound port, read once they go (``bound_port``). Returns what was sent
    ({radar: datagrams, "can": frames})."""
    if laps < 1:
        raise SarbotError(f"--laps: must be at least 1, got {laps}")
    with Recording(path) as rec:
        for name in radar_targets:
            if name not in rec.radar_names:
                raise SarbotError(f"--radar {name}: {path} has no such radar (radars: {', '.join(rec.radar_names)})")
        if laps > 1 and can is not None:
            raise SarbotError("--laps: CAN cannot be replayed in laps (its frames carry no time to move on)")
        lap_ns = lap_duration_ns(rec, radar_targets) if laps > 1 else 0
        emulators: dict[str, tuple[XbusPty, Path]] = {}  # "IMU" or "IMU of radar NAME" -> emulator, its link
        if imu_link:
            if rec.imu_sample_count() == 0:
                raise SarbotError(f"--imu-link: {path} has no IMU samples to replay")
            _link_to_pty(Path(imu_link), "--imu-link")
        for name, link in (radar_imu_links or {}).items():
            if name not in rec.radar_names:
                raise SarbotError(f"--radar-imu-link {name}: {path} has no such radar (radars: {', '.join(rec.radar_names)})")
            if rec.imu_sample_count(name) == 0:
                raise SarbotError(f"--radar-imu-link {name}: {path} has no samples of an IMU on radar {name} to replay")
            _link_to_pty(Path(link), "--radar-imu-link")
        if imu_link:
            emulators["IMU"] = (imu_emulator(rec, speed=speed, laps=laps, lap_ns=lap_ns), Path(imu_link))
        for name, link in (radar_imu_links or {}).items():
            emulators[f"IMU of radar {name}"] = (imu_emulator(rec, speed=speed, laps=laps, lap_ns=lap_ns, radar=name), Path(link))
        for emu, link in emulators.values():
            link.symlink_to(emu.port)
        can_bus = can.open() if can is not None else None
        if held is not None:
            held.go.wait(MAX_HOLD_S)
        radar_targets = {name: (host, bound_port(port)) for name, (host, port) in radar_targets.items()}
        time.sleep(start_delay_s)
        sent = {}
        failures = []

        def send_can(t0_ns):
            try:
                sent["can"] = replay_can(rec, can_bus, speed, t0_ns)
            except Exception as exc:  # noqa: BLE001 - reported below, after the radars finish
                failures.append(f"can: {exc}")

        # One process per radar, as on the robot: threads would share one interpreter with the IMU
        # emulator, and its 400 Hz packets would come late whenever the radars send a frame.
        ctx = mp.get_context("spawn")
        results = ctx.Queue()
        go = ctx.Event()
        start = ctx.Value("d", 0.0)  # the senders' common start (time.monotonic() is shared by all processes)
        procs = {name: ctx.Process(target=_radar_sender_process, args=(str(path), name, address, speed, go, start, results,
                                                                                   laps, lap_ns),
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
            # /can times are receive times on the host clock (+ TAI-UTC); a radar's frame times are its own
            # clock's (PTP, or a simulation's). The radars' recorded receive times tie the two together.
            firsts = [int(rec.host_time_ns(n)[0]) + TAI_MINUS_UTC_NS for n in radar_targets if rec.n_frames(n)]
            can_thread = threading.Thread(target=send_can, args=(min(firsts) if firsts else None,))
        if emulators:
            time.sleep(max(start.value - time.monotonic(), 0.0))
            for emu, _ in emulators.values():
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
            except Exception:  # noqa: BLE001 - queue.Empty: a sender died without a word (its exit code is above)
                break
            if isinstance(value, str):
                failures.append(f"{key}: {value}")
            else:
                sent[key] = value
        if can_thread is not None:
            can_thread.join()
            time.sleep(0.2)  # frames still in flight on the emulated bus
            can_bus.shutdown()
        for emu, _ in emulators.values():
            emu.done.wait()
        if emulators:
            time.sleep(0.5)  # let the readers drain the ptys
        if held is not None:
            held.sent.set()
            held.release.wait(MAX_HOLD_S)
        for label, (emu, link) in emulators.items():
            emu.close()
            if emu.failure:
                failures.append(f"{label}: {emu.failure}")
            if link.is_symlink() and os.readlink(link) == emu.port:  # ours still: take it away
                link.unlink()
    if failures:
        raise SarbotError("replay failed: " + "; ".join(failures))
    return sent
