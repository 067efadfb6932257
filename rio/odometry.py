"""Radar-inertial odometry over a recording: scans -> ego velocity -> EKF -> trajectory."""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter

import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.constants import GRAVITY_MPS2
from imaging.core.rig import Mount
from imaging.core.trajectory import SampledTrajectory
from imaging.io.recording import Recording

from .ego_velocity import EgoStatus, EgoVelocityConfig, body_velocity, sensor_velocity
from .ekf import CalibrationEstimate, EkfConfig, RadarInertialEkf

log = logging.getLogger(f"sarbot.{__name__}")


@dataclasses.dataclass
class RadarScan:
    """One radar's detections at one measurement time (mid-frame, on the PTP/IMU time base)."""

    time_ns: int
    radar: str
    mount: Mount
    xyz_m: np.ndarray  # [D, 3] sensor frame
    doppler_mps: np.ndarray  # [D]


@dataclasses.dataclass
class ImuData:
    time_ns: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray


@dataclasses.dataclass
class RioOptions:
    ekf: EkfConfig = dataclasses.field(default_factory=EkfConfig)
    ego: EgoVelocityConfig = dataclasses.field(default_factory=EgoVelocityConfig)
    radars: tuple[str, ...] | None = None  # None: all radars with detections
    joint_radars: bool = False  # solve scans of all radars at one time together (body velocity)
    static_init_s: float = 1.0
    output_rate_hz: float = 100.0
    coast_warning_s: float = 0.5
    imu_decimation: int = 1  # use every n-th IMU sample (speed against accuracy)
    seed: int = 0
    #: Start pose in the world frame. The world frame's origin is the start pose (see docs/conventions.md), so the
    #: defaults are zero; a simulation whose truth starts elsewhere can start from its first true pose.
    initial_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    initial_yaw_rad: float = 0.0
    #: Online calibration (rio.ekf): every radar's mount and/or time offset as filter states, starting from
    #: the mounts the scans carry. Needs per-radar updates (not ``joint_radars``).
    calibrate_extrinsics: bool = False
    calibrate_time_offset: bool = False
    #: Per radar name, the rig's calibration prior (imaging.core.rig.CalibrationPrior): the time offset to
    #: start from and the standard deviations; radars not named start at offset 0 with the EkfConfig's. Not
    #: calibrating, the time offsets are taken as known (``shift_by_known_offsets``).
    calibration_priors: dict = dataclasses.field(default_factory=dict)

    @property
    def calibrating(self) -> bool:
        """Whether the filter carries calibration states (mounts, time offsets or both)."""
        return self.calibrate_extrinsics or self.calibrate_time_offset


@dataclasses.dataclass
class RioResult:
    trajectory: SampledTrajectory
    covariance_diag: np.ndarray  # [N, 15]
    stats: dict
    #: Time of every radar scan and whether the radar helped (for diagnostics and tests).
    scan_status: list[tuple[int, str, str]]
    gyro_bias_radps: np.ndarray | None = None  # [N, 3] at the trajectory's times
    accel_bias_mps2: np.ndarray | None = None
    #: Online calibration: each calibrated radar's final estimate, and after every one of its updates
    #: (time_ns, radar, rotation vector from the start mount [3] rad (sensor frame), lever arm [3] m,
    #: time offset s, standard deviations [7]).
    calibration: dict[str, CalibrationEstimate] = dataclasses.field(default_factory=dict)
    calibration_log: list = dataclasses.field(default_factory=list)

    @property
    def zero_velocity_times_ns(self) -> np.ndarray:
        return np.array([t for t, _, s in self.scan_status if s == EgoStatus.ZERO_VELOCITY.value], np.int64)


