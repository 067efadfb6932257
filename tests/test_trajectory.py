"""SampledTrajectory's interpolation against scipy's: the attitude by slerp, the rest linear, held outside."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from imaging.core.trajectory import SampledTrajectory


def test_sampling_matches_scipy_slerp_and_linear_interpolation():
    rng = np.random.default_rng(3)
    n = 200
    time_ns = 10 ** 18 + np.cumsum(rng.integers(5_000_000, 15_000_000, n))
    # Attitudes from slow turns and a few large steps (up to ~170 degrees between samples), unnormalised.
    rotvec = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    rotvec[50] += [0.0, 0.0, 2.9]
    quat = Rotation.from_rotvec(rotvec).as_quat() * rng.uniform(0.5, 2.0, (n, 1))
    quat[::7] *= -1  # either sign of a quaternion is the same attitude
    position = np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0)
    velocity = rng.normal(0, 0.5, (n, 3))
    traj = SampledTrajectory(time_ns, position, quat, velocity)
    t = np.concatenate([time_ns, rng.integers(time_ns[0], time_ns[-1], 5000), [time_ns[0] - 10 ** 9, time_ns[-1] + 10 ** 9]])
    s = traj.sample(t)
    seconds = (np.clip(t, time_ns[0], time_ns[-1]) - time_ns[0]) * 1e-9
    knots = (time_ns - time_ns[0]) * 1e-9
    expected = Slerp(knots, Rotation.from_quat(quat))(seconds)
    assert np.max((expected.inv() * s.rotation).magnitude()) < 1e-12
    assert np.allclose(np.linalg.norm(s.orientation_xyzw, axis=1), 1.0, atol=1e-12)
    for got, table in ((s.position_m, position), (s.velocity_mps, velocity)):
        want = np.column_stack([np.interp(seconds, knots, table[:, j]) for j in range(3)])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # The body rate is that of the interval a time falls in: R_k^T R_{k+1} over its length.
    k = 17
    mid = (time_ns[k] + time_ns[k + 1]) // 2
    step = (Rotation.from_quat(quat[k]).inv() * Rotation.from_quat(quat[k + 1])).as_rotvec()
    np.testing.assert_allclose(traj.sample(np.array([mid])).angular_velocity_body_radps[0],
                               step / ((time_ns[k + 1] - time_ns[k]) * 1e-9), rtol=1e-9)
