"""A frame imaged through its own polar beams ("polar" algorithm): a few beam signals formed from the
frame's raw chirps, range-compressed, then read once per pixel.

A frame is a tiny aperture (its chirps' motion and the virtual array: a few centimetres), so its image
varies slowly across angle. Backprojection of profile p at pixel g sums the fast-time samples x_p[n] with
exp(-j k_n R_p(g)) (k_n = 2 pi f_n / c, R_p the two-way range; see docs/signal-model.md). With the frame's
phase centre c, R_p(g) = 2 |g - c| + Delta_p(g), so the frame's image at g is one range profile placed at c:
the compression of Z_g[n] = sum_p x_p[n] exp(-j k_n Delta_p(g)). Delta_p depends on g through the pixel's
angle alpha (u . (g - c) / |g - c|, u the horizontal axis across the look) and, near the aperture, its
inverse range; so Z is formed on a few beams alpha_a (spaced by the frame aperture's angular band,
oversampled ``OVERSAMPLE_ANGLE`` times) and interpolated across them at each pixel, and Delta_p's range
dependence is a line in eps = 1/r - 1/r_mid between the footprint's nearest and farthest range:

    Delta_p(r, alpha_a) = mean_a + slope_a * eps + d_pa + s_pa * eps        (mean over p pulled out)

The means are exact at the pixel (a range shift and its phase); the rest is a Taylor series to first
order, exp(-j k_n (d + s eps)) ~ exp(-j k_c d) (1 - j dk d) - j k_n s eps exp(-j k_c d), with dk = k_n - k_c
(the band's half-width times the frame's few millimetres of path difference: a few tenths of a radian; the
second-order terms, (dk d)^2 / 2 and the cross term, changed the soak scene's map by under 0.05 dB of its
-57 dB error, so they are left out). So the frame costs one matrix product (profiles x samples x 3 weights
per beam), 2 range compressions per beam instead of one per profile, and per pixel ``TAPS`` beams x 2
signals, instead of every profile at every pixel: on the soak's scene 20 beams for 256 profiles, the map
within -55 dB of every frame at presum 1 by the direct kernel, as the direct map at presum 4 is (-58 dB;
``benchmarks/stripmap_polar.py``). The pixels' angles need a side-looking footprint (|alpha| < 1).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math

import numba
import numpy as np

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.ffbp_interpolation import interpolation_table
from imaging.core.windows import get_window
from imaging.pocketfft import fft_in_place
from imaging.range_compression import range_bin_spacing_m
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)

#: exp(j x) by ``_cis``: x reduced to |y| <= pi / 4 by the nearest multiple of pi / 2 (pi / 2 in two parts,
#: Cody and Waite's, so q pi / 2 is exact for |q| < 2^20), then fdlibm's polynomials for sin and cos there
#: (``__kernel_sin``, ``__kernel_cos``: under 1e-16 on that interval).
_TWO_OVER_PI = 0.63661977236758134308
_PIO2_HI = 1.57079632673412561417e+00  # pi / 2's first 33 bits
_PIO2_LO = 6.07710050650619224932e-11  # pi / 2 less _PIO2_HI
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11

#: Beams per Nyquist interval of the frame's angular band, and interpolation taps across them: the
#: least-squares kernel's worst error for a tone in that band is -48 dB (``interpolation_error(6, 2)``).
OVERSAMPLE_ANGLE = 2.0
TAPS = 6


@dataclasses.dataclass
class FrameBeams:
    """A frame's beam signals and where they sit.

    ``signals`` [2 x beams, bins], the beams' main signals then their slope signals, are range-compressed
    (two-way range ``range_step_m`` per bin) and carry each beam's exp(-j k ``shift_m``); a pixel at range
    r, angle alpha from ``centre_m`` reads them at 2 r + ``shift_m`` + ``shift_slope_m`` x eps, eps = 1/r -
    ``inv_r_mid``, takes main - j k eps slope and restores exp(-j k (2 r + ``shift_slope_m`` eps)). Beam a
    lies at angle ``alpha0`` + a ``dalpha``; only those from ``first_beam`` on are held (row a -
    ``first_beam``): the ones below it no pixel reads."""

    centre_m: np.ndarray  # [3]
    axis: np.ndarray  # [3], horizontal, across the look
    alpha0: float
    dalpha: float
    inv_r_mid: float
    k_rad_per_m: float  # at the carrier (the centred sweep's middle frequency)
    range_step_m: float
    signals: np.ndarray  # complex64 [2 x beams, bins]
    shift_m: np.ndarray  # float64 [beams]
    shift_slope_m: np.ndarray  # float64 [beams]
    first_beam: int = 0


def plane_points(centre: np.ndarray, axis: np.ndarray, normal: np.ndarray, r: np.ndarray, alpha: np.ndarray,
                 z_m: float) -> np.ndarray:
    """Points [..., 3] on the plane z_m at range r from ``centre`` and angle alpha (u component of the unit
    direction) on the ``normal`` side."""
    h = z_m - centre[2]
    b = np.sqrt(np.maximum(r * r * (1 - alpha * alpha) - h * h, 0.0))
    return centre + (alpha * r)[..., None] * axis + b[..., None] * normal + np.array([0.0, 0.0, h])


def frame_beams(samples: np.ndarray, tx_m: np.ndarray, rx_m: np.ndarray, pts: np.ndarray, f0_hz: float,
                frequency_step_hz: float, window: str, oversample: int, look_xy: np.ndarray) -> FrameBeams:
    """The beams of one frame over the pixels ``pts`` [N, 3] it images.

    Parameters
    ----------
    samples : ndarray, complex, shape (P, n)
        The frame's fast-time samples, one row per profile (chirp or chirp sum, and channel).
    tx_m, rx_m : ndarray, shape (P, 3)
        Each row's TX and RX phase centre, world frame.
    window, oversample
        Range compression, as the direct path's (``imaging.range_compression.range_compress``).
    look_xy : ndarray, shape (2,)
        The frame's horizontal look direction (the pixels lie on that side).
    """
    centre, axis, _ = frame_axes(tx_m, rx_m, look_xy)
    extent = _extent(np.ascontiguousarray(pts, np.float64), centre, axis)
    return frame_beams_over(samples, tx_m, rx_m, extent, float(pts[0, 2]), f0_hz, frequency_step_hz, window, oversample,
                            look_xy)


def frame_axes(tx_m: np.ndarray, rx_m: np.ndarray, look_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A frame's phase centre, its horizontal axis across the look and its horizontal look, each [3]."""
    centre = 0.5 * (tx_m + rx_m).mean(axis=0)
    normal = np.array([look_xy[0], look_xy[1], 0.0]) / math.hypot(look_xy[0], look_xy[1])
    return centre, np.array([-normal[1], normal[0], 0.0]), normal


