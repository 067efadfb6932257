"""Strapdown propagation of the error-state EKF (``rio.ekf``): the nominal state through one IMU interval and
the error-state covariance with it.

Nominal state p, v (world frame, z up), R (body -> world); error state [dp, dv, dtheta, db_a, db_g] with the
attitude error in the body frame (R = R_hat Exp(dtheta)). Within an interval the bias-corrected specific force
f and rate w are held (the sample at the interval's start, zero-order hold).

The specific force is rotated by the attitude at the interval's MIDPOINT, R Exp(w dt / 2), not its start.
With w and f constant the exact velocity increment is R (I dt + [w]x dt^2/2 + [w]x^2 dt^3/6 + ...) f: the
body turns while it accelerates (the sculling term of Savage's strapdown algorithms). The start attitude
drops the dt^2 term, an error of order dt per unit time (first order); the midpoint keeps it and leaves
[w]x^2 dt^3/24 per step (second order, global error ~dt^2). On the 2 m/s^2 calibration drive the start
attitude left a +0.5 mm lever-arm x error on every radar that the covariance did not cover.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.core.constants import GRAVITY_MPS2
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


@numba.njit(cache=True)
def _exp_so3_nb(phi):
    """Rodrigues' formula, written out: a 3 x 3 product through BLAS costs more than the arithmetic."""
    angle = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    K = _skew_nb(phi)
    KK = _mat3(K, K)
    if angle < 1e-8:
        a, b = 1.0, 0.5
    else:
        a, b = math.sin(angle) / angle, (1.0 - math.cos(angle)) / (angle * angle)
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = (1.0 if i == j else 0.0) + a * K[i, j] + b * KK[i, j]
    return out