def run_rio(imu: ImuData, scans: list[RadarScan], options: RioOptions = RioOptions(), progress=None) -> RioResult:
    """Run the filter over IMU samples and radar scans (both sorted by time here)."""
    rng = np.random.default_rng(options.seed)
    step = max(1, int(options.imu_decimation))
    t_imu = np.ascontiguousarray(imu.time_ns[::step], dtype=np.int64)
    acc = imu.accel_mps2[::step]
    gyr = imu.gyro_radps[::step]
    if t_imu.size < 10:
        raise ValueError("too few IMU samples to run odometry")
    scans = sorted(scans, key=lambda s: s.time_ns)
    ekf = RadarInertialEkf(options.ekf)
    init_end = t_imu[0] + int(options.static_init_s * 1e9)
    still = t_imu <= init_end
    if np.std(np.linalg.norm(acc[still], axis=1)) > 0.2 or np.max(np.std(gyr[still], axis=0)) > 0.02:
        log.warning("the first %.1f s do not look static: initial attitude and gyro bias may be off", options.static_init_s)
    k0 = int(np.argmax(~still)) if (~still).any() else t_imu.size - 1
    ekf.initialise_static(t_imu[k0], acc[still], gyr[still], options.initial_position_m, options.initial_yaw_rad)
    ekf.propagate(t_imu[k0], acc[k0], gyr[k0])
    start_mounts = add_calibration_states(ekf, scans, options)
    if not options.calibrating:  # the rig's known clock offsets, where the filter does not estimate them
        scans = shift_by_known_offsets(scans, options.calibration_priors)
    calibration_log: list = []
    out_every = max(1, int(round((1e9 / np.median(np.diff(t_imu))) / options.output_rate_hz)))
    record = (np.arange(t_imu.size) - k0) % out_every == 0
    acc = np.ascontiguousarray(acc, dtype=np.float64)
    gyr = np.ascontiguousarray(gyr, dtype=np.float64)
    chunks = []  # recorded states of each run of IMU samples
    stats: Counter = Counter()
    status_log: list[tuple[int, str, str]] = []
    j = 0
    while j < len(scans) and scans[j].time_ns < t_imu[k0]:
        j += 1
    last_help_ns = t_imu[k0]
    coasting = False
    total = t_imu.size - k0
    k = k0 + 1
    while k < t_imu.size:
        # IMU samples up to the next radar scan in one compiled run, then the scan itself.
        k_end = t_imu.size if j >= len(scans) else \
            int(np.searchsorted(t_imu, ekf.measurement_time_ns(scans[j].radar, scans[j].time_ns), side="left"))
        k_end = max(k_end, k)
        if k_end > k:
            chunks.append(ekf.propagate_samples(t_imu[k:k_end], acc[k:k_end], gyr[k:k_end], record[k:k_end]))
            if not (np.all(np.isfinite(ekf.state.p)) and np.all(np.isfinite(ekf.state.P))):
                raise FloatingPointError(f"filter diverged before IMU sample {k_end}")
            if progress is not None and (k_end - k0) // 20000 != (k - k0) // 20000:
                progress(k_end - k0, total)
            k = k_end
        if j >= len(scans):
            break
        group = [scans[j]]
        j += 1
        if options.joint_radars:
            while j < len(scans) and scans[j].time_ns - group[0].time_ns < 5_000_000:
                group.append(scans[j])
                j += 1
        ekf.propagate(max(ekf.state.time_ns, ekf.measurement_time_ns(group[-1].radar, group[-1].time_ns)))
        helped, reason = radar_update(ekf, group, options, rng, stats)
        status_log.extend((g.time_ns, g.radar, reason) for g in group)
        if start_mounts:
            calibration_log.extend(calibration_entry(ekf, g.radar, start_mounts) for g in group if g.radar in start_mounts)
        if options.ekf.planar:
            ekf.update_planar()
        if helped:
            last_help_ns = group[-1].time_ns
            if coasting:
                log.info("radar helps again at t=%.2f s", (group[-1].time_ns - t_imu[k0]) * 1e-9)
            coasting = False
        elif not coasting and group[-1].time_ns - last_help_ns > options.coast_warning_s * 1e9:
            coasting = True
            stats["coast_episodes"] += 1
            log.warning("radar cannot help (%s) for %.1f s: coasting on the IMU", reason,
                        (group[-1].time_ns - last_help_ns) * 1e-9)
    if progress is not None:
        progress(total, total)
    chunks = [c for c in chunks if c is not None and c[0].size]
    times = np.concatenate([c[0] for c in chunks])
    pos = np.concatenate([c[1] for c in chunks])
    vel = np.concatenate([c[2] for c in chunks])
    quat = np.concatenate([c[3] for c in chunks])
    cov = np.concatenate([c[4] for c in chunks])
    # Biases change only at updates: the value at each recorded time is the latest one before it.
    bgs, bas = _bias_history(ekf, times)
    quat = Rotation.from_matrix(quat).as_quat()
    traj = SampledTrajectory(times, pos, quat, vel, source="rio")
    ekf.end_standstill()
    stats.pop("_rejected_in_row", None)
    if ekf.bias_resets:
        stats["gyro_bias_resets"] = ekf.bias_resets
    stats["scans"] = len(scans)
    stats["imu_samples"] = int(t_imu.size)
    return RioResult(traj, cov, dict(stats), status_log, bgs, bas, ekf.calibration_estimates(), calibration_log)


def shift_by_known_offsets(scans: list[RadarScan], priors: dict) -> list[RadarScan]:
    """Each scan at the IMU time its stamp stands for: the stamp less its radar's time offset (radar stamp
    minus IMU time) as ``priors`` (name -> CalibrationPrior, a rig's ``[radar.NAME.calibration]``) give it."""
    offsets_ns = {name: int(round(p.time_offset_s * 1e9)) for name, p in priors.items() if p is not None}
    if not any(offsets_ns.values()):
        return scans
    return sorted((dataclasses.replace(s, time_ns=s.time_ns - offsets_ns.get(s.radar, 0)) for s in scans),
                  key=lambda s: s.time_ns)


