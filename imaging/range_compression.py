"""Range compression: window and zero-padded FFT along fast time, onto a two-way range axis."""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.fft

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.windows import get_window


@dataclasses.dataclass
class RangeProfiles:
    """Range-compressed data and the axis it lives on.

    Bin i of ``data[..., i]`` holds two-way range (or, for data referenced to a scene centre, two-way
    range difference) ``range_start_m + i * range_step_m``. Backprojection samples a profile at the
    two-way range r of a pixel and multiplies by ``exp(-j 2 pi carrier_hz r / c)``.

    ``carrier_hz`` is f0 for a profile exactly as DESIGN.md defines it; with ``centred`` compression the
    linear phase of the fast-time origin is removed and the carrier is the centre frequency, which makes
    the profile vary slowly with range so that interpolating it is accurate (same result, exactly).
    ``samples`` keeps the windowed, normalised fast-time samples for the exact matched filter.
    """

    data: np.ndarray  # complex64 [..., n_bins]
    range_start_m: float
    range_step_m: float
    carrier_hz: float
    f0_hz: float
    frequency_step_hz: float
    samples: np.ndarray | None = None  # complex64 [..., n_samples], windowed / sum(window)

    @property
    def n_bins(self) -> int:
        return self.data.shape[-1]

    @property
    def range_axis_m(self) -> np.ndarray:
        """Two-way range of every bin."""
        return self.range_start_m + self.range_step_m * np.arange(self.n_bins)


def range_compress(
    samples: np.ndarray,
    f0_hz: float,
    frequency_step_hz: float,
    window: str = "hann",
    oversample: int = 16,
    n_fft: int | None = None,
    centred: bool = True,
    signed: bool = False,
    keep_samples: bool = True,
) -> RangeProfiles:
    """Window and FFT along the last axis.

    Parameters
    ----------
    samples : ndarray, shape (..., n)
        Complex fast-time samples, taken at frequencies ``f0_hz + n * frequency_step_hz`` (FMCW: the
        frequency step is slope / fs; a stepped-frequency phase history has its own step).
    window : str
        "rectangular", "hann", "hamming" or "taylor".
    oversample : int
        Zero-padding factor; ``n_fft = oversample * n`` unless ``n_fft`` is given.
    centred : bool
        Remove the linear phase of the fast-time origin (carrier becomes the centre frequency).
    signed : bool
        Put range zero in the middle (for data whose range axis is relative to a reference range).

    Returns
    -------
    RangeProfiles
        ``data`` complex64 (..., n_fft), normalised so a unit-amplitude target peaks at 1.
    """
    samples = np.asarray(samples)
    n = samples.shape[-1]
    n_fft = int(n_fft or oversample * n)
    if n_fft < n:
        raise ValueError(f"n_fft={n_fft} is shorter than the {n} samples")
    w = get_window(window, n)
    windowed = (samples * (w / w.sum())).astype(np.complex64)
    spectrum = scipy.fft.fft(windowed, n_fft, axis=-1)  # single precision stays single (numpy's works in double)
    step = SPEED_OF_LIGHT_MPS / (n_fft * frequency_step_hz)
    start = 0.0
    if signed:
        spectrum = scipy.fft.fftshift(spectrum, axes=-1)
        start = -(n_fft // 2) * step
    carrier = f0_hz
    if centred:
        m = 0.5 * (n - 1)
        r = start + step * np.arange(n_fft)
        spectrum *= np.exp(2j * np.pi * m * frequency_step_hz * r / SPEED_OF_LIGHT_MPS).astype(np.complex64)
        carrier = f0_hz + m * frequency_step_hz
    return RangeProfiles(
        data=spectrum.astype(np.complex64),
        range_start_m=start,
        range_step_m=step,
        carrier_hz=carrier,
        f0_hz=f0_hz,
        frequency_step_hz=frequency_step_hz,
        samples=windowed if keep_samples else None,
    )
