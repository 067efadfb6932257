"""Minimum entropy over a low-order model of the track error: Legendre polynomials of order 2 and up
(orders 0 and 1 only move the image) plus sinusoids whose frequencies are free parameters, started from a
PGA estimate.

The gradient is exact and costs one product of the group images with a vector,
``dE/dphi_qg = 2 Im(exp(j phi) sum_g B[q, g] D_g)`` with ``D = (ln p + E) conj(I) / S``, not a finite
difference over images (``imaging.autofocus.subapertures.entropy_and_gradient``).
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import numpy as np
import scipy.optimize

from imaging.autofocus.subapertures import GroupImages, entropy_and_gradient, peak_power
from imaging.autofocus.pga import phase_gradient_autofocus
from imaging.core.track_error import remove_line

if TYPE_CHECKING:
    from imaging.autofocus.options import AutofocusOptions

log = logging.getLogger("sarbot.imaging.autofocus")

#: The entropy model's estimate is kept over PGA's only if the brightest pixel keeps at least this part of
#: its power under it (-0.5 dB). Undoing a real track error gathers a scatterer's energy back into its peak;
#: a model that lowers the peak while lowering the entropy has moved energy out of the estimation pixels.
MODEL_PEAK_KEEP = 10 ** -0.05
#: The entropy model is also started from a drift of at most this order with the sinusoids: on an estimate
#: with errors of its own (PGA's), the information criterion picks a high-order polynomial that takes the
#: vibration over a short aperture, and the sinusoid goes to whatever is left.
LOW_DRIFT_ORDER = 3


def _legendre(tau: np.ndarray, order: int) -> np.ndarray:
    """Columns P2..P_order of tau in [-1, 1] (P0 and P1 only move the image)."""
    cols = [np.polynomial.legendre.Legendre.basis(n)(tau) for n in range(2, order + 1)]
    return np.column_stack(cols) if cols else np.zeros((tau.size, 0))


def evaluate_model(model: dict, time_s: np.ndarray) -> np.ndarray:
    """The displacement of a fitted ``legendre+sinusoids`` model at ``time_s``."""
    t0, half = model["t_centre_s"], model["t_half_s"]
    tau = np.clip((time_s - t0) / half, -1.0, 1.0)
    out = _legendre(tau, model["poly_order"]) @ np.asarray(model["poly_m"], float) if model["poly_order"] >= 2 else np.zeros_like(tau)
    for f, a, b in model["sinusoids"]:
        w = 2 * math.pi * f * (time_s - t0)
        out = out + a * np.cos(w) + b * np.sin(w)
    return out


def best_frequency(t: np.ndarray, v: np.ndarray, fixed: np.ndarray, weight_sqrt: np.ndarray,
                   band_hz: tuple[float, float]) -> float | None:
    """The frequency in ``band_hz`` of the sinusoid that, fitted jointly with the columns ``fixed`` [N, m]
    (weighted least squares, ``weight_sqrt`` [N] on every row), leaves the least residual; None for an
    empty band.

    Variable projection on a grid a quarter of the span's frequency resolution apart: for each trial
    frequency the residual is one linear fit, made for the whole grid at once by projecting v and the
    cosine and sine out of the span of ``fixed``. Over an aperture of one or two periods a polynomial takes
    most of a sinusoid: taking the polynomial out first and looking in what it leaves for a peak (a
    periodogram) finds the wrong frequency, and the polynomial then stands in for the sinusoid, to within
    micrometres the image does not see but a fit of the vibration does (see ``imaging.autofocus.vibration``).
    """
    lo, hi = band_hz
    if not hi > lo:
        return None
    t0 = 0.5 * (t.min() + t.max())
    q, _ = np.linalg.qr(fixed * weight_sqrt[:, None])
    r = v * weight_sqrt
    r = r - q @ (q.T @ r)
    n_grid = int(np.ceil(4.0 * (hi - lo) * np.ptp(t))) + 1
    grid = np.linspace(lo, hi, max(n_grid, 2))
    best, best_f = -np.inf, None
    for i in range(0, grid.size, 256):  # a few megabytes at a time however many groups
        w = 2 * math.pi * grid[i:i + 256, None] * (t - t0)[None, :]
        c, s = np.cos(w) * weight_sqrt, np.sin(w) * weight_sqrt
        c -= (c @ q) @ q.T
        s -= (s @ q) @ q.T
        cc, ss, cs = (c * c).sum(1), (s * s).sum(1), (c * s).sum(1)
        cr, sr = c @ r, s @ r
        det = cc * ss - cs ** 2
        ok = det > 1e-12 * np.maximum(cc * ss, 1e-300)
        # The residual's reduction by the best combination of the two: [cr sr] [[cc cs] [cs ss]]^-1 [cr sr]^T
        gain = np.where(ok, (ss * cr ** 2 - 2 * cs * cr * sr + cc * sr ** 2) / np.where(ok, det, 1.0), -np.inf)
        j = int(np.argmax(gain))
        if gain[j] > best:
            best, best_f = float(gain[j]), float(grid[i + j])
    return best_f


def fit_sinusoids(t, v, poly_order: int, n_sin: int, weight=None, joint: bool = False):
    """Least-squares fit v ~ line + P2..P_order + n_sin sinusoids (``joint``: each sinusoid's frequency
    chosen jointly with the polynomial and the sinusoids before it, ``best_frequency``; else from the
    residual's periodogram; then all refined together; none below one cycle over the span).
    Returns (t_centre_s, t_half_s, coefficients [line, P2.., cos, sin per sinusoid], frequencies, residual
    rms)."""
    t0 = 0.5 * (t.min() + t.max())
    half = max(0.5 * np.ptp(t), 1e-12)
    tau = (t - t0) / half
    sw = np.ones_like(t) if weight is None else np.sqrt(weight / weight.mean())
    fixed = np.column_stack([np.ones_like(tau), tau, _legendre(tau, poly_order)])
    freqs: list[float] = []

    def design(fs):
        cols = [fixed]
        for f in fs:
            w = 2 * math.pi * f * (t - t0)
            cols.append(np.column_stack([np.cos(w), np.sin(w)]))
        return np.column_stack(cols)

    def solve(fs):
        a = design(fs)
        coef, *_ = np.linalg.lstsq(a * sw[:, None], v * sw, rcond=None)
        return coef, v - a @ coef

    dt = np.median(np.diff(np.sort(t))) if t.size > 1 else 1.0
    lo, hi = 1.0 / max(np.ptp(t), 1e-12), 0.5 / dt
    for _ in range(n_sin):
        if joint:
            f = best_frequency(t, v, design(freqs), sw, (lo, hi))
        else:  # the former start: the residual's zero-padded periodogram
            _, r = solve(freqs)
            n_fft = 1 << int(np.ceil(np.log2(64 * t.size)))
            tu = np.linspace(t.min(), t.max(), t.size)
            spec = np.abs(np.fft.rfft(np.interp(tu, t, r) * np.hanning(t.size), n_fft))
            fgrid = np.fft.rfftfreq(n_fft, (tu[1] - tu[0]) if t.size > 1 else dt)
            spec[fgrid < lo] = 0
            f = float(fgrid[np.argmax(spec)]) if spec.any() else None
        if f is None:
            break
        freqs.append(f)
    if freqs:
        def resid(fs):
            return solve(fs)[1] * sw
        tight = {"ftol": 1e-15, "xtol": 1e-12, "gtol": 1e-15} if joint else {}  # the cost is flat along a bend
        sol = scipy.optimize.least_squares(resid, np.clip(freqs, lo * 1.0001, hi * 0.9999), bounds=(lo, hi),
                                           x_scale=np.maximum(np.array(freqs), 1e-9) * 0.05, **tight)
        freqs = [float(f) for f in sol.x]
    coef, r = solve(freqs)
    return t0, half, coef, freqs, float(np.sqrt(np.mean(r ** 2)))


def fit_track_model(time_s: np.ndarray, displacement_m: np.ndarray, max_poly_order: int, sinusoids: int,
                    weight: np.ndarray | None = None, joint: bool = False) -> dict:
    """The ``legendre+sinusoids`` model fitted to an estimated track error, its polynomial order chosen by
    the Bayesian information criterion (no more terms than the data support). Offset and drift are fitted
    and left out of the model."""
    t, v = np.asarray(time_s, float), np.asarray(displacement_m, float)
    best = None
    for order in range(1, max_poly_order + 1):
        t0, half, coef, freqs, rms = fit_sinusoids(t, v, order, sinusoids, weight, joint)
        k = 2 + max(order - 1, 0) + 3 * len(freqs)
        bic = t.size * math.log(max(rms, 1e-15) ** 2) + k * math.log(t.size)
        if best is None or bic < best[0] - 1e-9:
            best = (bic, order, t0, half, coef, freqs)
    _, order, t0, half, coef, freqs = best
    n_poly = max(order - 1, 0)
    return {"kind": "legendre+sinusoids", "t_centre_s": t0, "t_half_s": half, "poly_order": order,
            "poly_m": coef[2:2 + n_poly].tolist(),
            "sinusoids": [[f, float(coef[2 + n_poly + 2 * i]), float(coef[3 + n_poly + 2 * i])] for i, f in enumerate(freqs)]}


def _model_design(g: GroupImages, model: dict):
    """The model's parameter vector, and a function giving (displacement [Q], d displacement / d params
    [Q, n]) for a parameter vector. Parameters: polynomial and sinusoid coefficients in units of
    1 / (2 k) metres (radians of two-way phase), frequencies in Hz."""
    t = g.time_s
    t0, half, order = model["t_centre_s"], model["t_half_s"], model["poly_order"]
    poly = _legendre(np.clip((t - t0) / half, -1, 1), order)
    n_poly = poly.shape[1]
    scale = 1.0 / (2.0 * g.k)
    x0 = [p / scale for p in model["poly_m"]]
    for f, a, b in model["sinusoids"]:
        x0 += [a / scale, b / scale, f]

    def evaluate(x):
        d = poly @ x[:n_poly] * scale
        jac = [poly * scale]
        for i in range(len(model["sinusoids"])):
            a, b, f = x[n_poly + 3 * i: n_poly + 3 * i + 3]
            w = 2 * math.pi * (t - t0)
            cw, sn = np.cos(f * w), np.sin(f * w)
            d = d + (a * cw + b * sn) * scale
            jac.append(np.column_stack([cw * scale, sn * scale, (-a * sn + b * cw) * w * scale]))
        return d, np.column_stack(jac)

    def to_model(x):
        out = dict(model)
        out["poly_m"] = (np.asarray(x[:n_poly]) * scale).tolist()
        out["sinusoids"] = [[float(x[n_poly + 3 * i + 2]), float(x[n_poly + 3 * i] * scale), float(x[n_poly + 3 * i + 1] * scale)]
                            for i in range(len(model["sinusoids"]))]
        return out

    return np.asarray(x0, float), evaluate, to_model


def minimum_entropy(g: GroupImages, model: dict, iterations: int) -> tuple[dict, float, int]:
    """Refine the model's parameters by minimising the entropy of the group images' sum (L-BFGS, exact
    gradient through the group images). Returns (model, entropy, iterations)."""
    x0, evaluate, to_model = _model_design(g, model)
    if x0.size == 0:
        return model, entropy_and_gradient(g, np.zeros_like(g.c))[0], 0

    def fun(x):
        d, jac = evaluate(x)
        ent, grad_phase = entropy_and_gradient(g, g.phase(d))
        grad_d = (grad_phase * 2.0 * g.k * g.c).sum(axis=1)
        return ent, jac.T @ grad_d

    # Frequencies stay within one cycle over the aperture and the groups' Nyquist rate; amplitudes are free.
    span = float(np.ptp(g.time_s))
    nyquist = 0.5 / float(np.median(np.diff(g.time_s)))
    n_poly = x0.size - 3 * len(model["sinusoids"])
    bounds = [(None, None)] * n_poly
    for _ in model["sinusoids"]:
        bounds += [(None, None), (None, None), (1.0 / span, nyquist)]
    # Entropy to a part in a million (a few micro-nats): finer steps change no image measurably.
    res = scipy.optimize.minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                                  options={"maxiter": iterations, "ftol": 1e-6})
    return to_model(res.x), float(res.fun), int(res.nit)



def _brightest(g: GroupImages, model: dict) -> int:
    """The estimation pixel brightest under a model's displacement."""
    img = g.image(g.phase(remove_line(g.time_s, evaluate_model(model, g.time_s)))) * g.weight.reshape(-1, g.b.shape[2])
    return int(np.argmax(np.abs(img)))


