"""A vibration read off an estimated track error: frequency, amplitude and phase by a sinusoid fit, with
the unobservable offset and drift as nuisance terms (so a vibration no longer has to be inferred from the
level of its paired side lobes)."""

from __future__ import annotations

import dataclasses
import math

from imaging.autofocus.track_model import fit_sinusoids
from imaging.core.track_error import TrackError


@dataclasses.dataclass
class VibrationFit:
    """A sinusoid A sin(2 pi f t + phase) read off a track error (t from the track error's time origin)."""

    frequency_hz: float
    amplitude_m: float
    phase_rad: float
    residual_rms_m: float


def fit_vibration(track_error: TrackError, poly_order: int = 1) -> VibrationFit:
    """Frequency, amplitude and phase of the strongest sinusoid in an estimated track error.

    The offset and drift (and, with ``poly_order`` >= 2, a slow bend) are fitted beside it and set aside: the
    estimate does not know them. The fit is made on the estimated displacement, whichever estimator made it:
    over an aperture of one or two periods a sinusoid and a bend are far from orthogonal, so the entropy
    model's own split between them is not a measurement of either, while their sum is. A track error with
    no oscillation of a cycle or more over its span raises ValueError.
    """
    t0, _, coef, freqs, resid = fit_sinusoids(track_error.time_s, track_error.displacement_m, poly_order, 1)
    if not freqs:
        raise ValueError("the track error holds no oscillation of a cycle or more over its span")
    n_poly = max(poly_order - 1, 0)
    f, a, b = freqs[0], coef[2 + n_poly], coef[3 + n_poly]
    # a cos(w (t - t0)) + b sin(w (t - t0)) = A sin(w t + phase)
    amp = math.hypot(a, b)
    phase = math.atan2(a, b) - 2 * math.pi * f * t0
    return VibrationFit(float(f), float(amp), float(math.remainder(phase, 2 * math.pi)), float(resid))
