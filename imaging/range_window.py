"""A window of a zero-padded range profile, computed alone: the bins an image needs, by a chirp-z transform.

Range compression zero-pads each chirp's n samples to n_fft (16 n by default) and takes the FFT; an image
only reads the bins between its nearest and farthest pixel's two-way range (on the benchmark case about a
sixth of them). Those M bins are the n samples' DTFT at spacing 1 / n_fft from bin k0 on, which Bluestein's
chirp-z transform gives with two FFTs of a length L >= n + M - 1 (its chirp's FFT is made once per window):
writing j t = (j^2 + t^2 - (j - t)^2) / 2,

    X[k0 + j] = sum_t y_t e^{-2 pi i (k0 + j) t / n_fft}
              = e^{-pi i j^2 / n_fft} sum_t [y_t e^{-2 pi i k0 t / n_fft} e^{-pi i t^2 / n_fft}] e^{pi i (j - t)^2 / n_fft}

a convolution with a chirp between two multiplications (t = i - m: the samples centred as
``range_compress`` centres them). The window, its normalisation and 1 / L are folded into the two
multiplications. It is cheaper than the full FFT while 2 L <= 0.75 n_fft (``worth_it``, measured:
benchmarks/range_window.py); the bins agree with the full FFT's to about -130 dB of the peak (float32).
"""

from __future__ import annotations

import functools

import numpy as np

from imaging.pocketfft import fft_in_place, ifft_in_place

#: Rows transformed at a time: a chunk's buffer (512 x L complex64, about 3 MB at L = 735) stays in cache
#: between the passes over it.
CHUNK_ROWS = 512


def fast_length(n: int) -> int:
    """The smallest length >= n whose prime factors are all 2, 3, 5, 7 or 11 (pocketfft's fast sizes)."""
    while True:
        rest = n
        for p in (2, 3, 5, 7, 11):
            while rest % p == 0:
                rest //= p
        if rest == 1:
            return n
        n += 1


def worth_it(n: int, n_fft: int, n_bins: int) -> bool:
    """Whether ``n_bins`` bins of an ``n_fft``-point profile of ``n`` samples are cheaper by the chirp-z
    transform than by the full FFT: two FFTs of L = ``fast_length(n + n_bins - 1)`` and three elementwise
    passes against one FFT of n_fft. Measured on 175 samples at 16x (benchmarks/range_window.py, ``chirp_costs``):
    1.4x faster at a quarter of the bins (2 L = 0.63 n_fft), even at 0.35 (2 L = 0.83 n_fft), so 2 L <= 0.75 n_fft."""
    return 0 < n_bins and 4 * 2 * fast_length(n + n_bins - 1) <= 3 * n_fft


@functools.lru_cache(maxsize=16)
def _plan(weights: bytes, n: int, n_fft: int, k0: int, n_bins: int, m: int):
    """(L, pre [n], chirp spectrum [L], post [n_bins]) complex64 for the window's normalised weights (float32
    bytes), computed in float64 with the squares reduced modulo 2 n_fft (exact phases for any k0)."""
    w = np.frombuffer(weights, np.float32).astype(np.float64)
    length = fast_length(n + n_bins - 1)
    two_n = 2 * n_fft
    t = np.arange(n, dtype=np.int64) - m
    pre = w * np.exp(-1j * np.pi * ((2 * k0 * t + t * t) % two_n) / n_fft)
    d = np.arange(n_bins + n - 1, dtype=np.int64) - (n - 1) + m  # j - t over every pair
    chirp = np.zeros(length, np.complex128)
    chirp[:d.size] = np.exp(1j * np.pi * ((d * d) % two_n) / n_fft)
    j = np.arange(n_bins, dtype=np.int64)
    post = np.exp(-1j * np.pi * ((j * j) % two_n) / n_fft) / length  # 1 / L: the inverse FFT is unnormalised
    return length, pre.astype(np.complex64), np.fft.fft(chirp).astype(np.complex64), post.astype(np.complex64)


