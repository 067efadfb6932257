"""Radar ego velocity from the Doppler of static detections: RANSAC, then least squares.

For a static point seen in direction u (unit, sensor frame) the range rate is d = -u . v_s, with v_s the
sensor's velocity. Moving targets and false alarms break this relation and are rejected as outliers.
Several radars at once: each detection's equation is expressed in the body velocity through the radar's
mount and the angular rate (lever arm), and all are solved together.

The directions come from measured angles. Least squares on noisy regressors is biased (errors in variables):
an elevation error d_e changes the horizontal cosine by -d_e sin e - d_e^2/2 cos e, which correlates with the
measured vertical sine sin e + d_e cos e. Over scatterers mostly below (or above) the radar, the vertical
velocity then comes out biased in proportion to the horizontal one (``fit_gain``: about 0.02 m/s per m/s for
3 deg over a floor robot's room, a 1 deg pitch). One radar's fit takes that cross-talk out for a known angle
noise (``EgoVelocityConfig.elevation_sigma_deg``, ``azimuth_sigma_deg``; ``remove_crosstalk``).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math

import numba
import numpy as np

from imaging.core.constants import CHI2_999
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)

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
    creep_chi2: float = CHI2_999[3]  # 99.9 % of chi2(3): a near-zero velocity this far from zero is creeping, not standing
    max_sigma_mps: float = 0.15
    max_condition: float = 1e4
    min_sigma_mps: float = 0.01  # floor on the per-detection Doppler noise used for the covariance
    #: Standard deviations of the detections' measured angles (Gaussian), which the fit corrects its bias for;
    #: 0 fits the measured directions as exact. The defaults are the simulated radar's
    #: (imaging.sim.detection_simulator.DetectionModel). Only a radar that measures elevation is corrected.
    elevation_sigma_deg: float = 3.0
    azimuth_sigma_deg: float = 1.0


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
def _solve3(m, r):
    """Cramer's rule for 3x3 (nan when singular): the minimal sets are solved thousands of times a second."""
    det = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
           + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))
    out = np.empty(3)
    if abs(det) < 1e-9:
        out[:] = np.nan
        return out
    out[0] = (r[0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (r[1] * m[2, 2] - m[1, 2] * r[2])
              + m[0, 2] * (r[1] * m[2, 1] - m[1, 1] * r[2])) / det
    out[1] = (m[0, 0] * (r[1] * m[2, 2] - m[1, 2] * r[2]) - r[0] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
              + m[0, 2] * (m[1, 0] * r[2] - r[1] * m[2, 0])) / det
    out[2] = (m[0, 0] * (m[1, 1] * r[2] - r[1] * m[2, 1]) - m[0, 1] * (m[1, 0] * r[2] - r[1] * m[2, 0])
              + r[0] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / det
    return out


@numba.njit(cache=True)
def _solve2(m, r):
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    out = np.empty(2)
    if abs(det) < 1e-9:
        out[:] = np.nan
        return out
    out[0] = (r[0] * m[1, 1] - m[0, 1] * r[1]) / det
    out[1] = (m[0, 0] * r[1] - r[0] * m[1, 0]) / det
    return out


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
        if dim == 3:
            v = _solve3(m_a, b[pick])
        else:
            v = _solve2(m_a, b[pick])
        if not np.isfinite(v[0]):
            continue
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


_STATUS_BY_CODE = (EgoStatus.OK, EgoStatus.ZERO_VELOCITY, EgoStatus.TOO_FEW, EgoStatus.NO_CONSENSUS,
                   EgoStatus.ILL_CONDITIONED, EgoStatus.NOISY)


@numba.njit(cache=True)
def _normal_solve(a, b, mask):
    """Least squares on the rows in ``mask`` by the normal equations; (ok, v, a^T a)."""
    dim = a.shape[1]
    ata = np.zeros((dim, dim))
    atb = np.zeros(dim)
    for i in range(a.shape[0]):
        if mask[i]:
            for r in range(dim):
                atb[r] += a[i, r] * b[i]
                for c in range(dim):
                    ata[r, c] += a[i, r] * a[i, c]
    if abs(np.linalg.det(ata)) < 1e-12:
        return False, np.zeros(dim), ata
    return True, np.linalg.solve(ata, atb), ata


@numba.njit(cache=True)
def _residual_sigma(a, b, mask, v, min_sigma):
    ss = 0.0
    m = 0
    for i in range(a.shape[0]):
        if mask[i]:
            r = -b[i]
            for k in range(a.shape[1]):
                r += a[i, k] * v[k]
            ss += r * r
            m += 1
    return max(min_sigma, math.sqrt(ss / max(m - a.shape[1], 1)))


@numba.njit(cache=True)
def _condition_nb(ata):
    w = np.linalg.eigvalsh(ata)
    return w[-1] / w[0] if w[0] > 0 else np.inf


@numba.njit(cache=True)
def _solve_core(a, b, min_detections, zv_threshold, zv_ratio, creep_chi2, iterations, inlier_threshold,
                min_inlier_ratio, max_condition, min_sigma, max_sigma, seed):
    """The whole estimator in one compiled call: (status code, v, covariance, inliers, sigma).

    Codes index _STATUS_BY_CODE: 0 ok, 1 zero velocity, 2 too few, 3 no consensus, 4 ill-conditioned, 5 noisy.
    """
    n, dim = a.shape
    nan_cov = np.full((dim, dim), np.nan)
    if n < min_detections:
        return 2, np.zeros(dim), nan_cov, np.zeros(n, np.bool_), np.nan
    # Standstill: most detections (the static world) have no Doppler at all.
    still = np.abs(b) < zv_threshold
    if still.sum() >= zv_ratio * n:
        # Standing still, or creeping below the threshold? The least-squares velocity of those
        # detections tells: zero only if it is not significantly different from zero.
        ok, v, ata = _normal_solve(a, b, still)
        sigma = _residual_sigma(a, b, still, v, min_sigma)
        if ok and _condition_nb(ata) < max_condition:
            cov = sigma ** 2 * np.linalg.inv(ata)
            if v @ np.linalg.solve(cov, v) > creep_chi2:
                return 0, v, cov, still, sigma
        cov = np.eye(dim) * (sigma ** 2) / max(still.sum() / dim, 1.0)
        return 1, np.zeros(dim), cov, still, sigma
    best = _ransac(a, b, iterations, inlier_threshold, seed)
    if best.sum() < max(min_detections, min_inlier_ratio * n):
        return 3, np.zeros(dim), nan_cov, best, np.nan
    # Refit on the inliers, then once more on the inliers of the refit.
    for _ in range(2):
        ok, v, ata = _normal_solve(a, b, best)
        if not ok:
            return 4, np.zeros(dim), nan_cov, best, np.nan
        best = np.abs(a @ v - b) < inlier_threshold
        if best.sum() < min_detections:
            return 3, np.zeros(dim), nan_cov, best, np.nan
    ok, v, ata = _normal_solve(a, b, best)
    if not ok or _condition_nb(ata) > max_condition:
        return 4, np.zeros(dim), nan_cov, best, np.nan
    sigma = _residual_sigma(a, b, best, v, min_sigma)
    if sigma > max_sigma:
        return 5, np.zeros(dim), nan_cov, best, sigma
    return 0, v, sigma ** 2 * np.linalg.inv(ata), best, sigma


def solve_ego_velocity(a: np.ndarray, b: np.ndarray, config: EgoVelocityConfig = EgoVelocityConfig(),
                       rng: np.random.Generator | None = None) -> EgoVelocity:
    """Solve a v = b robustly: rows of ``a`` [D, dim] are the equations, ``b`` [D] the right-hand sides.

    For one radar, ``a = -u`` (unit directions) and ``b`` the Doppler; ``v`` is then the sensor velocity.
    Status: too few detections, zero velocity (most Doppler near zero and the fit not significantly
    non-zero), no RANSAC consensus, ill-conditioned geometry, too noisy, or ok with a covariance.
    """
    rng = rng or np.random.default_rng(0)
    c = config
    code, v, cov, inliers, sigma = _solve_core(
        np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64), c.min_detections,
        c.zero_velocity_threshold_mps, c.zero_velocity_ratio, c.creep_chi2, c.ransac_iterations,
        c.inlier_threshold_mps, c.min_inlier_ratio, c.max_condition, c.min_sigma_mps, c.max_sigma_mps,
        int(rng.integers(1, 2**62)))
    status = _STATUS_BY_CODE[code]
    if status in (EgoStatus.OK, EgoStatus.ZERO_VELOCITY):
        return EgoVelocity(status, v, cov, inliers, float(sigma))
    return EgoVelocity(status, None, None, inliers, float(sigma))


def direction_moments(u: np.ndarray, elevation_sigma_rad: float, azimuth_sigma_rad: float,
                      sign: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum of u u^T over unit directions u [D, 3] with Gaussian angle noise put in or taken out, and the factors
    on the mean direction.

    ``sign`` +1: from true directions, the expectation of the sum over measured ones and E[u'] = g * u.
    ``sign`` -1: from measured directions, an unbiased estimate of the sum over the true ones, and 1 / g.
    Why it is exact: u u^T is linear in cos 2e, sin 2e, cos 2a, sin 2a, cos a, sin a (and their products across
    e and a), and E[cos k(e + d)] = exp(-k^2 s^2 / 2) cos ke for d ~ N(0, s^2).
    """
    el = np.arcsin(np.clip(u[:, 2], -1.0, 1.0))
    az = np.arctan2(u[:, 1], u[:, 0])
    k_e2, k_a2 = math.exp(-2 * sign * elevation_sigma_rad ** 2), math.exp(-2 * sign * azimuth_sigma_rad ** 2)
    k_e1, k_a1 = math.exp(-0.5 * sign * elevation_sigma_rad ** 2), math.exp(-0.5 * sign * azimuth_sigma_rad ** 2)
    c2e, s2e = k_e2 * np.cos(2 * el), k_e2 * np.sin(2 * el)
    c2a, s2a = k_a2 * np.cos(2 * az), k_a2 * np.sin(2 * az)
    ca, sa = k_a1 * np.cos(az), k_a1 * np.sin(az)
    m = np.empty((3, 3))
    m[0, 0] = np.sum((1 + c2e) * (1 + c2a)) / 4
    m[1, 1] = np.sum((1 + c2e) * (1 - c2a)) / 4
    m[2, 2] = np.sum(1 - c2e) / 2
    m[0, 1] = m[1, 0] = np.sum((1 + c2e) * s2a) / 4
    m[0, 2] = m[2, 0] = np.sum(s2e * ca) / 2
    m[1, 2] = m[2, 1] = np.sum(s2e * sa) / 2
    return m, np.array([k_e1 * k_a1, k_e1 * k_a1, k_e1])


def fit_gain(u_true: np.ndarray, elevation_sigma_rad: float, azimuth_sigma_rad: float = 0.0) -> np.ndarray:
    """What least squares on measured directions returns for a sensor velocity v, as G v [3, 3] (many detections).

    The fit solves (sum u' u'^T) v' = sum u' (u . v); in expectation over the angle noise that is
    G = E[sum u' u'^T]^-1 diag(g) sum u u^T. G - I is the bias: its (z, x) entry is the vertical velocity's error
    per m/s along the boresight, even in the elevation error, so it is there on average in every radar that
    measures elevation with error, not only in a simulator.
    """
    m_noisy, gain = direction_moments(u_true, elevation_sigma_rad, azimuth_sigma_rad, +1)
    return np.linalg.solve(m_noisy, gain[:, None] * (u_true.T @ u_true))


def remove_crosstalk(u: np.ndarray, est: EgoVelocity, config: EgoVelocityConfig) -> None:
    """Take out of ``est`` (the fit on ``u``, unit measured directions [D, 3] of which ``est.inliers`` were
    fitted) the vertical velocity's cross-talk from the horizontal one, for the config's angle noise.

    The cross-talk is ``fit_gain``'s (z, x) and (z, y) entries, G[:, :2] = (sum u' u'^T)^-1 diag(g) M[:, :2],
    with the measured sum as it is and the true directions' moments M estimated from the measured ones
    (``direction_moments``, sign -1). Only M's horizontal columns enter: its (z, z) entry, the vertical
    spread less the noise's, is what makes a fully noise-corrected fit (the corrected score) noisier where the
    elevations spread little: its vertical error's spread is 1.1-1.3x the plain fit's on synthetic scans, and
    the one-lap hall odometry's mean ATE over three seeds 22.3 mm against the plain fit's 20.2 mm; this fit
    keeps both (1.0x, 20.3 mm; benchmarks/calibration_elevation.py). The horizontal velocity is kept as
    fitted. The joint fit of several radars (``body_velocity``) is not corrected.
    """
    est.velocity_mps, est.covariance = _remove_crosstalk_nb(
        np.ascontiguousarray(u, dtype=np.float64), est.inliers, est.velocity_mps, est.covariance,
        *_noise_factors(config.elevation_sigma_deg, config.azimuth_sigma_deg))


@functools.lru_cache(maxsize=16)
def _noise_factors(elevation_sigma_deg: float, azimuth_sigma_deg: float) -> tuple[float, ...]:
    """``direction_moments``' factors for sign -1 (taking the noise out), as ``_remove_crosstalk_nb`` takes them:
    exp(2 s_e^2), exp(2 s_a^2), exp(s_a^2 / 2), and the mean direction's horizontal and vertical 1 / g."""
    e2, a2 = math.radians(elevation_sigma_deg) ** 2, math.radians(azimuth_sigma_deg) ** 2
    return (math.exp(2 * e2), math.exp(2 * a2), math.exp(0.5 * a2), math.exp(0.5 * e2) * math.exp(0.5 * a2),
            math.exp(0.5 * e2))


@numba.njit(cache=True)
def _remove_crosstalk_nb(u, inliers, velocity, covariance, k_e2, k_a2, k_a1, inv_gain_horizontal,
                         inv_gain_vertical):
    """``remove_crosstalk`` for one scan in one compiled call: (velocity [3], covariance [3, 3]) corrected.

    The same quantities as ``direction_moments`` (sign -1) and ``np.linalg.solve``, without their per-scan
    overhead (about 20 numpy calls on a few dozen detections, the largest part of what had halved the
    odometry's speed since fae5f5c; docs/results/odometry_speed.json):
    the angles' cosines and sines come from u itself, el = arcsin(u_z) and az = atan2(u_y, u_x) giving
    cos 2el = 1 - 2 u_z^2, sin 2el = 2 u_z sqrt(1 - u_z^2), cos az = u_x / h, sin az = u_y / h with
    h = hypot(u_x, u_y), and row 2 of (sum u u^T)^-1 from its cofactors. Equal to the numpy form to rounding
    (tests/test_odometry_speed.py).
    """
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    m00 = m01 = m11 = m20 = m21 = 0.0
    for i in range(u.shape[0]):
        if not inliers[i]:
            continue
        x, y, z = u[i, 0], u[i, 1], u[i, 2]
        a00 += x * x
        a01 += x * y
        a02 += x * z
        a11 += y * y
        a12 += y * z
        a22 += z * z
        z = min(1.0, max(-1.0, z))
        c2e = k_e2 * (1.0 - 2.0 * z * z)
        s2e = k_e2 * 2.0 * z * math.sqrt(1.0 - z * z)
        h2 = x * x + y * y
        if h2 > 0.0:
            h = math.sqrt(h2)
            ca, sa, c2a, s2a = x / h, y / h, (x * x - y * y) / h2, 2.0 * x * y / h2
        else:  # straight up or down: atan2(0, 0) = 0
            ca, sa, c2a, s2a = 1.0, 0.0, 1.0, 0.0
        c2a *= k_a2
        s2a *= k_a2
        ca *= k_a1
        sa *= k_a1
        m00 += (1.0 + c2e) * (1.0 + c2a) / 4.0
        m11 += (1.0 + c2e) * (1.0 - c2a) / 4.0
        m01 += (1.0 + c2e) * s2a / 4.0
        m20 += s2e * ca / 2.0
        m21 += s2e * sa / 2.0
    # Row 2 of the inverse of the symmetric sum u u^T, by its cofactors.
    c0 = a01 * a12 - a11 * a02
    c1 = a01 * a02 - a00 * a12
    c2 = a00 * a11 - a01 * a01
    det = a02 * c0 + a12 * c1 + a22 * c2
    # The true directions' moments times the mean direction's gain g, row by row (direction_moments gives 1 / g)
    crosstalk_x = (c0 * m00 / inv_gain_horizontal + c1 * m01 / inv_gain_horizontal + c2 * m20 / inv_gain_vertical) / det
    crosstalk_y = (c0 * m01 / inv_gain_horizontal + c1 * m11 / inv_gain_horizontal + c2 * m21 / inv_gain_vertical) / det
    v = velocity.copy()
    v[2] = velocity[2] - crosstalk_x * velocity[0] - crosstalk_y * velocity[1]
    rows = covariance.copy()  # J C with J the identity whose row 2 is (-crosstalk_x, -crosstalk_y, 1)
    for k in range(3):
        rows[2, k] = covariance[2, k] - crosstalk_x * covariance[0, k] - crosstalk_y * covariance[1, k]
    out = rows.copy()  # (J C) J^T
    for k in range(3):
        out[k, 2] = rows[k, 2] - crosstalk_x * rows[k, 0] - crosstalk_y * rows[k, 1]
    return v, out


def sensor_velocity(xyz_m: np.ndarray, doppler_mps: np.ndarray, config: EgoVelocityConfig = EgoVelocityConfig(),
                    rng: np.random.Generator | None = None) -> EgoVelocity:
    """One radar's velocity in its own frame from detections xyz_m [D, 3] and range rates [D]."""
    r = np.linalg.norm(xyz_m, axis=1)
    keep = r > config.min_range_m
    u = xyz_m[keep] / r[keep, None]
    planar = u.shape[0] > 0 and np.ptp(u[:, 2]) < 1e-6 and np.abs(u[:, 2]).max() < 1e-6
    est = solve_ego_velocity(-u[:, :2] if planar else -u, doppler_mps[keep], config, rng)
    if not planar and est.status is EgoStatus.OK and (config.elevation_sigma_deg > 0 or config.azimuth_sigma_deg > 0):
        remove_crosstalk(u, est, config)
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

    ``scans``: sequence of (mount, xyz_m [D, 3], doppler_mps [D]) with ``mount`` an imaging.core.rig.Mount.
    Each detection: d = -u . R_m^T (v_b + w x l)  ->  (-u^T R_m^T) v_b = d + u . R_m^T (w x l).
    """
    rows, rhs = [], []
    for mount, xyz, dop in scans:
        r = np.linalg.norm(xyz, axis=1)
        keep = r > config.min_range_m
        u = xyz[keep] / r[keep, None]
        rm = mount.rotation_matrix
        lever_vel_s = rm.T @ np.cross(angular_velocity_body_radps, mount.translation_m)
        rows.append(-u @ rm.T)
        rhs.append(dop[keep] + u @ lever_vel_s)
    a = np.concatenate(rows) if rows else np.zeros((0, 3))
    b = np.concatenate(rhs) if rhs else np.zeros(0)
    return solve_ego_velocity(a, b, config, rng)