def add_calibration_states(ekf: RadarInertialEkf, scans: list[RadarScan], options: RioOptions) -> dict:
    """Give the filter every scanned radar's calibration states, as ``options`` ask; returns the start
    mount of each (empty when not calibrating)."""
    if not options.calibrating:
        return {}
    if options.joint_radars:
        raise ValueError("online calibration needs per-radar updates: joint_radars must be off")
    mounts = {}
    for scan in scans:
        mounts.setdefault(scan.radar, scan.mount)
    for name, mount in mounts.items():
        prior = options.calibration_priors.get(name)
        sigma = prior_sigma(options, name)
        ekf.add_radar_calibration(name, mount, 0.0 if prior is None else prior.time_offset_s,
                                  rotation_sigma_rad=sigma[0:3] if options.calibrate_extrinsics else 0.0,
                                  translation_sigma_m=sigma[3:6] if options.calibrate_extrinsics else 0.0,
                                  time_offset_sigma_s=sigma[6] if options.calibrate_time_offset else 0.0)
    return mounts


def prior_sigma(options: RioOptions, name: str) -> np.ndarray:
    """[7] The standard deviations radar ``name``'s calibration starts from (rad, m, s): the rig's
    ``[radar.NAME.calibration]`` (``options.calibration_priors``) where it gives them, else the filter's defaults."""
    c, p = options.ekf, options.calibration_priors.get(name)
    rotation = (np.radians(p.rotation_sigma_deg) if p is not None and p.rotation_sigma_deg is not None
                else np.full(3, c.calibration_rotation_sigma_rad))
    translation = (np.asarray(p.translation_sigma_m, float) if p is not None and p.translation_sigma_m is not None
                   else np.full(3, c.calibration_translation_sigma_m))
    offset = (p.time_offset_sigma_s if p is not None and p.time_offset_sigma_s is not None
              else c.calibration_time_offset_sigma_s)
    return np.concatenate([rotation, translation, [offset]])


def calibration_entry(ekf: RadarInertialEkf, radar: str, start_mounts: dict) -> tuple:
    """One row of ``RioResult.calibration_log``."""
    cal = ekf.calibration[radar]
    rotvec = Rotation.from_matrix(start_mounts[radar].rotation_matrix.T @ cal.rotation_matrix).as_rotvec()
    return (ekf.state.time_ns, radar, rotvec, cal.translation_m.copy(), cal.time_offset_s, ekf.calibration_sigma(radar))


def _bias_history(ekf: RadarInertialEkf, times: np.ndarray):
    """Bias estimates at ``times``, from the filter's log of (time, b_g, b_a) after each update."""
    log_t = np.array([t for t, _, _ in ekf.bias_log], np.int64)
    idx = np.clip(np.searchsorted(log_t, times, side="right") - 1, 0, len(log_t) - 1)
    bg = np.array([g for _, g, _ in ekf.bias_log])[idx]
    ba = np.array([a for _, _, a in ekf.bias_log])[idx]
    return bg, ba


def radar_update(ekf: RadarInertialEkf, group: list[RadarScan], options: RioOptions, rng, stats: Counter):
    """One radar update of the filter from simultaneous scans (jointly or one by one, as ``options`` say);
    returns (whether it helped, the reason when not). Shared by the batch and the streaming odometry."""
    if options.joint_radars and len(group) > 1:
        w = ekf.last_gyro_radps - ekf.state.bg
        est = body_velocity([(g.mount, g.xyz_m, g.doppler_mps) for g in group], w, options.ego, rng)
        return _apply(ekf, est, None, stats, options.ego)
    helped, reason = False, ""
    for g in group:
        est = sensor_velocity(g.xyz_m, g.doppler_mps, options.ego, rng)
        h, reason = _apply(ekf, est, g.mount, stats, options.ego, g.radar, g.time_ns)
        helped |= h
    return helped, reason


def _imu_still(ekf: RadarInertialEkf) -> bool:
    """The IMU agrees the robot stands still: no rotation beyond noise, specific force of gravity alone
    (over the IMU samples of the last ``still_window_s``; the latest sample where there are too few)."""
    still = ekf.imu_was_still()
    if still is not None:
        return still
    w = ekf.last_gyro_radps - ekf.state.bg
    f = ekf.last_accel_mps2 - ekf.state.ba
    return bool(np.linalg.norm(w) < 0.01 and abs(np.linalg.norm(f) - GRAVITY_MPS2) < 0.15)


