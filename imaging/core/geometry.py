"""Where every antenna is at every chirp: trajectory x mount x array (x vibration)."""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.core.rig import RadarConfig
from imaging.core.trajectory import Trajectory


@dataclasses.dataclass(frozen=True)
class Vibration:
    """Sinusoidal displacement of a sensor along its boresight: A sin(2 pi f t + phase), t from ``t0_ns``."""

    frequency_hz: float = 0.0
    amplitude_m: float = 0.0
    phase_rad: float = 0.0

    def displacement_m(self, t_s: np.ndarray) -> np.ndarray:
        return self.amplitude_m * np.sin(2 * np.pi * self.frequency_hz * t_s + self.phase_rad)

    def velocity_mps(self, t_s: np.ndarray) -> np.ndarray:
        w = 2 * np.pi * self.frequency_hz
        return self.amplitude_m * w * np.cos(w * t_s + self.phase_rad)

    def acceleration_mps2(self, t_s: np.ndarray) -> np.ndarray:
        w = 2 * np.pi * self.frequency_hz
        return -self.amplitude_m * w * w * np.sin(w * t_s + self.phase_rad)


def principal_axis(points_m: np.ndarray) -> np.ndarray:
    """The unit direction [3] along which points [N, 3] (an aperture's phase centres) spread most: the first
    right singular vector of the points about their mean (its sign is arbitrary)."""
    _, _, vt = np.linalg.svd(points_m - points_m.mean(axis=0), full_matrices=False)
    return vt[0]


@dataclasses.dataclass
class AntennaTrack:
    """World positions (and velocities) of the TX that sent each chirp and of every RX.

    Shapes: ``tx_m`` [P, 3], ``rx_m`` [P, n_rx, 3]; velocities alike. P is the number of chirps.
    """

    time_ns: np.ndarray
    tx_index: np.ndarray
    tx_m: np.ndarray
    rx_m: np.ndarray
    tx_velocity_mps: np.ndarray
    rx_velocity_mps: np.ndarray
    boresight: np.ndarray  # [P, 3] world


def chirp_times_ns(frame_time_ns: np.ndarray, chirps_per_frame: int, chirp_interval_s: float) -> np.ndarray:
    """Start time of every chirp, [F, chirps_per_frame] int64 ns."""
    offsets = np.round(np.arange(chirps_per_frame) * chirp_interval_s * 1e9).astype(np.int64)
    return np.asarray(frame_time_ns, np.int64)[:, None] + offsets[None, :]


def antenna_track(
    radar: RadarConfig,
    trajectory: Trajectory,
    time_ns: np.ndarray,
    tx_index: np.ndarray,
    vibration: Vibration | None = None,
    vibration_t0_ns: int = 0,
) -> AntennaTrack:
    """Antenna world positions at each chirp start.

    Parameters
    ----------
    radar : RadarConfig
        Array (sensor frame), mount (sensor -> body) and, in ``calibration``, the radar clock's offset from
        the IMU's (radar stamp minus IMU time, s).
    trajectory : Trajectory
        Body pose in the world frame, in the IMU's time.
    time_ns : ndarray, shape (P,)
        Chirp start times on the radar's clock, int64 ns.
    tx_index : ndarray, shape (P,)
        TX that sent each chirp.
    vibration : Vibration, optional
        Displacement of the whole sensor along its boresight (not known to the trajectory).
    """
    time_ns = np.asarray(time_ns, np.int64).ravel()
    tx_index = np.asarray(tx_index).ravel()
    # A radar whose clock runs ahead of the IMU's by the rig's time offset (``[radar.NAME.calibration]``)
    # measured at stamp - offset: that is where the trajectory, in the IMU's time, has it.
    offset_ns = 0 if radar.calibration is None else int(round(radar.calibration.time_offset_s * 1e9))
    s = trajectory.sample(time_ns - np.int64(offset_ns))
    rot = s.rotation_matrix  # [P, 3, 3] body -> world
    mount = radar.mount
    # Lever arms of each antenna in the body frame.
    tx_body = mount.to_body(radar.array.tx_positions_m)[tx_index]  # [P, 3]
    rx_body = mount.to_body(radar.array.rx_positions_m)  # [n_rx, 3]
    omega = s.angular_velocity_body_radps  # [P, 3]
    tx_m = s.position_m + np.einsum("pij,pj->pi", rot, tx_body)
    rx_m = s.position_m[:, None, :] + np.einsum("pij,rj->pri", rot, rx_body)
    tx_vel = s.velocity_mps + np.einsum("pij,pj->pi", rot, np.cross(omega, tx_body))
    rx_vel = s.velocity_mps[:, None, :] + np.einsum("pij,prj->pri", rot, np.cross(omega[:, None, :], rx_body[None, :, :]))
    boresight = rot @ mount.boresight_body
    if vibration is not None and vibration.amplitude_m != 0.0:
        t = (time_ns - np.int64(vibration_t0_ns)).astype(np.float64) * 1e-9
        d = vibration.displacement_m(t)[:, None] * boresight
        dv = vibration.velocity_mps(t)[:, None] * boresight
        tx_m = tx_m + d
        rx_m = rx_m + d[:, None, :]
        tx_vel = tx_vel + dv
        rx_vel = rx_vel + dv[:, None, :]
    return AntennaTrack(time_ns, tx_index, tx_m, rx_m, tx_vel, rx_vel, boresight)
