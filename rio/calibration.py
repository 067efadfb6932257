"""Radar calibration from a drive: each radar's mount (rotation, lever arm) and time offset, refined by the
odometry's filter with its calibration states on, and only where the drive made them observable.

What a drive makes observable (see rio.ekf): a radar measures its own velocity, R_m^T (v_b + w x l) at the
stamp less its time offset. So the lever arm l shows only while the robot turns, and only across the axis it
turns about (a robot on a floor turns about z: the lever arm along z never shows); the rotation about the
boresight's horizontal normal (the mount's pitch for a radar looking sideways, a turn about its own array's
axis) shows only through velocity along the boresight, which a robot driving forward gives a sideways radar
only from w x l, and then only in the vertical velocity. The lever arm along z is refused on a floor robot; the
pitch is taken where the drive turned fast and long enough (tight circles both ways, rio.calibration_drive's
TIGHT_TURNS, benchmarks/calibration_pitch.py) and refused otherwise. Left wrong, both are harmless on a floor
(rio.calibration_unobservable, benchmarks/calibration_unobservable.py). The time offset shows only while the sensor's velocity changes (accelerating, braking, turning in and out). An axis whose
standard deviation the drive did not bring below ``CalibrationLimits`` is refused: it keeps the rig's value,
and the report says which axis and why, instead of a confident wrong value.

Pure computation; ``write_rig_toml`` is the one function that writes a file.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.rig import CalibrationPrior, Mount, RadarConfig, Rig

from .ekf import CalibrationEstimate
from .odometry import ImuData, RadarScan, RioOptions, RioResult, prior_sigma, run_rio

#: The 7 calibration axes, in the filter's order.
AXES = ("rotation about x (roll about the boresight)", "rotation about y (pitch, the boresight's tilt)",
        "rotation about z (yaw)", "lever arm x", "lever arm y", "lever arm z", "time offset")
AXIS_KEYS = ("roll", "pitch", "yaw", "lever_x", "lever_y", "lever_z", "time_offset")


@dataclasses.dataclass(frozen=True)
class CalibrationLimits:
    """When an axis is taken: its standard deviation at most this, and the drive excited it at least this
    much (RMS over the drive, see ``RadarExcitation``) -- a filter's standard deviation alone can shrink on
    what a model error, not the data, tells it (the elevation of a radar's detections is poor, so is the
    vertical velocity it gives)."""

    rotation_sigma_deg: float = 0.1
    translation_sigma_m: float = 0.0025
    time_offset_sigma_s: float = 0.0005
    min_speed_across_mps: float = 0.2  # the radar's velocity across the rotation's axis
    min_rate_across_radps: float = 0.2  # the robot's rate of turn across the lever arm's axis
    min_velocity_change_mps2: float = 0.2  # how fast the radar's velocity changes

    def as_array(self) -> np.ndarray:
        return np.array([math.radians(self.rotation_sigma_deg)] * 3 + [self.translation_sigma_m] * 3
                        + [self.time_offset_sigma_s])


@dataclasses.dataclass(frozen=True)
class DriveExcitation:
    """How much the drive moved the way calibration needs: time turning (|w_z| above 0.2 rad/s), time
    rolling or pitching (|w_x|, |w_y| above 0.2 rad/s), time accelerating (horizontal specific force beyond
    0.2 m/s^2), seconds."""

    turning_s: float
    tilting_s: float
    accelerating_s: float

    @classmethod
    def of(cls, imu: ImuData) -> "DriveExcitation":
        t = imu.time_ns
        if t.size < 2:
            return cls(0.0, 0.0, 0.0)
        dt = float(np.median(np.diff(t))) * 1e-9
        bias = imu.gyro_radps[: max(1, int(1.0 / dt))].mean(axis=0)  # the static start
        w = imu.gyro_radps - bias
        f = imu.accel_mps2
        gravity_dir = f[: max(1, int(1.0 / dt))].mean(axis=0)
        gravity_dir /= np.linalg.norm(gravity_dir)
        horizontal = f - np.outer(f @ gravity_dir, gravity_dir)
        return cls(float(np.sum(np.abs(w[:, 2]) > 0.2) * dt), float(np.sum(np.linalg.norm(w[:, :2], axis=1) > 0.2) * dt),
                   float(np.sum(np.linalg.norm(horizontal, axis=1) > 0.2) * dt))


@dataclasses.dataclass(frozen=True)
class RadarExcitation:
    """What the drive gave one radar, RMS over the time it moved: its velocity across each of its own axes
    (what a rotation about that axis needs), the robot's rate of turn across each body axis (what the lever
    arm along it needs), and the rate of change of the radar's velocity (what the time offset needs)."""

    speed_across_mps: np.ndarray  # [3] sensor x, y, z
    rate_across_radps: np.ndarray  # [3] body x, y, z
    velocity_change_mps2: float

    @classmethod
    def of(cls, res: RioResult, imu: ImuData, mount: Mount) -> "RadarExcitation":
        traj = res.trajectory
        R = Rotation.from_quat(traj.orientation_xyzw)
        v_body = R.inv().apply(traj.velocity_mps)
        idx = np.clip(np.searchsorted(imu.time_ns, traj.time_ns), 0, imu.time_ns.size - 1)
        w = imu.gyro_radps[idx] - (res.gyro_bias_radps if res.gyro_bias_radps is not None else 0.0)
        v_s = (v_body + np.cross(w, mount.translation_m)) @ mount.rotation_matrix
        moving = np.linalg.norm(v_body, axis=1) > 0.05
        if moving.sum() < 10:
            return cls(np.zeros(3), np.zeros(3), 0.0)
        v_s, w = v_s[moving], w[moving]
        speed = np.sqrt(np.mean(np.sum(v_s ** 2, axis=1)[:, None] - v_s ** 2, axis=0))
        rate = np.sqrt(np.mean(np.sum(w ** 2, axis=1)[:, None] - w ** 2, axis=0))
        dt = np.diff(traj.time_ns[moving]) * 1e-9
        change = np.linalg.norm(np.diff(v_s, axis=0), axis=1) / np.where(dt > 0, dt, np.inf)
        change = change[dt < 0.05]  # not across a standstill
        return cls(speed, rate, float(np.sqrt(np.mean(change ** 2))) if change.size else 0.0)

    def excited(self, limits: CalibrationLimits) -> np.ndarray:
        """[7] bool: whether the drive excited each axis enough."""
        return np.concatenate([self.speed_across_mps >= limits.min_speed_across_mps,
                               self.rate_across_radps >= limits.min_rate_across_radps,
                               [self.velocity_change_mps2 >= limits.min_velocity_change_mps2]])


