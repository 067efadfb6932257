"""Range compression: window and zero-padded FFT along fast time, onto a two-way range axis."""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.windows import get_window
from imaging.pocketfft import fft_in_place
from imaging.range_window import worth_it, zoom_spectrum


@dataclasses.dataclass
class RangeProfiles:
    """Range-compressed data and the axis it lives on.

    Bin i of ``data[..., i]`` holds two-way range (or, for data referenced to a scene centre, two-way
    range difference) ``range_start_m + i * range_step_m``. Backprojection samples a profile at the
    two-way range r of a pixel and multiplies by ``exp(-j 2 pi carrier_hz r / c)``.

    ``carrier_hz`` is f0 for a profile exactly as docs/signal-model.md defines it; with ``centred`` compression the
    linear phase of the fast-time origin is removed and the carrier is the frequency of the middle sample
    (the lower of the two for an even count), which makes the profile vary slowly with range so that
    interpolating it is accurate (same result, exactly).
    ``samples`` keeps the windowed, normalised fast-time samples for the exact matched filter.
    ``rows``, when compression was asked for ``guarded`` profiles, is the buffer ``data`` is a view of:
    [P, n_bins + 3] with one zero bin before each profile and two after, the layout the backprojection
    kernel reads, so it needs no copy of the profiles.
    """

    data: np.ndarray  # complex64 [..., n_bins]
    range_start_m: float
    range_step_m: float
    carrier_hz: float
    f0_hz: float
    frequency_step_hz: float
    samples: np.ndarray | None = None  # complex64 [..., n_samples], windowed / sum(window)
    rows: np.ndarray | None = None  # complex64 [P, n_bins + 3]: data with its guard bins
    bandwidth_hz: float | None = None  # samples x frequency step (None where not known)

    @property
    def n_bins(self) -> int:
        return self.data.shape[-1]

    @property
    def range_axis_m(self) -> np.ndarray:
        """Two-way range of every bin."""
        return self.range_start_m + self.range_step_m * np.arange(self.n_bins)


