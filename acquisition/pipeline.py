"""The acquisition loops, as functions a process (or a thread in tests) runs until told to stop:
radar driver (UDP -> SRF1 or DCA1000 frames -> bus), IMU driver (serial -> samples -> bus), CAN driver
(python-can -> frames -> bus), and replay (recording -> emulated hardware on the wire)."""

from __future__ import annotations

import logging
import socket
import threading
import time

import numpy as np

from drivers.can_driver import CanDriver, message_from_row
from drivers.dca1000 import encode_data_packets, iq_to_complex_1x
from drivers.emulators import XbusPty
from drivers.imu import ImuDriver
from drivers.pcap import read_udp
from drivers.radar_stream import trouble
from drivers.srf1 import encode_frame
from drivers.udp import UdpReceiver
from imaging.io.recording import Recording

from .bus import BusPublisher
from .recorder import publish_frame

log = logging.getLogger(__name__)


def radar_driver_loop(receiver: UdpReceiver, radar: str, stream, pub: BusPublisher, stop: threading.Event,
                      report_every_s: float = 1.0):
    """Receive datagrams, reassemble frames with ``stream`` (a ``drivers.radar_stream`` object), publish
    each frame; wire trouble and kernel drops are published as events. Returns the stream."""
    reported = trouble(stream.counters)
    last_report = time.monotonic()
    kernel_drops = 0

    def report(now_ns: int) -> None:
        nonlocal reported
        now = trouble(stream.counters)
        changes = {k: now[k] - reported[k] for k in now if now[k] != reported[k]}
        if changes:
            pub.publish("event", now_ns, source=f"radar.{radar}", level="warning",
                        message=", ".join(f"{k} +{v}" for k, v in changes.items()))
        reported = now

    while not stop.is_set():
        got = receiver.receive()
        if got is None:
            continue
        data, t_ns, drops = got
        if drops > kernel_drops:
            pub.publish("event", t_ns, source=f"radar.{radar}", level="error",
                        message=f"kernel dropped {drops - kernel_drops} datagram(s) (socket buffer full)")
            kernel_drops = drops
        for frame in stream.feed(data, t_ns):
            publish_frame(pub, radar, frame)
            if not frame.valid:
                report(t_ns)
        if time.monotonic() - last_report > report_every_s:
            report(time.time_ns())
            last_report = time.monotonic()
    for frame in stream.flush():
        publish_frame(pub, radar, frame)
    report(time.time_ns())
    return stream


def can_driver_loop(driver: CanDriver, pub: BusPublisher, stop: threading.Event) -> None:
    """Read CAN frames, publish them in batches raw, and each sync-box trigger frame as a trigger."""
    while not stop.is_set():
        frames, triggers = driver.read(timeout_s=0.05)
        for t in triggers:
            pub.publish("trigger", t, source="can")
        if len(frames):
            pub.publish("can", int(frames.time_ns[0]), [frames.time_ns, frames.arbitration_id, frames.dlc, frames.data])


def imu_driver_loop(driver: ImuDriver, pub: BusPublisher, stop: threading.Event) -> None:
    """Read the IMU, publish batches of timed samples (and the trigger once seen)."""
    trigger_sent = False
    while not stop.is_set():
        samples = driver.read()
        if not samples:
            continue
        if not trigger_sent and driver.clock.trigger_ticks is not None:
            pub.publish("trigger", driver.clock.trigger_time_ns, source="imu_syncin")
            trigger_sent = True
        publish_imu_samples(pub, samples, driver.clock.drift_ppm())


def publish_imu_samples(pub: BusPublisher, samples, clock_drift_ppm: float | None = None) -> None:
    """A batch of timed IMU samples onto the bus as the recorder stores them: times, gyro, accel,
    counters, host times; the header carries the IMU clock's drift against the host clock."""
    if not samples:
        return
    pub.publish("imu", samples[0].time_ns, [
        np.array([s.time_ns for s in samples], np.int64), np.array([s.gyro_radps for s in samples]),
        np.array([s.accel_mps2 for s in samples]), np.array([s.counter for s in samples], np.uint32),
        np.array([s.host_time_ns for s in samples], np.int64)], clock_drift_ppm=clock_drift_ppm)


def _wait_until(start_monotonic: float, offset_ns: int, speed: float | None) -> None:
    """Sleep until ``offset_ns`` of recording time after ``start_monotonic``, at ``speed`` x real time (None or
    0: do not wait)."""
    if speed:
        wait = start_monotonic + offset_ns * 1e-9 / speed - time.monotonic()
        if wait > 0:
            time.sleep(wait)


def replay_radar(recording: Recording, radar: str, address, speed: float | None = 1.0, radar_id: int = 0,
                 start_monotonic: float | None = None) -> int:
    """Send a radar's frames to ``address`` in the wire format it was recorded in (SRF1 datagrams, or the
    DCA1000 byte stream) at the recorded frame timing (x ``speed``; None or 0: as fast as the receiver
    keeps up). ``start_monotonic``: when the first frame goes out (time.monotonic(), which all processes of a
    Linux machine share), so several radars replayed by several processes stay in step. Returns the number of
    datagrams sent."""
    times = recording.frame_time_ns(radar)
    counters = recording.file[f"radar/{radar}/frame_counter"][()]
    dca1000 = recording.file[f"radar/{radar}"].attrs.get("wire_format", "SRF1") == "DCA1000"
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
    t0 = time.monotonic() if start_monotonic is None else start_monotonic
    sent = 0
    seq = 1
    stream_bytes = 0
    for k in range(times.size):
        _wait_until(t0, times[k] - times[0], speed)
        iq = recording.adc_iq(radar, slice(k, k + 1))[0]
        if dca1000:
            wire = iq_to_complex_1x(iq)
            datagrams = encode_data_packets(wire, start_seq=seq, start_byte=stream_bytes)
            seq += len(datagrams)
            stream_bytes += len(wire)
        else:
            datagrams = encode_frame(radar_id, int(counters[k]), int(times[k]), iq)
        for d in datagrams:
            sock.sendto(d, address)
            sent += 1
        if not speed:
            time.sleep(0.0005)  # as fast as the receiver keeps up on loopback
    sock.close()
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


def imu_emulator(recording: Recording, speed: float | None = 1.0) -> XbusPty:
    """An Xsens IMU on a pty replaying the recording's /imu; the first sample carries the trigger."""
    imu = recording.imu()
    return XbusPty(imu["gyro_radps"], imu["accel_mps2"], rate_hz=float(imu["rate_hz"]), trigger_index=0, speed=speed,
                   start_counter=int(imu["counter"][0]))
