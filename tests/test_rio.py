"""Radar-inertial odometry: ego velocity, IMU synthesis, the EKF on simulated drives, and where it breaks."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns
from imaging.sim.detection_simulator import (
    DetectionModel,
    Person,
    room_scatterers,
    simulate_scan,
)
from imaging.sim.imu_simulator import GRAVITY_MPS2, ImuErrors, simulate_imu
from imaging.sim.scene import DEFAULT_START_TIME_NS
from rio.ego_velocity import EgoStatus, body_velocity, sensor_velocity
from rio.evaluation import drift_report
from rio.odometry import ImuData, RadarScan, RioOptions, run_rio

T0 = DEFAULT_START_TIME_NS
DRIVE = [("straight", 4.0), ("arc", 1.0, 90.0), ("straight", 3.0), ("arc", 1.0, 90.0), ("straight", 4.0)]


def simulate(trajectory, duration_s, *, model=DetectionModel(detection_probability=0.5), people=(), errors=None,
             radars=None, scan_interval_s=0.052, seed=1, drop=0.0, time_offset_s=0.0, points=None):
    """IMU samples and radar scans in memory (no file), four radars unless told otherwise."""
    rng = np.random.default_rng(seed)
    rig = default_rig()
    imu = simulate_imu(trajectory, rig.imu, T0, T0 + int(duration_s * 1e9),
                       errors=errors or ImuErrors(gyro_bias_radps=(0.002, -0.003, 0.001), accel_bias_mps2=(0.05, -0.04, 0.03)),
                       rng=rng)
    static = room_scatterers(size_m=(14.0, 10.0), centre_m=(2.0, 1.5), spacing_m=0.5, clutter=60) if points is None else points
    scans = []
    for r in (radars or rig.radars):
        for k in range(int(duration_s / scan_interval_s)):
            t = T0 + int((k + 0.5) * scan_interval_s * 1e9)
            if rng.random() < drop:
                continue
            sc = simulate_scan(r, trajectory, t, static, list(people), model, rng, T0)
            scans.append(RadarScan(t + int(time_offset_s * 1e9), r.name, r.mount, sc.xyz_m, sc.doppler_mps))
    return ImuData(imu.time_ns, imu.gyro_radps, imu.accel_mps2), scans, imu


def drive(speed=0.6, start_delay_s=3.0, stops=((4.0, 3.0),), segments=DRIVE, accel=0.4):
    return PathWithTurns(segments=segments, start_m=(-2.0, -2.0, 0.0), speed_mps=speed, accel_mps2=accel,
                         start_delay_s=start_delay_s, stops=stops, t0_ns=T0)


# -- ego velocity -----------------------------------------------------------------------------------------
def detections(v_sensor, n=60, outliers=0.3, sigma=0.02, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(-1.0, 1.0, n)
    el = rng.uniform(-0.3, 0.3, n)
    r = rng.uniform(1, 8, n)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    dop = -u @ v_sensor + rng.normal(0, sigma, n)
    bad = rng.random(n) < outliers
    dop[bad] += rng.uniform(-2, 2, bad.sum())
    return u * r[:, None], dop, bad


def test_ego_velocity_rejects_moving_targets():
    v = np.array([0.7, -0.2, 0.05])
    xyz, dop, bad = detections(v)
    est = sensor_velocity(xyz, dop)
    assert est.status is EgoStatus.OK
    assert np.abs(est.velocity_mps - v).max() < 0.03
    assert not np.any(est.inliers[bad & (np.abs(dop + xyz @ v / np.linalg.norm(xyz, axis=1)) > 0.2)])
    # The covariance is honest: error within 4 sigma per axis.
    assert np.all(np.abs(est.velocity_mps - v) < 4 * np.sqrt(np.diag(est.covariance)))


def test_ego_velocity_zero_few_and_degenerate():
    xyz, dop, _ = detections(np.zeros(3), outliers=0.1, sigma=0.005)
    assert sensor_velocity(xyz, dop).status is EgoStatus.ZERO_VELOCITY
    xyz, dop, _ = detections(np.array([0.5, 0, 0]), n=4)
    assert sensor_velocity(xyz, dop).status is EgoStatus.TOO_FEW
    # All points in one direction: the velocity is not observable across it.
    xyz = np.tile([[5.0, 0.0, 0.0]], (20, 1)) + np.random.default_rng(0).normal(0, 1e-4, (20, 3))
    est = sensor_velocity(xyz, np.full(20, -0.5))
    assert est.status in (EgoStatus.ILL_CONDITIONED, EgoStatus.NO_CONSENSUS)
    # Garbage only: no consensus.
    rng = np.random.default_rng(2)
    est = sensor_velocity(rng.normal(0, 3, (40, 3)), rng.uniform(-3, 3, 40))
    assert est.status in (EgoStatus.NO_CONSENSUS, EgoStatus.NOISY)


def test_body_velocity_from_several_radars_with_lever_arms():
    rig = default_rig()
    v_b, w_b = np.array([0.5, 0.05, 0.0]), np.array([0.0, 0.0, 0.8])
    scans = []
    for k, r in enumerate(rig.radars):
        rm = r.mount.rotation.as_matrix()
        v_s = rm.T @ (v_b + np.cross(w_b, r.mount.translation_m))
        xyz, dop, _ = detections(v_s, n=30, outliers=0.2, seed=k)
        scans.append((r.mount, xyz, dop))
    est = body_velocity(scans, w_b)
    assert est.status is EgoStatus.OK
    assert np.abs(est.velocity_mps - v_b).max() < 0.02


# -- IMU synthesis ----------------------------------------------------------------------------------------------
def test_imu_synthesis_static_and_turning():
    traj = drive()
    imu = simulate_imu(traj, default_rig().imu, T0, T0 + int(30e9), noise=False)
    t = (imu.time_ns - T0) * 1e-9
    still = t < 2.5
    np.testing.assert_allclose(imu.accel_mps2[still], np.tile([0, 0, GRAVITY_MPS2], (still.sum(), 1)), atol=1e-9)
    s = traj.sample(imu.time_ns)
    np.testing.assert_allclose(imu.gyro_radps[:, 2], s.angular_velocity_body_radps[:, 2], atol=1e-12)
    turning = np.abs(s.angular_velocity_body_radps[:, 2]) > 0.1
    speed = np.linalg.norm(s.velocity_mps, axis=1)
    # Centripetal: lateral specific force v * yaw rate.
    np.testing.assert_allclose(imu.accel_mps2[turning, 1], speed[turning] * imu.gyro_radps[turning, 2], atol=1e-9)


def test_speed_profile_is_smooth_and_consistent():
    traj = drive()
    times = T0 + np.arange(0, int(25e9), 1_000_000)
    s = traj.sample(times)
    v_num = np.gradient(s.position_m, 1e-3, axis=0)
    assert np.abs(v_num - s.velocity_mps)[1:-1].max() < 1e-3
    speed = np.linalg.norm(s.velocity_mps, axis=1)
    a_num = np.gradient(speed, 1e-3)
    a_tan = np.einsum("ij,ij->i", s.acceleration_mps2, s.velocity_mps) / np.maximum(speed, 1e-9)
    assert np.abs(a_num - a_tan)[2:-2][speed[2:-2] > 0.01].max() < 1e-2
    assert speed.max() == pytest.approx(0.6) and np.abs(a_num).max() < 0.41
    stopped = (times - T0) * 1e-9 < 3.0
    assert np.all(speed[stopped] == 0)


# -- the filter -------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def nominal():
    traj = drive()
    imu, scans, truth_imu = simulate(traj, 45.0)
    return traj, imu, scans, run_rio(imu, scans), truth_imu


def test_drift_on_a_drive_with_turns_and_stops(nominal):
    traj, _, _, res, _ = nominal
    report = drift_report(res.trajectory, traj)
    assert report["distance_m"] > 12
    assert report["final_drift_percent"] < 0.5
    assert report["ate_rmse_percent"] < 0.5
    assert abs(report["final_yaw_error_deg"]) < 0.5


def test_static_initialisation_and_zero_velocity(nominal):
    traj, _, _, res, truth_imu = nominal
    first = res.trajectory.sample(res.trajectory.time_ns[:1])
    roll, pitch = np.degrees(first.rotation.as_euler("xyz")[0, :2])
    # Truth is level; the accelerometer bias (0.05, -0.04) m/s^2 tilts the gravity estimate by ~0.3 deg.
    assert abs(roll) < 0.5 and abs(pitch) < 0.5
    zv = res.zero_velocity_times_ns
    speed = np.linalg.norm(traj.sample(zv).velocity_mps, axis=1)
    # Recognised while standing or creeping below the Doppler threshold (0.03 m/s), never while driving.
    assert zv.size > 100 and np.all(speed < 0.1) and np.mean(speed < 0.03) > 0.9
    # The gyro bias is learned from the standstills.
    cov_bg = res.covariance_diag[-1, 12:15]
    assert np.all(np.sqrt(cov_bg) < 5e-3)


def test_filter_is_consistent(nominal):
    traj, _, _, res, _ = nominal
    true = traj.sample(res.trajectory.time_ns)
    err_v = res.trajectory.velocity_mps - true.velocity_mps
    nees = np.sum(err_v ** 2 / res.covariance_diag[:, 3:6], axis=1)
    # Normalised estimation error squared of the velocity (3 dof): mean near 3, within a generous band.
    assert 0.3 < np.mean(nees) < 9.0


def test_no_detections_coasts_on_the_imu_and_says_so(caplog):
    traj = drive(start_delay_s=3.0, stops=())
    imu, scans, _ = simulate(traj, 12.0, points=np.zeros((0, 3)), model=DetectionModel(false_alarms_per_scan=0.0))
    with caplog.at_level(logging.WARNING, logger="rio.odometry"):
        res = run_rio(imu, scans)
    assert res.stats.get("ego_too_few_detections", 0) > 0.9 * len(scans)
    assert "radar_updates" not in res.stats and "zero_velocity_updates" not in res.stats
    assert any("coasting on the IMU" in r.message for r in caplog.records)
    assert np.all(np.isfinite(res.trajectory.position_m))


def test_few_detections_and_mostly_moving_targets():
    traj = drive(stops=())
    sparse = DetectionModel(detection_probability=0.03)
    imu, scans, _ = simulate(traj, 30.0, model=sparse)
    res = run_rio(imu, scans)
    assert np.all(np.isfinite(res.trajectory.position_m))
    assert drift_report(res.trajectory, traj)["final_drift_percent"] < 5.0
    crowd = [Person((x, -4.5, 1.0), (x, 6.0, 1.0), 1.3, points=12) for x in np.linspace(-3, 6, 8)]
    imu, scans, _ = simulate(traj, 30.0, model=DetectionModel(detection_probability=0.15), people=crowd)
    res = run_rio(imu, scans)
    assert drift_report(res.trajectory, traj)["final_drift_percent"] < 2.0


def test_a_minute_standing_still_does_not_drift():
    traj = PathWithTurns(segments=[("straight", 1.0)], start_m=(0, 0, 0), speed_mps=0.5, accel_mps2=0.4,
                         start_delay_s=65.0, t0_ns=T0)
    imu, scans, _ = simulate(traj, 62.0)
    res = run_rio(imu, scans)
    assert np.linalg.norm(res.trajectory.position_m[-1] - res.trajectory.position_m[0]) < 0.02


def test_fast_turns():
    spin = [("straight", 1.0), ("arc", 0.4, 360.0), ("straight", 1.0), ("arc", 0.4, -360.0), ("straight", 1.0)]
    traj = drive(speed=0.8, stops=(), segments=spin, accel=0.8)  # 2 rad/s
    imu, scans, _ = simulate(traj, 20.0)
    res = run_rio(imu, scans)
    assert drift_report(res.trajectory, traj)["final_drift_percent"] < 1.0


def test_dropped_frames_and_time_offset():
    traj = drive(stops=())
    imu, scans, _ = simulate(traj, 30.0, drop=0.5)
    assert drift_report(run_rio(imu, scans).trajectory, traj)["final_drift_percent"] < 0.6
    # Radar stamps 20 ms late: worse, still bounded.
    imu, scans, _ = simulate(traj, 30.0, time_offset_s=0.02)
    assert drift_report(run_rio(imu, scans).trajectory, traj)["final_drift_percent"] < 3.0


def test_imu_bias_step_is_learned_at_the_next_stop():
    traj = drive(stops=((6.0, 4.0),))
    errors = ImuErrors(step_time_s=8.0, step_gyro_radps=(0.0, 0.0, 0.005), step_accel_mps2=(0.1, 0.0, 0.0))
    imu, scans, truth_imu = simulate(traj, 30.0, errors=errors)
    res = run_rio(imu, scans)
    assert np.all(np.isfinite(res.trajectory.position_m))
    # Yaw error piles up until the stop (radar velocity does not observe heading); then the zero-rate
    # update learns the new gyro bias.
    t = res.trajectory.time_ns
    before, end_of_stop = np.searchsorted(t, T0 + int(8.0e9)) - 1, np.searchsorted(t, T0 + int(19.3e9))
    true_bg = truth_imu.gyro_bias_radps[np.searchsorted(truth_imu.time_ns, t[end_of_stop])]
    assert abs(res.gyro_bias_radps[before, 2] - true_bg[2]) > 4e-3  # the step, not yet known
    assert abs(res.gyro_bias_radps[end_of_stop, 2] - true_bg[2]) < 1e-3
    assert drift_report(res.trajectory, traj)["final_drift_percent"] < 5.0


def test_joint_radars_and_planar_mode(nominal):
    traj, imu, scans, _, _ = nominal
    from rio.ekf import EkfConfig

    for opts in (RioOptions(joint_radars=True), RioOptions(ekf=EkfConfig(planar=True))):
        res = run_rio(imu, scans, opts)
        assert drift_report(res.trajectory, traj)["final_drift_percent"] < 0.5


def test_streaming_rio_matches_the_batch_filter(nominal):
    """The same drive fed in pieces as the bus delivers it (IMU batches of 20, each radar's scan arriving
    a frame late) gives the batch trajectory; a scan older than the filter is counted and left out."""
    from rio.streaming import StreamingRio

    traj, imu, scans, res, _ = nominal
    rio = StreamingRio(RioOptions(), imu_rate_hz=400.0)
    out = []
    pending = sorted(scans, key=lambda s: s.time_ns)
    j = 0
    for k in range(0, imu.time_ns.size, 20):
        t_end = imu.time_ns[min(k + 20, imu.time_ns.size) - 1]
        out.append(rio.add_imu(imu.time_ns[k:k + 20], imu.accel_mps2[k:k + 20], imu.gyro_radps[k:k + 20]))
        while j < len(pending) and pending[j].time_ns + 52_000_000 <= t_end:  # delivered one frame after its time
            out.append(rio.add_scan(pending[j]))
            j += 1
    out.append(rio.finish())
    times = np.concatenate([b.time_ns for b in out])
    pos = np.concatenate([b.position_m for b in out])
    assert np.all(np.diff(times) > 0)
    np.testing.assert_array_equal(times, res.trajectory.time_ns[:times.size])
    assert times.size >= res.trajectory.time_ns.size - 1
    # Identical up to the last scan this feed delivered (the batch filter also has the final frame's scans).
    upto = times < pending[j - 1].time_ns
    err = np.linalg.norm(pos - res.trajectory.position_m[:times.size], axis=1)
    assert upto.sum() > 4000 and err[upto].max() < 1e-9 and err.max() < 1e-3
    assert rio.stats["radar_updates"] >= res.stats["radar_updates"] - 8  # all but the final frame's scans
    late, before = rio.stats["scans_late"], rio.stats["scans_before_start"]
    assert rio.add_scan(pending[len(pending) // 2]).time_ns.size == 0 and rio.stats["scans_late"] == late + 1
    # One from the standstill the filter started from is not late: the batch filter leaves it out too.
    assert rio.add_scan(pending[0]).time_ns.size == 0 and rio.stats["scans_before_start"] == before + 1


def test_streaming_rio_poses_reach_as_far_as_the_imu_and_every_radar_have_come(nominal):
    """No hold-back beyond the data: a radar's scans come in order, so once every radar is past a time the
    filter can run to it. Fed as the bus delivers (IMU batches of 20 samples, 50 ms; each scan at the end of
    its frame), after every delivery the newest pose is within one output interval (10 ms) of the IMU's and
    the slowest radar's newest time, and the poses are still the batch filter's. With a fixed 0.2 s hold-back
    the live map waited that much longer for every frame."""
    from rio.streaming import StreamingRio

    _, imu, scans, res, _ = nominal
    rio = StreamingRio(RioOptions(), imu_rate_hz=400.0)
    pending = sorted(scans, key=lambda s: s.time_ns)
    radars, seen = {s.radar for s in scans}, set()
    newest_pose, shortfall, out = None, [], []
    j = 0
    for k in range(0, imu.time_ns.size, 20):
        t_end = imu.time_ns[min(k + 20, imu.time_ns.size) - 1]
        deliveries = [lambda k=k: rio.add_imu(imu.time_ns[k:k + 20], imu.accel_mps2[k:k + 20], imu.gyro_radps[k:k + 20])]
        while j < len(pending) and pending[j].time_ns + 26_000_000 <= t_end:  # the frame's end, half a frame on
            deliveries.append(lambda scan=pending[j]: seen.add(scan.radar) or rio.add_scan(scan))
            j += 1
        for deliver in deliveries:
            batch = deliver()
            out.append(batch)
            if len(batch):
                newest_pose = int(batch.time_ns[-1])
            if rio.initialised and newest_pose is not None and seen == radars:
                shortfall.append(min(int(t_end), rio.radar_watermark_ns) - newest_pose)
    out.append(rio.finish())
    shortfall = np.array(shortfall) * 1e-9
    assert shortfall.size > 1000
    assert shortfall.max() < 0.0125, f"poses up to {shortfall.max():.3f} s behind the data"  # 10 ms + a sample
    times = np.concatenate([b.time_ns for b in out])
    pos = np.concatenate([b.position_m for b in out])
    np.testing.assert_array_equal(times, res.trajectory.time_ns[:times.size])
    err = np.linalg.norm(pos - res.trajectory.position_m[:times.size], axis=1)
    assert err[times < pending[j - 1].time_ns].max() < 1e-9


def _feed(rio, imu, scans, imu_ahead_s, silent_after_s=None):
    """Feed the drive as a backlogged bus delivers it: each radar scan ``imu_ahead_s`` (per radar, if a
    dict) after the IMU samples of its time (a frame is 0.7 MB, an IMU batch 1 kB). ``silent_after_s``: no
    scan after then, and the consumer says the radars went silent."""
    out = []
    ahead_ns = {s.radar: int((imu_ahead_s.get(s.radar, 0.0) if isinstance(imu_ahead_s, dict) else imu_ahead_s) * 1e9)
                for s in scans}
    pending = sorted(scans, key=lambda s: s.time_ns + ahead_ns[s.radar])
    if silent_after_s is not None:
        pending = [s for s in pending if s.time_ns < imu.time_ns[0] + silent_after_s * 1e9]
    j = 0
    for k in range(0, imu.time_ns.size, 20):
        t_end = imu.time_ns[min(k + 20, imu.time_ns.size) - 1]
        out.append(rio.add_imu(imu.time_ns[k:k + 20], imu.accel_mps2[k:k + 20], imu.gyro_radps[k:k + 20]))
        while j < len(pending) and pending[j].time_ns + ahead_ns[pending[j].radar] <= t_end:
            out.append(rio.add_scan(pending[j]))
            j += 1
        if silent_after_s is not None and j == len(pending):
            rio.radar_silent()
    out += [rio.add_scan(scan) for scan in pending[j:]]  # the backlog, drained at the end
    out.append(rio.finish())
    return (np.concatenate([b.time_ns for b in out]), np.concatenate([b.position_m for b in out]))


def test_streaming_rio_waits_for_a_radar_delivered_seconds_behind_the_imu(nominal):
    """A consumer that falls behind gets the IMU seconds before the radar. The filter waits for the radar
    (its watermark) and gives the batch trajectory; before, every scan came too late and the IMU alone
    drifted off. A radar gone silent does not hold the filter: it goes on with the IMU."""
    from rio.streaming import StreamingRio

    traj, imu, scans, res, _ = nominal
    rio = StreamingRio(RioOptions(), imu_rate_hz=400.0)
    times, pos = _feed(rio, imu, scans, imu_ahead_s=3.0)
    assert rio.stats["scans_late"] == 0
    assert rio.stats["radar_updates"] >= res.stats["radar_updates"] - 8
    np.testing.assert_array_equal(times, res.trajectory.time_ns[:times.size])
    err = np.linalg.norm(pos - res.trajectory.position_m[:times.size], axis=1)
    assert err.max() < 1e-3

    # One radar's frames a second behind the others' (its queue longer): the filter waits for the one
    # furthest behind, so none of its scans is late either.
    names = sorted({s.radar for s in scans})
    uneven = StreamingRio(RioOptions(), imu_rate_hz=400.0)
    times, pos = _feed(uneven, imu, scans, imu_ahead_s={**dict.fromkeys(names, 0.5), names[0]: 1.5})
    assert uneven.stats["scans_late"] == 0
    err = np.linalg.norm(pos - res.trajectory.position_m[:times.size], axis=1)
    assert err.max() < 1e-3

    # Beyond the wait the filter goes on without the radar; what comes after is late, and counted.
    short = StreamingRio(RioOptions(), imu_rate_hz=400.0, max_radar_wait_s=1.0)
    _feed(short, imu, scans, imu_ahead_s=3.0)
    assert short.stats["scans_late"] > 0.9 * len(scans)

    # A radar gone silent: poses still come for the whole IMU record, not only up to the last scan.
    silent = StreamingRio(RioOptions(), imu_rate_hz=400.0)
    times, _ = _feed(silent, imu, scans, imu_ahead_s=0.1, silent_after_s=20.0)
    assert times[-1] >= imu.time_ns[-1] - 10_000_000
