"""Whether a weak point target's own phase history shows a track error: the brightest pixel detected as
an isolated point, a low-order track error fitted to that point alone, and the fits of the two half-bands
compared within their known noise.

Where the half-bands' estimates (``imaging.autofocus.consistency``) are too noisy to agree, a weak point
target still holds its track error's lowest orders: at 14 dB image SNR each half-band has 11 dB, and the
method's estimate over the whole image then fits the noise (several radians rms where the track error holds
0.8). This test reads the track error where it can be read there, and asks two questions:

1. **Is the brightest pixel a point, not the brightest speckle of its background?** With the background's
   mean power ``m`` (its median over ln 2: robust to the point itself), the brightest of ``N`` cells of
   complex Gaussian speckle (clutter or noise) exceeds ``T m`` with probability
   ``1 - (1 - exp(-T))^N <= N exp(-T)``. The pixel is taken for a point where its power exceeds
   ``ln(N / alpha) m``, every estimation pixel counted as a cell of its own (neighbouring pixels are
   correlated, so the true count is smaller and the false-alarm rate on clutter below ``alpha``). Only here
   can a clutter-only scene get through, and the fit below would distort it: this is its guard.
2. **Do both half-bands give that point one track error?** For an isolated point under white noise the
   group images at its pixel are ``B_q = a exp(j phi_q) + n_q``; the likelihood, maximised over the complex
   amplitude a, is ``|I(theta)|^2 / m`` with ``I(theta) = sum_q B_q exp(j phi_q(theta))`` (the pixel refocused
   with the track error theta), so the maximum-likelihood track error is the one that maximises the pixel's
   power. Its Cramer-Rao variance is ``Q m / (2 |I|^2)`` per group and per orthonormal column. Each half-band
   is fitted alone at the same pixel; the fits must agree within their variances
   (``sum (theta_lo - theta_up)^2 / (var_lo + var_up)`` below the chi-square quantile at ``1 - alpha``:
   never applied where independent estimates disagree). The full band's fit is applied.

``theta`` holds the Legendre polynomials of order 2 up to ``POINT_ORDER`` (the offset and drift only move
the image): few enough parameters that a weak point's fit is its track error, not its noise. A detected
point has ``|I|^2 > ln(N / alpha) m``, so the fit's phase uncertainty is at most
``sqrt(K / (2 ln(N / alpha)))`` rad rms (0.28 rad for 4000 pixels): applied to an error-free point, it
changes the width by under 1 %. Twice the log-likelihood ratio of the fit, ``2 (|I(theta)|^2 - |I(0)|^2) / m``
(chi-square with K degrees of freedom without a track error), is reported as the evidence for one; a
14 dB point's error of 0.8 rad rms is too small for it to decide at 1 %. A vibration is left to the
half-band test. See docs/signal-model.md for the phase model.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.optimize
import scipy.stats

from imaging.autofocus.subapertures import TILE, GroupImages
from imaging.autofocus.track_model import _legendre

#: The highest Legendre order of the track error fitted to a weak point (2: a bend; 3: its asymmetric part).
POINT_ORDER = 3


@dataclasses.dataclass
class PointCheck:
    """A weak point's test (see the module's docstring): ``contrast``, the brightest pixel's power over the
    background's mean power, against ``detection_threshold`` (``ln(N / alpha)``); ``disagreement``, the
    half-bands' fits' squared difference over its variance, against ``disagreement_limit`` (chi-square
    quantile for ``dof`` parameters; inf where nothing was detected and fitted); ``ratio``, twice the
    log-likelihood ratio of the full band's fit (evidence, not a condition), and ``critical_ratio`` its
    quantile; ``displacement_m`` [Q], the full band's fit at the group times (line-free, zero where nothing
    was fitted); ``uncertainty_m``, its rms standard deviation (Cramer-Rao bound at the point's SNR)."""

    contrast: float
    detection_threshold: float
    disagreement: float
    disagreement_limit: float
    ratio: float
    critical_ratio: float
    dof: int
    displacement_m: np.ndarray
    uncertainty_m: float

    @property
    def detected(self) -> bool:
        return self.contrast > self.detection_threshold

    @property
    def passed(self) -> bool:
        return self.detected and self.disagreement < self.disagreement_limit

    @property
    def margin_db(self) -> float:
        """The detection's margin where nothing was detected, else the smaller of the two margins (dB;
        positive: both tests passed)."""
        detection = 10 * math.log10(max(self.contrast, 1e-12) / self.detection_threshold)
        if not self.detected:
            return detection
        return min(detection, 10 * math.log10(max(self.disagreement_limit / max(self.disagreement, 1e-12), 1e-12)))


def point_basis(time_s: np.ndarray, order: int = POINT_ORDER) -> np.ndarray:
    """[Q, order - 1] Legendre polynomials of order 2..order over the span, orthonormalised against the
    line (so their coefficients are independent under white noise)."""
    t = np.asarray(time_s, float)
    tau = (t - 0.5 * (t.min() + t.max())) / max(0.5 * np.ptp(t), 1e-12)
    q, _ = np.linalg.qr(np.column_stack([np.ones_like(tau), tau, _legendre(tau, order)]))
    return q[:, 2:]


def _pixel_history(g: GroupImages, pixel: int) -> tuple[np.ndarray, np.ndarray]:
    """The group images at one estimation pixel [Q] and the phase per metre of track error there [Q]."""
    tile, i = divmod(pixel, TILE)
    return g.b[tile, :, i].astype(np.complex128), 2.0 * g.k * g.c[:, tile]


def _refocused_power(history: np.ndarray, rad_per_m: np.ndarray, basis: np.ndarray, theta_m: np.ndarray
                     ) -> tuple[float, np.ndarray]:
    """|I|^2 of the pixel refocused with the track error ``basis @ theta_m``, and its gradient."""
    w = history * np.exp(1j * rad_per_m * (basis @ theta_m))
    s = w.sum()
    # d|s|^2/dtheta = 2 Re(conj(s) ds/dtheta), ds/dtheta_k = sum_q j rad_per_m_q basis_qk w_q
    grad = 2.0 * np.real(np.conj(s) * (1j * (rad_per_m * w)) @ basis)
    return float(abs(s) ** 2), grad


def _fit_point(history: np.ndarray, rad_per_m: np.ndarray, basis: np.ndarray, span_rad: float) -> np.ndarray:
    """theta [K] (metres) maximising the pixel's refocused power: a coarse grid over +-span_rad of phase
    per orthonormal column's rms (the likelihood has side maxima where the bend is large), then L-BFGS."""
    q = basis.shape[0]
    scale = 1.0 / (math.sqrt(q) * float(np.mean(rad_per_m)))  # metres of a column giving 1 rad rms of phase
    steps = np.linspace(-span_rad, span_rad, 13)
    grid = np.stack(np.meshgrid(*([steps] * basis.shape[1]), indexing="ij"), axis=-1).reshape(-1, basis.shape[1])
    powers = np.abs(np.exp(1j * math.sqrt(q) * (grid @ basis.T)) @ history) ** 2

    def negative(x):
        value, grad = _refocused_power(history, rad_per_m, basis, x * scale)
        return -value, -grad * scale

    res = scipy.optimize.minimize(negative, grid[int(np.argmax(powers))], jac=True, method="L-BFGS-B")
    return res.x * scale


def _fit_at(g: GroupImages, pixel: int, basis: np.ndarray, span_rad: float
            ) -> tuple[np.ndarray, float, float, float, float]:
    """The point fit at one pixel of one set of group images: theta [K] (m), the pixel's power before and
    after, the Cramer-Rao variance of each theta (m^2) and the background's mean power m of those images."""
    power = _power(g)
    background = float(np.median(power[power > 0])) / math.log(2)
    history, rad_per_m = _pixel_history(g, pixel)
    theta = _fit_point(history, rad_per_m, basis, span_rad)
    refocused, _ = _refocused_power(history, rad_per_m, basis, theta)
    # Per group the phase variance is Q m / (2 |I|^2) (m = Q sigma_group^2, |I| = Q |a|); an orthonormal
    # column's coefficient has the same variance.
    var_m2 = g.time_s.size * background / (2.0 * max(refocused, 1e-300)) / float(np.mean(rad_per_m)) ** 2
    return theta, float(power[pixel]), refocused, var_m2, background


def detect_point(power: np.ndarray, false_alarm: float) -> tuple[int, float, float]:
    """The brightest pixel of an image's power (any shape; pixels at 0, which nothing was integrated into,
    are no background), its power over the background's mean power, and the threshold ``ln(N / alpha)``
    it must exceed to be taken for a point (see the module's docstring)."""
    power = np.asarray(power, np.float64).ravel()
    lit = power > 0
    n = int(lit.sum())
    threshold = math.log(max(n, 1) / false_alarm)
    background = float(np.median(power[lit])) / math.log(2) if n else 0.0
    pixel = int(np.argmax(power))
    return pixel, (float(power[pixel]) / background if background > 0 else 0.0), threshold


def _power(g: GroupImages) -> np.ndarray:
    image = g.image(np.zeros_like(g.c)).ravel()
    return np.where(g.weight > 0, image.real.astype(np.float64) ** 2 + image.imag.astype(np.float64) ** 2, 0.0)


def point_check(g: GroupImages, halves: tuple[GroupImages, GroupImages], false_alarm: float,
                order: int = POINT_ORDER, span_rad: float = 3.0) -> PointCheck:
    """Test whether the brightest estimation pixel is an isolated point to which both half-bands (the same
    groups imaged from the lower and the upper half of the band) fit one low-order track error, and fit it
    on the full band ``g`` (see the module's docstring)."""
    basis = point_basis(g.time_s, order)
    dof = basis.shape[1]
    critical = float(scipy.stats.chi2.ppf(1.0 - false_alarm, dof))
    pixel, contrast, threshold = detect_point(_power(g), false_alarm)
    if not contrast > threshold:  # not a point: nothing is fitted (its phase history is the speckle's)
        return PointCheck(contrast, threshold, math.inf, critical, 0.0, critical, dof, np.zeros(g.time_s.size), 0.0)
    theta, before, after, var_m2, background = _fit_at(g, pixel, basis, span_rad)
    (lower, *_, var_lower, _), (upper, *_, var_upper, _) = (_fit_at(h, pixel, basis, span_rad) for h in halves)
    disagreement = float(np.sum((lower - upper) ** 2) / (var_lower + var_upper))
    ratio = 2.0 * (after - before) / background
    return PointCheck(contrast, threshold, disagreement, critical, ratio, critical, dof, basis @ theta,
                      math.sqrt(var_m2 * dof / g.time_s.size))
