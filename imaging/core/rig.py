"""Antenna arrays, sensor mounts and the rig of several radars plus an IMU, loaded from TOML.

A rig file::

    [imu]
    rate_hz = 400.0

    [radar.left_front]
    mount_translation_m = [0.15, 0.20, 0.30]
    mount_yaw_deg = 90.0            # or mount_rotation_xyzw = [x, y, z, w]
    [radar.left_front.waveform]
    f0_hz = 76.0e9
    [radar.left_front.imu]          # optional: an IMU on the radar's own mount (axes: the radar's)
    rate_hz = 1000.0

Every value is checked on load; an error names the field, e.g. ``radar.left_front.waveform.n_tx``.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from imaging.core import quaternion
from imaging.core.config import ConfigError, as_vector, from_dict, read_toml, require
from imaging.core.waveform import Waveform

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


@dataclasses.dataclass(frozen=True)
class AntennaArray:
    """TX and RX phase-centre positions in the sensor frame (x boresight, y left, z up), metres."""

    tx_positions_m: np.ndarray  # [n_tx, 3]
    rx_positions_m: np.ndarray  # [n_rx, 3]

    def __post_init__(self) -> None:
        for name in ("tx_positions_m", "rx_positions_m"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1 or not np.all(np.isfinite(arr)):
                raise ConfigError(name, f"expected a list of [x, y, z] positions, got shape {arr.shape}")
            object.__setattr__(self, name, arr)

    @classmethod
    def uniform_tdm(cls, waveform: Waveform) -> "AntennaArray":
        """docs/signal-model.md's default: RX at y = j*lambda0/2, TX at y = n_rx*i*lambda0/2 (a filled virtual array)."""
        half = waveform.wavelength_f0_m / 2.0
        rx = np.zeros((waveform.n_rx, 3))
        rx[:, 1] = np.arange(waveform.n_rx) * half
        tx = np.zeros((waveform.n_tx, 3))
        tx[:, 1] = waveform.n_rx * np.arange(waveform.n_tx) * half
        return cls(tx, rx)

    @property
    def n_tx(self) -> int:
        return self.tx_positions_m.shape[0]

    @property
    def n_rx(self) -> int:
        return self.rx_positions_m.shape[0]


@dataclasses.dataclass(frozen=True)
class Mount:
    """Pose of a sensor in the body frame: p_b = translation + R(rotation) p_s."""

    translation_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    rotation_xyzw: np.ndarray = dataclasses.field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))

    def __post_init__(self) -> None:
        object.__setattr__(self, "translation_m", as_vector(self.translation_m, 3, "mount_translation_m"))
        q = as_vector(self.rotation_xyzw, 4, "mount_rotation_xyzw")
        norm = np.linalg.norm(q)
        if not 0.9 < norm < 1.1:
            raise ConfigError("mount_rotation_xyzw", f"is not a unit quaternion (norm {norm:.3g})")
        object.__setattr__(self, "rotation_xyzw", q / norm)

    @classmethod
    def from_yaw(cls, translation_m, yaw_deg: float) -> "Mount":
        """A sensor whose boresight points at ``yaw_deg`` from body x towards body y, level."""
        return cls(np.asarray(translation_m, float), quaternion.about_z(np.deg2rad(yaw_deg)))

    @property
    def rotation(self) -> Rotation:
        """Sensor -> body as scipy's Rotation (imported here: the imaging path needs only the matrix)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.rotation_xyzw)

    @functools.cached_property
    def rotation_matrix(self) -> np.ndarray:
        """Sensor -> body rotation matrix (computed once: filters use it at every update)."""
        return quaternion.to_matrix(quaternion.normalized(self.rotation_xyzw))  # as scipy's from_quat(q).as_matrix()

    def to_body(self, points_sensor_m: np.ndarray) -> np.ndarray:
        """Sensor-frame points [..., 3] to body frame."""
        # by the cached matrix: a live map places every frame's antennas, and building a Rotation each
        # time cost more than the arithmetic
        return np.asarray(points_sensor_m, float) @ self.rotation_matrix.T + self.translation_m

    @property
    def boresight_body(self) -> np.ndarray:
        return self.rotation_matrix[:, 0].copy()


#: What a radar may be called: its name is a path element of the recording (/radar/NAME) and the bus.
RADAR_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{0,63}")


@dataclasses.dataclass(frozen=True)
class CalibrationPrior:
    """What is known of a radar's mount and clock beyond its nominal values (rig: ``[radar.NAME.calibration]``,
    written by ``sarbot calibrate``): the time offset (radar stamp minus IMU time, s) and the standard
    deviations of the mount's rotation (about the sensor's x, y, z, degrees), lever arm (body x, y, z, m) and
    time offset. The odometry's online calibration starts from them; None: its defaults."""

    rotation_sigma_deg: tuple[float, float, float] | None = None
    translation_sigma_m: tuple[float, float, float] | None = None
    time_offset_s: float = 0.0
    time_offset_sigma_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("rotation_sigma_deg", "translation_sigma_m"):
            value = getattr(self, name)
            if value is not None:
                value = tuple(float(x) for x in as_vector(value, 3, name))
                require(all(x >= 0 for x in value), name, "must not be negative")
                object.__setattr__(self, name, value)
        require(self.time_offset_sigma_s is None or self.time_offset_sigma_s >= 0, "time_offset_sigma_s",
                "must not be negative")


