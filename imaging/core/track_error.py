"""A track error: how far the antennas were displaced along a known direction from where the trajectory put
them, over slow time (what autofocus estimates and the radar's own IMU measures; see docs/signal-model.md).

Only what an image can see of it is defined: a constant offset and a linear drift move the image without
blurring it, so :func:`remove_line` takes them out and a track error holds the rest.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class TrackError:
    """Displacement of the antennas along the block's direction against the trajectory, over slow time.

    ``time_s`` [Q] group centres (seconds from ``time_origin_ns`` where the profiles came from a recording),
    ``displacement_m`` [Q]. Constant and linear parts are arbitrary (they only move the image); they are
    set to zero over the aperture. ``model`` holds the fitted terms where the estimate is parametric.
    """

    time_s: np.ndarray
    displacement_m: np.ndarray
    method: str
    model: dict | None = None
    time_origin_ns: int = 0

    def at(self, time_s: np.ndarray) -> np.ndarray:
        """The displacement at any time (linear between group centres, held beyond them). The model, where
        there is one, is not used here: its offset and drift are arbitrary and would move the image."""
        return np.interp(np.asarray(time_s, float), self.time_s, self.displacement_m)

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.displacement_m ** 2)))

    @classmethod
    def of_vibration(cls, vibration, time_s: np.ndarray, vibration_t0_ns: int, time_origin_ns: int) -> "TrackError":
        """A known vibration (``imaging.core.geometry.Vibration``, phase referred to ``vibration_t0_ns``) as a
        track error at ``time_s`` from ``time_origin_ns``: what a perfect estimate would give."""
        t = np.asarray(time_s, float)
        return cls(t, vibration.displacement_m(t + (time_origin_ns - vibration_t0_ns) * 1e-9), "truth", None, int(time_origin_ns))


def remove_line(t: np.ndarray, v: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """v less its (weighted) least-squares line over t: a track error as an image can see it (an offset and
    a drift only move the image)."""
    a = np.column_stack([np.ones_like(t), t - t.mean()])
    sw = np.ones_like(t) if w is None else np.sqrt(w)
    coef, *_ = np.linalg.lstsq(a * sw[:, None], v * sw, rcond=None)
    return v - a @ coef
