"""Tapering windows for range and cross-range compression, and their half-power widths."""

from __future__ import annotations

import functools

import numpy as np

#: Windows sarbot knows, by the name used in configuration and on the command line.
WINDOWS = ("rectangular", "hann", "hamming", "taylor")

#: The half-power widths docs/conventions.md fixes as convention (in bins of 1/duration).
NOMINAL_WIDTH_FACTOR = {"rectangular": 0.88448, "hann": 1.4381}


def get_window(name: str, n: int) -> np.ndarray:
    """Periodic window of ``n`` samples, float64, shape (n,).

    Periodic (DFT-even) windows are used so that an n-sample window spans exactly n samples of
    bandwidth: the half-power width is then factor / (n * step) with the factors of docs/conventions.md.
    Taylor: 4 nearly constant side lobes at -35 dB.
    """
    if name == "rectangular":
        return np.ones(n)
    # Hann and Hamming written out: importing scipy.signal costs almost a second in every process.
    phase = 2.0 * np.pi * np.arange(n) / n
    if name == "hann":
        return 0.5 - 0.5 * np.cos(phase)
    if name == "hamming":
        return 0.54 - 0.46 * np.cos(phase)
    if name == "taylor":
        import scipy.signal.windows

        return scipy.signal.windows.taylor(n, nbar=4, sll=35, norm=False, sym=False)
    raise ValueError(f"unknown window {name!r}; known: {', '.join(WINDOWS)}")


def half_power_width(values: np.ndarray, spacing: float = 1.0, peak_index: int | None = None) -> float:
    """Width of the main lobe at -3.0 dB (power ratio 10**-0.3) of a sampled amplitude or power cut.

    Parameters
    ----------
    values : ndarray, shape (n,)
        Complex or real amplitude samples (magnitude is taken; it is squared to power).
    spacing : float
        Sample spacing, in the unit the width is wanted in.
    peak_index : int, optional
        Index of the peak to measure; the maximum by default.

    Returns
    -------
    float
        Distance between the two -3.0 dB crossings, found by linear interpolation of power between
        samples; ``nan`` if a crossing lies outside the cut.
    """
    power = np.abs(np.asarray(values)) ** 2
    k = int(np.argmax(power)) if peak_index is None else int(peak_index)
    level = power[k] * 10.0 ** -0.3
    right = _crossing(power, k, level, +1)
    left = _crossing(power, k, level, -1)
    return (right - left) * spacing


def _crossing(power: np.ndarray, k: int, level: float, step: int) -> float:
    i = k
    while 0 <= i + step < power.size and power[i + step] > level:
        i += step
    j = i + step
    if not 0 <= j < power.size:
        return float("nan")
    frac = (power[i] - level) / (power[i] - power[j])
    return i + step * frac


def window_at(name: str, u: np.ndarray) -> np.ndarray:
    """The window as a function of position across the span it tapers: ``u`` from 0 (one end) to 1 (the
    other), float64 of ``u``'s shape; 0 outside [0, 1].

    For a slow-time (aperture) taper, whose samples are the phase centres along the track, not a regular
    grid. It is the same window as ``get_window`` (its half-power width factor holds for a span of length
    L in units of 1/L), interpolated from 4097 samples.
    """
    u = np.asarray(u, float)
    table = _symmetric_table(name)
    return np.interp(u, np.linspace(0.0, 1.0, table.size), table, left=0.0, right=0.0)


@functools.cache
def _symmetric_table(name: str) -> np.ndarray:
    w = get_window(name, 4096)
    return np.append(w, w[0])  # the periodic window closed at its far end: symmetric over [0, 1]


@functools.cache
def window_width_factor(name: str) -> float:
    """Half-power width of the window's spectrum in units of 1/(n * step), computed numerically.

    For "rectangular" and "hann" this reproduces docs/conventions.md's 0.88448 and 1.4381 (checked in the tests).
    """
    n = 1024
    spectrum = np.fft.fft(get_window(name, n), 64 * n)
    cut = np.fft.fftshift(spectrum)
    return half_power_width(cut, spacing=n / (64 * n))