def why_unobservable(axis: int, mount: Mount, drive: DriveExcitation, sigma_over_limit: float | None = None) -> str:
    """Why the drive left calibration ``axis`` (an index into AXES) undetermined, in words; ``sigma_over_limit``:
    the standard deviation the drive left over the one needed, for how much more of the same drive it takes."""
    if axis in (3, 4, 5):
        if drive.turning_s < 2.0 and drive.tilting_s < 2.0:
            return (f"the drive hardly turned ({drive.turning_s:.1f} s above 0.2 rad/s): the lever arm shows only in "
                    "the velocity w x l a rotation gives the radar, and on a straight drive it trades against the yaw")
        if axis == 5 and drive.tilting_s < 2.0:
            return ("the drive turned only about z: a lever arm along z changes no velocity then (w x l = 0), and on a "
                    "level track it shifts a strip map's targets by lz^2/2r without blurring them: unobservable and "
                    "harmless on a floor (rio.calibration_unobservable)")
        return "the turns were too few or too slow for the lever arm along this axis"
    if axis in (0, 1, 2):
        boresight = mount.rotation_matrix[:, 0]
        if axis == 1 and abs(boresight[2]) < 0.5 and abs(boresight[0]) < 0.5:
            return _sideways_pitch_refusal(drive, sigma_over_limit)
        if drive.accelerating_s < 2.0 and drive.turning_s < 2.0:
            return "the drive had too few accelerations and turns to tell the mount's rotation from the velocity's"
        return "the drive's velocity directions in the radar frame were too few for this rotation"
    if drive.accelerating_s < 2.0 and drive.turning_s < 2.0:
        return "the velocity hardly changed (no accelerations, no turns): a time offset shows only then"
    return "the accelerations and turn onsets were too few or too gentle for this time offset"