def frame_beams_over(samples: np.ndarray, tx_m: np.ndarray, rx_m: np.ndarray, extent: tuple, z_m: float, f0_hz: float,
                     frequency_step_hz: float, window: str, oversample: int, look_xy: np.ndarray,
                     axes: tuple | None = None) -> FrameBeams:
    """As :func:`frame_beams`, for pixels on the plane ``z_m`` within ``extent`` (nearest and farthest range,
    smallest and largest alpha: ``_extent``'s, or ``masked_extent``'s); ``axes``: ``frame_axes`` of the same
    antennas and look, where the caller has them."""
    n = samples.shape[1]
    centre, axis, normal = axes if axes is not None else frame_axes(tx_m, rx_m, look_xy)
    m = (n - 1) // 2  # range_compress's centring: the carrier is the middle sample's frequency
    carrier_hz = f0_hz + m * frequency_step_hz
    k_c = 2 * math.pi * carrier_hz / SPEED_OF_LIGHT_MPS
    k_max = 2 * math.pi * (f0_hz + (n - 1) * frequency_step_hz) / SPEED_OF_LIGHT_MPS
    r_near, r_far, a_min, a_max = extent
    # The angular band: the phase of profile p changes with alpha by k (its two antennas' offset along u).
    reach = np.abs(((tx_m - centre) + (rx_m - centre)) @ axis).max()
    dalpha = math.pi / (k_max * max(reach, 1e-4) * OVERSAMPLE_ANGLE)
    margin = TAPS // 2 + 1
    lo = a_min - margin * dalpha
    beams = int(math.ceil((a_max + margin * dalpha - lo) / dalpha)) + 1
    # Only the beams a pixel reads: a pixel at fa = (alpha - lo) / dalpha reads floor(fa) - TAPS // 2 + 1 to
    # floor(fa) + TAPS // 2, and fa runs from ``margin`` to (a_max - lo) / dalpha, each end a rounding either
    # way (the kernels' fastmath); the grid's margin kept a beam below and one or two above that nobody read
    # (3 of the soak's 20 beams: their weights, product rows and range compressions).
    first = margin - TAPS // 2
    last = min(beams, int(math.floor((a_max - lo) / dalpha)) + TAPS // 2 + 2)
    alpha_a = np.clip(lo + dalpha * np.arange(beams), -0.999, 0.999)[first:last]
    beams = alpha_a.size
    r_far = max(r_far, r_near + 1e-3)
    inv_mid = 0.5 * (1 / r_near + 1 / r_far)
    weights = np.empty((samples.shape[0], 3 * beams), np.complex64)
    shift, shift_slope = np.empty(beams), np.empty(beams)
    _weights(weights, shift, shift_slope, np.ascontiguousarray(tx_m, np.float64), np.ascontiguousarray(rx_m, np.float64),
             centre, axis, normal, z_m, alpha_a, r_near, r_far, inv_mid, k_c)
    with one_blas_thread():  # OpenBLAS's own threads cost 15x the CPU of one on this small product
        # [3 beams, n]: the one product over the frame's chirps, a beam's weights a row, as the compression
        # takes them (samples.T @ weights, its transpose, cost 10 % more and a transposing copy after it)
        z = weights.T @ samples
    dk = (2 * math.pi * frequency_step_hz / SPEED_OF_LIGHT_MPS * (np.arange(n) - m)).astype(np.float32)
    # each beam's mean range shift as its phase exp(-j k shift), here once per beam, not per pixel and tap
    turn = np.exp(-1j * k_c * shift).astype(np.complex64)
    # Range compression as ``range_compress`` does it (window, zero padding to oversample x n, centred on sample
    # m, the FFT in place), the same numbers; the beam signals written windowed straight into the padded rows.
    n_fft = oversample * n
    rows = np.zeros((2 * beams, n_fft), np.complex64)
    _beam_signals(rows, z, dk, turn, np.float32(k_c), _window(window, n), m)
    fft_in_place(rows)
    return FrameBeams(centre, axis, float(lo), float(dalpha), inv_mid, k_c, range_bin_spacing_m(n_fft, frequency_step_hz),
                      rows, shift, shift_slope, first)


@functools.lru_cache(maxsize=8)
def _window(name: str, n: int) -> np.ndarray:
    """``range_compress``'s window: normalised to unit sum, float32 (read-only, shared)."""
    w = get_window(name, n)
    w = (w / w.sum()).astype(np.float32)
    w.flags.writeable = False
    return w


@contextlib.contextmanager
def one_blas_thread():
    """numpy's OpenBLAS on one thread (this thread only) for the block: on a loaded two-core machine its
    threads spin for a product this small (7.7 against 0.55 ms of CPU for the frame's). Without the
    library's per-thread setting (another BLAS), nothing changes."""
    setter = _blas_thread_setter()
    previous = setter(1) if setter is not None else None
    try:
        yield
    finally:
        if setter is not None and previous is not None and previous > 0:
            setter(previous)


@functools.lru_cache(maxsize=1)
def _blas_thread_setter():
    import ctypes
    import glob
    import os

    for path in glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs", "libscipy_openblas*")):
        try:
            f = ctypes.CDLL(path).openblas_set_num_threads_local
        except (OSError, AttributeError):
            continue
        f.restype, f.argtypes = ctypes.c_int, [ctypes.c_int]
        return f
    return None


def masked_extent(beams_centre: np.ndarray, axis: np.ndarray, x: np.ndarray, y: np.ndarray, z_m: float,
                  masks: np.ndarray) -> tuple:
    """``_extent`` of the pixels the masks take: x [T, nx], y [T, ny] the tiles' pixel centres, ``masks`` [T, ny,
    nx]; the same numbers as ``_extent`` of their pixel list, without making it."""
    return _masked_extent(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64), float(z_m),
                          np.ascontiguousarray(masks), beams_centre, axis)


