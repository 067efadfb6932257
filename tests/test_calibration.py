"""Online calibration of each radar's mount and time offset (rio.ekf's calibration states, rio.calibration):
on simulated drives with a miscalibrated rig, what converges, what a drive cannot tell and says so, and the
rig file it writes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imaging.core.rig import CalibrationPrior, Mount, default_rig, load_rig
from imaging.core.trajectory import PathWithTurns
from imaging.sim.scene import DEFAULT_START_TIME_NS as T0
from rio.calibration import AXIS_KEYS, calibrate, refined_rig, rig_toml, write_rig_toml
from rio.calibration_drive import (
    LATE_RADAR,
    LATE_S,
    PITCH_ERROR_DEG,
    SIM_EKF,
    calibration_drive,
    estimate_errors,
    fits_with_truth,
    simulate_drive,
    wrong_mount,
)
from rio.evaluation import drift_report
from rio.odometry import RioOptions, run_rio

@pytest.fixture(scope="module")
def curvy():
    traj = calibration_drive()
    imu, wrong, right = simulate_drive(traj, 90.0, seed=1)
    result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
    return traj, imu, wrong, right, result


@pytest.fixture(scope="module")
def true_rig_run(curvy):
    """The odometry on the curvy drive with the true rig file."""
    _, imu, _, right, _ = curvy
    return run_rio(imu, right, RioOptions(ekf=SIM_EKF)).trajectory


def test_mounts_and_time_offset_converge_where_the_drive_shows_them(curvy):
    _, _, _, _, result = curvy
    observable = [AXIS_KEYS.index(k) for k in ("yaw", "lever_x", "lever_y", "time_offset")]
    for name, r in result.radars.items():
        err = estimate_errors(result, name)
        assert r.accepted[observable].all(), (name, r.lines())
        assert abs(math.degrees(err[2])) < 0.2, name
        assert np.abs(err[3:5]).max() < 0.005, name
        assert abs(err[6]) < 0.0005, name
        # and the standard deviations cover the errors
        assert np.all(np.abs(err[observable]) < 3 * r.estimate.sigma[observable]), (name, err / r.estimate.sigma)
    # The late radar's clock is found: 5 ms, not the others' 0.
    assert result.radars[LATE_RADAR].estimate.time_offset_s == pytest.approx(LATE_S, abs=0.0005)


def test_what_a_floor_robot_cannot_show_is_refused_with_the_reason(curvy):
    """The robot turns only about z: a lever arm along z changes no velocity, and a sideways radar's pitch
    shows only in velocity along its boresight, which driving forward does not give it, and these curves turn
    too little for it (tests/test_calibration_pitch.py: tight circles do). Both keep the rig's values and the
    report says so."""
    _, _, _, _, result = curvy
    for name, r in result.radars.items():
        assert not r.accepted[AXIS_KEYS.index("lever_z")] and not r.accepted[AXIS_KEYS.index("pitch")]
        assert "turned only about z" in r.reasons["lever_z"]
        assert "looks sideways" in r.reasons["pitch"]
        refined = r.refined_mount()
        prior = wrong_mount(default_rig().radar(name).mount)
        assert refined.translation_m[2] == prior.translation_m[2]
        # the refined mount: yaw and lever arm corrected, pitch as the rig had it
        truth = default_rig().radar(name).mount
        left = np.degrees((truth.rotation.inv() * refined.rotation).as_euler("ZYX"))
        assert abs(left[0]) < 0.2 and abs(left[1] - PITCH_ERROR_DEG) < 0.05
        assert np.abs(refined.translation_m[:2] - truth.translation_m[:2]).max() < 0.005
    text = result.report()
    assert "lever arm z" in text and "NOT taken" in text


def test_drift_with_calibration_equals_the_true_rig(curvy, true_rig_run):
    traj, imu, wrong, right, result = curvy
    true_rig = drift_report(true_rig_run, traj)
    uncalibrated = drift_report(run_rio(imu, wrong, RioOptions(ekf=SIM_EKF)).trajectory, traj)
    calibrated = drift_report(result.rio.trajectory, traj)
    assert calibrated["ate_rmse_m"] <= 1.1 * true_rig["ate_rmse_m"]
    assert uncalibrated["ate_rmse_m"] > 1.5 * true_rig["ate_rmse_m"]  # the miscalibration does matter


def test_calibration_standard_deviations_are_consistent_over_seeds():
    """NEES of the observable axes (yaw, lever x, y, time offset: 4 dof per radar) over seeds: a filter
    whose standard deviations fit its errors averages 4.

    The standard deviations must cover the errors: the mean stays below 4. They are conservative: with the
    midpoint strapdown the mean is 1.1 (per axis 0.26, 0.51, 0.19, 0.15), and still 1.9 with the velocity
    floor at the Doppler fit's measured 4.5 mm/s instead of SIM_EKF's 8 mm/s. The lower bound (was 4 * 0.3)
    is therefore 4 * 0.15: it catches standard deviations several times too large, not the filter's
    conservatism measured here. With the start-attitude strapdown of before the mean was 3.0, most of it lever
    arm x (2.45), whose error averaged +0.61 mm over these 12 radar-drives (now +0.07 mm): the last assertion.
    """
    traj = calibration_drive(repeats=4)
    observable = [AXIS_KEYS.index(k) for k in ("yaw", "lever_x", "lever_y", "time_offset")]
    nees, lever_x_errors_m = [], []
    for seed in (11, 12, 13):
        imu, wrong, _ = simulate_drive(traj, 60.0, seed)
        result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
        for name, r in result.radars.items():
            e = estimate_errors(result, name)[observable]
            nees.append(float(np.sum((e / r.estimate.sigma[observable]) ** 2)))
            lever_x_errors_m.append(e[1])
    assert 4 * 0.15 < np.mean(nees) < 4.0, nees
    assert abs(np.mean(lever_x_errors_m)) < 0.00025, lever_x_errors_m  # no common lever-arm x bias


def test_brisk_starts_and_stops_bring_every_time_offset_within_half_a_millisecond():
    """The time offset shows only while the radar's velocity changes, and its information grows with how fast
    (benchmarks/calibration_time_offset.py): starting and stopping at 2 m/s^2 instead of 1, a 60 s drive leaves
    a standard deviation below 0.4 ms (about 0.5 ms at 1 m/s^2), every radar's offset within 0.5 ms and
    within 3 standard deviations."""
    traj = calibration_drive(repeats=6, accel_mps2=2.0)
    imu, wrong, _ = simulate_drive(traj, 60.0, seed=5)
    result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
    for name, r in result.radars.items():
        err = estimate_errors(result, name)[6]
        assert r.accepted[6] and r.estimate.sigma[6] < 0.0004, (name, r.lines())
        assert abs(err) < 0.0005 and abs(err) < 3 * r.estimate.sigma[6], (name, err, r.estimate.sigma[6])


def test_a_straight_drive_refuses_the_lever_arm_instead_of_a_confident_wrong_value():
    traj = PathWithTurns(segments=[("straight", 8.0)], start_m=(0, 0, 0), speed_mps=0.6, accel_mps2=1.0,
                         start_delay_s=2.0, stops=((2.0, 0.5), (4.0, 0.5), (6.0, 0.5)), t0_ns=T0)
    imu, wrong, _ = simulate_drive(traj, 22.0, seed=3)
    result = calibrate(imu, wrong, RioOptions(ekf=SIM_EKF))
    for name, r in result.radars.items():
        for key in ("lever_x", "lever_y", "lever_z"):
            assert not r.accepted[AXIS_KEYS.index(key)]
            assert "hardly turned" in r.reasons[key] and "trades against the yaw" in r.reasons[key]
        err = estimate_errors(result, name)
        taken = r.accepted
        # whatever it did take, it took within its standard deviation
        assert np.all(np.abs(err[taken]) < 3 * r.estimate.sigma[taken]), (name, r.lines())


def test_the_rig_file_written_reads_back_refined(curvy, tmp_path):
    _, _, _, _, result = curvy
    rig = default_rig()
    wrong_rig = dataclasses.replace(rig, radars=tuple(dataclasses.replace(r, mount=wrong_mount(r.mount)) for r in rig.radars))
    refined = refined_rig(wrong_rig, result)
    path = write_rig_toml(refined, tmp_path / "rig.toml", header="calibrated\n" + result.report())
    back = load_rig(path)
    assert rig_toml(back) == rig_toml(refined)  # every value survives the file
    for r in back.radars:
        c = result.radars[r.name]
        np.testing.assert_allclose(r.mount.rotation_xyzw, c.refined_mount().rotation_xyzw, atol=1e-12)
        assert isinstance(r.calibration, CalibrationPrior)
        assert r.calibration.time_offset_s == pytest.approx(c.refined_time_offset_s())
        assert r.calibration.rotation_sigma_deg[2] < 0.1 and r.calibration.translation_sigma_m[2] > 0.02
        np.testing.assert_allclose(r.waveform.f0_hz, rig.radar(r.name).waveform.f0_hz)
    assert back.radar(LATE_RADAR).calibration.time_offset_s == pytest.approx(LATE_S, abs=0.0005)
    # The next calibration starts from the file's values and standard deviations.
    assert "# radar left_front:" in path.read_text()


def test_calibration_off_leaves_the_filter_as_it_was(curvy):
    traj, imu, wrong, _, _ = curvy
    a = run_rio(imu, wrong[:400], RioOptions(ekf=SIM_EKF))
    assert a.calibration == {} and a.calibration_log == []
    assert a.covariance_diag.shape[1] == 15


def test_the_estimates_go_into_the_trajectory_file_and_info(curvy, tmp_path):
    from acquisition.info import format_info, info
    from imaging.io.trajectory_file import read_calibration, write_calibration, write_trajectory
    from rio.calibration import calibration_for_file

    _, _, _, _, result = curvy
    path = write_trajectory(tmp_path / "traj.h5", result.rio.trajectory, result.rio.covariance_diag)
    write_calibration(path, *calibration_for_file(result.rio))
    back = read_calibration(path)
    late = back[LATE_RADAR]
    assert late["time_offset_s"] == pytest.approx(result.radars[LATE_RADAR].estimate.time_offset_s)
    np.testing.assert_allclose(late["sigma"], result.radars[LATE_RADAR].estimate.sigma)
    import h5py

    with h5py.File(path) as f:  # how it converged: the time offset's standard deviation shrinks
        sigma = f[f"calibration/{LATE_RADAR}/sigma"][()]
        assert sigma.shape[1] == 7 and sigma[-1, 6] < 0.2 * sigma[0, 6]
    text = format_info(info(path))
    assert f"calibration {LATE_RADAR}: lever arm" in text
    assert "time offset +5." in text.split(f"calibration {LATE_RADAR}")[1].splitlines()[0]


def _recording_of(path, imu, scans, rig):
    """A recording as a robot would have written it: the rig's (wrong) mounts, the scans' detections."""
    from imaging.io.recording import RecordingWriter

    with RecordingWriter(path, rig.radars, imu=rig.imu, detections=rig.radar_names) as w:
        w.append_imu(imu.time_ns, imu.gyro_radps, imu.accel_mps2, np.arange(imu.time_ns.size) % 65536, imu.time_ns)
        for name in rig.radar_names:
            mine = [s for s in scans if s.radar == name]
            w.append_scans(name, [s.time_ns for s in mine], np.arange(len(mine)), [s.time_ns for s in mine])
            for k, s in enumerate(mine):
                w.append_detections(name, np.full(len(s.doppler_mps), s.time_ns), np.full(len(s.doppler_mps), k),
                                    s.xyz_m, s.doppler_mps, np.full(len(s.doppler_mps), 20.0))


def test_sarbot_calibrate_and_rio_calibrate(tmp_path):
    import json
    import subprocess
    import sys

    def sarbot(*args):
        return subprocess.run([sys.executable, "-m", "acquisition.cli", *map(str, args)], capture_output=True,
                              text=True, timeout=300)

    traj = calibration_drive(repeats=5)
    imu, wrong, _ = simulate_drive(traj, 60.0, seed=21)
    rig = default_rig()
    wrong_rig = dataclasses.replace(rig, radars=tuple(dataclasses.replace(r, mount=wrong_mount(r.mount)) for r in rig.radars))
    rec = tmp_path / "drive.h5"
    _recording_of(rec, imu, wrong, wrong_rig)
    out = tmp_path / "rig.toml"
    res = sarbot("calibrate", rec, "-o", out, "--velocity-floor", "0.008")
    assert res.returncode == 0, res.stderr
    assert "radar left_rear:" in res.stdout and "lever arm z" in res.stdout and "NOT taken" in res.stdout
    refined = load_rig(out)
    for r in refined.radars:
        truth = rig.radar(r.name).mount
        yaw_left = np.degrees((truth.rotation.inv() * r.mount.rotation).as_euler("ZYX"))[0]
        assert abs(yaw_left) < 0.2, (r.name, yaw_left)  # was 2 deg
        assert r.mount.translation_m[2] == pytest.approx(wrong_mount(truth).translation_m[2])  # not shown: kept
    again = sarbot("calibrate", rec, "-o", out)
    assert again.returncode == 2 and "exists already" in again.stderr and "Traceback" not in again.stderr

    trajectory = tmp_path / "traj.h5"
    res = sarbot("rio", rec, "-o", trajectory, "--calibrate", "--velocity-floor", "0.008")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert set(summary["calibration"]) == set(rig.radar_names)
    res = sarbot("info", trajectory)
    assert res.returncode == 0 and "calibration left_rear: lever arm" in res.stdout


def test_the_live_odometry_calibrates_too_and_says_so_in_health():
    """rio.streaming (the odometry worker's filter) with calibration on: each radar's states from its first
    scan; the late radar found; the estimates travel in WorkerState to health's line."""
    import msgpack

    from acquisition.bus import Message
    from acquisition.messages import ClockState, Health, WorkerState
    from rio.streaming import StreamingRio

    traj = calibration_drive(repeats=5)
    imu, wrong, _ = simulate_drive(traj, 60.0, seed=31)
    rio = StreamingRio(RioOptions(ekf=SIM_EKF, calibrate_extrinsics=True, calibrate_time_offset=True), imu_rate_hz=400.0)
    scans = sorted(wrong, key=lambda s: s.time_ns)
    j = 0
    for start in range(0, imu.time_ns.size, 40):  # IMU in 0.1 s batches, the scans up to there in between
        end = min(start + 40, imu.time_ns.size)
        rio.add_imu(imu.time_ns[start:end], imu.accel_mps2[start:end], imu.gyro_radps[start:end])
        while j < len(scans) and scans[j].time_ns <= imu.time_ns[end - 1]:
            rio.add_scan(scans[j])
            j += 1
    rio.finish()
    estimates = rio.ekf.calibration_estimates()
    assert set(estimates) == set(default_rig().radar_names)
    late = estimates[LATE_RADAR]
    assert late.time_offset_s == pytest.approx(LATE_S, abs=3 * late.sigma[6]) and late.sigma[6] < 0.001
    for name, e in estimates.items():
        truth = default_rig().radar(name).mount
        assert abs(np.degrees((truth.rotation.inv() * e.mount.rotation).as_euler("ZYX"))[0]) < 0.2

    state = WorkerState("rio", True, 1.0, {}, {n: {"mount_translation_m": e.mount.translation_m.tolist(),
                                                   "mount_rotation_xyzw": e.mount.rotation_xyzw.tolist(),
                                                   "time_offset_s": e.time_offset_s, "sigma": e.sigma.tolist()}
                                               for n, e in estimates.items()})
    health = Health({}, 0.0, 0, 0, 0, {}, 0, None, {}, ClockState({}, True, None), workers={"rio": state})
    parts = health.to_parts()
    header = msgpack.unpackb(msgpack.packb(parts.fields, use_bin_type=True), raw=False)
    line = Health.from_message(Message(parts.topic, 0, parts.sensor_time_ns, 0, header, [])).line()
    assert f"rio {LATE_RADAR} time offset +{late.time_offset_s * 1e3:.1f} ms +- " in line


def test_images_on_the_calibrated_trajectory_are_as_sharp_as_on_the_true_rig(curvy, true_rig_run):
    """Point targets seen by the late, mis-mounted radar while the robot sets off into a turn (raw frames
    along the true track, rio.calibration_imaging), imaged by backprojection as each odometry run has the
    track, mount and clock: what the strip map's tiles hold for those frames. With calibration the image is
    the true rig's (peak within 1 dB, main lobe within 5 %); with the wrong rig file it is not: the response
    loses its peak, grows side lobes (a turning track bent the wrong way) and lands centimetres off."""
    from rio.calibration_imaging import Aperture, compare_runs, place_targets, runs_of, turning_aperture_starts_ns

    traj, imu, wrong, right, result = curvy
    true_rig = true_rig_run
    wrong_rig = run_rio(imu, wrong, RioOptions(ekf=SIM_EKF)).trajectory
    radar = default_rig().radar(LATE_RADAR)
    starts = turning_aperture_starts_ns(traj, T0 + int(45e9), T0 + int(88e9))
    assert starts.size >= 2
    runs = {k: v for k, v in runs_of(LATE_RADAR, traj, true_rig, wrong_rig, result).items()
            if k in ("true_rig", "wrong_rig", "calibrated")}
    for start in starts[:2]:  # a turn each way
        frames = start + np.arange(12, dtype=np.int64) * 52_000_000
        aperture = Aperture(radar, frames, place_targets(radar, traj, int(frames[6])))
        q = compare_runs(aperture, traj, runs)
        loss_db, pslr_gain_db = [], []
        for ref, cal, bad in zip(q["true_rig"], q["calibrated"], q["wrong_rig"]):
            assert abs(20 * math.log10(cal["peak"] / ref["peak"])) < 1.0, (start, cal, ref)
            assert abs(cal["width_m"] / ref["width_m"] - 1) < 0.05, (start, cal, ref)
            assert cal["offset_m"] < 0.015 and bad["offset_m"] > 0.02, (start, cal, bad)
            loss_db.append(20 * math.log10(ref["peak"] / bad["peak"]))
            pslr_gain_db.append((bad["cross_range_pslr_db"] or -99.0) - ref["cross_range_pslr_db"])  # None: no side lobe
        assert np.mean(loss_db) > 2.0, (start, loss_db)
        assert np.mean(pslr_gain_db) > 3.0, (start, pslr_gain_db)


# -- what the refused axes cost -----------------------------------------------------------------------------
def test_a_tilt_about_the_array_axis_moves_no_antenna_and_a_level_doppler_by_1_minus_cos():
    """The reference radars' virtual array is a line along the sensor's y: a 1 deg tilt about it (a sideways
    radar's pitch) moves no antenna and no cone angle; a Doppler level with the radar changes by 1 - cos(1 deg)
    of the velocity across the axis, the vertical velocity by sin(1 deg). A lever arm along z adds no velocity
    on the calibration drive (it turns about z only) and moves a level target at 1 m by 0.2 mm."""
    from rio.calibration_unobservable import lever_z_range_change_m, lever_z_velocity_mps, tilt_effects

    for radar in default_rig().radars:
        e = tilt_effects(radar, 1.0)
        assert e.antenna_shift_max_m < 1e-15 and e.cone_angle_change_max_deg < 1e-6, (radar.name, e)
        assert e.doppler_change_level_relative == pytest.approx(1.523e-4, rel=1e-3)
        assert e.vertical_velocity_per_mps == pytest.approx(0.01745, rel=1e-3)
    # An array 1 cm below the axis would move: 1 deg about y shifts it by 0.17 mm (what the check measures).
    r = default_rig().radars[0]
    below = dataclasses.replace(r, array=dataclasses.replace(r.array, tx_positions_m=r.array.tx_positions_m - [0, 0, 0.01]))
    assert tilt_effects(below, 1.0).antenna_shift_max_m == pytest.approx(0.01 * math.radians(1.0), rel=1e-3)
    traj = calibration_drive(repeats=2)
    rates = traj.sample(T0 + np.arange(0, 20_000_000_000, 10_000_000, dtype=np.int64)).angular_velocity_body_radps
    assert np.abs(rates[:, 2]).max() > 1.0  # it does turn ...
    assert lever_z_velocity_mps(rates, 0.02).max() < 1e-12  # ... about z alone: a lever arm along z shows nothing
    assert lever_z_velocity_mps([[0.5, 0.0, 0.0]], 0.02)[0] == pytest.approx(0.01)  # a roll would show it
    assert lever_z_range_change_m(1.0, 0.02) == pytest.approx(2e-4, rel=1e-3)


def test_the_refused_axes_left_wrong_cost_neither_drift_nor_image_sharpness(curvy, true_rig_run):
    """Every mount tilted 1 deg about its array's axis and 2 cm too high, not calibrated (``sarbot calibrate``
    refuses both): the drift is the true rig's within 10 %, and the strip map's point targets where the robot
    sets off into a turn are the true rig's within 1 dB of peak and 5 % of main-lobe width."""
    from rio.calibration_imaging import Aperture, BelievedRig, compare_runs, place_targets, turning_aperture_starts_ns
    from rio.calibration_unobservable import tilted_mount, tilted_scans

    traj, imu, _, right, _ = curvy
    tilted = run_rio(imu, tilted_scans(right), RioOptions(ekf=SIM_EKF)).trajectory
    true_rig = drift_report(true_rig_run, traj)
    left_wrong = drift_report(tilted, traj)
    assert left_wrong["ate_rmse_m"] == pytest.approx(true_rig["ate_rmse_m"], rel=0.10)
    assert left_wrong["final_drift_m"] <= 1.1 * true_rig["final_drift_m"] + 0.001
    radar = default_rig().radar("right_front")
    starts = turning_aperture_starts_ns(traj, T0 + int(20e9), T0 + int(88e9))
    runs = {"true_rig": (0.0, BelievedRig(true_rig_run, radar.mount)),
            "tilted_rig": (0.0, BelievedRig(tilted, tilted_mount(radar.mount)))}
    for start in starts[:2]:
        frames = start + np.arange(12, dtype=np.int64) * 52_000_000
        q = compare_runs(Aperture(radar, frames, place_targets(radar, traj, int(frames[6]))), traj, runs)
        for ref, tilt in zip(q["true_rig"], q["tilted_rig"]):
            assert abs(20 * math.log10(tilt["peak"] / ref["peak"])) < 1.0, (start, tilt, ref)
            assert abs(tilt["width_m"] / ref["width_m"] - 1) < 0.05, (start, tilt, ref)


def test_the_refusal_says_the_axes_are_unobservable_and_harmless(curvy):
    _, _, _, _, result = curvy
    r = result.radars["left_front"]
    assert "1.5e-4 at 1 deg" in r.reasons["pitch"] and "unobservable" in r.reasons["pitch"]
    assert "harmless" in r.reasons["pitch"] and "harmless" in r.reasons["lever_z"]
    assert "w x l = 0" in r.reasons["lever_z"]


def test_the_fits_truth_is_the_radars_own_velocity_in_its_own_frame():
    """``fits_with_truth`` (what the calibration benchmarks hold the Doppler fit against): the fit agrees with the
    truth it gives on the true mount, and not on a mount turned 90 degrees (a truth in the wrong frame)."""
    traj = calibration_drive()
    _, _, right = simulate_drive(traj, 12.0, seed=3)
    rig = default_rig()
    for name in rig.radar_names:
        mount = rig.radar(name).mount
        turned = Mount(mount.translation_m, (mount.rotation * Rotation.from_euler("z", 90, degrees=True)).as_quat())
        for m, bound in ((mount, 0.02), (turned, None)):
            pairs = list(fits_with_truth(traj, right, name, m, np.random.default_rng(0)))
            moving = [(est, v) for est, v in pairs if np.linalg.norm(v) > 0.3]
            assert len(moving) > 50, name
            error = np.median([np.linalg.norm(est.velocity_mps - v) for est, v in moving])
            assert (error < bound) if bound else (error > 0.2), (name, error)