@dataclasses.dataclass(frozen=True)
class RadarConfig:
    """One radar of the rig: its name, waveform, array and mount."""

    name: str
    waveform: Waveform
    array: AntennaArray
    mount: Mount
    #: An IMU fixed to the radar itself (its axes the radar's: x along the boresight), for the vibration
    #: the robot's IMU cannot see; None where the rig declares none.
    imu: "ImuConfig | None" = None
    #: The mount's and clock's uncertainty and time offset, where a calibration gave them.
    calibration: CalibrationPrior | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not RADAR_NAME.fullmatch(self.name):
            raise ConfigError(f"radar.{self.name}", "a radar's name is 1 to 64 letters, digits, '_' or '-' (it names "
                                                    "an HDF5 group and a bus topic: no '/', '.' or spaces)")
        if self.array.n_tx != self.waveform.n_tx:
            raise ConfigError(f"radar.{self.name}.tx_positions_m", f"has {self.array.n_tx} TX, waveform.n_tx is {self.waveform.n_tx}")
        if self.array.n_rx != self.waveform.n_rx:
            raise ConfigError(f"radar.{self.name}.rx_positions_m", f"has {self.array.n_rx} RX, waveform.n_rx is {self.waveform.n_rx}")


@dataclasses.dataclass(frozen=True)
class ImuConfig:
    """The IMU: sample rate, mount and (if known) noise densities, SI units."""

    rate_hz: float = 400.0
    mount: Mount = dataclasses.field(default_factory=Mount)
    gyro_noise_density_radps_per_sqrt_hz: float = 1.0e-4
    accel_noise_density_mps2_per_sqrt_hz: float = 1.0e-3
    gyro_bias_random_walk_radps2_per_sqrt_hz: float = 1.0e-5
    accel_bias_random_walk_mps3_per_sqrt_hz: float = 1.0e-4

    def __post_init__(self) -> None:
        require(self.rate_hz > 0, "rate_hz", f"must be positive, got {self.rate_hz}")
        for f in dataclasses.fields(self):
            if f.name.endswith("sqrt_hz"):
                require(getattr(self, f.name) >= 0, f.name, "must not be negative")


@dataclasses.dataclass(frozen=True)
class Rig:
    """Radars and IMU of one robot."""

    radars: tuple[RadarConfig, ...]
    imu: ImuConfig = dataclasses.field(default_factory=ImuConfig)

    def __post_init__(self) -> None:
        names = [r.name for r in self.radars]
        if len(set(names)) != len(names):
            raise ConfigError("radar", f"duplicate radar names in {names}")

    def radar(self, name: str) -> RadarConfig:
        for r in self.radars:
            if r.name == name:
                return r
        raise KeyError(name)

    @property
    def radar_names(self) -> list[str]:
        return [r.name for r in self.radars]

    def calibration_priors(self) -> dict[str, CalibrationPrior]:
        """Per radar name, its ``[radar.NAME.calibration]``, for the radars that have one."""
        return {r.name: r.calibration for r in self.radars if r.calibration is not None}


def default_rig() -> Rig:
    """Four reference radars facing outward, perpendicular to travel, start frequencies 76.0-76.3 GHz.

    Two look left (+y body), two right; front and rear pairs 0.3 m apart, 0.3 m above the IMU.
    """
    placements = [
        ("left_front", (0.15, 0.20, 0.30), 90.0),
        ("left_rear", (-0.15, 0.20, 0.30), 90.0),
        ("right_front", (0.15, -0.20, 0.30), -90.0),
        ("right_rear", (-0.15, -0.20, 0.30), -90.0),
    ]
    radars = []
    for i, (name, t, yaw) in enumerate(placements):
        wf = Waveform(f0_hz=76.0e9 + i * 100e6)
        radars.append(RadarConfig(name, wf, AntennaArray.uniform_tdm(wf), Mount.from_yaw(t, yaw)))
    return Rig(tuple(radars))


