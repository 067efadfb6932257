"""A short (20 s) calibration drive with the miscalibrated rig (rio.calibration_drive): what the calibrated
rig's drift is compared with, and what the rig file says of an axis the drive did not show."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from imaging.core.rig import default_rig, load_rig
from rio.calibration import AXIS_KEYS, calibrate, prior_sigma, refined_rig, write_rig_toml
from rio.calibration_drive import LATE_RADAR, LATE_S, SIM_EKF, calibration_drive, estimate_errors, simulate_drive, wrong_mount
from rio.evaluation import drift_report
from rio.odometry import RioOptions, run_rio

OPTIONS = RioOptions(ekf=SIM_EKF)


@pytest.fixture(scope="module")
def short_drive():
    """20 s of the 2 m/s^2 drive, seed 1 (benchmarks/calibration.py's first row): the wrong rig calibrated and
    the true rig through the same filter."""
    traj = calibration_drive(repeats=3, accel_mps2=2.0)
    imu, wrong, right = simulate_drive(traj, 20.0, seed=1)
    return traj, imu, wrong, right, calibrate(imu, wrong, OPTIONS), calibrate(imu, right, OPTIONS)


def test_drift_equals_the_true_rig_through_the_same_filter_within_10_percent(short_drive):
    """The issue's 'drift equals the run with the true rig within 10 %', like with like: the calibration's 7
    error states per radar change the filter by themselves (on the true rig, its pitch and lever arm z states
    absorb the Doppler fit's vertical-velocity bias), so the wrong rig calibrated is compared with the true rig
    calibrated. Against the true rig without calibration states this drive is 21 % apart (calibration.json)."""
    traj, imu, _, right, calibrated, reference = short_drive
    ate = drift_report(calibrated.rio.trajectory, traj)["ate_rmse_m"]
    ate_reference = drift_report(reference.rio.trajectory, traj)["ate_rmse_m"]
    assert ate == pytest.approx(ate_reference, rel=0.10)
    # The other comparison is not like with like, and on this drive the difference shows beyond the 10 %.
    ate_uncalibrated_filter = drift_report(run_rio(imu, right, OPTIONS).trajectory, traj)["ate_rmse_m"]
    assert ate / ate_uncalibrated_filter > 1.10


def test_the_true_rig_calibrated_stays_where_it_was_on_the_axes_the_drive_shows(short_drive):
    """The reference run starts at the truth: what it keeps of yaw and lever arm x, y is what the filter does to
    a right rig (the drive cannot move them by more than the tolerances)."""
    *_, reference = short_drive
    for name in reference.radars:
        err = estimate_errors(reference, name, late_stamps=False)
        assert abs(math.degrees(err[2])) < 0.2 and np.abs(err[3:5]).max() < 0.005 and abs(err[6]) < 0.0005, (name, err)


def test_a_refused_axis_keeps_the_rigs_standard_deviation_and_the_next_calibration_starts_from_the_file(short_drive,
                                                                                                       tmp_path):
    """On 20 s the late radar's time offset is refused (standard deviation 0.53 ms, 0.5 needed): the rig file
    keeps its offset (0) and must not call that 0 known to 0.53 ms -- a second calibration from the file would
    then settle 2.6 ms from the truth, 7 of its standard deviations. The file's per-axis standard deviations
    are what the next calibration (sarbot calibrate --rig) starts from."""
    _, imu, wrong, _, calibrated, _ = short_drive
    late = calibrated.radars[LATE_RADAR]
    assert not late.accepted[AXIS_KEYS.index("time_offset")]
    rig = default_rig()
    wrong_rig = dataclasses.replace(rig, radars=tuple(dataclasses.replace(r, mount=wrong_mount(r.mount)) for r in rig.radars))
    back = load_rig(write_rig_toml(refined_rig(wrong_rig, calibrated), tmp_path / "rig.toml"))
    prior = back.radar(LATE_RADAR).calibration
    assert prior.time_offset_s == 0.0
    assert prior.time_offset_sigma_s == pytest.approx(SIM_EKF.calibration_time_offset_sigma_s)
    for name, r in calibrated.radars.items():  # taken axes: the estimate's; refused ones: the prior's
        expected = np.where(r.accepted, r.estimate.sigma, prior_sigma(OPTIONS, name))
        c = back.radar(name).calibration
        np.testing.assert_allclose(np.concatenate([np.radians(c.rotation_sigma_deg), c.translation_sigma_m,
                                                   [c.time_offset_sigma_s]]), expected, rtol=1e-9)
    scans = [dataclasses.replace(s, mount=back.radar(s.radar).mount) for s in wrong]
    again = calibrate(imu, scans, dataclasses.replace(OPTIONS, calibration_priors=back.calibration_priors()))
    r = again.radars[LATE_RADAR]
    err = r.estimate.time_offset_s - LATE_S
    assert abs(err) < 0.0005 and abs(err) < 3 * r.estimate.sigma[6], (err, r.estimate.sigma[6])