def range_bin_spacing_m(n_fft: int, frequency_step_hz: float) -> float:
    """Two-way range between adjacent bins of an ``n_fft``-point profile.

    Parameters
    ----------
    n_fft : int
        Points of the (zero-padded) FFT along fast time.
    frequency_step_hz : float
        Frequency step between fast-time samples (Hz): slope x sample interval for an FMCW chirp.

    Returns
    -------
    float
        ``c / (n_fft * frequency_step_hz)`` (metres of two-way range).
    """
    return SPEED_OF_LIGHT_MPS / (n_fft * frequency_step_hz)


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
    guarded: bool = False,
    workers: int | None = None,
    rows_out: np.ndarray | None = None,
    bins: tuple[int, int] | None = None,
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
        Remove the linear phase of the fast-time origin (carrier becomes the middle sample's frequency).
    signed : bool
        Put range zero in the middle (for data whose range axis is relative to a reference range).
    guarded : bool
        Write the profiles into the backprojection kernel's layout (``RangeProfiles.rows``); samples must
        then be 2-D [P, n].
    workers : int, optional
        Threads for the FFT (scipy.fft's ``workers``; -1: all cores). One by default.
    rows_out : ndarray, complex64, shape (P, n_fft + 3), optional
        With ``guarded``: where to write the profiles' rows (``RangeProfiles.rows``), a buffer of an
        earlier call reused (C-contiguous; whatever it holds is overwritten) instead of a new one: a block of
        profiles is hundreds of MB, and the new pages of each new one cost the system time of their faults.
        With ``bins``: shape (P, k1 - k0 + 3).
    bins : (k0, k1), optional
        Only bins k0 .. k1 - 1 of the n_fft-point profile (unsigned), by a chirp-z transform
        (``imaging.range_window``): ``data`` is then (..., k1 - k0) and starts at ``range_start_m = k0 *
        range_step_m``, the same numbers as those bins of the full profile to float32 precision. Where that
        is not cheaper than the full FFT (``range_window.worth_it``: the window is more than about a third of
        the range) the full profile is made, as without ``bins``. An image reads only the bins between its
        nearest and farthest pixel (``imaging.range_window.needed_bins``).

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
    if guarded and samples.ndim != 2:
        raise ValueError(f"guarded profiles need samples [P, n], got shape {samples.shape}")
    w = get_window(window, n)
    w = (w / w.sum()).astype(np.float32)  # float32: complex64 samples stay complex64, no double-width temporaries
    if bins is not None:
        k0, k1 = int(bins[0]), int(bins[1])
        if signed or not 0 <= k0 < k1 <= n_fft:
            raise ValueError(f"bins {bins} must be a non-empty part of 0..{n_fft} of unsigned profiles")
        if worth_it(n, n_fft, k1 - k0) and samples.ndim == 2:
            return _window_of_bins(samples, w, f0_hz, frequency_step_hz, n_fft, k0, k1, centred, keep_samples,
                                   guarded, workers, rows_out)
    lead = 1 if guarded else 0
    shape = (*samples.shape[:-1], n_fft + (3 if guarded else 0))
    m = (n - 1) // 2 if centred else 0
    rows = _output_rows(shape, rows_out, guarded, np.zeros)
    if rows_out is not None:
        # All but the samples' bins, written below: the guards, and the zero padding the last FFT filled.
        rows[:, :lead] = 0
        rows[:, lead + n - m:lead + n_fft - m] = 0
        rows[:, lead + n_fft:] = 0
    buf = rows[..., lead:lead + n_fft]
    # Centring multiplies bin k by exp(2j pi m k / n_fft), which is the same as moving sample i to
    # position i - m (mod n_fft) before the FFT; so the samples are written there and no pass over the
    # (oversampled, 16 times larger) spectrum is needed. m is the middle sample, rounded down for even n.
    np.multiply(samples[..., m:], w[m:], out=buf[..., :n - m], casting="same_kind")
    if m:
        np.multiply(samples[..., :m], w[:m], out=buf[..., n_fft - m:], casting="same_kind")
    windowed = None
    if keep_samples:
        windowed = np.empty((*samples.shape[:-1], n), np.complex64)
        windowed[..., m:] = buf[..., :n - m]
        windowed[..., :m] = buf[..., n_fft - m:]
    # In place where scipy can (it can for a complex64 view): the profiles are written once, where the
    # kernel reads them. numpy's FFT would work in double precision. scipy's FFT, without scipy.fft's
    # import (imaging/pocketfft.py).
    spectrum = fft_in_place(buf, workers)
    if signed:
        spectrum = np.fft.fftshift(spectrum, axes=-1)  # a roll, as scipy.fft.fftshift
    if not np.shares_memory(spectrum, rows):
        buf[...] = spectrum
    step = range_bin_spacing_m(n_fft, frequency_step_hz)
    start = -(n_fft // 2) * step if signed else 0.0
    carrier = f0_hz + m * frequency_step_hz
    return RangeProfiles(
        data=buf,
        range_start_m=start,
        range_step_m=step,
        carrier_hz=carrier,
        f0_hz=f0_hz,
        frequency_step_hz=frequency_step_hz,
        samples=windowed,
        rows=rows if guarded else None,
        bandwidth_hz=n * frequency_step_hz,
    )


def _output_rows(shape: tuple, rows_out: np.ndarray | None, guarded: bool, new) -> np.ndarray:
    """The complex64 rows of ``shape`` to write profiles into: ``rows_out`` where given (checked: only guarded
    profiles, as the kernel reads them, go into a caller's buffer), else a new array made by ``new``
    (``np.zeros`` where the caller relies on the zero padding, ``np.empty`` where it writes every element)."""
    if rows_out is None:
        return new(shape, np.complex64)
    if not guarded or rows_out.shape != shape or rows_out.dtype != np.complex64 or not rows_out.flags.c_contiguous:
        raise ValueError(f"rows_out must be C-contiguous complex64 {shape} for guarded profiles, got "
                         f"{rows_out.dtype} {rows_out.shape}")
    return rows_out


def _window_of_bins(samples, w, f0_hz, frequency_step_hz, n_fft, k0, k1, centred, keep_samples, guarded, workers,
                    rows_out) -> RangeProfiles:
    """``range_compress`` of bins k0 .. k1 - 1 only (its ``bins``), by ``imaging.range_window.zoom_spectrum``."""
    n_p, n = samples.shape
    n_bins = k1 - k0
    shape = (n_p, n_bins + (3 if guarded else 0))
    rows = _output_rows(shape, rows_out, guarded, np.empty)
    lead = 1 if guarded else 0
    if guarded:  # the kernel's guard bins: one zero before each profile, two after
        rows[:, :1] = 0
        rows[:, -2:] = 0
    m = (n - 1) // 2 if centred else 0
    data = zoom_spectrum(samples, w, m, n_fft, k0, rows[:, lead:lead + n_bins], workers)
    step = range_bin_spacing_m(n_fft, frequency_step_hz)
    return RangeProfiles(
        data=data,
        range_start_m=k0 * step,
        range_step_m=step,
        carrier_hz=f0_hz + m * frequency_step_hz,
        f0_hz=f0_hz,
        frequency_step_hz=frequency_step_hz,
        samples=np.multiply(samples, w, dtype=np.complex64) if keep_samples else None,
        rows=rows if guarded else None,
        bandwidth_hz=n * frequency_step_hz,
    )
