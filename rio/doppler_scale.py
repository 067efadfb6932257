"""The radars' Doppler scale from the map's velocity errors: the weighted mean of what each measurement reads,
as unsure as the readings' disagreement says.

Each map measurement taken reads the scale on its own. The scans of its span were multiplied by the scale then
in use, ``s_span``; its velocity error ``dv`` (truth minus trajectory) over the trajectory's speed ``v`` there says
the truth is ``s_span (1 + dv / v)``, to its sigma over the speed. The estimate is the weighted mean of these
readings and the prior (1, a few per cent). For one reading that is the scalar Kalman update; where the readings
agree, many give what a sequential filter gives. Where they disagree beyond their sigmas, the mean's variance is
multiplied by their chi2 per degree of freedom (the scale factor the Particle Data Group applies to measurements
that disagree): two tiles that disagree leave the scale as unsure as their disagreement, not as sure as both
claim, and the odometry's gate for wild tiles (``rio.map_feedback``) opens with it.

Why not the sequential filter: it let the first tile decide. A live CI run's first tile read the scale at
-3.3 % +- 0.8 % (the truth +2.0 %: that tile erred by 6.7 of its sigmas); the filter took it at a gain of 0.97,
and the next tile, +3.1 % +- 0.6 %, lay 6.5 of the scale's sigmas off and was refused by the scale's gate.
Every later one spanned an update, so the scale ended at -3.2 % +- 0.8 %. The same two readings give +0.6 % +-
2.2 % here. A CI run's seven tiles that scattered by 18 mm/s while claiming 2-5 give +0.1 % +- 1.4 % (the
sequential filter: 7 of its sigmas off; tests/test_map_feedback.py).

Nor is a reading left out for lying far from the others (the sequential filter's gate did that): where the
tiles' sigmas claim too much they split into groups that each look consistent, and leaving out the reading
farthest from the rest, again and again, kept whichever group was larger. Replayed as independent readings,
those seven kept the four latest, which erred together: -2.5 % +- 0.5 % for a truth of +2.0 %. A wild tile
is kept out before it reads the scale, by the odometry's gate for wild tiles.

Pure computation (used by ``rio.map_feedback.MapFeedback``).
"""

from __future__ import annotations

import numpy as np


def inflated_weighted_mean(values: np.ndarray, sigmas: np.ndarray, prior: float,
                           prior_sigma: float) -> tuple[float, float]:
    """Weighted mean of ``values`` [N] (standard deviations ``sigmas`` [N]) and a ``prior`` (``prior_sigma``),
    and its variance, multiplied by chi2 / N where that exceeds 1 (chi2 of the values and the prior against the
    mean; N degrees of freedom)."""
    w = np.concatenate([[1.0 / prior_sigma ** 2], 1.0 / np.asarray(sigmas, float) ** 2])
    x = np.concatenate([[prior], np.asarray(values, float)])
    mean = float(w @ x / w.sum())
    chi2 = float(w @ (x - mean) ** 2)
    return mean, max(1.0, chi2 / max(x.size - 1, 1)) / float(w.sum())


class DopplerScaleEstimator:
    """The Doppler scale from readings (``add``): ``scale`` and ``variance`` (relative, about 1), re-estimated
    from every reading at each new one (``inflated_weighted_mean``, the prior 1 +- ``prior_sigma``)."""

    def __init__(self, prior_sigma: float):
        self.prior_sigma = prior_sigma
        self.scale = 1.0
        self.variance = prior_sigma ** 2
        self.values: list[float] = []
        self.sigmas: list[float] = []

    def add(self, scale: float, sigma: float) -> None:
        """One reading of the scale (``sigma``: its standard deviation)."""
        self.values.append(float(scale))
        self.sigmas.append(float(sigma))
        self.scale, self.variance = inflated_weighted_mean(self.values, self.sigmas, 1.0, self.prior_sigma)
