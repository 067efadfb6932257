"""Radar-inertial odometry as the data arrives: the same filter and updates as ``run_rio``, fed in pieces.

IMU batches and radar scans come in whatever order the bus delivers them. A radar scan reaches the bus a
frame or more after its measurement time (it is formed from a whole frame), and a busy consumer falls
further behind on the radar (a frame is 0.7 MB, an IMU batch 1 kB): the IMU then runs seconds ahead of the
radar, and every scan would come too late, leaving the filter to the IMU alone. So each radar's progress
is a watermark (``radar_seen``, also for frames not made into scans): the filter runs up to the radar
furthest behind, however far ahead the IMU is, up to ``max_radar_wait_s``, and takes each scan in time
order on the way. A radar's frames come in order, so once every radar is past a time no scan before it
can still come, and the filter need hold back no further: its poses are out as soon as the last radar's
frame is (a fixed hold-back behind the watermark would only keep the live map waiting for them). A radar
gone silent (``radar_silent``) is not waited for until it sends again; with none left, the filter goes on
with the IMU alone, ``max_scan_delay_s`` behind the newest IMU sample in case a radar comes back. Before
the first radar data it waits as well, since a backlog starts at once. A scan later than the filter is
counted and left out. Poses come out at ``options.output_rate_hz``; ``finish`` runs the filter to the end
of the data.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter

import numpy as np
from scipy.spatial.transform import Rotation

from .ekf import RadarInertialEkf
from .odometry import RadarScan, RioOptions, add_calibration_states, radar_update, shift_by_known_offsets

log = logging.getLogger(f"sarbot.{__name__}")

_NO_RADAR_YET = -(1 << 62)  # the watermark before any radar data: wait the longest


@dataclasses.dataclass
class PoseBatch:
    """Filter states: time_ns [N], position_m [N, 3], orientation_xyzw [N, 4], velocity_mps [N, 3]."""

    time_ns: np.ndarray
    position_m: np.ndarray
    orientation_xyzw: np.ndarray
    velocity_mps: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.size)


class StreamingRio:
    """Feed ``add_imu`` and ``add_scan``; each returns the poses the filter passed meanwhile."""

    def __init__(self, options: RioOptions = RioOptions(), imu_rate_hz: float = 400.0, max_scan_delay_s: float = 0.2,
                 max_radar_wait_s: float = 60.0):
        self.options = options
        self.max_scan_delay_ns = int(max_scan_delay_s * 1e9)
        self.max_radar_wait_ns = int(max_radar_wait_s * 1e9)
        self._radar_ns: dict[str, int] = {}  # each radar's newest time, of those not silent
        self._wait_for_first_radar = True
        self.ekf: RadarInertialEkf | None = None
        self.stats: Counter = Counter()
        self._rng = np.random.default_rng(options.seed)
        self._init: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._imu_t = np.zeros(0, np.int64)
        self._imu_a = np.zeros((0, 3))
        self._imu_g = np.zeros((0, 3))
        self._scans: list[RadarScan] = []
        self._out_every = max(1, int(round(imu_rate_hz / options.output_rate_hz)))
        self._n_imu = 0
        self._start_ns = 0

    @property
    def initialised(self) -> bool:
        return self.ekf is not None

    def radar_seen(self, radar: str, time_ns: int) -> None:
        """``radar``'s data has come up to ``time_ns`` (a frame's time, whether or not it is made into a
        scan). Runs nothing: the next ``add_imu`` or ``add_scan`` does."""
        self._radar_ns[radar] = max(int(time_ns), self._radar_ns.get(radar, int(time_ns)))

    def radar_silent(self, radar: str | None = None) -> None:
        """``radar`` (None: every radar) stopped sending: the filter no longer waits for it, until
        ``radar_seen`` says it is back."""
        if radar is None:
            self._radar_ns.clear()
        else:
            self._radar_ns.pop(radar, None)
        self._wait_for_first_radar = False

    @property
    def radar_watermark_ns(self) -> int | None:
        """How far the radar data has come: the radar furthest behind of those sending; None when the filter
        waits for no radar."""
        if self._radar_ns:
            return min(self._radar_ns.values())
        return _NO_RADAR_YET if self._wait_for_first_radar else None

    def add_scan(self, scan: RadarScan) -> PoseBatch:
        if not self.options.calibrating:
            (scan,) = shift_by_known_offsets([scan], self.options.calibration_priors)
        self.radar_seen(scan.radar, scan.time_ns)
        if self.ekf is not None and scan.time_ns < self.ekf.state.time_ns:
            # Scans of the standstill the filter started from are not late: the batch filter leaves them out too.
            self.stats["scans_before_start" if scan.time_ns < self._start_ns else "scans_late"] += 1
            return self._empty()
        self._scans.append(scan)
        self._scans.sort(key=lambda s: s.time_ns)
        return self._run()

    def add_imu(self, time_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray) -> PoseBatch:
        time_ns = np.asarray(time_ns, np.int64)
        acc = np.asarray(accel_mps2, np.float64).reshape(-1, 3)
        gyr = np.asarray(gyro_radps, np.float64).reshape(-1, 3)
        if self.ekf is None:
            self._init.append((time_ns, acc, gyr))
            t = np.concatenate([c[0] for c in self._init])
            if t[-1] - t[0] < self.options.static_init_s * 1e9:
                return self._empty()
            a = np.concatenate([c[1] for c in self._init])
            g = np.concatenate([c[2] for c in self._init])
            self._init = []
            still = t <= t[0] + int(self.options.static_init_s * 1e9)
            k0 = int(np.argmax(~still))
            self.ekf = RadarInertialEkf(self.options.ekf, keep_bias_log=False)  # runs for hours: stays flat
            self.ekf.initialise_static(t[k0], a[still], g[still], self.options.initial_position_m, self.options.initial_yaw_rad)
            self.ekf.propagate(t[k0], a[k0], g[k0])
            self._start_ns = int(t[k0])
            self._scans = [s for s in self._scans if s.time_ns >= t[k0]]
            self._n_imu = 1  # sample k0 is the first; poses are kept every n-th sample after it, as run_rio does
            time_ns, acc, gyr = t[k0 + 1:], a[k0 + 1:], g[k0 + 1:]
            log.info("RIO initialised from %.1f s of standstill", self.options.static_init_s)
        self._imu_t = np.concatenate([self._imu_t, time_ns])
        self._imu_a = np.concatenate([self._imu_a, acc])
        self._imu_g = np.concatenate([self._imu_g, gyr])
        return self._run()

    def _empty(self) -> PoseBatch:
        return PoseBatch(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)))

    def _propagate_to(self, k_end: int, chunks: list) -> None:
        if k_end <= 0:
            return
        idx = self._n_imu + np.arange(k_end)
        record = idx % self._out_every == 0
        chunks.append(self.ekf.propagate_samples(self._imu_t[:k_end], np.ascontiguousarray(self._imu_a[:k_end]),
                                                 np.ascontiguousarray(self._imu_g[:k_end]), record))
        self._n_imu += k_end
        self._imu_t, self._imu_a, self._imu_g = self._imu_t[k_end:], self._imu_a[k_end:], self._imu_g[k_end:]

    def finish(self) -> PoseBatch:
        """Run the filter through everything received (end of the data)."""
        return self._run(final=True)

    def _run(self, final: bool = False) -> PoseBatch:
        if self.ekf is None or self._imu_t.size == 0:
            return self._empty()
        chunks: list = []
        horizon = int(self._imu_t[-1])
        if not final:
            watermark = self.radar_watermark_ns
            if watermark is None:
                horizon -= self.max_scan_delay_ns
            else:
                # Never further ahead of the radar than the wait allows, so a radar stalled for good (a
                # consumer starved for minutes) cannot hold the IMU without bound.
                horizon = min(horizon, max(watermark, horizon - self.max_radar_wait_ns))
        while self._scans and self._scans[0].time_ns <= horizon:
            scan = self._scans.pop(0)
            if scan.time_ns < self.ekf.state.time_ns:
                self.stats["scans_late"] += 1
                continue
            if self.options.calibrating and scan.radar not in self.ekf.calibration:
                add_calibration_states(self.ekf, [scan], self.options)  # each radar's states from its first scan
            self._propagate_to(int(np.searchsorted(self._imu_t, scan.time_ns, side="left")), chunks)
            self.ekf.propagate(scan.time_ns)
            helped, _ = radar_update(self.ekf, [scan], self.options, self._rng, self.stats)
            if self.options.ekf.planar:
                self.ekf.update_planar()
        self._propagate_to(int(np.searchsorted(self._imu_t, horizon, side="right")), chunks)
        if not (np.all(np.isfinite(self.ekf.state.p)) and np.all(np.isfinite(self.ekf.state.P))):
            raise FloatingPointError("the odometry filter diverged")
        chunks = [c for c in chunks if c is not None and c[0].size]
        if not chunks:
            return self._empty()
        return PoseBatch(np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
                         Rotation.from_matrix(np.concatenate([c[3] for c in chunks])).as_quat(),
                         np.concatenate([c[2] for c in chunks]))
