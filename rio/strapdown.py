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
    angle = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if angle < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (math.sin(angle) / angle) * K + ((1.0 - math.cos(angle)) / (angle * angle)) * (K @ K)


@numba.njit(cache=True)
def _skew_nb(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@numba.njit(cache=True)
def _strapdown_jacobian(R, f, w, dt):
    """Error-state transition F [15, 15] of one ``_strapdown`` step (the derivative of its nominal update).

    With a = R Exp(w dt/2) f - g and the true state R Exp(dtheta), f - db_a, w - db_g (to first order):
    da/dtheta = -R [Exp(w dt/2) f]x, da/db_a = -R Exp(w dt/2), da/db_g = R Exp(w dt/2) [f]x dt/2 (the
    midpoint attitude depends on the rate). Velocity takes a dt, position a dt^2/2.
    """
    R_mid = R @ _exp_so3_nb(0.5 * w * dt)
    da_dtheta = -(R @ _skew_nb(_exp_so3_nb(0.5 * w * dt) @ f))
    da_dba = -R_mid
    da_dbg = 0.5 * dt * (R_mid @ _skew_nb(f))
    F = np.eye(15)
    F[0:3, 3:6] = np.eye(3) * dt
    F[0:3, 6:9] = 0.5 * dt * dt * da_dtheta
    F[0:3, 9:12] = 0.5 * dt * dt * da_dba
    F[0:3, 12:15] = 0.5 * dt * dt * da_dbg
    F[3:6, 6:9] = da_dtheta * dt
    F[3:6, 9:12] = da_dba * dt
    F[3:6, 12:15] = da_dbg * dt
    F[6:9, 6:9] = _exp_so3_nb(-w * dt)
    F[6:9, 12:15] = -np.eye(3) * dt
    return F


@numba.njit(cache=True)
def _strapdown(p, v, R, P, f, w, dt, q_density):
    """One IMU step: nominal state (bias-corrected specific force f and rate w held over dt) and covariance
    P <- F P F^T + Q dt for the error state [dp, dv, dtheta, dba, dbg] (plus constant calibration states)."""
    a = R @ (_exp_so3_nb(0.5 * w * dt) @ f)  # the midpoint attitude: second order (module docstring)
    a[2] -= GRAVITY_MPS2
    p_new = p + v * dt + 0.5 * a * dt * dt
    v_new = v + a * dt
    R_new = R @ _exp_so3_nb(w * dt)
    F = _strapdown_jacobian(R, f, w, dt)
    n = P.shape[0]
    if n == 15:
        out = F @ P @ F.T
    else:
        # Calibration states are constants: their transition is the identity, so only the core block and
        # its correlations with them change.
        out = P.copy()
        out[:15, :15] = F @ P[:15, :15] @ F.T
        cross = F @ P[:15, 15:]
        out[:15, 15:] = cross
        out[15:, :15] = cross.T
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
