"""SampledTrajectory's interpolation against scipy's: the attitude by slerp, the rest linear, held outside;
and the numpy quaternion helpers the imaging path uses instead of scipy's Rotation, against it."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from imaging.core import quaternion
from imaging.core.rig import Mount
from imaging.core.trajectory import SampledTrajectory, StraightLine


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


def _random_quaternions(rng, n):
    """Unnormalised quaternions of every sign, with rotations of nearly nothing and nearly half a turn."""
    q = rng.normal(size=(n, 4)) * rng.uniform(0.5, 2.0, (n, 1))
    q[:10, :3] *= 1e-6  # tiny angles: the rotation vector's series
    q[10:20, 3] *= 1e-6  # angles near pi
    q[::3] *= -1
    return q


def test_quaternion_helpers_give_scipys_numbers():
    rng = np.random.default_rng(7)
    q = _random_quaternions(rng, 500)
    r, qn = Rotation.from_quat(q), quaternion.normalized(q)
    np.testing.assert_allclose(qn, r.as_quat(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(quaternion.to_matrix(qn), r.as_matrix(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(quaternion.inverse(qn), r.inv().as_quat(), rtol=0, atol=1e-12)
    composed = quaternion.compose(quaternion.inverse(qn[:-1]), qn[1:])
    np.testing.assert_allclose(composed, (r[:-1].inv() * r[1:]).as_quat(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(quaternion.to_rotvec(qn), r.as_rotvec(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(quaternion.to_rotvec(composed), (r[:-1].inv() * r[1:]).as_rotvec(), rtol=0, atol=1e-12)
    angle = rng.uniform(-7, 7, 50)
    np.testing.assert_allclose(quaternion.about_z(angle), Rotation.from_euler("z", angle[:, None]).as_quat(),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(quaternion.to_matrix(q[0] / np.linalg.norm(q[0])), r[0].as_matrix(), rtol=0, atol=1e-12)


def test_mounts_and_samples_give_the_matrices_of_scipys_rotation():
    mount = Mount.from_yaw([0.1, 0.2, 0.3], 57.0)
    np.testing.assert_allclose(mount.rotation_xyzw, Rotation.from_euler("z", 57.0, degrees=True).as_quat(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(mount.rotation_matrix, mount.rotation.as_matrix(), rtol=0, atol=1e-15)
    s = StraightLine(start_m=(0, 0, 0), speed_mps=0.4, heading_deg=115.0).sample(np.arange(5) * 10 ** 8)
    np.testing.assert_allclose(s.orientation_xyzw, Rotation.from_euler("z", np.full((5, 1), 115.0), degrees=True).as_quat(),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(s.rotation_matrix, s.rotation.as_matrix(), rtol=0, atol=1e-15)