def _sideways_pitch_refusal(drive: DriveExcitation, sigma_over_limit: float | None) -> str:
    """A sideways radar's pitch: observable only from turning (benchmarks/calibration_pitch.py)."""
    why = ("the radar looks sideways: this tilt turns it about its own array's axis, which moves no antenna and no "
           "cone angle and changes a Doppler level with the radar by 1 - cos (1.5e-4 at 1 deg); only the vertical "
           "velocity a turn gives the boresight (w x l) shows it")
    harmless = "harmless to odometry and strip map on a floor (rio.calibration_unobservable)"
    if drive.turning_s < 2.0:
        return (f"{why}, and the drive hardly turned ({drive.turning_s:.1f} s above 0.2 rad/s): unobservable on this "
                f"drive, and {harmless}")
    more = ""
    if sigma_over_limit is not None and sigma_over_limit > 1.0:
        # the information grows with the time spent turning: the variance falls as 1 / turning time
        more = f": about {drive.turning_s * (sigma_over_limit ** 2 - 1):.0f} s more of such turning"
    return (f"{why}, and the {drive.turning_s:.0f} s of turning were too few or too slow{more}, or tight circles "
            "both ways (rio.calibration_drive.TIGHT_TURNS); unobservable without turns, and left wrong "
            f"{harmless}")


@dataclasses.dataclass
class RadarCalibrationResult:
    """One radar: the rig's mount and offset, the estimate, which axes were taken and why others were not."""

    name: str
    prior_mount: Mount
    prior_time_offset_s: float
    estimate: CalibrationEstimate
    accepted: np.ndarray  # [7] bool, in AXES order
    reasons: dict[str, str]  # refused axis key -> why

    @property
    def rotation_change_deg(self) -> np.ndarray:
        """The estimate's rotation against the rig's, about the sensor's x, y, z (deg)."""
        d = self.prior_mount.rotation.inv() * self.estimate.mount.rotation
        return np.degrees(d.as_rotvec())

    def refined_mount(self) -> Mount:
        """The rig's mount with the accepted axes moved to the estimate."""
        rotvec = np.radians(self.rotation_change_deg) * self.accepted[0:3]
        rotation = self.prior_mount.rotation * Rotation.from_rotvec(rotvec)
        translation = np.where(self.accepted[3:6], self.estimate.mount.translation_m, self.prior_mount.translation_m)
        return Mount(translation, rotation.as_quat())

    def refined_time_offset_s(self) -> float:
        return self.estimate.time_offset_s if self.accepted[6] else self.prior_time_offset_s

    def prior(self) -> CalibrationPrior:
        """What the rig file should say of this radar now: the refined offset and every axis's standard
        deviation (the estimate's where taken, the prior's where refused)."""
        return CalibrationPrior(rotation_sigma_deg=tuple(float(x) for x in np.degrees(self.sigma[0:3])),
                                translation_sigma_m=tuple(float(x) for x in self.sigma[3:6]),
                                time_offset_s=self.refined_time_offset_s(), time_offset_sigma_s=float(self.sigma[6]))

    sigma: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(7))

    def lines(self) -> list[str]:
        """What the calibration says of this radar, for people."""
        est, rot = self.estimate, self.rotation_change_deg
        out = [f"radar {self.name}:"]
        for i, key in enumerate(AXIS_KEYS):
            if i < 3:
                value = f"{rot[i]:+.3f} deg +- {math.degrees(est.sigma[i]):.3f}"
            elif i < 6:
                change = (est.mount.translation_m[i - 3] - self.prior_mount.translation_m[i - 3]) * 1e3
                value = f"{change:+.1f} mm +- {est.sigma[i] * 1e3:.1f}"
            else:
                value = f"{(est.time_offset_s - self.prior_time_offset_s) * 1e3:+.2f} ms +- {est.sigma[6] * 1e3:.2f}"
            verdict = "taken" if self.accepted[i] else f"NOT taken: {self.reasons[key]}"
            out.append(f"  {AXES[i]}: {value}: {verdict}")
        return out


@dataclasses.dataclass
class CalibrationResult:
    radars: dict[str, RadarCalibrationResult]
    rio: RioResult
    drive: DriveExcitation

    def report(self) -> str:
        return "\n".join(line for r in self.radars.values() for line in r.lines())