def _mount_from_table(table: dict[str, Any], prefix: str) -> Mount:
    translation = table.pop("mount_translation_m", [0.0, 0.0, 0.0])
    has_yaw = "mount_yaw_deg" in table
    has_quat = "mount_rotation_xyzw" in table
    if has_yaw and has_quat:
        raise ConfigError(f"{prefix}.mount_yaw_deg", "give either mount_yaw_deg or mount_rotation_xyzw, not both")
    try:
        if has_yaw:
            yaw = table.pop("mount_yaw_deg")
            if isinstance(yaw, bool) or not isinstance(yaw, (int, float)):
                raise ConfigError("mount_yaw_deg", f"expected a number, got {yaw!r}")
            return Mount.from_yaw(as_vector(translation, 3, "mount_translation_m"), float(yaw))
        return Mount(translation, table.pop("mount_rotation_xyzw", [0.0, 0.0, 0.0, 1.0]))
    except ConfigError as exc:
        raise ConfigError(f"{prefix}.{exc.field}", str(exc).split(": ", 1)[-1]) from None
    except (TypeError, ValueError) as exc:  # strings, nested lists where numbers belong
        raise ConfigError(f"{prefix}.mount", f"expected numbers for the mount ({exc})") from None


def rig_from_dict(table: dict[str, Any], source: str | None = None) -> Rig:
    """Build a Rig from a parsed TOML table (see the module docstring for the layout)."""
    try:
        table = dict(table)
        radar_tables = table.pop("radar", None)
        imu_table = table.pop("imu", {})
        if not isinstance(imu_table, dict):
            raise ConfigError("imu", "expected a table")
        imu_table = dict(imu_table)
        if table:
            raise ConfigError(sorted(table)[0], "unknown section (known: radar, imu)")
        if not isinstance(radar_tables, dict) or not radar_tables:
            raise ConfigError("radar", "at least one [radar.NAME] table is required")
        radars = []
        for name, rt in radar_tables.items():
            prefix = f"radar.{name}"
            if not isinstance(rt, dict):
                raise ConfigError(prefix, "expected a table")
            rt = dict(rt)
            mount = _mount_from_table(rt, prefix)
            wf = from_dict(Waveform, rt.pop("waveform", {}), prefix=f"{prefix}.waveform")
            default_array = AntennaArray.uniform_tdm(wf)
            tx = rt.pop("tx_positions_m", default_array.tx_positions_m)
            rx = rt.pop("rx_positions_m", default_array.rx_positions_m)
            radar_imu = rt.pop("imu", None)
            if radar_imu is not None:
                if not isinstance(radar_imu, dict):
                    raise ConfigError(f"{prefix}.imu", "expected a table")
                for key in ("mount_translation_m", "mount_yaw_deg", "mount_rotation_xyzw", "mount"):
                    if key in radar_imu:
                        raise ConfigError(f"{prefix}.imu.{key}", "a radar's IMU sits on the radar's mount, with the radar's axes")
                radar_imu = from_dict(ImuConfig, radar_imu, prefix=f"{prefix}.imu")
            calibration = rt.pop("calibration", None)
            if calibration is not None:
                if not isinstance(calibration, dict):
                    raise ConfigError(f"{prefix}.calibration", "expected a table")
                calibration = from_dict(CalibrationPrior, calibration, prefix=f"{prefix}.calibration")
            if rt:
                raise ConfigError(f"{prefix}.{sorted(rt)[0]}", "unknown setting")
            try:
                array = AntennaArray(np.asarray(tx, float), np.asarray(rx, float))
            except (ConfigError, ValueError) as exc:
                raise ConfigError(f"{prefix}.array", str(exc)) from None
            radars.append(RadarConfig(name, wf, array, mount, radar_imu, calibration))
        imu_mount = _mount_from_table(imu_table, "imu")
        imu = from_dict(ImuConfig, imu_table, prefix="imu")
        imu = dataclasses.replace(imu, mount=imu_mount)
        return Rig(tuple(radars), imu)
    except ConfigError as exc:
        if source and exc.source is None:
            raise ConfigError(exc.field, str(exc).split(": ", 1)[-1], source=source) from None
        raise


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig TOML file."""
    return rig_from_dict(read_toml(path), source=str(path))
