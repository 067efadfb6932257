"""Radar scans at the detection level: what a radar that delivers point clouds reports.

Used where raw ADC is not needed (odometry over long drives): every static scatterer inside the field of
view and range yields, with some probability, a detection with noisy range, angles and Doppler (range
rate); people walking yield detections with their own motion; a few false alarms are scattered
uniformly. Cost is per scatterer, not per ADC sample: a 10-minute, four-radar drive takes seconds.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.core.rig import RadarConfig
from imaging.core.trajectory import Trajectory


@dataclasses.dataclass(frozen=True)
class DetectionModel:
    """Field of view, range and measurement noise of a radar's point cloud (sensor frame, SI)."""

    max_range_m: float = 10.0
    min_range_m: float = 0.3
    azimuth_fov_deg: float = 60.0  # half angle
    elevation_fov_deg: float = 20.0  # half angle
    range_sigma_m: float = 0.02
    azimuth_sigma_deg: float = 1.0
    elevation_sigma_deg: float = 3.0
    doppler_sigma_mps: float = 0.02
    detection_probability: float = 0.8
    false_alarms_per_scan: float = 1.0
    snr_db: float = 20.0


@dataclasses.dataclass(frozen=True)
class Person:
    """Someone walking back and forth between two points at a constant speed."""

    start_m: tuple[float, float, float]
    end_m: tuple[float, float, float]
    speed_mps: float = 1.2
    points: int = 3  # scattering points (torso, arms) moving together

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        a, b = np.asarray(self.start_m, float), np.asarray(self.end_m, float)
        length = np.linalg.norm(b - a)
        period = 2 * length / self.speed_mps
        phase = (t_s % period) / period
        direction = (b - a) / length
        if phase < 0.5:
            return a + (b - a) * 2 * phase, direction * self.speed_mps
        return b + (a - b) * (2 * phase - 1), -direction * self.speed_mps


@dataclasses.dataclass
class Scan:
    """Detections of one scan: xyz_m [D,3] in the sensor frame, doppler_mps [D], snr_db [D]."""

    time_ns: int
    xyz_m: np.ndarray
    doppler_mps: np.ndarray
    snr_db: np.ndarray
    moving: np.ndarray  # [D] bool, truth: from a moving target or a false alarm


def simulate_scan(radar: RadarConfig, trajectory: Trajectory, time_ns: int, static_points_m: np.ndarray,
                  people: list[Person], model: DetectionModel, rng: np.random.Generator, t0_ns: int = 0) -> Scan:
    """One scan of ``radar`` at ``time_ns`` (the scan's mid time)."""
    s = trajectory.sample(np.array([time_ns]))
    r_b = s.rotation.as_matrix()[0]
    r_s = r_b @ radar.mount.rotation_matrix  # sensor -> world
    lever = radar.mount.translation_m
    p_s = s.position_m[0] + r_b @ lever
    v_s = s.velocity_mps[0] + r_b @ np.cross(s.angular_velocity_body_radps[0], lever)
    t_s = (time_ns - t0_ns) * 1e-9
    pts, vel, moving = [static_points_m], [np.zeros_like(static_points_m)], [np.zeros(len(static_points_m), bool)]
    for person in people:
        centre, v = person.state(t_s)
        offsets = rng.normal(0.0, 0.15, (person.points, 3)) * [1, 1, 2]
        pts.append(centre + offsets)
        vel.append(np.broadcast_to(v, (person.points, 3)))
        moving.append(np.ones(person.points, bool))
    pts, vel, moving = np.concatenate(pts), np.concatenate(vel), np.concatenate(moving)
    rel_world = pts - p_s
    rel = rel_world @ r_s  # world -> sensor: R_s^T x
    rng_m = np.linalg.norm(rel, axis=1)
    az = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))
    el = np.degrees(np.arcsin(np.clip(rel[:, 2] / np.maximum(rng_m, 1e-9), -1, 1)))
    visible = ((rng_m > model.min_range_m) & (rng_m < model.max_range_m) & (np.abs(az) < model.azimuth_fov_deg)
               & (np.abs(el) < model.elevation_fov_deg) & (rel[:, 0] > 0))
    visible &= rng.random(len(pts)) < model.detection_probability
    u = rel_world[visible] / rng_m[visible, None]
    doppler = np.einsum("ij,ij->i", u, vel[visible] - v_s)  # range rate
    n = int(visible.sum())
    r_meas = rng_m[visible] + rng.normal(0, model.range_sigma_m, n)
    az_meas = np.radians(az[visible] + rng.normal(0, model.azimuth_sigma_deg, n))
    el_meas = np.radians(el[visible] + rng.normal(0, model.elevation_sigma_deg, n))
    dop_meas = doppler + rng.normal(0, model.doppler_sigma_mps, n)
    mov = moving[visible]
    n_fa = rng.poisson(model.false_alarms_per_scan)
    if n_fa:
        r_fa = rng.uniform(model.min_range_m, model.max_range_m, n_fa)
        az_fa = np.radians(rng.uniform(-model.azimuth_fov_deg, model.azimuth_fov_deg, n_fa))
        el_fa = np.radians(rng.uniform(-model.elevation_fov_deg, model.elevation_fov_deg, n_fa))
        r_meas = np.concatenate([r_meas, r_fa])
        az_meas = np.concatenate([az_meas, az_fa])
        el_meas = np.concatenate([el_meas, el_fa])
        dop_meas = np.concatenate([dop_meas, rng.uniform(-2.0, 2.0, n_fa)])
        mov = np.concatenate([mov, np.ones(n_fa, bool)])
    xyz = np.column_stack([r_meas * np.cos(el_meas) * np.cos(az_meas), r_meas * np.cos(el_meas) * np.sin(az_meas),
                           r_meas * np.sin(el_meas)])
    snr = model.snr_db - 20 * np.log10(np.maximum(r_meas, 0.1)) + rng.normal(0, 2.0, r_meas.size)
    return Scan(int(time_ns), xyz, dop_meas, snr, mov)


def room_scatterers(size_m=(12.0, 8.0), centre_m=(0.0, 0.0), height_m: float = 2.5, spacing_m: float = 0.3,
                    clutter: int = 80, rng: np.random.Generator | None = None) -> np.ndarray:
    """Point scatterers on the four walls of a rectangular room plus random clutter (furniture) inside."""
    rng = rng or np.random.default_rng(0)
    sx, sy = size_m
    cx, cy = centre_m
    pts = []
    zs = np.arange(0.1, height_m, 0.4)
    for x in np.arange(-sx / 2, sx / 2 + 1e-9, spacing_m):
        for y in (-sy / 2, sy / 2):
            pts.extend([(cx + x, cy + y, z) for z in zs])
    for y in np.arange(-sy / 2, sy / 2 + 1e-9, spacing_m):
        for x in (-sx / 2, sx / 2):
            pts.extend([(cx + x, cy + y, z) for z in zs])
    pts = np.asarray(pts) + rng.normal(0, 0.02, (len(pts), 3))
    inner = np.column_stack([rng.uniform(cx - sx / 2 + 0.3, cx + sx / 2 - 0.3, clutter),
                             rng.uniform(cy - sy / 2 + 0.3, cy + sy / 2 - 0.3, clutter),
                             rng.uniform(0.0, 1.5, clutter)])
    return np.concatenate([pts, inner])
