"""Trajectory error against ground truth: alignment, absolute and relative errors, drift."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imaging.core.trajectory import SampledTrajectory, Trajectory


def align_start(est: SampledTrajectory, truth: Trajectory) -> np.ndarray:
    """Estimated positions moved and rotated (about z) so that the first pose matches the truth's."""
    t0 = truth.sample(est.time_ns[:1])
    yaw_est = Rotation.from_quat(est.orientation_xyzw[0]).as_euler("ZYX")[0]
    yaw_true = Rotation.from_quat(t0.orientation_xyzw[0]).as_euler("ZYX")[0]
    rot = Rotation.from_euler("z", yaw_true - yaw_est)
    return rot.apply(est.position_m - est.position_m[0]) + t0.position_m[0]


def align_position_yaw(est_p: np.ndarray, true_p: np.ndarray) -> np.ndarray:
    """Least-squares alignment with a translation and a rotation about z (4-DoF, as evo's posyaw)."""
    me, mt = est_p.mean(axis=0), true_p.mean(axis=0)
    a, b = est_p[:, :2] - me[:2], true_p[:, :2] - mt[:2]
    h = a.T @ b
    yaw = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    rot = Rotation.from_euler("z", yaw)
    return rot.apply(est_p - me) + mt


def drift_report(est: SampledTrajectory, truth: Trajectory) -> dict:
    """Final drift (start-aligned) and ATE RMSE (position+yaw aligned), also as % of distance travelled."""
    true = truth.sample(est.time_ns)
    dist = float(np.sum(np.linalg.norm(np.diff(true.position_m, axis=0), axis=1)))
    start = align_start(est, truth)
    final = float(np.linalg.norm(start[-1] - true.position_m[-1]))
    aligned = align_position_yaw(est.position_m, true.position_m)
    ate = float(np.sqrt(np.mean(np.sum((aligned - true.position_m) ** 2, axis=1))))
    yaw_err = (Rotation.from_quat(est.orientation_xyzw[-1]) * Rotation.from_quat(true.orientation_xyzw[-1]).inv()).as_euler("ZYX", degrees=True)[0]
    yaw0 = (Rotation.from_quat(est.orientation_xyzw[0]) * Rotation.from_quat(true.orientation_xyzw[0]).inv()).as_euler("ZYX", degrees=True)[0]
    return {
        "distance_m": dist,
        "final_drift_m": final,
        "final_drift_percent": 100 * final / dist if dist > 0 else float("nan"),
        "ate_rmse_m": ate,
        "ate_rmse_percent": 100 * ate / dist if dist > 0 else float("nan"),
        "final_yaw_error_deg": float((yaw_err - yaw0 + 180) % 360 - 180),
    }
