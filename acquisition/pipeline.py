"""The acquisition loops, as functions a process (or a thread in tests) runs until told to stop:
radar driver (UDP -> SRF1 frames -> bus), IMU driver (serial -> samples -> bus), and replay
(recording -> emulated hardware on the wire)."""

from __future__ import annotations

import logging
import socket
import threading
import time

import numpy as np

from drivers.emulators import XbusPty
from drivers.imu import ImuDriver
from drivers.srf1 import FrameAssembler, encode_frame
from drivers.udp import UdpReceiver
from imaging.recording import Recording

from .bus import BusPublisher
from .recorder import publish_frame

log = logging.getLogger(__name__)


def radar_driver_loop(receiver: UdpReceiver, radar: str, shape: tuple[int, ...], pub: BusPublisher,
                      stop: threading.Event, radar_id: int | None = None, report_every_s: float = 1.0) -> FrameAssembler:
    """Receive SRF1 datagrams, reassemble frames, publish each; loss is published as events."""
    frame_bytes = int(np.prod(shape)) * 2
    asm = FrameAssembler(frame_bytes, radar_id=radar_id)
    reported = dict(vars(asm.counters))
    last_report = time.monotonic()
    kernel_drops = 0

    def report(now_ns: int) -> None:
        nonlocal reported
        now = dict(vars(asm.counters))
        changes = {k: now[k] - reported[k] for k in ("malformed", "truncated", "duplicates", "frames_incomplete",
                                                       "frames_skipped", "bytes_lost", "resyncs") if now[k] != reported[k]}
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
        for frame in asm.feed(data, t_ns):
            publish_frame(pub, radar, frame, shape)
            if not frame.valid:
                report(t_ns)
        if time.monotonic() - last_report > report_every_s:
            report(time.time_ns())
            last_report = time.monotonic()
    for frame in asm.flush():
        publish_frame(pub, radar, frame, shape)
    report(time.time_ns())
    return asm


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
        publish_imu_samples(pub, samples)


def publish_imu_samples(pub: BusPublisher, samples) -> None:
    """A batch of timed IMU samples onto the bus as the recorder stores them: times, gyro, accel,
    counters, host times."""
    if not samples:
        return
    pub.publish("imu", samples[0].time_ns, [
        np.array([s.time_ns for s in samples], np.int64), np.array([s.gyro_radps for s in samples]),
        np.array([s.accel_mps2 for s in samples]), np.array([s.counter for s in samples], np.uint32),
        np.array([s.host_time_ns for s in samples], np.int64)])


def replay_radar(recording: Recording, radar: str, address, speed: float | None = 1.0, radar_id: int = 0) -> int:
    """Send a radar's frames as SRF1 datagrams to ``address`` at the recorded frame timing (x speed)."""
    times = recording.frame_time_ns(radar)
    counters = recording.file[f"radar/{radar}/frame_counter"][()]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
    t0 = time.monotonic()
    sent = 0
    for k in range(times.size):
        if speed:
            wait = t0 + (times[k] - times[0]) * 1e-9 / speed - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        adc = recording.adc(radar, slice(k, k + 1))[0]
        iq = np.stack([adc.real, adc.imag], axis=-1).astype(np.int16)
        for d in encode_frame(radar_id, int(counters[k]), int(times[k]), iq):
            sock.sendto(d, address)
            sent += 1
        if speed is None:
            time.sleep(0.0005)  # as fast as the receiver keeps up on loopback
    sock.close()
    return sent


def imu_emulator(recording: Recording, speed: float | None = 1.0) -> XbusPty:
    """An Xsens IMU on a pty replaying the recording's /imu; the first sample carries the trigger."""
    imu = recording.imu()
    return XbusPty(imu["gyro_radps"], imu["accel_mps2"], rate_hz=float(imu["rate_hz"]), trigger_index=0, speed=speed,
                   start_counter=int(imu["counter"][0]))