def beams_at_masked(beams: FrameBeams, x: np.ndarray, y: np.ndarray, z_m: float, masks: np.ndarray) -> np.ndarray:
    """``beams_at_points`` of the pixels the masks take, in the order of their pixel list (tile by tile, row by
    row): x [T, nx], y [T, ny], ``masks`` [T, ny, nx]; complex128 [pixels taken]. The same numbers, without
    the list of points (a live frame's pixel lists were as much of its CPU as reading the beams,
    benchmarks/stripmap_capacity.py); to float rounding, as the kernels are compiled with fastmath."""
    masks = np.ascontiguousarray(masks)
    out = np.zeros(int(np.count_nonzero(masks)), np.complex128)
    _beams_at_masked(out, np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64), float(z_m), masks,
                     beams.centre_m, beams.axis, beams.alpha0, beams.dalpha, beams.inv_r_mid, beams.k_rad_per_m,
                     beams.range_step_m, beams.signals, beams.shift_m, beams.shift_slope_m, beams.first_beam, _table())
    return out


def beams_at_points(beams: FrameBeams, pts: np.ndarray) -> np.ndarray:
    """The frame's image at ``pts`` [N, 3] from its beams, complex128 [N]."""
    out = np.zeros(pts.shape[0], np.complex128)
    _beams_at_points(out, np.ascontiguousarray(pts, np.float64), beams.centre_m, beams.axis, beams.alpha0,
                     beams.dalpha, beams.inv_r_mid, beams.k_rad_per_m, beams.range_step_m, beams.signals, beams.shift_m,
                     beams.shift_slope_m, beams.first_beam, _table())
    return out


