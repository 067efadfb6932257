"""Rotations as unit quaternions (x, y, z, w) [N, 4] in plain numpy, for the code every command runs.

scipy's ``Rotation`` costs a quarter of a second to import (scipy.spatial pulls in qhull and scipy.linalg),
which ``sarbot image`` paid only to turn a trajectory's attitudes into matrices. These are the few
operations that path needs, written in the order of scipy's own arithmetic, so that they give scipy's
numbers (tests/test_trajectory.py compares them). Conventions as scipy's and docs/conventions.md: scalar
last, ``compose(p, q)`` is the rotation q, then p (scipy's ``p * q``).
"""

from __future__ import annotations

import numpy as np


def normalized(q) -> np.ndarray:
    """Quaternions [N, 4] (or one [4]) scaled to unit norm (scipy's ``from_quat``)."""
    q = np.asarray(q, dtype=np.float64)
    return q / np.sqrt(q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1] + q[..., 2] * q[..., 2]
                       + q[..., 3] * q[..., 3])[..., None]


def to_matrix(q) -> np.ndarray:
    """Rotation matrices [N, 3, 3] (or one [3, 3]) of unit quaternions (scipy's ``as_matrix``)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty((*q.shape[:-1], 3, 3))
    m[..., 0, 0] = x2 - y2 - z2 + w2
    m[..., 1, 0] = 2 * (xy + zw)
    m[..., 2, 0] = 2 * (xz - yw)
    m[..., 0, 1] = 2 * (xy - zw)
    m[..., 1, 1] = -x2 + y2 - z2 + w2
    m[..., 2, 1] = 2 * (yz + xw)
    m[..., 0, 2] = 2 * (xz + yw)
    m[..., 1, 2] = 2 * (yz - xw)
    m[..., 2, 2] = -x2 - y2 + z2 + w2
    return m


def about_z(angle_rad) -> np.ndarray:
    """Quaternions [..., 4] of rotations by ``angle_rad`` about z (scipy's ``from_euler("z", angle)``)."""
    half = np.asarray(angle_rad, dtype=np.float64) / 2
    q = np.zeros((*half.shape, 4))
    q[..., 2] = np.sin(half)
    q[..., 3] = np.cos(half)
    return q


def inverse(q) -> np.ndarray:
    """The inverse rotations: the conjugate quaternions (scipy's ``inv``)."""
    q = np.array(q, dtype=np.float64)
    q[..., :3] *= -1
    return q


def compose(p, q) -> np.ndarray:
    """The rotation q, then p, for quaternions [N, 4] (scipy's ``p * q``), normalised."""
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    cross = np.stack([p[..., 1] * q[..., 2] - p[..., 2] * q[..., 1],
                      p[..., 2] * q[..., 0] - p[..., 0] * q[..., 2],
                      p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]], axis=-1)
    r = np.empty(np.broadcast_shapes(p.shape, q.shape))
    r[..., :3] = p[..., 3:] * q[..., :3] + q[..., 3:] * p[..., :3] + cross
    r[..., 3] = p[..., 3] * q[..., 3] - p[..., 0] * q[..., 0] - p[..., 1] * q[..., 1] - p[..., 2] * q[..., 2]
    return normalized(r)


def to_rotvec(q) -> np.ndarray:
    """Rotation vectors [N, 3] (axis times angle, the angle in [0, pi]) of unit quaternions (scipy's
    ``as_rotvec``)."""
    q = np.asarray(q, dtype=np.float64)
    q = np.where(q[..., 3:] < 0, -q, q)  # the same rotation with w >= 0: an angle of at most pi
    angle = 2 * np.arctan2(np.sqrt(q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1] + q[..., 2] * q[..., 2]), q[..., 3])
    small = angle <= 1e-3
    # angle / sin(angle / 2), by its series where the angle is small
    scale = np.where(small, 2 + angle ** 2 / 12 + 7 * angle ** 4 / 2880,
                     angle / np.sin(np.where(small, 1.0, angle) / 2))
    return scale[..., None] * q[..., :3]
