"""The odometry's speed-ups change no result beyond rounding: each compiled kernel against the numpy form it
replaced, and a drive's trajectory with all of those forms put back (benchmarks/odometry_speed.py times them)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rio.ego_velocity as ego_velocity
import rio.ekf as ekf_module
from rio.ego_velocity import EgoStatus, EgoVelocity, EgoVelocityConfig, direction_moments, remove_crosstalk
from rio.ekf import EkfConfig, RadarInertialEkf
from rio.odometry import run_rio
from rio.strapdown import _strapdown, _strapdown_jacobian
from test_rio import drive, simulate

GRAVITY = np.array([0.0, 0.0, -9.80665])


# -- the numpy forms the kernels replaced (ac0c048) ----------------------------------------------------------
def crosstalk_numpy(u, est, config):
    u_in = u[est.inliers]
    moments, inv_gain = direction_moments(u_in, math.radians(config.elevation_sigma_deg),
                                          math.radians(config.azimuth_sigma_deg), -1)
    crosstalk = np.linalg.solve(u_in.T @ u_in, moments[:, :2] / inv_gain[:, None])[2]
    j = np.eye(3)
    j[2, :2] = -crosstalk
    est.velocity_mps = j @ est.velocity_mps
    est.covariance = j @ est.covariance @ j.T


def strapdown_numpy(p, v, R, P, f, w, dt, q_density):
    """One step with the dense F (``_strapdown_jacobian``) and Rotation's exponential."""
    a = R @ Rotation.from_rotvec(0.5 * w * dt).as_matrix() @ f + GRAVITY
    F = np.eye(P.shape[0])
    F[:15, :15] = _strapdown_jacobian(R, f, w, dt)
    out = F @ P @ F.T + np.diag(q_density * dt)
    return (p + v * dt + 0.5 * a * dt * dt, v + a * dt, R @ Rotation.from_rotvec(w * dt).as_matrix(),
            0.5 * (out + out.T))


def strapdown_batch_numpy(p, v, R, P, t_ns, f_last, w_last, ba, bg, times, accs, gyros, record, q_density):
    rec = []
    for i in range(times.size):
        dt = (times[i] - t_ns) * 1e-9
        if dt > 0:
            p, v, R, P = strapdown_numpy(p, v, R, P, f_last - ba, w_last - bg, dt, q_density)
            t_ns = times[i]
        f_last, w_last = accs[i], gyros[i]
        if record[i]:
            rec.append((t_ns, p, v, R, np.diag(P)[:15].copy()))
    out = [np.array([r[k] for r in rec]).reshape((len(rec),) + shape) for k, shape in
           ((0, ()), (1, (3,)), (2, (3,)), (3, (3, 3)), (4, (15,)))]
    out[0] = out[0].astype(np.int64)
    return (p, v, R, P, t_ns, f_last, w_last, *out)


def imu_was_still_numpy(self, accel_limit_mps2=None):
    c = self.config
    limit = c.still_accel_mps2 if accel_limit_mps2 is None else accel_limit_mps2
    t, gyro, accel = self._recent_imu
    keep = t >= t[-1] - int(c.still_window_s * 1e9) if t.size else t.astype(bool)
    if keep.sum() < 3:
        return None
    t, gyro, accel = t[keep], gyro[keep], accel[keep]
    s = self.state
    latest = t >= t[-1] - 25_000_000
    latest[-3:] = True
    return bool(np.linalg.norm(gyro.mean(axis=0) - s.bg) < c.still_gyro_radps
                and np.linalg.norm(s.R @ (accel.mean(axis=0) - s.ba) + GRAVITY) < limit
                and np.linalg.norm(s.R @ (accel[latest].mean(axis=0) - s.ba) + GRAVITY) < limit
                and accel.std(axis=0).max() < c.still_accel_std_mps2)


# -- kernels ---------------------------------------------------------------------------------------------
def test_crosstalk_kernel_is_the_numpy_form():
    rng = np.random.default_rng(1)
    config = EgoVelocityConfig()
    for trial in range(300):
        n = int(rng.integers(6, 120))
        az = rng.uniform(-1.2, 1.2, n) + (math.pi if trial % 3 == 0 else 0.0)  # behind too: atan2's other half
        el = rng.uniform(-0.5, 0.2, n)
        u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        if trial == 1:
            u[0] = (0.0, 0.0, -1.0)  # straight down: azimuth 0 as atan2(0, 0) gives it
        inliers = rng.random(n) < 0.8
        inliers[:6] = True
        a = rng.normal(size=(3, 3))
        velocity, covariance = rng.normal(size=3), a @ a.T * 1e-4
        fast = EgoVelocity(EgoStatus.OK, velocity, covariance, inliers, 0.02)
        slow = EgoVelocity(EgoStatus.OK, velocity, covariance, inliers, 0.02)
        remove_crosstalk(u, fast, config)
        crosstalk_numpy(u, slow, config)
        assert abs(slow.velocity_mps[2] - velocity[2]) > 1e-6  # there is cross-talk to take out
        np.testing.assert_allclose(fast.velocity_mps, slow.velocity_mps, rtol=0, atol=1e-14 * np.abs(velocity).max())
        np.testing.assert_allclose(fast.covariance, slow.covariance, rtol=0, atol=1e-13 * np.abs(covariance).max())


