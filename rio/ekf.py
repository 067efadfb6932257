"""Error-state EKF radar-inertial odometry (in the spirit of Doer & Trommer's EKF-RIO, 2020).

Nominal state: position p and velocity v in the world frame n (z up), attitude R (body -> world),
accelerometer bias b_a and gyro bias b_g. Error state (15): dp, dv, dtheta (body frame, R = R_hat Exp(dtheta)),
db_a, db_g. Strapdown propagation at IMU rate; radar ego-velocity updates (sensor frame, lever arm and
angular rate included) with chi-square gating and the Joseph form; zero-velocity and zero-rate updates at
standstill; static initialisation of roll, pitch and gyro bias. The strapdown (midpoint attitude, second
order) is in ``rio.strapdown``. Pure computation: arrays in, states out.

Online calibration (switchable, ``add_radar_calibration``): each radar added gets 7 more error states after
the 15 -- its mount rotation (3, sensor frame: R_m = R_m_hat Exp(dtheta_m)), its lever arm (3, body frame)
and its time offset (1, seconds: the radar's stamp minus the IMU time of the same instant), as in ekf_rio's
extrinsic states and EKF-RIO-TC's time offset. They are constants (no process noise); the ego-velocity
updates observe them while the robot turns (lever arm, the boresight's pitch) and accelerates (rotation,
time offset). A state left out (sigma 0) never moves.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.constants import CHI2_999, GRAVITY_MPS2
from rio.strapdown import _exp_so3_nb, _strapdown, _strapdown_batch
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)

GRAVITY = np.array([0.0, 0.0, -GRAVITY_MPS2])


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross costs ten times more for one pair)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclasses.dataclass(frozen=True)
class EkfConfig:
    """Noise densities (continuous, SI) and filter settings."""

    accel_noise_density: float = 2e-3
    gyro_noise_density: float = 2e-4
    accel_bias_random_walk: float = 2e-4
    gyro_bias_random_walk: float = 2e-5
    init_position_sigma_m: float = 1e-3
    init_velocity_sigma_mps: float = 0.02
    init_attitude_sigma_rad: float = math.radians(2.0)
    init_yaw_sigma_rad: float = 1e-4  # the world frame takes its heading from the start pose
    init_accel_bias_sigma: float = 0.1
    init_gyro_bias_sigma: float = 0.01
    zero_velocity_sigma_mps: float = 0.02  # the radar's zero-velocity threshold: creeping below it looks still
    zero_rate_sigma_radps: float = 2e-3
    #: Zero-velocity update when the radar calls a standstill and the IMU has not moved since the last radar
    #: update (``imu_was_still``), in a stop after driving: then the robot stands, it does not creep into or
    #: out of a stop, and the velocity the drive left is pulled to zero at once (0.02 m/s would leave it
    #: crawling there over seconds). Not at the start, which the static initialisation gives zero velocity
    #: already, and where the tighter update would lean harder on a tilt the IMU cannot tell from its bias.
    still_zero_velocity_sigma_mps: float = 0.002
    still_gyro_radps: float = 0.01  # the mean rate between two radar scans this far from the bias ...
    still_accel_std_mps2: float = 0.1  # ... or the specific force scattered this much ...
    #: ... or its mean this far from gravity (world frame) is motion: a robot creeping out of a stop below
    #: the radar's threshold accelerates (0.4 m/s^2), a bias step not yet learned (0.1 m/s^2) is no motion
    still_accel_mps2: float = 0.15
    still_window_s: float = 0.1  # over the IMU samples of this long before the radar's verdict
    #: The tighter zero-velocity update wants the mean specific force this close to gravity: a robot
    #: creeping out of a stop on a gentle (jerk-limited) ramp has reached 0.01 m/s before 0.15 m/s^2.
    standing_accel_mps2: float = 0.08
    gate_chi2: float = CHI2_999[3]
    #: Added to every radar velocity covariance: what the Doppler fit does not see (time-stamp jitter,
    #: velocity change within a frame, Doppler quantisation).
    radar_velocity_sigma_floor_mps: float = 0.05
    gate_recovery_rejections: int = 8  # radar updates refused in a row before the velocity is re-opened
    recovery_velocity_sigma_mps: float = 1.0
    standstill_trim_s: float = 0.5  # gyro samples left out at both ends of a standstill (creeping in and out)
    standstill_min_samples: int = 50
    standstill_update_s: float = 2.0  # a zero-rate update from every this much of a long standstill
    planar: bool = False  # pseudo-measurement: no vertical velocity (robots on flat floors)
    #: Let radar velocity updates correct the gyro bias through the lever arm (w x l). The coupling is weak
    #: (0.2 m lever arms) and small systematic ego-velocity errors that differ between radars then leak
    #: into the yaw-rate bias; off by default, the bias is learned at standstill (zero-rate update).
    radar_observes_gyro_bias: bool = False
    planar_sigma_mps: float = 0.05
    #: Priors of the online calibration (``RadarInertialEkf.add_radar_calibration``) where the rig gives none.
    calibration_rotation_sigma_rad: float = math.radians(3.0)
    calibration_translation_sigma_m: float = 0.05
    calibration_time_offset_sigma_s: float = 0.01


@dataclasses.dataclass
class EkfState:
    time_ns: int
    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    ba: np.ndarray
    bg: np.ndarray
    P: np.ndarray  # [15, 15]

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return Rotation.from_matrix(self.R).as_quat()


#: Error states of the core filter (p, v, theta, b_a, b_g) and of each calibrated radar (theta_m, l, t_d).
N_CORE = 15
N_CALIBRATION = 7


@dataclasses.dataclass
class RadarCalibration:
    """One radar's calibration estimate inside the filter: the nominal values and where its error states are.

    ``rotation_matrix`` rotates sensor to body, ``translation_m`` is the lever arm (body frame),
    ``time_offset_s`` the radar's stamp minus the IMU time of the same instant (a radar 5 ms late: +0.005).
    """

    name: str
    index: int  # first of its 7 error states in P
    rotation_matrix: np.ndarray
    translation_m: np.ndarray
    time_offset_s: float

    @property
    def mount(self):
        from imaging.core.rig import Mount

        return Mount(self.translation_m.copy(), Rotation.from_matrix(self.rotation_matrix).as_quat())


@dataclasses.dataclass(frozen=True)
class CalibrationEstimate:
    """A radar's calibration as the filter has it: the mount (sensor -> body), the time offset (s, radar
    stamp minus IMU time) and the standard deviations of the 7 error states: rotation about the sensor's
    x, y, z (rad), lever arm along body x, y, z (m), time offset (s)."""

    mount: object  # imaging.core.rig.Mount
    time_offset_s: float
    sigma: np.ndarray  # [7]

    @property
    def rotation_sigma_rad(self) -> np.ndarray:
        return self.sigma[0:3]

    @property
    def translation_sigma_m(self) -> np.ndarray:
        return self.sigma[3:6]

    @property
    def time_offset_sigma_s(self) -> float:
        return float(self.sigma[6])


@dataclasses.dataclass
class UpdateResult:
    """Whether the gate let the measurement in, its chi2, and its innovation covariance S = H P H^T + R (the
    residual's covariance the gate judged it by; [rows, rows])."""

    accepted: bool
    chi2: float
    innovation_covariance: np.ndarray | None = None


@numba.njit(cache=True)
def _joseph_update(P, H, R_meas, residual, gate):
    """Kalman update in Joseph form with a chi-square gate: (accepted, chi2, dx, P_new, S)."""
    S = H @ P @ H.T + R_meas
    if abs(np.linalg.det(S)) < 1e-300:
        return False, np.inf, np.zeros(P.shape[0]), P, S
    S_inv = np.linalg.inv(S)
    chi2 = residual @ S_inv @ residual
    if not np.isfinite(chi2) or chi2 > gate:
        return False, chi2, np.zeros(P.shape[0]), P, S
    K = P @ H.T @ S_inv
    dx = K @ residual
    I_KH = np.eye(P.shape[0]) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R_meas @ K.T  # Joseph form: stays symmetric positive definite
    return True, chi2, dx, 0.5 * (P_new + P_new.T), S


@numba.njit(cache=True)
def _imu_still_nb(t, gyro, accel, window_ns, R, ba, bg, gyro_limit, accel_limit, accel_std_limit):
    """``RadarInertialEkf.imu_was_still`` on the recent samples (times ascending) in one compiled call: 1 still,
    0 moving, -1 fewer than 3 samples in the window. The specific force's mean is taken over the window and
    over its last 25 ms (at least 3 samples): a robot that has just started to creep out of a stop has
    accelerated for a fraction of the window only."""
    n = t.size
    first = n
    while first > 0 and t[first - 1] >= t[n - 1] - window_ns:
        first -= 1
    if n - first < 3:
        return -1
    latest = n
    while latest > first and t[latest - 1] >= t[n - 1] - 25_000_000:
        latest -= 1
    latest = min(latest, n - 3)
    rate = np.zeros(3)
    force = np.zeros(3)
    force_latest = np.zeros(3)
    for i in range(first, n):
        for k in range(3):
            rate[k] += gyro[i, k]
            force[k] += accel[i, k]
            if i >= latest:
                force_latest[k] += accel[i, k]
    rate = rate / (n - first) - bg
    force = force / (n - first)
    if math.sqrt(rate[0] ** 2 + rate[1] ** 2 + rate[2] ** 2) >= gyro_limit:
        return 0
    for mean in (force, force_latest / (n - latest)):
        world = R @ (mean - ba)
        world[2] -= GRAVITY_MPS2
        if math.sqrt(world[0] ** 2 + world[1] ** 2 + world[2] ** 2) >= accel_limit:
            return 0
    for k in range(3):
        spread = 0.0
        for i in range(first, n):
            spread += (accel[i, k] - force[k]) ** 2
        if math.sqrt(spread / (n - first)) >= accel_std_limit:
            return 0
    return 1


class RadarInertialEkf:
    """The filter. Call ``initialise_static`` once, then feed IMU samples and radar measurements in time order."""

    def __init__(self, config: EkfConfig = EkfConfig(), keep_bias_log: bool = True):
        """``keep_bias_log`` False keeps only the latest (time, b_g, b_a) in ``bias_log``: a filter running
        for hours (the live odometry) must not grow with every update."""
        self.config = config
        self.keep_bias_log = keep_bias_log
        self._q_density = np.concatenate([np.zeros(3), np.full(3, config.accel_noise_density ** 2),
                                          np.full(3, config.gyro_noise_density ** 2), np.full(3, config.accel_bias_random_walk ** 2),
                                          np.full(3, config.gyro_bias_random_walk ** 2)])
        self.state: EkfState | None = None
        # Chunks of (times [k], gyro [k, 3]) of the current standstill, for its zero-rate updates.
        self._standstill: list[tuple[np.ndarray, np.ndarray]] = []
        self._in_standstill = False
        self._standstill_started = True  # whether the gathered samples begin with the standstill (trim them)
        self.bias_resets = 0
        self.bias_log: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._last_gyro = np.zeros(3)
        self._last_accel = np.zeros(3)
        #: The calibrated radars by name (empty: the 15-state filter of before).
        self.calibration: dict[str, RadarCalibration] = {}
        # The runs of IMU samples (time ns, rate, specific force) that hold the last ``still_window_s`` (at
        # least 50 ms, at most 512 samples): whether the IMU stands still, and the gyro's slope, the angular
        # acceleration the time-offset update needs (d/dt of w x l). Joined only when asked (``_recent_imu``):
        # joining them at every run of samples cost more than the runs' strapdown.
        self._recent_runs: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._recent_joined: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._has_moved = False  # a radar velocity update has been taken: the robot has driven

    # -- initialisation -----------------------------------------------------------------------------
    def initialise_static(self, time_ns: int, accel_mps2: np.ndarray, gyro_radps: np.ndarray,
                          position_m=(0.0, 0.0, 0.0), yaw_rad: float = 0.0) -> EkfState:
        """Roll and pitch from the mean specific force, gyro bias from the mean rate, while standing still.

        ``accel_mps2``, ``gyro_radps``: [N, 3] samples of the static period.
        """
        f = np.mean(accel_mps2, axis=0)
        roll = math.atan2(f[1], f[2])
        pitch = math.atan2(-f[0], math.hypot(f[1], f[2]))
        R = Rotation.from_euler("ZYX", [yaw_rad, pitch, roll]).as_matrix()
        c = self.config
        P = np.diag(np.concatenate([
            np.full(3, c.init_position_sigma_m ** 2), np.full(3, c.init_velocity_sigma_mps ** 2),
            [c.init_attitude_sigma_rad ** 2, c.init_attitude_sigma_rad ** 2, c.init_yaw_sigma_rad ** 2],
            np.full(3, c.init_accel_bias_sigma ** 2), np.full(3, c.init_gyro_bias_sigma ** 2)]))
        # The gyro bias is the mean rate of the standstill: its uncertainty is that of a mean (plus the
        # random walk it may still do), not the wide prior.
        n = len(gyro_radps)
        bg_var = np.maximum(np.var(gyro_radps, axis=0) / max(n, 1), (1e-5) ** 2)
        P[12:15, 12:15] = np.diag(bg_var)
        # What the mean specific force has beyond gravity's magnitude is accelerometer bias along gravity:
        # left to the zero-velocity updates, it would first show as a vertical velocity of mm/s growing
        # each IMU sample (the horizontal bias cannot be told from tilt, and stays with the attitude).
        ba = (np.linalg.norm(f) - GRAVITY_MPS2) * f / np.linalg.norm(f)
        self.state = EkfState(int(time_ns), np.asarray(position_m, float).copy(), np.zeros(3), R, ba,
                              np.mean(gyro_radps, axis=0), P)
        self._last_gyro = np.mean(gyro_radps, axis=0)
        self._last_accel = f
        self.bias_log = [(int(time_ns), self.state.bg.copy(), self.state.ba.copy())]
        return self.state

    def add_radar_calibration(self, name: str, mount, time_offset_s: float = 0.0, *,
                              rotation_sigma_rad: float | None = None, translation_sigma_m: float | None = None,
                              time_offset_sigma_s: float | None = None) -> RadarCalibration:
        """Estimate radar ``name``'s mount and time offset online, starting from ``mount`` and
        ``time_offset_s`` (the rig's values) with these prior standard deviations (None: the config's;
        0: that part stays fixed). The rotation's and the lever arm's are one value for all three axes or
        one per axis (a rig file's ``[radar.NAME.calibration]``, see docs/config/rig.md). Call after
        ``initialise_static``."""
        if name in self.calibration:
            return self.calibration[name]
        c = self.config
        sig = [c.calibration_rotation_sigma_rad if rotation_sigma_rad is None else rotation_sigma_rad,
               c.calibration_translation_sigma_m if translation_sigma_m is None else translation_sigma_m,
               c.calibration_time_offset_sigma_s if time_offset_sigma_s is None else time_offset_sigma_s]
        s = self.state
        n = s.P.shape[0]
        P = np.zeros((n + N_CALIBRATION, n + N_CALIBRATION))
        P[:n, :n] = s.P
        P[n:, n:] = np.diag(np.square(np.concatenate([np.broadcast_to(np.asarray(sig[0], float), 3),
                                                      np.broadcast_to(np.asarray(sig[1], float), 3), [float(sig[2])]])))
        s.P = P
        self._q_density = np.concatenate([self._q_density, np.zeros(N_CALIBRATION)])
        cal = RadarCalibration(name, n, np.array(mount.rotation_matrix, float), np.array(mount.translation_m, float),
                               float(time_offset_s))
        self.calibration[name] = cal
        return cal

    def calibration_sigma(self, name: str) -> np.ndarray:
        """Standard deviations of radar ``name``'s 7 calibration error states (rad, m, s)."""
        return np.sqrt(np.clip(np.diag(self.state.P)[self.calibration[name].index:][:N_CALIBRATION], 0.0, None))

    def calibration_estimates(self) -> dict[str, CalibrationEstimate]:
        """Every calibrated radar's current estimate and standard deviations."""
        return {name: CalibrationEstimate(cal.mount, cal.time_offset_s, self.calibration_sigma(name))
                for name, cal in self.calibration.items()}

    def angular_acceleration_radps2(self) -> np.ndarray:
        """Slope of the latest gyro samples (rad/s^2); zero before there are enough."""
        t, g, _ = self._recent_imu
        keep = t >= t[-1] - 50_000_000 if t.size else t.astype(bool)
        t, g = t[keep], g[keep]  # 50 ms: a slope through the gyro noise, short against a turn's onset
        if t.size < 4:
            return np.zeros(3)
        x = (t - t.mean()) * 1e-9
        return (x @ (g - g.mean(axis=0))) / (x @ x)

    @property
    def last_gyro_radps(self) -> np.ndarray:
        """The latest IMU rate of turn the filter propagated with (bias not removed), rad/s."""
        return self._last_gyro

    @property
    def last_accel_mps2(self) -> np.ndarray:
        """The latest IMU specific force the filter propagated with (bias not removed), m/s^2."""
        return self._last_accel

    # -- propagation ------------------------------------------------------------------------------------
    def propagate(self, time_ns: int, accel_mps2: np.ndarray | None = None, gyro_radps: np.ndarray | None = None) -> None:
        """Strapdown from the state time to ``time_ns`` with the IMU sample taken at the state time, then
        remember the new sample (zero-order hold between samples)."""
        s = self.state
        dt = (int(time_ns) - s.time_ns) * 1e-9
        if dt < 0:
            raise ValueError(f"measurement at {time_ns} is older than the filter state at {s.time_ns}")
        if accel_mps2 is not None:  # one IMU sample: the batch path with a run of one
            self.propagate_samples(np.array([int(time_ns)]), np.asarray(accel_mps2, float).reshape(1, 3),
                                   np.asarray(gyro_radps, float).reshape(1, 3), np.zeros(1, bool))
        elif dt > 0:
            s.p, s.v, s.R, s.P = _strapdown(s.p, s.v, s.R, s.P, self._last_accel - s.ba, self._last_gyro - s.bg, dt, self._q_density)
            s.time_ns = int(time_ns)

    def propagate_samples(self, times_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray,
                          record: np.ndarray):
        """Propagate through a run of IMU samples in one compiled call (what ``propagate`` does per sample).

        Returns the recorded states (time, p, v, R, diag P) after every sample flagged in ``record``.
        """
        s = self.state
        if times_ns.size == 0:
            return None
        if self._in_standstill:
            self._standstill.append((times_ns, gyro_radps))
        self._keep_recent(times_ns, gyro_radps, accel_mps2)
        (s.p, s.v, s.R, s.P, t_ns, self._last_accel, self._last_gyro,
         *recorded) = _strapdown_batch(s.p, s.v, s.R, s.P, s.time_ns, self._last_accel, self._last_gyro, s.ba, s.bg,
                                       times_ns, accel_mps2, gyro_radps, record, self._q_density)
        s.time_ns = int(t_ns)
        self._last_accel = self._last_accel.copy()
        self._last_gyro = self._last_gyro.copy()
        return recorded

    def _keep_recent(self, times_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray) -> None:
        """Add a run of IMU samples to the recent ones, dropping the runs ``_recent_imu`` can no longer hold."""
        runs = self._recent_runs
        runs.append((times_ns, gyro_radps, accel_mps2))
        oldest_ns = int(times_ns[-1]) - int(max(self.config.still_window_s, 0.05) * 1e9)
        newer = 0
        for i in range(len(runs) - 1, 0, -1):  # runs[i - 1] goes when every sample it holds is too old or beyond 512
            newer += runs[i][0].size
            if newer >= 512 or runs[i - 1][0][-1] < oldest_ns:
                del runs[:i]
                break
        self._recent_joined = None

    @property
    def _recent_imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The IMU samples of the last ``still_window_s`` (at least 50 ms, at most the last 512): times (ns),
        rates [k, 3], specific forces [k, 3]."""
        if self._recent_joined is None:
            runs = self._recent_runs
            if not runs:
                return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
            t = np.concatenate([r[0] for r in runs])[-512:]
            keep = t >= t[-1] - int(max(self.config.still_window_s, 0.05) * 1e9)
            self._recent_joined = (t[keep], np.concatenate([r[1] for r in runs])[-512:][keep],
                                   np.concatenate([r[2] for r in runs])[-512:][keep])
        return self._recent_joined

    def update(self, residual: np.ndarray, H: np.ndarray, R_meas: np.ndarray, gate: float | None,
               kind: str = "") -> UpdateResult:
        """A measurement update (H from ``jacobian_rows``; gate: chi2, None for none; "velocity": it moved)."""
        s = self.state
        ok, chi2, dx, P, S = _joseph_update(s.P, np.ascontiguousarray(H, dtype=np.float64),
                                         np.ascontiguousarray(R_meas, dtype=np.float64),
                                         np.ascontiguousarray(residual, dtype=np.float64), np.inf if gate is None else gate)
        if not ok:
            return UpdateResult(False, chi2, S)
        s.P = P
        s.p = s.p + dx[0:3]
        if kind == "velocity":
            self._has_moved = True
        s.v = s.v + dx[3:6]
        s.R = s.R @ _exp_so3_nb(dx[6:9])
        s.ba = s.ba + dx[9:12]
        s.bg = s.bg + dx[12:15]
        for cal in self.calibration.values():
            i = cal.index
            cal.rotation_matrix = cal.rotation_matrix @ _exp_so3_nb(dx[i:i + 3])
            cal.translation_m = cal.translation_m + dx[i + 3:i + 6]
            cal.time_offset_s += float(dx[i + 6])
        entry = (s.time_ns, s.bg.copy(), s.ba.copy())
        if self.keep_bias_log:
            self.bias_log.append(entry)
        else:
            self.bias_log[-1:] = [entry]
        return UpdateResult(True, chi2, S)

    def jacobian_rows(self, rows: int) -> np.ndarray:  # a measurement Jacobian's rows, as wide as the error state
        return np.zeros((rows, self.state.P.shape[0]))

    def measurement_time_ns(self, radar: str, stamp_ns: int) -> int:
        """The IMU time a radar stamp stands for: the stamp less the radar's estimated time offset."""
        cal = self.calibration.get(radar)
        return int(stamp_ns) if cal is None else int(stamp_ns) - int(round(cal.time_offset_s * 1e9))

    def update_radar_velocity(self, velocity_sensor_mps: np.ndarray, covariance: np.ndarray, mount,
                              radar: str | None = None, stamp_ns: int | None = None) -> UpdateResult:
        """Sensor-frame ego velocity from one radar: v_s = R_m^T (R^T v + w x l), w = gyro - b_g.

        A radar under calibration (``radar`` named in ``add_radar_calibration``) uses the filter's mount
        instead of ``mount`` and its time offset: the scan stamped ``stamp_ns`` was measured at
        stamp - t_d, which may differ from the filter's time by what the state's time offset says; the
        prediction is moved by that difference along dh/dt, and dh/dt is the time offset's Jacobian.
        """
        self.end_standstill()
        s = self.state
        cal = self.calibration.get(radar) if radar is not None else None
        Rm = mount.rotation_matrix if cal is None else cal.rotation_matrix
        lever = mount.translation_m if cal is None else cal.translation_m
        w = self._last_gyro - s.bg
        v_body = s.R.T @ s.v
        predicted = Rm.T @ (v_body + cross3(w, lever))
        H = self.jacobian_rows(3)
        H[:, 3:6] = Rm.T @ s.R.T
        H[:, 6:9] = Rm.T @ skew(v_body)
        covariance = covariance + np.eye(3) * self.config.radar_velocity_sigma_floor_mps ** 2
        if self.config.radar_observes_gyro_bias:
            H[:, 12:15] = Rm.T @ skew(lever)
        if cal is not None:
            i = cal.index
            H[:, i:i + 3] = skew(predicted)  # R_m^T = Exp(-dtheta) R_m_hat^T
            H[:, i + 3:i + 6] = Rm.T @ skew(w)
            # d/dt of the body velocity (specific force + gravity - w x v) and of the lever arm's w x l
            accel_body = (self._last_accel - s.ba) + s.R.T @ GRAVITY - cross3(w, v_body)
            rate = Rm.T @ (accel_body + cross3(self.angular_acceleration_radps2(), lever))
            H[:, i + 6] = -rate
            if stamp_ns is not None:
                # The strapdown holds each IMU sample over the interval after it, so the velocity it gives
                # lags by half an interval: the state stands for half an interval before its time.
                t_hist = self._recent_imu[0]
                half_interval_s = 0.5e-9 * (t_hist[-1] - t_hist[-2]) if t_hist.size > 1 else 0.0
                predicted = predicted + rate * ((int(stamp_ns) - s.time_ns) * 1e-9 + half_interval_s - cal.time_offset_s)
        return self.update(np.asarray(velocity_sensor_mps) - predicted, H, covariance, self.config.gate_chi2, "velocity")

    def update_body_velocity(self, velocity_body_mps: np.ndarray, covariance: np.ndarray) -> UpdateResult:
        """Body-frame velocity (several radars solved together)."""
        self.end_standstill()
        s = self.state
        v_body = s.R.T @ s.v
        H = self.jacobian_rows(3)
        H[:, 3:6] = s.R.T
        H[:, 6:9] = skew(v_body)
        covariance = covariance + np.eye(3) * self.config.radar_velocity_sigma_floor_mps ** 2
        return self.update(np.asarray(velocity_body_mps) - v_body, H, covariance, self.config.gate_chi2, "velocity")

    def inflate_velocity_uncertainty(self) -> None:
        """Reset the velocity block of P (and its correlations) to a wide prior."""
        P = self.state.P
        P[3:6, :] = 0.0
        P[:, 3:6] = 0.0
        P[3:6, 3:6] = np.eye(3) * self.config.recovery_velocity_sigma_mps ** 2

    def imu_was_still(self, accel_limit_mps2: float | None = None) -> bool | None:
        """Whether the IMU samples of the last ``still_window_s`` show no motion: their mean rate is the bias,
        their mean specific force is gravity and does not scatter beyond noise (a test of single samples
        trips on a real IMU's noise: an ADIS16448 at rest shows 0.015 rad/s and 0.15 m/s^2 in single
        samples). ``accel_limit_mps2``: how far from gravity the mean may be (None: ``still_accel_mps2``).
        None with fewer than 3 samples."""
        c = self.config
        limit = c.still_accel_mps2 if accel_limit_mps2 is None else accel_limit_mps2
        t, gyro, accel = self._recent_imu
        if t.size < 3:
            return None
        s = self.state
        still = _imu_still_nb(t, gyro, accel, int(c.still_window_s * 1e9), s.R, s.ba, s.bg, c.still_gyro_radps, limit,
                              c.still_accel_std_mps2)
        return None if still < 0 else bool(still)

    def update_zero_velocity(self) -> UpdateResult:
        """Standstill: world velocity zero now; the angular rate is used once the standstill ends.

        Radar Doppler cannot tell standing from creeping a few mm/s, and a robot creeping out of a stop on
        an arc already turns. So the gyro samples of the standstill are gathered and, when it ends, their
        mean without the first and last ``standstill_trim_s`` becomes one zero-rate update (the gyro bias).
        """
        standing = self._has_moved and bool(self.imu_was_still(self.config.standing_accel_mps2))
        if not self._in_standstill:
            self._standstill_started = True
        self._in_standstill = True
        self._zero_rate_during_standstill()
        s = self.state
        H = self.jacobian_rows(3)
        H[:, 3:6] = np.eye(3)
        c = self.config
        sigma = c.still_zero_velocity_sigma_mps if standing else c.zero_velocity_sigma_mps
        return self.update(-s.v, H, np.eye(3) * sigma ** 2, None)

    def _zero_rate_during_standstill(self) -> None:
        """A long standstill gives its zero-rate update every ``standstill_update_s``, not only when it ends:
        a robot standing for minutes learns its gyro bias meanwhile. The last ``standstill_trim_s`` of
        samples are kept back (the end may yet be creeping) and start the next piece."""
        c = self.config
        if not self._standstill:
            return
        t_first, t_last = self._standstill[0][0][0], self._standstill[-1][0][-1]
        trim = c.standstill_trim_s * 1e9
        if t_last - t_first < c.standstill_update_s * 1e9 + trim * (2 if self._standstill_started else 1):
            return
        samples = self._standstill
        t = np.concatenate([ts for ts, _ in samples])
        gyro = np.concatenate([g for _, g in samples])
        held = t > t[-1] - trim
        self._zero_rate_update(samples, self._standstill_started)
        self._standstill = [(t[held], gyro[held])]
        self._standstill_started = False

    def end_standstill(self) -> UpdateResult | None:
        """Close the current standstill: one zero-rate update from its trimmed mean gyro rate.

        If that mean lies far outside the bias covariance, the bias has stepped (a temperature jump, a
        knock): its uncertainty is re-opened first, so the update learns the new value.
        """
        samples, self._standstill, self._in_standstill = self._standstill, [], False
        trim_start, self._standstill_started = self._standstill_started, True
        return self._zero_rate_update(samples, trim_start)

    def _zero_rate_update(self, samples, trim_start: bool) -> UpdateResult | None:
        """One zero-rate update from the standstill's gyro ``samples`` without their last
        ``standstill_trim_s`` (and their first, with ``trim_start``)."""
        c = self.config
        if not samples:
            return None
        t = np.concatenate([ts for ts, _ in samples])
        gyro = np.concatenate([g for _, g in samples])
        trim = int(c.standstill_trim_s * 1e9)
        keep = (t >= t[0] + (trim if trim_start else 0)) & (t <= t[-1] - trim)
        n = int(keep.sum())
        if n < c.standstill_min_samples:
            return None
        s = self.state
        rate = gyro[keep].mean(axis=0) - s.bg
        rate_cov = np.eye(3) * c.zero_rate_sigma_radps ** 2 / n
        if float(rate @ np.linalg.solve(s.P[12:15, 12:15] + rate_cov, rate)) > CHI2_999[3]:
            s.P[12:15, :] = 0.0
            s.P[:, 12:15] = 0.0
            s.P[12:15, 12:15] = np.eye(3) * c.init_gyro_bias_sigma ** 2
            self.bias_resets += 1
        H = self.jacobian_rows(3)
        H[:, 12:15] = -np.eye(3)  # measured rate - b_g = 0
        return self.update(-rate, H, rate_cov, None)

    def update_planar(self) -> UpdateResult:
        """No vertical velocity in the world frame (a robot on a flat floor)."""
        s = self.state
        H = self.jacobian_rows(1)
        H[0, 5] = 1.0
        return self.update(np.array([-s.v[2]]), H, np.array([[self.config.planar_sigma_mps ** 2]]), CHI2_999[1])