def zoom_spectrum(samples: np.ndarray, weights: np.ndarray, m: int, n_fft: int, k0: int, out: np.ndarray,
                  workers: int | None = None) -> np.ndarray:
    """Bins k0 .. k0 + M - 1 of the n_fft-point FFT of the weighted samples, centred on sample m.

    Parameters
    ----------
    samples : ndarray, complex, shape (P, n)
        Fast-time samples.
    weights : ndarray, float32, shape (n,)
        The range window, normalised (``range_compress``'s).
    m : int
        The sample at fast-time zero (``range_compress``'s centring; 0 for none).
    n_fft : int
        The zero-padded length whose bins are wanted; bin spacing 1 / n_fft cycles a sample.
    k0 : int
        The first bin wanted (any integer: bins are periodic in n_fft).
    out : ndarray, complex64, shape (P, M)
        Where to write the M bins (may be a strided view, such as the kernel's guarded rows).
    workers : int, optional
        FFT threads (scipy.fft's ``workers``).

    Returns
    -------
    ndarray
        ``out``: the same numbers as ``fft(weighted samples, n_fft)[..., k0:k0 + M]`` to float32 precision.
    """
    n_p, n = samples.shape
    n_bins = out.shape[1]
    length, pre, chirp, post = _plan(np.ascontiguousarray(weights, np.float32).tobytes(), n, n_fft, k0 % n_fft,
                                     n_bins, m)
    buf = np.empty((min(CHUNK_ROWS, n_p), length), np.complex64)
    for p0 in range(0, n_p, CHUNK_ROWS):
        c = min(CHUNK_ROWS, n_p - p0)
        b = buf[:c]
        np.multiply(samples[p0:p0 + c], pre, out=b[:, :n], casting="same_kind")
        b[:, n:] = 0
        fft_in_place(b, workers)
        b *= chirp
        ifft_in_place(b, workers)
        np.multiply(b[:, n - 1:n - 1 + n_bins], post, out=out[p0:p0 + c])
    return out


def two_way_range_bounds_m(tx_m: np.ndarray, rx_m: np.ndarray, box_lo_m, box_hi_m) -> tuple[float, float]:
    """Bounds on the two-way range |tx - g| + |rx - g| over every point g of an axis-aligned box and every
    antenna pair: the sums of each antenna's nearest and farthest distance to the box (metres; tx_m and
    rx_m [P, 3]). The bounds hold, they need not be tight (each antenna's extremes may be at different
    corners)."""
    lo, hi = np.asarray(box_lo_m, np.float64), np.asarray(box_hi_m, np.float64)

    def near_far(a):
        near = np.linalg.norm(a - np.clip(a, lo, hi), axis=1)
        far = np.linalg.norm(np.maximum(np.abs(a - lo), np.abs(a - hi)), axis=1)
        return near, far

    tx_near, tx_far = near_far(np.asarray(tx_m, np.float64))
    rx_near, rx_far = near_far(np.asarray(rx_m, np.float64))
    return float((tx_near + rx_near).min()), float((tx_far + rx_far).max())


#: Bins kept beyond the bounds each side: the linear interpolation's neighbour and the kernel's float32
#: rounding of a pixel's position (a small fraction of a bin) with room to spare.
MARGIN_BINS = 4


def needed_bins(range_lo_m: float, range_hi_m: float, range_step_m: float, n_fft: int) -> tuple[int, int]:
    """The bins [k0, k1) of an unsigned profile (bin i at two-way range i * range_step_m) that hold the
    ranges from range_lo_m to range_hi_m with ``MARGIN_BINS`` each side, within 0 .. n_fft."""
    k0 = max(0, int(np.floor(range_lo_m / range_step_m)) - MARGIN_BINS)
    k1 = min(n_fft, int(np.ceil(range_hi_m / range_step_m)) + 1 + MARGIN_BINS)
    return k0, max(k0, k1)