@pytest.mark.parametrize("states", [15, 22, 29])  # the core filter, with one and with two calibrated radars
def test_strapdown_step_is_the_dense_numpy_form(states):
    rng = np.random.default_rng(states)
    for _ in range(50):
        a = rng.normal(size=(states, states))
        P = a @ a.T
        R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        f, w, q = rng.normal(size=3) + (0, 0, 9.8), rng.normal(size=3), rng.random(states) * 1e-4
        p, v = rng.normal(size=3), rng.normal(size=3)
        fast = _strapdown(p, v, R, P, f, w, 0.0025, q)
        slow = strapdown_numpy(p, v, R, P, f, w, 0.0025, q)
        for x, y in zip(fast, slow):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-14 * max(1.0, np.abs(y).max()))


def test_imu_stillness_kernel_decides_as_the_numpy_form():
    rng = np.random.default_rng(4)
    decided = {True: 0, False: 0, None: 0}
    for trial in range(400):
        ekf = RadarInertialEkf(EkfConfig())
        tilt = Rotation.from_rotvec(rng.normal(0, 0.05, 3))
        ekf.initialise_static(0, np.tile(tilt.inv().apply(-GRAVITY), (10, 1)), np.zeros((10, 3)))
        n = int(rng.integers(1, 80))
        times = np.cumsum(rng.integers(2_000_000, 3_000_000, n)).astype(np.int64)
        # noise and a motion of the size of each limit: every test decides some of the cases
        accel = tilt.inv().apply(-GRAVITY) + rng.normal(0, rng.choice([0.01, 0.1]), (n, 3)) \
            + rng.normal(0, 0.1, 3) * (trial % 2)
        gyro = rng.normal(0, 0.01, (n, 3)) + rng.normal(0, 0.01, 3)
        ekf._keep_recent(times, gyro, accel)
        for limit in (None, 0.08):
            fast, slow = ekf.imu_was_still(limit), imu_was_still_numpy(ekf, limit)
            assert fast == slow
            decided[fast] += 1
    assert min(decided.values()) > 10


def test_recent_imu_samples_joined_when_asked_are_those_kept_at_every_run():
    rng = np.random.default_rng(5)
    ekf = RadarInertialEkf(EkfConfig(still_window_s=0.1))
    t_all, g_all, a_all = np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    t0 = 0
    for run in range(300):
        k = int(rng.choice([1, 2, 5, 40, 300]))
        times = t0 + np.cumsum(rng.integers(200_000, 3_000_000, k)).astype(np.int64)
        t0 = int(times[-1])
        gyro, accel = rng.normal(size=(k, 3)), rng.normal(size=(k, 3))
        ekf._keep_recent(times, gyro, accel)
        # what propagate_samples kept before (ac0c048): joined at every run, the last 512, within the window
        t = np.concatenate([t_all, times])[-512:]
        keep = t >= t[-1] - 100_000_000
        t_all, g_all, a_all = t[keep], np.concatenate([g_all, gyro])[-512:][keep], np.concatenate([a_all, accel])[-512:][keep]
        if run % 7 == 0 or k == 300:
            t_lazy, g_lazy, a_lazy = ekf._recent_imu
            np.testing.assert_array_equal(t_lazy, t_all)
            np.testing.assert_array_equal(g_lazy, g_all)
            np.testing.assert_array_equal(a_lazy, a_all)
    assert len(ekf._recent_runs) < 300  # runs out of the window were let go


# -- a drive ---------------------------------------------------------------------------------------------
def test_a_drive_s_trajectory_is_that_of_the_numpy_forms(monkeypatch):
    # Turns, a stop after driving (the IMU's stillness decides the zero-velocity update), all four radars.
    imu, scans, _ = simulate(drive(stops=((2.0, 2.0),)), 14.0)
    fast = run_rio(imu, scans)
    monkeypatch.setattr(ego_velocity, "remove_crosstalk", crosstalk_numpy)
    monkeypatch.setattr(ekf_module, "_strapdown_batch", strapdown_batch_numpy)
    monkeypatch.setattr(ekf_module, "_strapdown", strapdown_numpy)
    monkeypatch.setattr(RadarInertialEkf, "imu_was_still", imu_was_still_numpy)
    slow = run_rio(imu, scans)
    assert fast.stats == slow.stats and fast.stats["zero_velocity_updates"] > 10 and fast.stats["radar_updates"] > 500
    assert [s for _, _, s in fast.scan_status] == [s for _, _, s in slow.scan_status]
    np.testing.assert_array_equal(fast.trajectory.time_ns, slow.trajectory.time_ns)
    np.testing.assert_allclose(fast.trajectory.position_m, slow.trajectory.position_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.trajectory.velocity_mps, slow.trajectory.velocity_mps, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.covariance_diag, slow.covariance_diag, rtol=1e-9, atol=0)
