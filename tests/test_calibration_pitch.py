"""A sideways radar's pitch (its tilt about its own array's axis) is calibrated where the drive made it
observable, and refused with the reason where not (rio.calibration, benchmarks/calibration_pitch.py): it shows
only in the vertical velocity that w x l gives the boresight while the robot turns."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns
from imaging.sim.scene import DEFAULT_START_TIME_NS as T0
from rio.calibration import AXIS_KEYS, calibrate
from rio.calibration_drive import PITCH_ERROR_DEG, SIM_EKF, TIGHT_TURNS, calibration_drive, estimate_errors, simulate_drive, wrong_mount
from rio.odometry import RioOptions

PITCH = AXIS_KEYS.index("pitch")
TURNING_DRIVE_S = 240.0


@pytest.fixture(scope="module")
def turning():
    """Circles of 0.2 m both ways at 3 rad/s (rio.calibration_drive.TIGHT_TURNS), every mount 1 deg off in pitch."""
    traj = calibration_drive(TIGHT_TURNS, repeats=int(TURNING_DRIVE_S / 9) + 2, accel_mps2=2.0)
    assert traj.duration_s > TURNING_DRIVE_S
    imu, wrong, _ = simulate_drive(traj, TURNING_DRIVE_S, seed=7)
    return calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))


def _pitch_left_deg(mount, name: str) -> float:
    """The pitch (about the sensor's y) ``mount`` has against the true rig's, deg."""
    truth = default_rig().radar(name).mount
    return math.degrees((truth.rotation.inv() * mount.rotation).as_rotvec()[1])


def test_a_drive_turning_tightly_both_ways_calibrates_the_pitch(turning):
    """Every radar's pitch is taken, within 0.2 deg of the truth and within 3 of its standard deviations (at
    most CalibrationLimits' 0.1 deg), and the refined mount has it: the rig file's 1 deg error is gone."""
    for name, r in turning.radars.items():
        err_deg = math.degrees(estimate_errors(turning, name)[PITCH])
        sigma_deg = math.degrees(r.estimate.sigma[PITCH])
        assert r.accepted[PITCH], (name, r.lines())
        assert sigma_deg <= 0.1 and abs(err_deg) < 0.2 and abs(err_deg) < 3 * sigma_deg, (name, err_deg, sigma_deg)
        assert abs(_pitch_left_deg(wrong_mount(default_rig().radar(name).mount), name) - PITCH_ERROR_DEG) < 0.01
        assert abs(_pitch_left_deg(r.refined_mount(), name)) < 0.2, name
        assert r.sigma[PITCH] == r.estimate.sigma[PITCH]  # the rig file gets the drive's standard deviation
        assert "pitch" in " ".join(r.lines()) and "pitch" not in r.reasons


def test_a_straight_drive_refuses_the_pitch_and_says_it_did_not_turn():
    traj = PathWithTurns(segments=[("straight", 8.0)], start_m=(0, 0, 0), speed_mps=0.6, accel_mps2=1.0,
                         start_delay_s=2.0, stops=((2.0, 0.5), (4.0, 0.5), (6.0, 0.5)), t0_ns=T0)
    imu, wrong, _ = simulate_drive(traj, 22.0, seed=3)
    result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
    for name, r in result.radars.items():
        assert not r.accepted[PITCH]
        reason = r.reasons["pitch"]
        assert "hardly turned" in reason and "unobservable on this drive" in reason, reason
        assert abs(_pitch_left_deg(r.refined_mount(), name) - PITCH_ERROR_DEG) < 0.01  # the rig's value kept
        assert r.sigma[PITCH] == pytest.approx(SIM_EKF.calibration_rotation_sigma_rad)  # and its prior's sigma


def test_a_drive_that_turned_too_little_says_how_much_more_turning_it_needs():
    """40 s of the tight circles leave the pitch's standard deviation near 0.2 deg (benchmarks/calibration_pitch.py):
    refused, and the reason asks for about (0.2 / 0.1)^2 - 1 = 3 times the turning it had."""
    traj = calibration_drive(TIGHT_TURNS, repeats=6, accel_mps2=2.0)
    imu, wrong, _ = simulate_drive(traj, 40.0, seed=1)
    result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
    for name, r in result.radars.items():
        reason = r.reasons["pitch"]
        ratio = r.estimate.sigma[PITCH] / math.radians(0.1)
        assert not r.accepted[PITCH] and 1.5 < ratio < 3.0, (name, ratio)
        more_s = float(reason.split(": about ")[1].split(" s more")[0])
        assert more_s == pytest.approx(result.drive.turning_s * (ratio ** 2 - 1), abs=1.0), reason
        assert "TIGHT_TURNS" in reason and "harmless" in reason
        assert np.isfinite(more_s) and more_s > result.drive.turning_s
