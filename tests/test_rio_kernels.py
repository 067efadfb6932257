"""The numba kernels of rio against plain numpy references."""

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from rio.ego_velocity import _ransac
from rio.ekf import _joseph_update
from rio.strapdown import _strapdown, _strapdown_batch, _strapdown_jacobian

G = np.array([0.0, 0.0, -9.80665])


def test_joseph_update_matches_numpy():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(15, 15))
    P = A @ A.T + np.eye(15)
    H = rng.normal(size=(3, 15))
    R = np.diag([0.01, 0.02, 0.03])
    y = rng.normal(size=3) * 0.1
    ok, chi2, dx, P_new, S_kernel = _joseph_update(P, H, R, y, np.inf)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    I_KH = np.eye(15) - K @ H
    assert ok
    np.testing.assert_allclose(chi2, y @ np.linalg.solve(S, y))
    np.testing.assert_allclose(dx, K @ y, atol=1e-12)
    np.testing.assert_allclose(P_new, I_KH @ P @ I_KH.T + K @ R @ K.T, atol=1e-9)
    np.testing.assert_allclose(S_kernel, S)  # the innovation covariance the update result carries
    ok, chi2_gated, _, P_same, _ = _joseph_update(P, H, R, y * 1e4, 16.27)
    assert not ok and chi2_gated > 16.27 and P_same is P


def test_strapdown_batch_matches_numpy():
    rng = np.random.default_rng(1)
    n = 50
    times = np.arange(1, n + 1, dtype=np.int64) * 2_500_000
    accs = rng.normal([0.2, 0.1, 9.8], 0.3, (n, 3))
    gyros = rng.normal(0, 0.3, (n, 3))
    ba, bg = np.array([0.01, -0.02, 0.03]), np.array([1e-3, -2e-3, 5e-4])
    q = np.full(15, 1e-6)
    p0, v0, R0 = np.zeros(3), np.array([0.5, 0.0, 0.0]), Rotation.from_euler("z", 0.3).as_matrix()
    record = np.zeros(n, bool)
    record[::7] = True
    p, v, R, P, t, f_last, w_last, out_t, out_p, *_ = _strapdown_batch(
        p0, v0, R0, np.eye(15) * 1e-4, 0, accs[0], gyros[0], ba, bg, times, accs, gyros, record, q)
    # Plain numpy: zero-order hold, the sample at the start of each interval; the specific force rotated by
    # the attitude at the interval's midpoint (rio/strapdown.py says why).
    pr, vr, Rr, f, w, t_prev = p0.copy(), v0.copy(), R0.copy(), accs[0], gyros[0], 0
    ref_p = []
    for i in range(n):
        dt = (times[i] - t_prev) * 1e-9
        a = Rr @ Rotation.from_rotvec(0.5 * (w - bg) * dt).as_matrix() @ (f - ba) + G
        pr = pr + vr * dt + 0.5 * a * dt * dt
        vr = vr + a * dt
        Rr = Rr @ Rotation.from_rotvec((w - bg) * dt).as_matrix()
        t_prev, f, w = times[i], accs[i], gyros[i]
        if record[i]:
            ref_p.append(pr)
    np.testing.assert_allclose(p, pr, atol=1e-12)
    np.testing.assert_allclose(v, vr, atol=1e-12)
    np.testing.assert_allclose(R, Rr, atol=1e-12)
    np.testing.assert_allclose(out_p, np.array(ref_p), atol=1e-12)
    np.testing.assert_array_equal(out_t, times[record])
    assert np.all(np.linalg.eigvalsh(P) > 0)


def _turn_velocity_error(dt_s, duration_s=2.0):
    """Velocity error (m/s) of the strapdown after a turn at a constant body rate with a constant body-frame
    specific force, against the closed form v(T) = v0 + R0 (integral of Exp(w s) ds over [0, T]) f + g T."""
    w = np.array([0.2, -0.3, 1.1])  # rad/s, about a tilted axis: all three components of the sculling term
    f = np.array([1.5, -0.8, 9.9])  # m/s^2, body frame
    R0 = Rotation.from_euler("xyz", [0.1, -0.05, 0.4]).as_matrix()
    v0 = np.array([0.3, 0.1, 0.0])
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    rate = np.linalg.norm(w)
    T = duration_s
    integral = T * np.eye(3) + (1 - np.cos(rate * T)) / rate ** 2 * K + (rate * T - np.sin(rate * T)) / rate ** 3 * K @ K
    v_exact = v0 + R0 @ integral @ f + G * T
    p, v, R, P = np.zeros(3), v0.copy(), R0.copy(), np.eye(15) * 1e-6
    for _ in range(int(round(T / dt_s))):
        p, v, R, P = _strapdown(p, v, R, P, f, w, dt_s, np.zeros(15))
    np.testing.assert_allclose(R, R0 @ Rotation.from_rotvec(w * T).as_matrix(), atol=1e-9)  # the attitude is exact
    return float(np.linalg.norm(v - v_exact))


