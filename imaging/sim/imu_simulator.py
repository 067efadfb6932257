"""IMU samples from a trajectory: specific force and angular rate with white noise and bias random walk."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.core.constants import GRAVITY_MPS2
from imaging.core.rig import ImuConfig
from imaging.core.trajectory import Trajectory


@dataclasses.dataclass
class ImuErrors:
    """Deterministic IMU errors on top of the noise densities of ImuConfig (body/IMU frame, SI)."""

    gyro_bias_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: A bias step (e.g. a temperature jump) at ``step_time_s`` after the start.
    step_time_s: float | None = None
    step_gyro_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    step_accel_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclasses.dataclass
class ImuSamples:
    time_ns: np.ndarray  # [N]
    gyro_radps: np.ndarray  # [N, 3]
    accel_mps2: np.ndarray  # [N, 3] specific force
    counter: np.ndarray  # [N] uint32
    gyro_bias_radps: np.ndarray  # [N, 3] the true biases (for evaluation)
    accel_bias_mps2: np.ndarray  # [N, 3]


def simulate_imu(trajectory: Trajectory, imu: ImuConfig, start_ns: int, stop_ns: int, *,
                 errors: ImuErrors | None = None, rng: np.random.Generator | None = None,
                 noise: bool = True) -> ImuSamples:
    """IMU output at ``imu.rate_hz`` from ``start_ns`` to ``stop_ns``.

    Specific force f = R^T (a - g) with g = (0, 0, -9.80665) in the level world frame; both f and the
    angular rate are rotated into the IMU frame by the IMU mount (the body frame sits at the IMU, so
    its translation is not used). Noise: white with the stated densities, plus a bias random walk.
    """
    rng = rng or np.random.default_rng()
    errors = errors or ImuErrors()
    dt = 1.0 / imu.rate_hz
    n = int(math.floor((stop_ns - start_ns) * 1e-9 * imu.rate_hz)) + 1
    time_ns = start_ns + np.round(np.arange(n) * dt * 1e9).astype(np.int64)
    s = trajectory.sample(time_ns)
    if s.acceleration_mps2 is None:
        raise ValueError("trajectory gives no acceleration; IMU synthesis needs it")
    rot = s.rotation.as_matrix()
    f_world = s.acceleration_mps2 + np.array([0.0, 0.0, GRAVITY_MPS2])
    f_body = np.einsum("nji,nj->ni", rot, f_world)  # R^T f
    mount = imu.mount.rotation_matrix
    f_imu = f_body @ mount  # (R_m^T f)^T = f^T R_m
    w_imu = s.angular_velocity_body_radps @ mount
    t_rel = (time_ns - start_ns) * 1e-9
    bg = np.broadcast_to(np.asarray(errors.gyro_bias_radps, float), (n, 3)).copy()
    ba = np.broadcast_to(np.asarray(errors.accel_bias_mps2, float), (n, 3)).copy()
    if errors.step_time_s is not None:
        after = t_rel >= errors.step_time_s
        bg[after] += errors.step_gyro_radps
        ba[after] += errors.step_accel_mps2
    if noise:
        bg += np.cumsum(rng.standard_normal((n, 3)) * imu.gyro_bias_random_walk_radps2_per_sqrt_hz * math.sqrt(dt), axis=0)
        ba += np.cumsum(rng.standard_normal((n, 3)) * imu.accel_bias_random_walk_mps3_per_sqrt_hz * math.sqrt(dt), axis=0)
        w_imu = w_imu + rng.standard_normal((n, 3)) * imu.gyro_noise_density_radps_per_sqrt_hz * math.sqrt(imu.rate_hz)
        f_imu = f_imu + rng.standard_normal((n, 3)) * imu.accel_noise_density_mps2_per_sqrt_hz * math.sqrt(imu.rate_hz)
    return ImuSamples(time_ns, w_imu + bg, f_imu + ba, np.arange(n, dtype=np.uint32), bg, ba)


def simulate_radar_imu(trajectory: Trajectory, radar, start_ns: int, stop_ns: int, *, vibration=None,
                       vibration_t0_ns: int = 0, rng: np.random.Generator | None = None) -> ImuSamples:
    """The IMU fixed to a radar (``radar.imu``): the body's specific force and rate in the radar's axes,
    plus the radar's vibration along its boresight (x), which the robot's IMU does not see.

    The lever arm from the body origin to the radar is left out (its rotational terms vanish on a straight
    drive; on turns they are slow beside a vibration)."""
    imu = dataclasses.replace(radar.imu, mount=dataclasses.replace(radar.imu.mount, rotation_xyzw=radar.mount.rotation_xyzw))
    out = simulate_imu(trajectory, imu, start_ns, stop_ns, rng=rng)
    if vibration is not None and vibration.amplitude_m != 0.0:
        out.accel_mps2[:, 0] += vibration.acceleration_mps2((out.time_ns - np.int64(vibration_t0_ns)) * 1e-9)
    return out
