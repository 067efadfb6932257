"""benchmarks/strapdown_rules.py: its dead reckoning integrates as the filter's strapdown does, so its table says
what rio/strapdown.py does with point samples and interval averages."""

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rio.strapdown import _strapdown

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import strapdown_rules  # noqa: E402

sys.path.pop(0)


def _samples(n=200, seed=4):
    rng = np.random.default_rng(seed)
    f = np.ascontiguousarray(rng.normal([0.3, -0.2, 9.8], 0.5, (n, 3)))
    w = np.ascontiguousarray(rng.normal(0.0, 0.4, (n, 3)))
    return f, w


def test_the_benchmarks_mid_rule_is_the_filters_strapdown():
    f, w = _samples()
    dt = 1.0 / strapdown_rules.RATE_HZ
    p0, v0 = np.array([1.0, 2.0, 0.0]), np.array([0.5, -0.1, 0.0])
    R0 = Rotation.from_euler("xyz", [0.05, -0.02, 0.7]).as_matrix()
    p, v, R = strapdown_rules._dead_reckon(strapdown_rules.RULES.index("mid"), p0, v0, R0, f, w, 0, 150, dt)
    pr, vr, Rr, P = p0.copy(), v0.copy(), R0.copy(), np.eye(15)
    for k in range(150):  # the filter: sample k held over [t_k, t_k+1]
        pr, vr, Rr, P = _strapdown(pr, vr, Rr, P, f[k], w[k], dt, np.zeros(15))
    np.testing.assert_allclose(p, pr, atol=1e-12)
    np.testing.assert_allclose(v, vr, atol=1e-12)
    np.testing.assert_allclose(R, Rr, atol=1e-12)


def test_the_rules_take_the_samples_they_name():
    # trap: the mean of both ends' samples; own: the sample at the interval's end; start: no midpoint rotation.
    f, w = _samples(3)
    dt = 0.01
    p0, v0, R0 = np.zeros(3), np.zeros(3), np.eye(3)
    idx = strapdown_rules.RULES.index
    _, v_trap, R_trap = strapdown_rules._dead_reckon(idx("trap"), p0, v0, R0, f, w, 0, 1, dt)
    _, v_mean, R_mean = strapdown_rules._dead_reckon(idx("mid"), p0, v0, R0, 0.5 * (f[:2] + f[1:]), 0.5 * (w[:2] + w[1:]), 0, 1, dt)
    np.testing.assert_allclose(v_trap, v_mean, atol=1e-15)
    np.testing.assert_allclose(R_trap, R_mean, atol=1e-15)
    _, v_own, _ = strapdown_rules._dead_reckon(idx("own"), p0, v0, R0, f, w, 0, 1, dt)
    _, v_next, _ = strapdown_rules._dead_reckon(idx("mid"), p0, v0, R0, f[1:], w[1:], 0, 1, dt)
    np.testing.assert_allclose(v_own, v_next, atol=1e-15)
    _, v_start, _ = strapdown_rules._dead_reckon(idx("start"), p0, v0, R0, f, w, 0, 1, dt)
    np.testing.assert_allclose(v_start, (f[0] - [0.0, 0.0, 9.80665]) * dt, atol=1e-15)
