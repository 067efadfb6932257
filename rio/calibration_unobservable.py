"""What the two axes a floor robot hardly or never shows do: a sideways radar's tilt about its own array's axis
(the mount's pitch, rotation about the sensor's y) and its lever arm along z. ``rio.calibration`` refuses the
lever arm along z always and the pitch unless the drive turned enough (benchmarks/calibration_pitch.py); this
module says why in numbers, and ``benchmarks/calibration_unobservable.py`` measures what leaving them wrong
costs the odometry and the strip map (docs/results/calibration_unobservable.json).

The reference radars' virtual array is a line along the sensor's y axis through the phase centre
(docs/config/rig.md). A rotation about that line moves no virtual antenna, so it changes no phase history and no
cone angle (the angle to the array's axis: all such an array measures of a direction). What it changes is the
split of the radar's velocity between its x (boresight) and z: a velocity (vx, vy, 0) in the sensor frame
becomes (vx cos t, vy, -vx sin t). The Doppler of a return level with the radar changes by vx (1 - cos t)
(1.5e-4 of vx at 1 deg); only the vertical velocity, which a horizontal array hardly measures, changes to first
order. On a floor robot vx (the velocity across a sideways radar's boresight plane) comes only from turning
(w x l), so the tilt shows only while turning and only there: slowly (the vertical velocity is known per scan
to a few cm/s, vx is 0.45 m/s at 3 rad/s), but without a bias since the Doppler fit's vertical cross-talk is
removed (rio.ego_velocity.remove_crosstalk).

A lever arm along z enters the radar's velocity as w x l: a robot that turns only about z gives w x (0, 0, lz)
= 0. It moves the antennas up or down by lz along the whole track, which moves a target level with the radar
by lz^2 / (2 r) in range: the same for every pulse, so the image moves, it does not blur.

Pure computation.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.rig import Mount, RadarConfig

#: The issue's mount error on the axes a floor robot shows slowly or never (rio.calibration_drive's rig has them wrong too).
TILT_ERROR_DEG = 1.0
LEVER_Z_ERROR_M = 0.02


def tilted_mount(mount: Mount, tilt_deg: float = TILT_ERROR_DEG, lever_z_m: float = LEVER_Z_ERROR_M) -> Mount:
    """``mount`` tilted by ``tilt_deg`` about the sensor's y axis (the array's axis) and raised by ``lever_z_m``."""
    rotation = mount.rotation * Rotation.from_rotvec([0.0, math.radians(tilt_deg), 0.0])
    return Mount(mount.translation_m + np.array([0.0, 0.0, lever_z_m]), rotation.as_quat())


def virtual_antennas_m(radar: RadarConfig) -> np.ndarray:
    """[n_tx * n_rx, 3] the virtual array (TX + RX phase centres) in the sensor frame."""
    a = radar.array
    return (a.tx_positions_m[:, None, :] + a.rx_positions_m[None, :, :]).reshape(-1, 3)


@dataclasses.dataclass(frozen=True)
class TiltEffects:
    """What a tilt of ``tilt_deg`` about the sensor's y axis changes, from the radar's array alone.

    antenna_shift_max_m: the largest move of a virtual antenna (0 for an array on the axis);
    cone_angle_change_max_deg: the largest change of a direction's angle to the array's axis (over directions
    in the field of view);
    doppler_change_level_relative: the Doppler change of a return level with the radar, as a fraction of the
    velocity across the axis (1 - cos t);
    vertical_velocity_per_mps: the vertical velocity it makes of 1 m/s across the axis (sin t), what the
    ego-velocity would have to measure to show the tilt."""

    tilt_deg: float
    antenna_shift_max_m: float
    cone_angle_change_max_deg: float
    doppler_change_level_relative: float
    vertical_velocity_per_mps: float


def tilt_effects(radar: RadarConfig, tilt_deg: float = TILT_ERROR_DEG, directions: int = 2000,
                 seed: int = 0) -> TiltEffects:
    """Measure a tilt about the sensor's y axis on ``radar``'s own array (see ``TiltEffects``)."""
    turn = Rotation.from_rotvec([0.0, math.radians(tilt_deg), 0.0])
    virtual = virtual_antennas_m(radar)
    shift = float(np.linalg.norm(turn.apply(virtual) - virtual, axis=1).max())
    # The array's axis from its antennas (not assumed): the principal direction of the virtual positions.
    centred = virtual - virtual.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    rng = np.random.default_rng(seed)
    az, el = rng.uniform(-math.pi / 3, math.pi / 3, directions), rng.uniform(-math.pi / 9, math.pi / 9, directions)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    cone = np.degrees(np.abs(np.arccos(np.clip(turn.apply(u) @ axis, -1, 1)) - np.arccos(np.clip(u @ axis, -1, 1))))
    t = math.radians(tilt_deg)
    return TiltEffects(tilt_deg, shift, float(cone.max()), 1.0 - math.cos(t), math.sin(t))


def lever_z_velocity_mps(angular_velocity_radps, lever_z_m: float = LEVER_Z_ERROR_M) -> np.ndarray:
    """[N] the speed a lever arm of ``lever_z_m`` along z adds to the radar's velocity (|w x l|) at each of the
    body rates [N, 3]: only roll and pitch rates give any."""
    w = np.atleast_2d(np.asarray(angular_velocity_radps, float))
    return np.linalg.norm(np.cross(w, [0.0, 0.0, lever_z_m]), axis=1)


def lever_z_range_change_m(range_m: float, lever_z_m: float = LEVER_Z_ERROR_M) -> float:
    """How far a radar raised by ``lever_z_m`` moves a target level with it at ``range_m`` (m): the same for every
    pulse of a level track, so the image shifts and keeps its focus."""
    return math.hypot(range_m, lever_z_m) - range_m


def tilted_scans(scans, tilt_deg: float = TILT_ERROR_DEG, lever_z_m: float = LEVER_Z_ERROR_M) -> list:
    """``scans`` (rio.odometry.RadarScan) as a rig file with every mount tilted and raised would have them: the
    same detections, the mounts ``tilted_mount``."""
    return [dataclasses.replace(s, mount=tilted_mount(s.mount, tilt_deg, lever_z_m)) for s in scans]