_TABLE = []


@numba.njit(cache=True, nogil=True)
def _extent(pts, c, u):
    """Nearest and farthest range from ``c`` and the smallest and largest alpha of the points."""
    r_lo, r_hi, a_lo, a_hi = np.inf, 0.0, np.inf, -np.inf
    for i in range(pts.shape[0]):
        dx, dy, dz = pts[i, 0] - c[0], pts[i, 1] - c[1], pts[i, 2] - c[2]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        a = (dx * u[0] + dy * u[1] + dz * u[2]) / r
        r_lo, r_hi, a_lo, a_hi = min(r_lo, r), max(r_hi, r), min(a_lo, a), max(a_hi, a)
    return r_lo, r_hi, a_lo, a_hi


@numba.njit(cache=True, nogil=True)
def _masked_extent(x, y, z, masks, c, u):
    """``_extent`` of the masked pixels (min and max do not depend on the order)."""
    r_lo, r_hi, a_lo, a_hi = np.inf, 0.0, np.inf, -np.inf
    for t in range(masks.shape[0]):
        for i in range(masks.shape[1]):
            for j in range(masks.shape[2]):
                if masks[t, i, j]:
                    dx, dy, dz = x[t, j] - c[0], y[t, i] - c[1], z - c[2]
                    r = math.sqrt(dx * dx + dy * dy + dz * dz)
                    a = (dx * u[0] + dy * u[1] + dz * u[2]) / r
                    r_lo, r_hi, a_lo, a_hi = min(r_lo, r), max(r_hi, r), min(a_lo, a), max(a_hi, a)
    return r_lo, r_hi, a_lo, a_hi