def _apply(ekf: RadarInertialEkf, est, mount, stats: Counter, ego: EgoVelocityConfig, radar: str | None = None,
           stamp_ns: int | None = None):
    """Turn one ego-velocity estimate into a filter update; returns (radar helped, reason)."""
    stats[f"ego_{est.status.value}"] += 1
    if est.status is EgoStatus.ZERO_VELOCITY:
        if _imu_still(ekf):
            ekf.update_zero_velocity()
            stats["zero_velocity_updates"] += 1
            return True, est.status.value
        # Creeping (Doppler below the threshold) but the IMU sees motion: an ordinary velocity update with
        # the near-zero velocity measured, as uncertain as the zero-velocity threshold.
        stats["zero_velocity_vetoed_by_imu"] += 1
        est = dataclasses.replace(est, covariance=np.eye(3) * ego.zero_velocity_threshold_mps ** 2)
        return _velocity_update(ekf, est, mount, stats, radar, stamp_ns), "zero_velocity_vetoed_by_imu"
    ekf.end_standstill()
    if est.status is not EgoStatus.OK:
        return False, est.status.value
    accepted = _velocity_update(ekf, est, mount, stats, radar, stamp_ns)
    return accepted, est.status.value if accepted else "rejected_by_gate"


def _velocity_update(ekf: RadarInertialEkf, est, mount, stats: Counter, radar: str | None = None,
                     stamp_ns: int | None = None) -> bool:
    res = ekf.update_radar_velocity(est.velocity_mps, est.covariance, mount, radar, stamp_ns) if mount is not None else \
        ekf.update_body_velocity(est.velocity_mps, est.covariance)
    stats["radar_updates" if res.accepted else "radar_rejected_by_gate"] += 1
    if res.accepted:
        stats["_rejected_in_row"] = 0
        return True
    stats["_rejected_in_row"] += 1
    if stats["_rejected_in_row"] >= ekf.config.gate_recovery_rejections:
        # The gate has refused the radar for a while: more likely the state drifted than every scan is
        # wrong. Re-open the velocity uncertainty so the next consistent scan can pull it back.
        ekf.inflate_velocity_uncertainty()
        stats["gate_recoveries"] += 1
        stats["_rejected_in_row"] = 0
    return False


# -- reading a recording -------------------------------------------------------------------------------------
def imu_from_recording(rec: Recording) -> ImuData:
    imu = rec.imu()
    if imu is None:
        from imaging.core.errors import FileFormatError

        raise FileFormatError(f"{rec.path}: no /imu samples: odometry needs the IMU")
    return ImuData(imu["time_ns"], imu["gyro_radps"], imu["accel_mps2"])


def scans_from_recording(rec: Recording, radars: tuple[str, ...] | None = None, time_offset_ns: int = 0,
                         pointcloud_config=None) -> list[RadarScan]:
    """Every radar's detections grouped by scan, at the scan's mid-frame time.

    Radars that deliver point clouds use their ``/detections``; radars with raw ADC frames only are
    turned into point clouds here (``rio.pointcloud``). Invalid (zero-filled) frames are left out.
    """
    names = radars or tuple(n for n in rec.radar_names if rec.has_detections(n) or rec.has_adc(n))
    scans = []
    for name in names:
        config = rec.radar(name)
        if rec.has_detections(name):
            d = rec.detections(name)
            if d["scan"].size == 0:
                continue
            order = np.argsort(d["scan"], kind="stable")
            cuts = np.flatnonzero(np.diff(d["scan"][order])) + 1
            for idx in np.split(order, cuts):
                scans.append(RadarScan(int(d["time_ns"][idx[0]]) + time_offset_ns, name, config.mount,
                                       d["xyz_m"][idx].astype(np.float64), d["doppler_mps"][idx].astype(np.float64)))
        elif rec.has_adc(name):
            scans.extend(_scans_from_adc(rec, name, config, time_offset_ns, pointcloud_config))
        else:
            from imaging.core.errors import FileFormatError

            raise FileFormatError(f"{rec.path}: radar {name} has neither detections nor ADC frames")
    return sorted(scans, key=lambda s: s.time_ns)


def _scans_from_adc(rec: Recording, name: str, config, time_offset_ns: int, pointcloud_config) -> list[RadarScan]:
    from .pointcloud import PointCloudConfig, detect

    pc_config = pointcloud_config or PointCloudConfig()
    wf = config.waveform
    tx_order = rec.tdm_tx_order(name)
    half_frame = wf.frame_duration_ns // 2
    n = rec.n_frames(name)
    out = []
    for start in range(0, n, 32):
        block = slice(start, min(start + 32, n))
        adc = rec.adc(name, block)
        times = rec.frame_time_ns(name, block)
        valid = rec.valid(name, block)
        for frame, t, ok in zip(adc, times, valid):
            if not ok:
                continue
            pc = detect(frame, config, tx_order, pc_config)
            out.append(RadarScan(int(t) + half_frame + time_offset_ns, name, config.mount, pc.xyz_m, pc.doppler_mps))
    return out