def test_strapdown_velocity_is_second_order_in_a_constant_rate_turn():
    # Halving the step quarters a second-order scheme's error and halves a first-order one's: rotating the
    # specific force by the attitude at the interval's start (before the midpoint fix) gives a ratio of 2.0
    # and 0.011 m/s after 2 s at 100 Hz.
    coarse, fine = _turn_velocity_error(0.01), _turn_velocity_error(0.005)
    assert 3.8 < coarse / fine < 4.2
    assert coarse < 5e-5


def test_strapdown_jacobian_is_the_derivative_of_the_propagation():
    # Finite differences of the nominal step against F, for every error state (p, v, theta in the body frame,
    # accelerometer and gyro bias). The velocity's dependence on the gyro bias (through the midpoint attitude)
    # is 0.5 dt^2 R Exp(w dt/2) [f]x (4e-4 here) and its attitude's [Exp(w dt/2) f]x, not [f]x (5e-4 apart):
    # the start-attitude Jacobian of before fails both by far more than the tolerance.
    rng = np.random.default_rng(3)
    dt = 0.01
    f_m, w_m = np.array([0.7, -0.4, 9.7]), np.array([0.3, -0.2, 0.9])
    p0, v0 = rng.normal(size=3), rng.normal(size=3)
    R0 = Rotation.from_euler("xyz", [0.2, -0.1, 0.7]).as_matrix()
    ba, bg = np.array([0.02, -0.01, 0.03]), np.array([1e-3, 2e-3, -1e-3])

    def step(dx):
        R = R0 @ Rotation.from_rotvec(dx[6:9]).as_matrix()
        p, v, R_new, _ = _strapdown(p0 + dx[0:3], v0 + dx[3:6], R, np.eye(15), f_m - ba - dx[9:12],
                                    w_m - bg - dx[12:15], dt, np.zeros(15))
        return p, v, R_new

    eps = 1e-6
    numeric = np.zeros((9, 15))
    for j in range(15):  # central differences
        dx = np.zeros(15)
        dx[j] = eps
        p, v, R = step(dx)
        p_m, v_m, R_m = step(-dx)
        numeric[:, j] = np.concatenate([p - p_m, v - v_m, Rotation.from_matrix(R_m.T @ R).as_rotvec()]) / (2 * eps)
    F = _strapdown_jacobian(R0, f_m - ba, w_m - bg, dt)
    np.testing.assert_allclose(F[0:9, 0:12], numeric[:, 0:12], atol=1e-9)
    # The gyro bias's columns take the right Jacobian of Exp(w dt) (and of Exp(w dt / 2)) as I: a relative error
    # of |w| dt / 2 (0.5 %) here.
    for rows in (slice(0, 3), slice(3, 6), slice(6, 9)):
        scale = np.abs(numeric[rows, 12:15]).max()
        np.testing.assert_allclose(F[rows, 12:15], numeric[rows, 12:15], atol=0.01 * scale)


def test_ransac_finds_the_largest_consensus():
    # Small enough to try every minimal set in numpy: the kernel must find the same best inlier count.
    rng = np.random.default_rng(2)
    for trial in range(5):
        n, dim = 9, 2
        a = rng.normal(size=(n, dim))
        v_true = rng.normal(size=dim)
        b = a @ v_true + rng.normal(0, 0.01, n)
        b[rng.random(n) < 0.35] += rng.uniform(-2, 2)
        best_numpy = 0
        for pick in itertools.combinations(range(n), dim):
            m = a[list(pick)]
            if abs(np.linalg.det(m)) < 1e-9:
                continue
            v = np.linalg.solve(m, b[list(pick)])
            best_numpy = max(best_numpy, int(np.sum(np.abs(a @ v - b) < 0.05)))
        found = _ransac(a, b, 400, 0.05, 12345 + trial)
        assert found.sum() == best_numpy
