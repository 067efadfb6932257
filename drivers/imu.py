"""The IMU driver: Xsens MTData2 over a serial port, samples put on the PTP time base.

The IMU's own clock (SampleTimeFine, 10 kHz ticks, 32-bit) times every sample. The sync box's hardware
trigger, which also marks the first chirp of the run (PTP time ``trigger_time_ns``), sets the SyncIn bit
of the sample it coincides with, so:

    t_ptp(sample) = trigger_time_ns + (ticks(sample) - ticks(trigger sample)) * 100 us

Until the trigger is seen the samples have no PTP time and are held back (at most ``max_pending``).
The IMU clock's drift against the host clock is estimated by a line through (IMU time, host receive
time) and reported in parts per million.

The SyncIn mark is in one packet only. When that packet is lost (a checksum error on the line) and the
host time of the trigger is known (the first radar frame's receive time less its duration), the
trigger's tick is estimated from the same line instead, after ``syncin_grace_s``: the run keeps its IMU,
timed to within the serial latency (a few ms) rather than to a tick, and ``trigger_estimated`` says so.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np

from imaging.core.constants import TAI_MINUS_UTC_NS

from .xbus import SAMPLE_TIME_FINE_HZ, ImuPacket, XbusParser

log = logging.getLogger(f"sarbot.{__name__}")
TICK_NS = 1_000_000_000 // SAMPLE_TIME_FINE_HZ
#: The counter recorded for a sample whose packet had no packet counter (an IMU not configured to send one).
NO_COUNTER = 0xFFFFFFFF


@dataclasses.dataclass
class ImuSample:
    time_ns: int  # PTP time base
    gyro_radps: tuple[float, float, float]
    accel_mps2: tuple[float, float, float]
    counter: int  # NO_COUNTER when the packet carried none
    host_time_ns: int
    sync_in: bool


#: The IMU clock's drift is said (health, the recording) once its fit's standard error is below this: a crystal
#: drifts tens of ppm, a replay at another speed (the demo's 0.5x) 500,000.
MAX_DRIFT_SIGMA_PPM = 20.0


def lower_hull(x_s: np.ndarray, y_s: np.ndarray) -> np.ndarray:
    """Indices of the lower convex hull of the points (x, y), ``x`` increasing (Andrew's monotone chain)."""
    hull: list[int] = []
    for i in range(len(x_s)):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            # b is not below the chord a -> i: not on the lower hull
            if (y_s[b] - y_s[a]) * (x_s[i] - x_s[a]) >= (y_s[i] - y_s[a]) * (x_s[b] - x_s[a]):
                hull.pop()
            else:
                break
        hull.append(i)
    return np.asarray(hull, int)


def hull_edge_at_host(imu_s: np.ndarray, host_s: np.ndarray, at_host_s: float) -> tuple[float, ...] | None:
    """The two points (x0, y0, x1, y1) of the lower hull of (IMU time, receive time) whose line gives the IMU
    time of a sample received at ``at_host_s`` with the least delay seen; None when no part of the hull rises
    (all samples read at once).

    ``imu_s``, increasing, and ``host_s`` are the samples' IMU times and receive times (s, any common
    origins). Between two points of the hull's rising part the IMU time is read off the line through them,
    so its error is at most their delay beyond the fastest (a tenth of a millisecond on a quiet pty).
    Outside the hull's span it is the line through its first and last rising points."""
    hull = lower_hull(imu_s, host_s)
    hx, hy = imu_s[hull], host_s[hull]
    rising = np.flatnonzero(np.diff(hy) > 0)
    if rising.size == 0:
        return None
    # the hull is convex: once it rises it keeps rising
    hx, hy = hx[rising[0]:], hy[rising[0]:]
    k = int(np.searchsorted(hy, at_host_s))
    if 0 < k < len(hy):
        return float(hx[k - 1]), float(hy[k - 1]), float(hx[k]), float(hy[k])
    return float(hx[0]), float(hy[0]), float(hx[-1]), float(hy[-1])


class ImuClock:
    """Unwraps the 32-bit tick counter and maps ticks to PTP time once the trigger has been seen and its
    PTP time is known (``trigger_time_ns`` may be set later, e.g. from the first radar frame)."""

    def __init__(self, trigger_time_ns: int | None, trigger_ticks: int | None = None):
        """``trigger_ticks``: the (unwrapped) tick count of the trigger sample when it is already known, for a
        driver restarted mid-run (the IMU sends the SyncIn mark only once)."""
        self.trigger_time_ns = trigger_time_ns
        self.trigger_ticks: int | None = trigger_ticks
        self._last_raw: int | None = None
        self._wraps = 0 if trigger_ticks is None else trigger_ticks // 2**32
        self._fit_imu: list[float] = []
        self._fit_host: list[float] = []
        self._drift: tuple[int, float | None] = (-1, None)  # (samples when fitted, ppm)
        self.estimate_basis: tuple[int, float, int, float] | None = None  # see ticks_at_host

    def unwrap(self, raw: int) -> int:
        if self._last_raw is not None and raw < self._last_raw and self._last_raw - raw > 2**31:
            self._wraps += 1
        self._last_raw = raw
        return raw + self._wraps * 2**32

    def time_ns(self, ticks: int) -> int | None:
        if self.trigger_ticks is None or self.trigger_time_ns is None:
            return None
        return self.trigger_time_ns + (ticks - self.trigger_ticks) * TICK_NS

    def observe(self, ticks: int, host_time_ns: int) -> None:
        self._fit_imu.append(ticks * TICK_NS * 1e-9)
        self._fit_host.append(host_time_ns * 1e-9)
        if len(self._fit_imu) > 20000:
            del self._fit_imu[:10000], self._fit_host[:10000]

    def ticks_at_host(self, host_time_ns: int) -> int | None:
        """The IMU tick count at a host clock time, from the received samples (None with fewer than 50).

        Serial, USB and scheduling latency only ever delay a sample, so its receive time lies on or above
        the line (IMU time -> host time of an instant delay) and the samples that came through fastest
        carry the line. The estimate is the lower convex hull of (IMU time, receive time), read where it
        reaches ``host_time_ns``: between the two fastest samples either side, so a run of late stamps (a
        busy host reading several samples at once) does not tilt it. A least-squares slope through all
        samples did: with the samples before the first radar frame stamped 5-24 ms late it put the trigger
        up to a 100 Hz sample late. See docs/wire/xbus.md."""
        if len(self._fit_imu) < 50:
            return None
        x = np.asarray(self._fit_imu) - self._fit_imu[0]
        y = np.asarray(self._fit_host) - self._fit_host[0]
        at_s = host_time_ns * 1e-9 - self._fit_host[0]
        edge = hull_edge_at_host(x, y, at_s)
        if edge is None:
            return None
        x0, y0, x1, y1 = edge
        imu_s = x0 + (at_s - y0) * (x1 - x0) / (y1 - y0)
        # for the log: which samples it was read between, received how long from the host time asked
        self.estimate_basis = (round((x0 + self._fit_imu[0]) * 1e9 / TICK_NS), (y0 - at_s) * 1e3,
                               round((x1 + self._fit_imu[0]) * 1e9 / TICK_NS), (y1 - at_s) * 1e3)
        return int(round((imu_s + self._fit_imu[0]) * 1e9 / TICK_NS))

    def drift_ppm(self) -> float | None:
        """(host clock rate / IMU clock rate - 1) in ppm, from the receive times seen so far; None until the
        fit's standard error is below ``MAX_DRIFT_SIGMA_PPM`` (or 1 % of the value).

        Over a short span the receive jitter dominates: 1 ms of it over half a second is thousands of ppm,
        which a crystal never drifts, so such a value is not said at all. Refitted after every 400 new samples
        (about a second at 400 Hz): a fit over up to 20000 points on every serial read would cost the driver
        more than everything else it does."""
        n = len(self._fit_imu)
        if n < 50:
            return None
        if self._drift[0] >= 0 and 0 <= n - self._drift[0] < 400:
            return self._drift[1]
        self._drift = (n, self._fit_drift_ppm())
        return self._drift[1]

    def _fit_drift_ppm(self) -> float | None:
        x = np.asarray(self._fit_imu) - self._fit_imu[0]
        y = np.asarray(self._fit_host) - self._fit_host[0]
        if np.ptp(x) <= 0:
            return None
        (slope, _), cov = np.polyfit(x, y, 1, cov=True)
        ppm, sigma_ppm = float((slope - 1.0) * 1e6), math.sqrt(max(cov[0, 0], 0.0)) * 1e6
        # a clock at another rate (a replay) is plain long before its ppm are known to 20
        return ppm if sigma_ppm <= max(MAX_DRIFT_SIGMA_PPM, 0.01 * abs(ppm)) else None


class ImuDriver:
    """Reads a serial port (a real one, or a pty from the emulator) and yields timed samples."""

    def __init__(self, port: str, trigger_time_ns: int | None, baudrate: int = 921_600, max_pending: int = 100_000,
                 trigger_ticks: int | None = None, trigger_host_ns: int | None = None, syncin_grace_s: float = 1.0):
        """``trigger_host_ns``: the host clock time of the trigger, when known, for the estimate of its tick
        should the SyncIn packet be lost (see the module's notes)."""
        import serial

        self.serial = serial.Serial(port, baudrate=baudrate, timeout=0.05)
        self.parser = XbusParser()
        self.clock = ImuClock(trigger_time_ns, trigger_ticks)
        self._pending: list[tuple[ImuPacket, int, int]] = []
        self.max_pending = max_pending
        self.dropped_before_trigger = 0
        self.trigger_host_ns = trigger_host_ns
        self.syncin_grace_s = syncin_grace_s
        self.trigger_estimated = False
        self.host_clock = False  # see use_host_clock

    def read(self) -> list[ImuSample]:
        """Whatever has arrived (waits up to the port timeout for the first byte).

        The samples a read returns are stamped with its time: later than their bytes arrived when it took
        several at once, never earlier, which the trigger estimate relies on (``ImuClock.ticks_at_host``)."""
        chunk = self.serial.read(max(1, self.serial.in_waiting))
        host = time.time_ns()
        out = []
        for packet in self.parser.feed(chunk):
            if packet.sample_time_fine is None or packet.accel_mps2 is None or packet.gyro_radps is None:
                continue
            ticks = self.clock.unwrap(packet.sample_time_fine)
            self.clock.observe(ticks, host)
            if self.host_clock and self.clock.trigger_ticks is None:
                self.clock.trigger_ticks = ticks
                self.clock.trigger_time_ns = host + TAI_MINUS_UTC_NS
            if packet.sync_in and self.clock.trigger_ticks is None:
                self.clock.trigger_ticks = ticks
                log.info("IMU: trigger seen at tick %d; %d samples before it are dropped", ticks, len(self._pending))
                self.dropped_before_trigger += len(self._pending)
                self._pending.clear()
                if self.clock.trigger_time_ns is None:
                    self._pending.append((packet, ticks, host))
                    continue
            if self.clock.trigger_ticks is None or self.clock.trigger_time_ns is None:
                self._pending.append((packet, ticks, host))
                if len(self._pending) > self.max_pending:
                    self._pending.pop(0)
                    self.dropped_before_trigger += 1
                continue
            out += self._release_pending()
            out.append(self._sample(packet, ticks, host))
        if self.clock.trigger_ticks is None and self.trigger_host_ns is not None \
                and host - self.trigger_host_ns > self.syncin_grace_s * 1e9:
            self._estimate_trigger_ticks()
        if self._pending and self.clock.trigger_ticks is not None and self.clock.trigger_time_ns is not None:
            out += self._release_pending()
        return out

    def _estimate_trigger_ticks(self) -> None:
        ticks = self.clock.ticks_at_host(self.trigger_host_ns)
        if ticks is None:
            return
        self.clock.trigger_ticks = ticks
        self.trigger_estimated = True
        log.warning("IMU: no SyncIn mark %.1f s after the trigger (its packet lost?): trigger tick %d estimated "
                    "from the receive times, between the samples at ticks %d and %d (received %+.1f and %+.1f ms "
                    "from the trigger's host time)", self.syncin_grace_s, ticks, *self.clock.estimate_basis[::2],
                    *self.clock.estimate_basis[1::2])

    def use_host_clock(self) -> None:
        """Time the samples on the host clock: with no radar there is no first chirp, so no trigger time to
        tie the IMU to. The first sample read is put at its receive time (CLOCK_REALTIME + TAI-UTC, so the
        times stay on the PTP scale, good to the serial latency); the others follow it by their ticks."""
        self.host_clock = True

    def set_trigger_time(self, trigger_time_ns: int, host_time_ns: int | None = None) -> None:
        """The PTP time of the trigger, when it becomes known after the IMU started (first radar frame), and
        its host clock time if known (for the estimate of its tick should the SyncIn packet be lost)."""
        self.clock.trigger_time_ns = int(trigger_time_ns)
        if host_time_ns is not None:
            self.trigger_host_ns = int(host_time_ns)

    def _release_pending(self) -> list[ImuSample]:
        pending, self._pending = self._pending, []
        timed = [self._sample(p, t, h) for p, t, h in pending if t >= self.clock.trigger_ticks]
        self.dropped_before_trigger += len(pending) - len(timed)
        return timed

    def _sample(self, packet: ImuPacket, ticks: int, host: int) -> ImuSample:
        return ImuSample(self.clock.time_ns(ticks), packet.gyro_radps, packet.accel_mps2,
                         packet.counter if packet.counter is not None else NO_COUNTER, host, packet.sync_in)

    def close(self) -> None:
        self.serial.close()
