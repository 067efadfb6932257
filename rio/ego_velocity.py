"""Radar ego velocity from the Doppler of static detections: RANSAC, then least squares.

For a static point seen in direction u (unit, sensor frame) the range rate is d = -u . v_s, with v_s the
sensor's velocity. Moving targets and false alarms break this relation and are rejected as outliers.
Several radars at once: each detection's equation is expressed in the body velocity through the radar's
mount and the angular rate (lever arm), and all are solved together.
"""

from __future__ import annotations

import dataclasses
import enum

import numba
import numpy as np


#: Variance given to a velocity component the radar does not measure (m/s)^2.
UNMEASURED_VARIANCE = 100.0


class EgoStatus(enum.Enum):
    OK = "ok"
    ZERO_VELOCITY = "zero_velocity"
    TOO_FEW = "too_few_detections"
    NO_CONSENSUS = "no_consensus"
    ILL_CONDITIONED = "ill_conditioned"
    NOISY = "noisy"


@dataclasses.dataclass(frozen=True)
class EgoVelocityConfig:
    """RANSAC and rejection settings (SI units)."""

    min_detections: int = 6
    min_range_m: float = 0.2
    ransac_iterations: int = 40
    inlier_threshold_mps: float = 0.08
    min_inlier_ratio: float = 0.35
    zero_velocity_threshold_mps: float = 0.03
    zero_velocity_ratio: float = 0.6
    creep_chi2: float = 16.27  # 99.9 % of chi2(3): a near-zero velocity this far from zero is creeping, not standing
    max_sigma_mps: float = 0.15
    max_condition: float = 1e4
    min_sigma_mps: float = 0.01  # floor on the per-detection Doppler noise used for the covariance


@dataclasses.dataclass
class EgoVelocity:
    """The estimate, its covariance and which detections were inliers."""

    status: EgoStatus
    velocity_mps: np.ndarray | None  # [3]
    covariance: np.ndarray | None  # [3, 3]
    inliers: np.ndarray  # [D] bool
    sigma_mps: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.status in (EgoStatus.OK, EgoStatus.ZERO_VELOCITY)


@numba.njit(cache=True)
def _ransac(a, b, iterations, threshold, seed):
    """Inliers of the best of ``iterations`` minimal-set hypotheses (dim equations each) for a v = b.

    A small xorshift generator picks the sets, so that a seed gives the same answer on every machine.
    """
    n, dim = a.shape
    best = np.zeros(n, np.bool_)
    best_count = -1
    state = np.uint64(seed) | np.uint64(1)
    pick = np.empty(dim, np.int64)
    for _ in range(iterations):
        for k in range(dim):
            state ^= state << np.uint64(13)
            state ^= state >> np.uint64(7)
            state ^= state << np.uint64(17)
            pick[k] = np.int64(state % np.uint64(n))
        distinct = True
        for k in range(dim):
            for m in range(k):
                if pick[k] == pick[m]:
                    distinct = False
        if not distinct:
            continue
        m_a = a[pick]
        if abs(np.linalg.det(m_a)) < 1e-9:
            continue
        v = np.linalg.solve(m_a, b[pick])
        count = 0
        for i in range(n):
            r = -b[i]
            for k in range(dim):
                r += a[i, k] * v[k]
            if abs(r) < threshold:
                count += 1
        if count > best_count:
            best_count = count
            for i in range(n):
                r = -b[i]
                for k in range(dim):
                    r += a[i, k] * v[k]
                best[i] = abs(r) < threshold
    return best


def _condition(ata: np.ndarray) -> float:
    """Condition number of a symmetric positive semi-definite matrix."""
    w = np.linalg.eigvalsh(ata)
    return float(w[-1] / w[0]) if w[0] > 0 else float("inf")


