"""A simulated calibration drive: the reference rig's four radars with mounts the rig file has wrong (2 deg in
yaw, 1 deg in pitch, 2 cm in the lever arm) and one radar's clock 5 ms late, on curves that tighten in both
directions with a stop at every join. Shared by the calibration tests and benchmarks/calibration.py."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.rig import Mount, default_rig
from imaging.core.trajectory import PathWithTurns
from imaging.sim.detection_simulator import DetectionModel, room_scatterers, simulate_scan
from imaging.sim.imu_simulator import ImuErrors, simulate_imu
from imaging.sim.scene import DEFAULT_START_TIME_NS as T0

from .ego_velocity import EgoStatus, EgoVelocityConfig, sensor_velocity
from .ekf import EkfConfig
from .odometry import ImuData, RadarScan

YAW_ERROR_DEG, PITCH_ERROR_DEG = 2.0, 1.0
#: In the plane the robot turns in: a floor robot cannot show a lever arm along z (see rio.calibration).
LEVER_ERROR_M = np.array([0.02, -0.02, 0.0]) / math.sqrt(2)
LATE_RADAR, LATE_S = "left_rear", 0.005
#: The simulated radar has no time-stamp jitter and no velocity change within a frame (it measures at the
#: stamp): the floor on its velocity noise is what its Doppler fit leaves.
SIM_EKF = EkfConfig(radar_velocity_sigma_floor_mps=0.008)
#: Curves that tighten (0.3-0.5 m), in both directions. A stop at every join: a real robot's yaw rate changes
#: smoothly, the path's would step where an arc meets a straight at speed.
CURVES = [("straight", 1.0), ("arc", 0.4, 180.0), ("straight", 0.5), ("arc", 0.3, -270.0), ("straight", 1.0),
          ("arc", 0.5, 120.0)]
#: A drive for a sideways radar's pitch: circles of 0.2 m (3 rad/s at the drive's 0.6 m/s) both ways, with short
#: straights between. The pitch shows only in the vertical velocity w x l gives the boresight (0.15 m of lever
#: arm across it: 0.45 m/s), so it needs time turning fast. The roll shows in the same vertical velocity, from
#: the velocity along the array; turning both ways (and the straights) changes the one against the other, which
#: tells them apart. 90 deg more one way than the other keeps the drive in the room
#: (benchmarks/calibration_pitch.py).
TIGHT_TURNS = [("straight", 0.4), ("arc", 0.2, 810.0), ("straight", 0.4), ("arc", 0.2, -720.0)]


def wrong_mount(mount: Mount) -> Mount:
    """The mount as the miscalibrated rig file has it."""
    rotation = mount.rotation * Rotation.from_euler("ZY", [YAW_ERROR_DEG, PITCH_ERROR_DEG], degrees=True)
    return Mount(mount.translation_m + LEVER_ERROR_M, rotation.as_quat())


def calibration_drive(segments=CURVES, repeats: int = 6, accel_mps2: float = 1.0) -> PathWithTurns:
    lengths = [s[1] if s[0] == "straight" else abs(math.radians(s[2])) * s[1] for s in segments * repeats]
    stops = tuple((float(x), 0.3) for x in np.cumsum(lengths)[:-1])
    return PathWithTurns(segments=segments * repeats, start_m=(0, 0, 0), speed_mps=0.6, accel_mps2=accel_mps2,
                         start_delay_s=2.0, stops=stops, t0_ns=T0)


def simulate_drive(trajectory, duration_s: float, seed: int):
    """IMU and scans of the four radars: (imu, scans with the wrong mounts and the late clock, the same scans
    as a perfect rig file would have them)."""
    rng = np.random.default_rng(seed)
    rig = default_rig()
    imu = simulate_imu(trajectory, rig.imu, T0, T0 + int(duration_s * 1e9), rng=rng,
                       errors=ImuErrors(gyro_bias_radps=(0.002, -0.003, 0.001), accel_bias_mps2=(0.05, -0.04, 0.03)))
    static = room_scatterers(size_m=(14.0, 10.0), centre_m=(0.0, 0.0), spacing_m=0.5, clutter=60)
    wrong, right = [], []
    for r in rig.radars:
        for k in range(int(duration_s / 0.052)):
            t = T0 + int((k + 0.5) * 0.052e9)
            sc = simulate_scan(r, trajectory, t, static, [], DetectionModel(detection_probability=0.5), rng, T0)
            late = int(LATE_S * 1e9) if r.name == LATE_RADAR else 0
            wrong.append(RadarScan(t + late, r.name, wrong_mount(r.mount), sc.xyz_m, sc.doppler_mps))
            right.append(RadarScan(t, r.name, r.mount, sc.xyz_m, sc.doppler_mps))
    return ImuData(imu.time_ns, imu.gyro_radps, imu.accel_mps2), wrong, right


def estimate_errors(result, name: str, late_stamps: bool = True) -> np.ndarray:
    """A calibration's error against the truth [7]: rotation (rad, sensor axes), lever arm (m), time offset (s).
    ``late_stamps``: the calibration ran on ``simulate_drive``'s wrong scans (LATE_RADAR's stamps LATE_S late);
    False: on its true ones (every radar's offset 0)."""
    truth = default_rig().radar(name).mount
    est = result.radars[name].estimate
    rot = (truth.rotation.inv() * est.mount.rotation).as_rotvec()
    return np.concatenate([rot, est.mount.translation_m - truth.translation_m,
                           [est.time_offset_s - (LATE_S if late_stamps and name == LATE_RADAR else 0.0)]])


def fits_with_truth(trajectory, scans, name: str, mount: Mount, rng: np.random.Generator,
                    config: EgoVelocityConfig = EgoVelocityConfig()):
    """Radar ``name``'s scans that the Doppler fit takes, each as (the fit, an ``EgoVelocity``; the true
    velocity of the radar [3], m/s, in the frame of ``mount``: the trajectory's velocity in the body frame plus
    its turn rate x the mount's lever arm). What the benchmarks hold the fit's errors against."""
    for s in scans:
        if s.radar != name:
            continue
        est = sensor_velocity(s.xyz_m, s.doppler_mps, config, rng)
        if est.status is not EgoStatus.OK:
            continue
        truth = trajectory.sample(np.array([s.time_ns]))
        v_body = truth.rotation_matrix[0].T @ truth.velocity_mps[0] + np.cross(truth.angular_velocity_body_radps[0],
                                                                               mount.translation_m)
        yield est, mount.rotation_matrix.T @ v_body