@numba.njit(cache=True)
def _skew_nb(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@numba.njit(cache=True)
def _mat3(a, b):
    """a b for 3 x 3 matrices, written out (numba's ``@`` calls BLAS, whose call costs more than 27 products)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@numba.njit(cache=True)
def _mat3_vec(a, x):
    return np.array([a[0, 0] * x[0] + a[0, 1] * x[1] + a[0, 2] * x[2], a[1, 0] * x[0] + a[1, 1] * x[1] + a[1, 2] * x[2],
                     a[2, 0] * x[0] + a[2, 1] * x[1] + a[2, 2] * x[2]])


@numba.njit(cache=True)
def _jacobian_blocks(R, half, f):
    """The acceleration's derivatives in one step's error-state transition (``_strapdown_jacobian``), given
    ``half`` = Exp(w dt/2), the midpoint attitude's rotation: on the attitude error, the accelerometer bias and
    (over dt) the gyro bias.

    With a = R Exp(w dt/2) f - g and the true state R Exp(dtheta), f - db_a, w - db_g (to first order):
    da/dtheta = -R [Exp(w dt/2) f]x, da/db_a = -R Exp(w dt/2), da/db_g = R Exp(w dt/2) [f]x dt/2 (the
    midpoint attitude depends on the rate); the last is returned without its dt/2.
    """
    R_mid = _mat3(R, half)
    da_dtheta = _mat3(R, _skew_nb(_mat3_vec(half, f)))
    for i in range(3):
        for j in range(3):
            da_dtheta[i, j] = -da_dtheta[i, j]
    return da_dtheta, -R_mid, _mat3(R_mid, _skew_nb(f))


@numba.njit(cache=True)
def _strapdown_jacobian(R, f, w, dt):
    """Error-state transition F [15, 15] of one ``_strapdown`` step (the derivative of its nominal update):
    ``_jacobian_blocks``' derivatives of the acceleration, times dt in the velocity's rows and dt^2/2 in the
    position's; the attitude error turns by Exp(-w dt) and takes the gyro bias's -dt. ``_strapdown`` applies
    it without forming it (``_transition_rows``)."""
    half = _exp_so3_nb(0.5 * w * dt)
    da_dtheta, da_dba, da_dbg_2_dt = _jacobian_blocks(R, half, f)
    F = np.eye(15)
    F[0:3, 3:6] = np.eye(3) * dt
    F[0:3, 6:9] = 0.5 * dt * dt * da_dtheta
    F[0:3, 9:12] = 0.5 * dt * dt * da_dba
    F[0:3, 12:15] = 0.5 * dt * dt * (0.5 * dt * da_dbg_2_dt)
    F[3:6, 6:9] = da_dtheta * dt
    F[3:6, 9:12] = da_dba * dt
    F[3:6, 12:15] = (0.5 * dt * da_dbg_2_dt) * dt
    F[6:9, 6:9] = _mat3(half, half).T
    F[6:9, 12:15] = -np.eye(3) * dt
    return F


@numba.njit(cache=True)
def _transition_rows(P, da_dtheta, da_dba, da_dbg_2_dt, attitude, dt):
    """F P for the F of ``_strapdown_jacobian`` (the identity beyond its first 9 rows, and on calibration
    states), its 3 x 3 blocks applied without forming F: F's zeros and BLAS's calls on 15 x 15 matrices cost
    more than the arithmetic. ``attitude``: Exp(-w dt)."""
    out = P.copy()
    half_dt = 0.5 * dt
    for j in range(P.shape[1]):
        for i in range(3):
            acc = 0.0
            turn = 0.0
            for k in range(3):
                acc += (da_dtheta[i, k] * P[6 + k, j] + da_dba[i, k] * P[9 + k, j]
                        + half_dt * da_dbg_2_dt[i, k] * P[12 + k, j])
                turn += attitude[i, k] * P[6 + k, j]
            acc *= dt  # the velocity's rows; the position's take half of it once more times dt
            out[i, j] = P[i, j] + dt * P[3 + i, j] + half_dt * acc
            out[3 + i, j] = P[3 + i, j] + acc
            out[6 + i, j] = turn - dt * P[12 + i, j]
    return out


@numba.njit(cache=True)
def _strapdown(p, v, R, P, f, w, dt, q_density):
    """One IMU step: nominal state (bias-corrected specific force f and rate w held over dt) and covariance
    P <- F P F^T + Q dt for the error state [dp, dv, dtheta, dba, dbg] (plus constant calibration states,
    whose transition is the identity: only the core block and its correlations with them change)."""
    half = _exp_so3_nb(0.5 * w * dt)
    turn = _mat3(half, half)  # Exp(w dt)
    a = _mat3_vec(R, _mat3_vec(half, f))  # the midpoint attitude: second order (module docstring)
    a[2] -= GRAVITY_MPS2
    p_new = p + v * dt + 0.5 * a * dt * dt
    v_new = v + a * dt
    R_new = _mat3(R, turn)
    blocks = _jacobian_blocks(R, half, f)
    attitude = np.ascontiguousarray(turn.T)
    rows = _transition_rows(P, blocks[0], blocks[1], blocks[2], attitude, dt)
    out = _transition_rows(np.ascontiguousarray(rows.T), blocks[0], blocks[1], blocks[2], attitude, dt)  # F (F P)^T
    n = P.shape[0]
    for i in range(n):
        out[i, i] += q_density[i] * dt
    return p_new, v_new, R_new, 0.5 * (out + out.T)


@numba.njit(cache=True)
def _strapdown_batch(p, v, R, P, t_ns, f_last, w_last, ba, bg, times, accs, gyros, record, q_density):
    """Propagate through IMU samples ``times``/``accs``/``gyros`` in order (zero-order hold: each interval
    uses the sample at its start), recording the state after every sample flagged in ``record``."""
    m = 0
    for i in range(record.size):
        if record[i]:
            m += 1
    out_t = np.empty(m, np.int64)
    out_p = np.empty((m, 3))
    out_v = np.empty((m, 3))
    out_R = np.empty((m, 3, 3))
    out_P = np.empty((m, 15))
    j = 0
    for i in range(times.size):
        dt = (times[i] - t_ns) * 1e-9
        if dt > 0:
            p, v, R, P = _strapdown(p, v, R, P, f_last - ba, w_last - bg, dt, q_density)
            t_ns = times[i]
        f_last = accs[i]
        w_last = gyros[i]
        if record[i]:
            out_t[j] = t_ns
            out_p[j] = p
            out_v[j] = v
            out_R[j] = R
            for k in range(15):
                out_P[j, k] = P[k, k]
            j += 1
    return p, v, R, P, t_ns, f_last, w_last, out_t, out_p, out_v, out_R, out_P
