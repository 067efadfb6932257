"""What autofocus is asked to do and what it gives back: options, the profiles it works on, the result."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.autofocus.consistency import Consistency
from imaging.autofocus.subapertures import TILE
from imaging.autofocus.registry import METHODS
from imaging.core.config import require
from imaging.core.track_error import TrackError
from imaging.range_compression import RangeProfiles


#: When an estimate is applied: the two half-bands' estimates agree ("consistency"), or the image has a
#: bright enough pixel and the estimate lowers the entropy ("contrast").
DECISIONS = ("consistency", "contrast")


@dataclasses.dataclass
class AutofocusOptions:
    """How to estimate the track error.

    ``groups``: slow-time groups (the resolution of the estimate in time); ``max_pixels``: the whole image
    is used up to this many pixels, else ``scatterers`` patches of ``patch_px`` x ``patch_px`` around the
    strongest; ``poly_order`` and ``sinusoids``: the entropy model (the polynomial order is chosen up to
    ``poly_order`` by the Bayesian information criterion on the PGA estimate: no more than the scene needs);
    ``per_profile_iterations``: the per-group sharpening of the "per-profile" and "combined" methods
    (``imaging.autofocus.per_profile``).

    ``decision``: when an estimate is applied. "consistency" (default): the method also estimates the track
    error from the lower and from the upper half of the band, and the estimate is applied only where the
    two agree (at the false-alarm rate ``false_alarm``) and it agrees with them
    (``imaging.autofocus.consistency``); the contrast gate is not used. "contrast": the former rule, an
    image whose brightest pixel stands less than ``min_contrast_db`` above its background is left as it
    is, and any estimate that lowers the entropy is applied.
    """

    method: str = "entropy"
    groups: int = 256
    max_pixels: int = 65536
    scatterers: int = 16
    patch_px: int = 64
    pga_iterations: int = 8
    pga_tolerance_rad: float = 0.01
    poly_order: int = 6
    sinusoids: int = 1
    entropy_iterations: int = 200
    per_profile_iterations: int = 100  # the per-group sharpening of "per-profile" and "combined"
    min_contrast_db: float = 20.0  # decision "contrast": brightest pixel over the background (noise median) needed
    decision: str = "consistency"
    false_alarm: float = 0.01  # decision "consistency": the chance two fits to nothing pass as one track error

    def __post_init__(self) -> None:
        require(self.method in METHODS, "method", f"must be one of {', '.join(METHODS)}, got {self.method!r}")
        require(4 <= self.groups <= 4096, "groups", f"must be 4 to 4096, got {self.groups}")
        require(self.max_pixels >= TILE, "max_pixels", f"must be at least {TILE}, got {self.max_pixels}")
        require(1 <= self.scatterers <= 256, "scatterers", f"must be 1 to 256, got {self.scatterers}")
        require(16 <= self.patch_px <= 256 and self.patch_px % 16 == 0, "patch_px",
                f"must be a multiple of 16 from 16 to 256, got {self.patch_px}")
        require(1 <= self.pga_iterations <= 100, "pga_iterations", f"must be 1 to 100, got {self.pga_iterations}")
        require(1 <= self.poly_order <= 8, "poly_order", f"must be 1 to 8, got {self.poly_order}")
        require(1 <= self.per_profile_iterations <= 10000, "per_profile_iterations",
                f"must be 1 to 10000, got {self.per_profile_iterations}")
        require(0 <= self.sinusoids <= 4, "sinusoids", f"must be 0 to 4, got {self.sinusoids}")
        require(math.isfinite(self.min_contrast_db), "min_contrast_db", f"must be finite, got {self.min_contrast_db}")
        require(self.decision in DECISIONS, "decision", f"must be one of {', '.join(DECISIONS)}, got {self.decision!r}")
        require(1e-6 <= self.false_alarm <= 0.5, "false_alarm", f"must be 1e-6 to 0.5, got {self.false_alarm}")


@dataclasses.dataclass
class ProfileBlock:
    """Range profiles and what autofocus needs of each: antennas [P, 3], slow time [P] in seconds (from any
    origin), the unit direction [P, 3] the track error displaces the antennas along, reference ranges."""

    profiles: RangeProfiles
    tx_m: np.ndarray
    rx_m: np.ndarray
    time_s: np.ndarray
    direction: np.ndarray
    reference_range_m: np.ndarray | None = None



@dataclasses.dataclass
class AutofocusResult:
    """The estimate, and the entropy of the estimation pixels before and after (nats); ``consistency``: the
    half-band estimates compared (``imaging.autofocus.consistency.Consistency``), None where not checked."""

    track_error: TrackError
    entropy_before: float
    entropy_after: float
    applied: bool
    pixels: int
    groups: int
    iterations: int
    note: str = ""
    consistency: Consistency | None = None

