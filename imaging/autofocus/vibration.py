"""A vibration read off an estimated track error: frequency, amplitude and phase of a sinusoid fitted
jointly with a drift (the unobservable offset and line, and a slow bend where the data support one).

The fit is a variable projection: for each trial frequency the drift polynomial and the sinusoid's cosine
and sine are one linear least-squares fit, and the frequency is the one that leaves the least residual
(a fine grid, then refined). Over an aperture of one or two periods a sinusoid and a bend are far from
orthogonal, so fitting the bend first and looking for the sinusoid in what it leaves (or the other way
round) finds the wrong frequency; fitted together, the two are told apart as far as the data allow. The
bend's order is chosen by the Bayesian information criterion: a vibration seen without drift is not made
worse by terms the data do not need (asked for with ``poly_order=None``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.optimize

from imaging.autofocus.track_model import _legendre, best_frequency
from imaging.core.track_error import TrackError

#: Highest drift (Legendre) order fitted beside the sinusoid when the order is chosen from the data.
MAX_DRIFT_ORDER = 3


@dataclasses.dataclass
class VibrationFit:
    """A sinusoid A sin(2 pi f t + phase) read off a track error (t from the track error's time origin),
    and the order of the drift polynomial fitted with it."""

    frequency_hz: float
    amplitude_m: float
    phase_rad: float
    residual_rms_m: float
    drift_order: int = 1


def _joint_fit(t: np.ndarray, v: np.ndarray, order: int) -> tuple[float, np.ndarray, float] | None:
    """(frequency, coefficients [drift 0..order, cos, sin], residual rms) of v ~ drift + sinusoid, the
    frequency by variable projection; None when the span holds no cycle."""
    t0 = 0.5 * (t.min() + t.max())
    half = max(0.5 * np.ptp(t), 1e-12)
    tau = (t - t0) / half
    drift = np.column_stack([np.ones_like(tau), tau, _legendre(tau, order)])
    span = float(np.ptp(t))
    dt = span / max(t.size - 1, 1)
    lo, hi = 1.0 / span, 0.5 / dt

    def solve(f):
        w = 2 * math.pi * f * (t - t0)
        a = np.column_stack([drift, np.cos(w), np.sin(w)])
        coef, *_ = np.linalg.lstsq(a, v, rcond=None)
        r = v - a @ coef
        return float(r @ r), coef

    f = best_frequency(t, v, drift, np.ones_like(t), (lo, hi))
    if f is None:
        return None
    step = 0.25 / span  # best_frequency's grid step
    f = float(scipy.optimize.minimize_scalar(lambda x: solve(x)[0], bounds=(max(f - step, lo), min(f + step, hi)),
                                             method="bounded", options={"xatol": 1e-9 * hi}).x)
    ss, coef = solve(f)
    return f, coef, math.sqrt(ss / t.size)


def fit_vibration(track_error: TrackError, poly_order: int | None = 1) -> VibrationFit:
    """Frequency, amplitude and phase of the strongest sinusoid in an estimated track error, fitted jointly
    with a drift polynomial.

    ``poly_order`` is the drift's order (1, the default: offset and line, which the estimate does not know;
    2 and up a bend besides); None chooses it from 1 to ``MAX_DRIFT_ORDER`` by the Bayesian information
    criterion. On the paper's vibration at 0.14 m with no drift, order 1 reads it within 0.1 % and the
    criterion within 0.3 %; with a bend of 0.1 mm on top, order 1 is 4-8 % off and the criterion's choice
    within 0.6 %, with 0.03 mm within 0.7 % (``tests/test_autofocus.py``). Reading a sinusoid of 1.3 periods
    beside a bend amplifies the estimate's own errors: a micrometre of 4th- to 6th-order error moves the
    amplitude by 0.4-1 %, so the fit is as good as the estimate holds the vibration (the entropy model holds
    it as a sinusoid, ``imaging.autofocus.track_model.LOW_DRIFT_ORDER``; PGA's estimate has errors of
    10 micrometres there and reads it 10-17 % off with a drift order of 2 or 3).
    The fit is made on the estimated displacement, whichever estimator made it: the entropy model's own
    split between a sinusoid and a bend is not a measurement of either, while their sum is. A track error
    with no oscillation of a cycle or more over its span raises ValueError.
    """
    t = np.asarray(track_error.time_s, float)
    v = np.asarray(track_error.displacement_m, float)
    orders = range(1, MAX_DRIFT_ORDER + 1) if poly_order is None else [poly_order]
    best = None
    for order in orders:
        fit = _joint_fit(t, v, order)
        if fit is None or not np.any(v):
            break
        f, coef, rms = fit
        n_par = (order + 1) + 3
        bic = t.size * math.log(max(rms, 1e-15) ** 2) + n_par * math.log(t.size)
        if best is None or bic < best[0] - 1e-9:
            best = (bic, order, f, coef, rms)
    if best is None:
        raise ValueError("the track error holds no oscillation of a cycle or more over its span")
    _, order, f, coef, rms = best
    a, b = coef[-2], coef[-1]
    t0 = 0.5 * (t.min() + t.max())
    # a cos(w (t - t0)) + b sin(w (t - t0)) = A sin(w t + phase)
    amp = math.hypot(a, b)
    phase = math.atan2(a, b) - 2 * math.pi * f * t0
    return VibrationFit(float(f), float(amp), float(math.remainder(phase, 2 * math.pi)), float(rms), order)
