"""The numba kernels of rio against plain numpy references."""

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from rio.ego_velocity import _ransac
from rio.ekf import _joseph_update, _strapdown_batch

G = np.array([0.0, 0.0, -9.80665])


def test_joseph_update_matches_numpy():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(15, 15))
    P = A @ A.T + np.eye(15)
    H = rng.normal(size=(3, 15))
    R = np.diag([0.01, 0.02, 0.03])
    y = rng.normal(size=3) * 0.1
    ok, chi2, dx, P_new = _joseph_update(P, H, R, y, np.inf)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    I_KH = np.eye(15) - K @ H
    assert ok
    np.testing.assert_allclose(chi2, y @ np.linalg.solve(S, y))
    np.testing.assert_allclose(dx, K @ y, atol=1e-12)
    np.testing.assert_allclose(P_new, I_KH @ P @ I_KH.T + K @ R @ K.T, atol=1e-9)
    ok, chi2_gated, _, P_same = _joseph_update(P, H, R, y * 1e4, 16.27)
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
    # Plain numpy: zero-order hold, the sample at the start of each interval.
    pr, vr, Rr, f, w, t_prev = p0.copy(), v0.copy(), R0.copy(), accs[0], gyros[0], 0
    ref_p = []
    for i in range(n):
        dt = (times[i] - t_prev) * 1e-9
        a = Rr @ (f - ba) + G
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