def calibrate(imu: ImuData, scans: list[RadarScan], options: RioOptions = RioOptions(), *,
              time_offset: bool = True, limits: CalibrationLimits = CalibrationLimits(),
              iterations: int = 1) -> CalibrationResult:
    """Run the odometry over a calibration drive with every radar's calibration states on and judge each
    axis. ``iterations`` > 1 runs the filter again from the previous estimate (the linearisation point; the
    prior's width stays the rig's, so no information is counted twice)."""
    opts = dataclasses.replace(options, calibrate_extrinsics=True, calibrate_time_offset=time_offset,
                               joint_radars=False)
    prior_mounts: dict[str, Mount] = {}
    for s in scans:
        prior_mounts.setdefault(s.radar, s.mount)
    prior_offsets = {n: (opts.calibration_priors[n].time_offset_s if n in opts.calibration_priors else 0.0)
                     for n in prior_mounts}
    current = scans
    res = None
    for _ in range(max(1, iterations)):
        res = run_rio(imu, current, opts)
        mounts = {n: e.mount for n, e in res.calibration.items()}
        current = [dataclasses.replace(s, mount=mounts[s.radar]) for s in scans]
        opts = dataclasses.replace(opts, calibration_priors={
            n: dataclasses.replace(opts.calibration_priors.get(n, CalibrationPrior()), time_offset_s=e.time_offset_s)
            for n, e in res.calibration.items()})
    drive = DriveExcitation.of(imu)
    limit = limits.as_array()
    radars = {}
    for name, est in res.calibration.items():
        excitation = RadarExcitation.of(res, imu, est.mount)
        excited = excitation.excited(limits)
        accepted = (est.sigma <= limit) & excited
        if not time_offset:
            accepted[6] = False
        reasons = {AXIS_KEYS[i]: ("not estimated" if i == 6 and not time_offset else
                                  f"{why_unobservable(i, prior_mounts[name], drive, est.sigma[i] / limit[i])} "
                                  f"({_excitation_text(i, excitation)}; "
                                  f"standard deviation {_axis_value(i, est.sigma[i])} left, {_axis_value(i, limit[i])} "
                                  "needed)")
                   for i in range(7) if not accepted[i]}
        # A refused axis keeps the rig's value, so it keeps the rig's standard deviation too: the filter's
        # would call the rig's value (a 5 ms late clock kept at 0) known to within what the drive nearly showed.
        sigma = np.where(accepted, est.sigma, prior_sigma(options, name))
        radars[name] = RadarCalibrationResult(name, prior_mounts[name], prior_offsets[name], est, accepted, reasons,
                                              sigma=sigma)
    return CalibrationResult(radars, res, drive)


def _excitation_text(axis: int, e: RadarExcitation) -> str:
    if axis < 3:
        return f"RMS velocity across the radar's {'xyz'[axis]} axis {e.speed_across_mps[axis]:.2f} m/s"
    if axis < 6:
        return f"RMS rate of turn across body {'xyz'[axis - 3]} {e.rate_across_radps[axis - 3]:.2f} rad/s"
    return f"RMS change of the radar's velocity {e.velocity_change_mps2:.2f} m/s^2"


def _axis_value(axis: int, value: float) -> str:
    if axis < 3:
        return f"{math.degrees(value):.3f} deg"
    if axis < 6:
        return f"{value * 1e3:.1f} mm"
    return f"{value * 1e3:.2f} ms"


def refined_rig(rig: Rig, result: CalibrationResult) -> Rig:
    """``rig`` with every calibrated radar's refined mount and its calibration prior."""
    radars = []
    for r in rig.radars:
        c = result.radars.get(r.name)
        radars.append(r if c is None else dataclasses.replace(r, mount=c.refined_mount(), calibration=c.prior()))
    return dataclasses.replace(rig, radars=tuple(radars))


# -- the rig file ----------------------------------------------------------------------------------------------
def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} to TOML")


def _init_fields(obj) -> dict:
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}