def _least_squares(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normal-equation least squares (the systems here are tiny and well conditioned once checked)."""
    try:
        return np.linalg.solve(a.T @ a, a.T @ b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(a, b, rcond=None)[0]


def solve_ego_velocity(a: np.ndarray, b: np.ndarray, config: EgoVelocityConfig = EgoVelocityConfig(),
                       rng: np.random.Generator | None = None) -> EgoVelocity:
    """Solve a v = b robustly: rows of ``a`` [D, 3] are the equations, ``b`` [D] the right-hand sides.

    For one radar, ``a = -u`` (unit directions) and ``b`` the Doppler; ``v`` is then the sensor velocity.
    """
    rng = rng or np.random.default_rng(0)
    n = b.size
    dim = a.shape[1]  # 3, or 2 for a radar that measures no elevation
    none = np.zeros(n, bool)
    if n < config.min_detections:
        return EgoVelocity(EgoStatus.TOO_FEW, None, None, none)
    # Standstill: most detections (the static world) have no Doppler at all.
    still = np.abs(b) < config.zero_velocity_threshold_mps
    if still.mean() >= config.zero_velocity_ratio:
        # Most Doppler is near zero. Standing still, or creeping below the threshold? The least-squares
        # velocity of those detections tells: zero only if it is not significantly different from zero.
        ai, bi = a[still], b[still]
        v = _least_squares(ai, bi)
        dof = max(int(still.sum()) - dim, 1)
        sigma = max(config.min_sigma_mps, float(np.sqrt(np.sum((ai @ v - bi) ** 2) / dof)))
        ata = ai.T @ ai
        if _condition(ata) < config.max_condition:
            cov = sigma ** 2 * np.linalg.inv(ata)
            if float(v @ np.linalg.solve(cov, v)) > config.creep_chi2:
                return EgoVelocity(EgoStatus.OK, v, cov, still, sigma)
        cov = np.eye(dim) * (sigma ** 2) / max(still.sum() / dim, 1.0)
        return EgoVelocity(EgoStatus.ZERO_VELOCITY, np.zeros(dim), cov, still, sigma)
    best = _ransac(np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64),
                   config.ransac_iterations, config.inlier_threshold_mps, int(rng.integers(1, 2**62)))
    if best.sum() < max(config.min_detections, config.min_inlier_ratio * n):
        return EgoVelocity(EgoStatus.NO_CONSENSUS, None, None, best)
    # Refit on the inliers, then once more on the inliers of the refit.
    for _ in range(2):
        v = _least_squares(a[best], b[best])
        best = np.abs(a @ v - b) < config.inlier_threshold_mps
        if best.sum() < config.min_detections:
            return EgoVelocity(EgoStatus.NO_CONSENSUS, None, None, best)
    ai, bi = a[best], b[best]
    v = _least_squares(ai, bi)
    ata = ai.T @ ai
    if _condition(ata) > config.max_condition:
        return EgoVelocity(EgoStatus.ILL_CONDITIONED, None, None, best)
    dof = max(int(best.sum()) - dim, 1)
    sigma = max(config.min_sigma_mps, float(np.sqrt(np.sum((ai @ v - bi) ** 2) / dof)))
    if sigma > config.max_sigma_mps:
        return EgoVelocity(EgoStatus.NOISY, None, None, best, sigma)
    return EgoVelocity(EgoStatus.OK, v, sigma ** 2 * np.linalg.inv(ata), best, sigma)


def sensor_velocity(xyz_m: np.ndarray, doppler_mps: np.ndarray, config: EgoVelocityConfig = EgoVelocityConfig(),
                    rng: np.random.Generator | None = None) -> EgoVelocity:
    """One radar's velocity in its own frame from detections xyz_m [D, 3] and range rates [D]."""
    r = np.linalg.norm(xyz_m, axis=1)
    keep = r > config.min_range_m
    u = xyz_m[keep] / r[keep, None]
    planar = u.shape[0] > 0 and np.ptp(u[:, 2]) < 1e-6 and np.abs(u[:, 2]).max() < 1e-6
    est = solve_ego_velocity(-u[:, :2] if planar else -u, doppler_mps[keep], config, rng)
    if planar and est.velocity_mps is not None:
        # A radar without elevation: the vertical velocity is not measured (a wide prior, not a zero).
        est.velocity_mps = np.append(est.velocity_mps, 0.0)
        cov = np.zeros((3, 3))
        cov[:2, :2] = est.covariance
        cov[2, 2] = UNMEASURED_VARIANCE
        est.covariance = cov
    inliers = np.zeros(r.size, bool)
    inliers[keep] = est.inliers
    est.inliers = inliers
    return est


def body_velocity(scans, angular_velocity_body_radps: np.ndarray, config: EgoVelocityConfig = EgoVelocityConfig(),
                  rng: np.random.Generator | None = None) -> EgoVelocity:
    """Body-frame velocity from several radars' detections at (nearly) the same time.

    ``scans``: sequence of (mount, xyz_m [D, 3], doppler_mps [D]) with ``mount`` an imaging.rig.Mount.
    Each detection: d = -u . R_m^T (v_b + w x l)  ->  (-u^T R_m^T) v_b = d + u . R_m^T (w x l).
    """
    rows, rhs = [], []
    for mount, xyz, dop in scans:
        r = np.linalg.norm(xyz, axis=1)
        keep = r > config.min_range_m
        u = xyz[keep] / r[keep, None]
        rm = mount.rotation.as_matrix()
        lever_vel_s = rm.T @ np.cross(angular_velocity_body_radps, mount.translation_m)
        rows.append(-u @ rm.T)
        rhs.append(dop[keep] + u @ lever_vel_s)
    a = np.concatenate(rows) if rows else np.zeros((0, 3))
    b = np.concatenate(rhs) if rhs else np.zeros(0)
    return solve_ego_velocity(a, b, config, rng)
