"""Emulated hardware for replay and tests, at the wire level: the drivers cannot tell it from the real thing."""

from __future__ import annotations

import os
import select
import threading
import time
import tty

import numpy as np

from .xbus import STATUS_SYNC_IN, ImuPacket, encode_mtdata2


def close_fds(*fds: int) -> None:
    """Close a pseudo-terminal's ends (or any descriptors), whichever are still open."""
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass


class XbusPty:
    """An Xsens IMU on a pseudo-terminal: writes MTData2 packets to the master end; ``port`` is the device
    path a driver opens like a serial port.

    Parameters
    ----------
    gyro_radps, accel_mps2 : ndarray, shape (N, 3)
    rate_hz : float
        Sample rate; the sample time advances by 10000 / rate_hz ticks per sample.
    trigger_index : int
        Sample that carries the SyncIn marker (the hardware trigger of the first chirp).
    speed : float or None
        Multiple of real time; None for as fast as the pty takes it.
    noise : callable(k) -> bytes, optional
        Bytes to write before packet k (line noise in tests).
    start_counter : int or None
        Packet counter of the first packet; None for an IMU configured without a packet counter.
    stall_timeout_s : float
        The emulator stops (``failure`` says why) when nobody has read the pty for this long.
    """

    def __init__(self, gyro_radps, accel_mps2, rate_hz: float, trigger_index: int = 0, start_ticks: int = 123_456,
                 speed: float | None = None, noise=None, start_counter: int | None = 0, stall_timeout_s: float = 5.0):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.gyro = np.asarray(gyro_radps, float)
        self.accel = np.asarray(accel_mps2, float)
        self.rate_hz = rate_hz
        self.trigger_index = trigger_index
        self.start_ticks = start_ticks
        self.speed = speed
        self.noise = noise
        self.start_counter = start_counter
        self.stall_timeout_s = stall_timeout_s
        self.failure: str | None = None  # why the emulator stopped early
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.done = threading.Event()

    def packet(self, k: int) -> bytes:
        ticks = self.start_ticks + round(k * 10_000 / self.rate_hz)
        counter = None if self.start_counter is None else (self.start_counter + k) & 0xFFFF
        return encode_mtdata2(ImuPacket(counter=counter, sample_time_fine=ticks & 0xFFFFFFFF,
                                        accel_mps2=tuple(self.accel[k]), gyro_radps=tuple(self.gyro[k]),
                                        status=STATUS_SYNC_IN if k == self.trigger_index else 0))

    def start(self) -> "XbusPty":
        self._thread.start()
        return self

    def _run(self) -> None:
        t0 = time.monotonic()
        for k in range(len(self.gyro)):
            if self.speed:
                wait = t0 + k / (self.rate_hz * self.speed) - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            data = (self.noise(k) if self.noise else b"") + self.packet(k)
            view = memoryview(data)
            while view:
                # The pty's buffer fills when nobody reads it: give up then instead of blocking for ever.
                if not select.select([], [self.master], [], self.stall_timeout_s)[1]:
                    self.failure = (f"nobody reads the IMU pty {self.port}: stalled {self.stall_timeout_s:g} s "
                                    f"at sample {k} of {len(self.gyro)}")
                    self.done.set()
                    return
                n = os.write(self.master, view)
                view = view[n:]
        self.done.set()

    def close(self) -> None:
        self._thread.join(timeout=5)
        close_fds(self.master, self.slave)