def entropy_estimate(g: GroupImages, options: AutofocusOptions) -> tuple[np.ndarray, dict | None, int]:
    """The "entropy" method: PGA's estimate refined by the model; whichever of the two leaves the lower
    entropy is kept (a model too poor for the track, or a local minimum, never makes the result worse than
    its start), and the model only if it keeps the brightest pixel (``MODEL_PEAK_KEEP``). Returns the
    displacement per group, the model (None where PGA's estimate is kept) and the iterations."""
    delta, it = phase_gradient_autofocus(g, options)
    e_pga, _ = entropy_and_gradient(g, g.phase(delta))
    weight = np.abs(g.b).sum(axis=(0, 2)).astype(float)
    orders = [options.poly_order]
    if options.sinusoids and options.poly_order > LOW_DRIFT_ORDER:
        orders.append(LOW_DRIFT_ORDER)
    model, e_model = None, math.inf
    brightest_pga = int(np.argmax(np.abs(g.image(g.phase(delta)) * g.weight.reshape(-1, g.b.shape[2]))))
    for order in orders:
        start = fit_track_model(g.time_s, delta, order, options.sinusoids, weight, joint=order == LOW_DRIFT_ORDER)
        candidate, e_candidate, it_model = minimum_entropy(g, start, options.entropy_iterations)
        it += it_model
        log.debug("autofocus (entropy): model from order %d: order %d, sinusoids %s, entropy %.7f", order,
                  candidate["poly_order"], [round(f[0], 3) for f in candidate["sinusoids"]], e_candidate)
        if e_candidate < e_model and (model is None or _brightest(g, candidate) == brightest_pga):
            # The low-order start is an alternative reading of the same focus, never one that moves the
            # target (seen over 2.5 frames: a bend that kept the peak's power but moved it 3 cm).
            model, e_model = candidate, e_candidate
    d_model = remove_line(g.time_s, evaluate_model(model, g.time_s))
    peak_pga, peak_model = peak_power(g, g.phase(delta)), peak_power(g, g.phase(d_model))
    if e_model < e_pga and peak_model >= MODEL_PEAK_KEEP * peak_pga:
        return d_model, model, it
    if e_model < e_pga:
        # Seen on a 0.05 m aperture under a Taylor taper: a sixth-order bend of millimetres that lowered
        # the entropy by pushing the target out of the pixels, and moved its peak 2 cm.
        log.info("autofocus (entropy): the model lowers the entropy but also the brightest pixel (%.1f dB); "
                 "keeping PGA's estimate", 10 * math.log10(peak_model / peak_pga))
    else:
        log.info("autofocus (entropy): the model did not beat PGA's estimate (%.4f against %.4f); keeping PGA's",
                 e_model, e_pga)
    return delta, None, it
