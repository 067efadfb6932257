"""Stepped-frequency phase histories from other SAR systems, in sarbot's sign convention.

sarbot's signal model (docs/signal-model.md) has a point at two-way range r contribute exp(+j 2 pi f r / c); a phase
history motion-compensated to a scene centre holds the same with r replaced by the two-way range
difference r - r_ref. Backprojection takes such data directly with ``reference_range_m``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from imaging.core.errors import FileFormatError


@dataclasses.dataclass
class PhaseHistory:
    """Samples [P, N] at frequencies ``f0_hz + n * frequency_step_hz``; one antenna position per pulse."""

    samples: np.ndarray  # complex [P, N]
    f0_hz: float
    frequency_step_hz: float
    antenna_m: np.ndarray  # [P, 3] world (monostatic: TX = RX)
    reference_range_m: np.ndarray  # [P] two-way range the samples' phase is relative to

    @property
    def bandwidth_hz(self) -> float:
        return self.samples.shape[1] * self.frequency_step_hz


def read_afrl_gotcha(folder: str | Path, pattern: str = "data_3dsar_*.mat") -> PhaseHistory:
    """AFRL "Gotcha" volumetric SAR files (MATLAB v5, field ``data``: fp, freq, x, y, z, r0), concatenated.

    The files hold exp(-j 4 pi f (R - R0) / c) per scatterer (one-way ranges, scene-centre referenced;
    the convention the RITSAR examples image them with), so the samples are conjugated into sarbot's
    convention and the reference range doubled to two-way.
    """
    import scipy.io

    files = sorted(Path(folder).glob(pattern))
    if not files:
        raise FileFormatError(f"{folder}: no files matching {pattern}")
    fps, pos, r0 = [], [], []
    freq = None
    for f in files:
        try:
            d = scipy.io.loadmat(f, squeeze_me=True, struct_as_record=False)["data"]
            fps.append(np.asarray(d.fp).T)
            pos.append(np.column_stack([d.x, d.y, d.z]))
            r0.append(np.atleast_1d(d.r0))
            this = np.asarray(d.freq, float)
        except (KeyError, AttributeError, ValueError, OSError) as exc:
            raise FileFormatError(f"{f}: not an AFRL phase-history file ({exc})") from None
        if freq is not None and not np.allclose(this, freq):
            raise FileFormatError(f"{f}: its frequencies differ from the other files'")
        freq = this
    # The files store frequencies in float32 (1 kHz resolution at 9 GHz): fit the uniform step.
    n = np.arange(freq.size)
    step, f0 = np.polyfit(n, freq, 1)
    if np.abs(freq - (f0 + step * n)).max() > 0.01 * abs(step):
        raise FileFormatError(f"{files[0]}: frequencies are not uniformly stepped")
    return PhaseHistory(
        samples=np.conj(np.concatenate(fps)).astype(np.complex64),
        f0_hz=float(f0),
        frequency_step_hz=float(step),
        antenna_m=np.concatenate(pos).astype(np.float64),
        reference_range_m=2.0 * np.concatenate(r0).astype(np.float64),
    )
