"""The interpolation kernels of fast factorized backprojection (``imaging.factorized_backprojection``):
least-squares coefficients that interpolate a band-limited polar grid at any fractional position, tabulated,
and their worst and RMS errors, from which the FFBP plan bounds its error.
"""

from __future__ import annotations

import functools
import math

import numpy as np

#: Fractional shifts tabulated per interpolation kernel (the nearest is used: phase error <= pi / (2 os NF)).
TABLE_SHIFTS = 2048
#: The designed band exceeds the Nyquist band of the oversampled grid by this factor (margin for the
#: bandwidth estimates: the bistatic offsets, the envelope's own variation).
BAND_MARGIN = 1.05

def _tap_offsets(taps: int) -> np.ndarray:
    return np.arange(-taps // 2 + 1, taps // 2 + 1)


def _band(oversample: float) -> float:
    return 0.5 / oversample * BAND_MARGIN


@functools.lru_cache(maxsize=16)
def interpolation_table(taps: int, oversample: float) -> np.ndarray:
    """Least-squares interpolation coefficients, float32 [TABLE_SHIFTS + 1, taps].

    Row i interpolates at fractional position d = i / TABLE_SHIFTS past sample ``floor``, from samples
    ``floor + (-taps/2 + 1 ... taps/2)``; the coefficients minimise the mean squared error over all tones
    within +-0.5 / oversample (x BAND_MARGIN) cycles per sample.
    """
    t = _tap_offsets(taps)
    f = _band(oversample)
    gram = 2 * f * np.sinc(2 * f * (t[:, None] - t[None, :]))
    d = np.arange(TABLE_SHIFTS + 1) / TABLE_SHIFTS
    rhs = 2 * f * np.sinc(2 * f * (d[None, :] - t[:, None]))  # [taps, shifts]
    coeff = np.linalg.solve(gram + 1e-13 * np.eye(taps), rhs)
    return np.ascontiguousarray(coeff.T, dtype=np.float32)


@functools.lru_cache(maxsize=16)
def _interpolation_errors(taps: int, oversample: float) -> tuple[float, float]:
    table = interpolation_table(taps, oversample).astype(np.float64)
    t = _tap_offsets(taps)
    f = np.linspace(-0.5 / oversample, 0.5 / oversample, 129)
    worst, power, count = 0.0, 0.0, 0
    # The positions actually used: the table's entries, each standing for shifts up to half an entry away.
    for i in range(0, TABLE_SHIFTS + 1, 8):
        resp = np.exp(2j * np.pi * f[:, None] * t[None, :]) @ table[i]
        for d in (i / TABLE_SHIFTS, (i - 0.5) / TABLE_SHIFTS, (i + 0.5) / TABLE_SHIFTS):
            e = np.abs(resp - np.exp(2j * np.pi * f * d))
            worst = max(worst, float(e.max()))
            power += float((e ** 2).sum())
            count += e.size
    return worst, math.sqrt(power / count)


def interpolation_error(taps: int, oversample: float) -> float:
    """Worst relative error of the tabulated kernel for a unit tone anywhere in the band it is designed
    for (the grid's +-0.5 / oversample cycles per sample), over all fractional positions, table rounding
    included (amplitude, not dB)."""
    return _interpolation_errors(taps, oversample)[0]


def interpolation_rms_error(taps: int, oversample: float) -> float:
    """The same error's root mean square over the band and the fractional positions (amplitude)."""
    return _interpolation_errors(taps, oversample)[1]