def rig_toml(rig: Rig, header: str = "") -> str:
    """The rig as a rig file (what ``imaging.core.rig.load_rig`` reads back)."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    imu = rig.imu
    lines += ["", "[imu]"]
    for key, value in _init_fields(imu).items():
        if key != "mount":
            lines.append(f"{key} = {_toml_value(value)}")
    lines.append(f"mount_translation_m = {_toml_value(imu.mount.translation_m)}")
    lines.append(f"mount_rotation_xyzw = {_toml_value(imu.mount.rotation_xyzw)}")
    for r in rig.radars:
        lines += ["", f"[radar.{r.name}]", f"mount_translation_m = {_toml_value(r.mount.translation_m)}",
                  f"mount_rotation_xyzw = {_toml_value(r.mount.rotation_xyzw)}",
                  "waveform = { " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in _init_fields(r.waveform).items()) + " }",
                  f"tx_positions_m = {_toml_value(r.array.tx_positions_m.tolist())}",
                  f"rx_positions_m = {_toml_value(r.array.rx_positions_m.tolist())}"]
        if r.calibration is not None:
            lines.append(f"[radar.{r.name}.calibration]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in _init_fields(r.calibration).items() if v is not None]
        if r.imu is not None:
            lines.append(f"[radar.{r.name}.imu]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in _init_fields(r.imu).items() if k != "mount"]
    return "\n".join(lines) + "\n"


def write_rig_toml(rig: Rig, path: str | Path, header: str = "") -> Path:
    """Write ``rig`` as a rig file at ``path``."""
    path = Path(path)
    path.write_text(rig_toml(rig, header))
    return path


def rig_of_recording(rec) -> Rig:
    """The rig a recording was made with, as far as it says (radars, IMU rate and mount)."""
    from imaging.core.rig import ImuConfig

    radars = tuple(rec.radar(n) for n in rec.radar_names)
    g = rec.file.get("imu")
    if g is None:
        return Rig(radars)
    rate = float(g.attrs.get("rate_hz", 400.0))
    mount = Mount(np.asarray(g.attrs.get("mount_translation_m", np.zeros(3)), float),
                  np.asarray(g.attrs.get("mount_rotation_xyzw", [0.0, 0.0, 0.0, 1.0]), float))
    return Rig(radars, ImuConfig(rate_hz=rate, mount=mount))


def calibrate_recording(path: str | Path, out: str | Path, rig: Rig | None = None, options: RioOptions = RioOptions(),
                        **kwargs) -> CalibrationResult:
    """``sarbot calibrate``: the calibration of the drive recorded at ``path`` (the rig the recording holds,
    or ``rig``), and the refined rig written to ``out`` with the report as its header."""
    from imaging.io.recording import Recording

    from .odometry import imu_from_recording, scans_from_recording

    with Recording(path) as rec:
        rig = rig or rig_of_recording(rec)
        imu = imu_from_recording(rec)
        scans = [dataclasses.replace(s, mount=rig.radar(s.radar).mount) for s in scans_from_recording(rec)]
    options = dataclasses.replace(options, calibration_priors={**rig.calibration_priors(), **options.calibration_priors})
    result = calibrate(imu, scans, options, **kwargs)
    header = f"Calibrated by sarbot calibrate from {Path(path).name}: axes not taken keep the rig's values.\n" + result.report()
    write_rig_toml(refined_rig(rig, result), out, header)
    return result


def calibration_for_file(res: RioResult) -> tuple[dict[str, dict], dict[str, dict]]:
    """The filter's calibration as ``imaging.io.trajectory_file.write_calibration`` takes it: (final values
    per radar, history per radar)."""
    radars = {name: {"mount_translation_m": e.mount.translation_m, "mount_rotation_xyzw": e.mount.rotation_xyzw,
                     "time_offset_s": e.time_offset_s, "sigma": e.sigma} for name, e in res.calibration.items()}
    history: dict[str, dict] = {}
    for name in radars:
        rows = [row for row in res.calibration_log if row[1] == name]
        history[name] = {"time_ns": np.array([r[0] for r in rows], np.int64),
                         "rotation_change_rad": np.array([r[2] for r in rows]).reshape(-1, 3),
                         "lever_arm_m": np.array([r[3] for r in rows]).reshape(-1, 3),
                         "time_offset_s": np.array([r[4] for r in rows], float),
                         "sigma": np.array([r[5] for r in rows]).reshape(-1, 7)}
    return radars, history