@numba.njit(cache=True, nogil=True)
def _weights(out, shift, shift_slope, tx, rx, c, u, nrm, z, alpha, r_near, r_far, inv_mid, k):
    """The product's weights [P, 3 beams] (see the module's docstring) and each beam's mean shift and slope.

    Delta_p at the nearest and farthest range on beam a's line of the plane; their mean and secant slope in
    eps, less the means over p; the weights exp(-j k d) x (1, d, s)."""
    p_n, nb = tx.shape[0], alpha.size
    base = np.empty((p_n, nb))
    slope = np.empty((p_n, nb))
    h = z - c[2]
    eps_near, eps_far = 1.0 / r_near - inv_mid, 1.0 / r_far - inv_mid
    for a in range(nb):
        for which in range(2):
            r = r_near if which == 0 else r_far
            b = math.sqrt(max(r * r * (1.0 - alpha[a] * alpha[a]) - h * h, 0.0))
            g0 = c[0] + alpha[a] * r * u[0] + b * nrm[0]
            g1 = c[1] + alpha[a] * r * u[1] + b * nrm[1]
            g2 = c[2] + h
            one = 2.0 * math.sqrt((g0 - c[0]) ** 2 + (g1 - c[1]) ** 2 + h * h)
            d_tx = 0.0
            for p in range(p_n):
                # a TX's distance once for the RX channels after it (a frame's rows: each chirp group's RXs)
                if p == 0 or tx[p, 0] != tx[p - 1, 0] or tx[p, 1] != tx[p - 1, 1] or tx[p, 2] != tx[p - 1, 2]:
                    d_tx = math.sqrt((g0 - tx[p, 0]) ** 2 + (g1 - tx[p, 1]) ** 2 + (g2 - tx[p, 2]) ** 2)
                d = (d_tx
                     + math.sqrt((g0 - rx[p, 0]) ** 2 + (g1 - rx[p, 1]) ** 2 + (g2 - rx[p, 2]) ** 2) - one)
                if which == 0:
                    base[p, a] = d
                else:
                    slope[p, a] = (base[p, a] - d) / (eps_near - eps_far)
                    base[p, a] = 0.5 * (base[p, a] + d)
        mb, ms = 0.0, 0.0
        for p in range(p_n):
            mb += base[p, a]
            ms += slope[p, a]
        shift[a], shift_slope[a] = mb / p_n, ms / p_n
        for p in range(p_n):
            d = base[p, a] - shift[a]
            s = slope[p, a] - shift_slope[a]
            e = _cis(-k * d)
            out[p, a] = e
            out[p, nb + a] = e * d
            out[p, 2 * nb + a] = e * s


@numba.njit(cache=True, nogil=True)
def _beam_signals(out, z, dk, turn, k_c, w, m):
    """The beams' main and slope signals from the product z [3 x beams, n] (main, d and s weights' rows; see
    the module's docstring), as numpy's complex64 arithmetic gave them to float32 rounding, in one pass instead
    of six numpy temporaries and a transposing copy: main = (z_1 - j dk z_d) turn, slope = (1 + dk / k_c) z_s
    turn (k_n / k_c: the slope's phase is k_n s eps). Each sample i is written times the window w[i] into
    ``out`` [2 x beams, n_fft] (zeros elsewhere) at i - m modulo n_fft, where ``range_compress`` puts it: its
    centring, and its product with the window, float32 by float32 as numpy's complex64 by float32."""
    nb, n = turn.size, z.shape[1]
    n_fft = out.shape[1]
    for a in range(nb):
        t = turn[a]
        for i in range(n):
            d = dk[i]
            zd = z[nb + a, i]
            main = complex(z[a, i].real + d * zd.imag, z[a, i].imag - d * zd.real)
            v = np.complex64(main * t)
            e = np.complex64((np.float32(1.0) + d / k_c) * z[2 * nb + a, i] * t)
            j = i - m if i >= m else n_fft - m + i
            out[a, j] = complex(v.real * w[i], v.imag * w[i])
            out[nb + a, j] = complex(e.real * w[i], e.imag * w[i])


def _table() -> np.ndarray:
    if not _TABLE:
        _TABLE.append(interpolation_table(TAPS, OVERSAMPLE_ANGLE))
    return _TABLE[0]


@numba.njit(fastmath=True, cache=True, nogil=True)
def _beams_at_points(out, pts, c, u, alpha0, dalpha, inv_r_mid, k, step, signals, shift, shift_slope, first, table):
    """Each pixel: ``TAPS`` beams around its angle, each read linearly at the pixel's range (its own shift),
    the phase exp(-j k (2 r + shift_slope eps)) restored once (the beams' exp(-j k shift) is in ``signals``;
    shift_slope changes by about a milliradian of phase across the taps, so the middle tap's stands for all)."""
    inv_step = 1.0 / step
    shift_bins, slope_bins = shift * inv_step, shift_slope * inv_step
    for i in range(pts.shape[0]):
        out[i] = _beam_pixel(pts[i, 0], pts[i, 1], pts[i, 2], c, u, alpha0, dalpha, inv_r_mid, k, inv_step, signals,
                             shift_bins, slope_bins, shift_slope, first, table)


@numba.njit(fastmath=True, cache=True, nogil=True)
def _beams_at_masked(out, x, y, z, masks, c, u, alpha0, dalpha, inv_r_mid, k, step, signals, shift, shift_slope, first,
                     table):
    """``_beams_at_points`` over the masked pixels of tiles, in their pixel list's order."""
    inv_step = 1.0 / step
    shift_bins, slope_bins = shift * inv_step, shift_slope * inv_step
    n = 0
    for t in range(masks.shape[0]):
        for i in range(masks.shape[1]):
            for j in range(masks.shape[2]):
                if masks[t, i, j]:
                    out[n] = _beam_pixel(x[t, j], y[t, i], z, c, u, alpha0, dalpha, inv_r_mid, k, inv_step, signals,
                                         shift_bins, slope_bins, shift_slope, first, table)
                    n += 1


@numba.njit(fastmath=True, cache=True, nogil=True, inline="always")
def _beam_pixel(px, py, pz, c, u, alpha0, dalpha, inv_r_mid, k, inv_step, signals, shift_bins, slope_bins, shift_slope,
                first, table):
    """One pixel's value (0 outside the beams held: beam a is row a - ``first``)."""
    taps = table.shape[1]
    nf = table.shape[0] - 1
    nb, bins = signals.shape[0] // 2, signals.shape[1]
    dx, dy, dz = px - c[0], py - c[1], pz - c[2]
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    fa = ((dx * u[0] + dy * u[1] + dz * u[2]) / r - alpha0) / dalpha
    ia = math.floor(fa)
    mid = int(ia) - first
    j0 = mid - taps // 2 + 1
    if j0 < 0 or j0 + taps > nb:
        return 0j
    w = table[int((fa - ia) * nf + 0.5)]
    eps = 1.0 / r - inv_r_mid
    gain = np.float32(-k * eps)  # the slope signal's factor is -j k eps
    base = 2.0 * r * inv_step
    re, im = np.float32(0.0), np.float32(0.0)
    for t in range(taps):
        a = j0 + t
        pos = base + shift_bins[a] + slope_bins[a] * eps
        b = int(pos)
        if b < 0 or b + 1 >= bins:
            continue
        f = np.float32(pos - b)
        g = np.float32(1.0) - f
        wt = w[t]
        m = signals[a, b] * g + signals[a, b + 1] * f
        s = signals[nb + a, b] * g + signals[nb + a, b + 1] * f
        re += wt * (m.real - gain * s.imag)
        im += wt * (m.imag + gain * s.real)
    main = complex(re, im)
    return main * _cis(-k * (2.0 * r + shift_slope[mid] * eps))


@numba.njit(cache=True, nogil=True, inline="always")
def _cis(x):
    """exp(j x) = cos x + j sin x, complex128, within 3e-16 of numpy's for |x| < 1e5 (tested; a pixel's phase is
    about 1.7e4 rad at 8 m of two-way range); inlined into a fastmath kernel, the compiler may fold the two-part
    reduction, about 1e-12 rad at such a phase. Half the pixels' CPU was libm's cos and sin, each with its own
    reduction of the argument; here one reduction serves both, and the quadrant is chosen without a branch
    (the pixels' quadrants are as good as random)."""
    q = math.floor(x * _TWO_OVER_PI + 0.5)
    y = (x - q * _PIO2_HI) - q * _PIO2_LO
    z = y * y
    s = y + y * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    n = int(q) & 3
    # quadrant n: (cos, sin) of x is (c, s), (-s, c), (-c, -s), (s, -c)
    cos_x = -s if n & 1 else c
    sin_x = c if n & 1 else s
    sign = 1.0 - (n & 2)
    return complex(sign * cos_x, sign * sin_x)
