"""A pixel's range offset from its block's centre, in float32, for the block kernel (``imaging.backprojection``).

For a float64 vector u from an antenna to the centre c of a block of pixels and a pixel's small float32
offset d from c,

    |u + d| - |u| = (2 u.d + d.d) / (|u + d| + |u|) = |u| t g(t),  t = (2 u.d + d.d) / |u|^2,

with g(t) = (sqrt(1 + t) - 1) / t. Where the block is small against its distance from the antenna (almost
always), g's Taylor series replaces the square root and the division: multiply-adds only
(``series_applies``, ``_series_offset``); elsewhere the quotient itself (``_range_offsets``).

A profile whose TX no other profile shares (a one-antenna pass) has two antennas to range per pixel. With m
their midpoint and b half their distance,

    |g - tx| + |g - rx| = 2 |g - m| + delta(g),

where delta is even in the half-baseline, of order b^2 / |g - m|, and bends slowly: over a block it is its
value at the centre plus its gradient there (both float64, per block and profile) times d, to within

    |remainder| <= 3/2 r^2 b^2 / (|c - m| - r - b)^3        (``midpoint_remainder_bound_m``)

for pixels within r of c (half r^2 times the Hessian of delta, the second difference along the half-baseline
of the Hessian of |.|, whose fourth derivative is at most 3 / |w|^3). Where that is within
MIDPOINT_PHASE_RAD of phase (``midpoint_applies``) one series per pixel on m does (``_midpoint_scales``),
else the two series per antenna. For a monostatic pair (TX at RX, as TX 0 and RX 0 of the default array)
delta is zero.

Numba caches a kernel by its own file's time stamp, not by these helpers' (inlined into it): after editing
this module, delete the ``imaging/__pycache__`` entries of the kernels that use it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.numba_target import prefer_full_width_vectors

# Before this module's first numba decorator, which sets up numba's target: full-width vectors on AVX-512
# (imaging/numba_target.py), as for the kernels these helpers are inlined into.
prefer_full_width_vectors()

#: Taylor coefficients of g(t) = (sqrt(1 + t) - 1) / t, and the first one left out (|t|^6's in sqrt(1 + t)).
_G = (0.5, -1.0 / 8, 1.0 / 16, -5.0 / 128, 7.0 / 256, -21.0 / 1024)
_G_NEXT = 33.0 / 2048
#: The series' truncation error allowed, metres of range (1.6e-6 rad at 77 GHz).
SERIES_TOLERANCE_M = 1e-9
#: The midpoint form's linearisation error allowed, radians of phase (-100 dB; a tenth of the float32
#: kernel's rounding budget, imaging.backprojection.PHASE_ROUNDING_RAD): 6.2e-9 m at 77 GHz.
MIDPOINT_PHASE_RAD = 1e-5


@numba.njit(inline="always")
def series_applies(u_n, radius):
    """Whether g's series (see ``_range_offsets``) is within SERIES_TOLERANCE_M for every point within
    ``radius`` of a block centre ``u_n`` metres from the antenna (|t| <= (2 |u| r + r^2) / |u|^2; the
    error is about |u| 33/2048 |t|^7, alternating terms; |t| < 0.5 keeps the series converging fast)."""
    t_max = (2.0 * u_n * radius + radius * radius) / (u_n * u_n)
    return t_max < 0.5 and u_n * _G_NEXT * t_max ** 7 <= SERIES_TOLERANCE_M


@numba.njit(inline="always")
def _series_scales(u_n):
    """Per (block, antenna): 1/|u|, 1/|u|^2 and g's coefficients, float32, for ``_series_offset``."""
    return (np.float32(1.0 / u_n), np.float32(1.0 / (u_n * u_n)), np.float32(_G[0]), np.float32(_G[1]),
            np.float32(_G[2]), np.float32(_G[3]), np.float32(_G[4]), np.float32(_G[5]))


@numba.njit(inline="always")
def _midpoint_scales(m_n):
    """``_series_scales`` of the midpoint m_n metres away, the range doubled (2 |g - m| - 2 |c - m|) in the
    first scale: ``_series_offset`` then gives both antennas' offset but for delta's."""
    return (np.float32(2.0 / m_n), np.float32(1.0 / (m_n * m_n)), np.float32(_G[0]), np.float32(_G[1]),
            np.float32(_G[2]), np.float32(_G[3]), np.float32(_G[4]), np.float32(_G[5]))


@numba.njit(inline="always", fastmath=True)
def _series_offset(num, sc):
    """|u + d| - |u| from num = 2 u.d + d.d by g's series (see ``_range_offsets``); ``sc`` from ``_series_scales``."""
    t = num * sc[1]
    return (num * sc[0]) * (sc[2] + t * (sc[3] + t * (sc[4] + t * (sc[5] + t * (sc[6] + t * sc[7])))))


@numba.njit(inline="always")
def _midpoint_remainder_m(m_n, radius, half_baseline_m):
    """The bound of ``midpoint_remainder_bound_m`` and the distance it divides by (inf-free: the kernel runs
    with fastmath, which assumes no infinities)."""
    near = m_n - radius - half_baseline_m
    return 1.5 * radius * radius * half_baseline_m * half_baseline_m / (near * near * near) if near > 0.0 else 0.0, near


def midpoint_remainder_bound_m(m_n: float, radius: float, half_baseline_m: float) -> float:
    """Bound on |delta(c + d) - delta(c) - grad delta(c).d| for |d| <= radius, the block centre c m_n metres
    from the antennas' midpoint, half_baseline_m half their distance (see the module's docstring); inf where
    the ball around c comes within b of m."""
    bound, near = _midpoint_remainder_m(m_n, radius, half_baseline_m)
    return bound if near > 0.0 else math.inf


@numba.njit(inline="always")
def midpoint_applies(m_n, radius, half_baseline_sq, k):
    """Whether one series on the midpoint m_n metres from a block's centre plus delta's linear term is within
    MIDPOINT_PHASE_RAD (at k radians per metre of range) for every point within ``radius``, and the series
    within SERIES_TOLERANCE_M of |g - m| - |c - m| (twice that, as the two series', for the pair).
    ``half_baseline_sq``: the squared half-distance of the antennas (its square root taken here, and only
    where it is not zero: fastmath's square root of 0 can be NaN)."""
    half_baseline = math.sqrt(half_baseline_sq) if half_baseline_sq > 0.0 else 0.0
    bound, near = _midpoint_remainder_m(m_n, radius, half_baseline)
    return near > 0.0 and series_applies(m_n, radius) and k * bound <= MIDPOINT_PHASE_RAD


@numba.njit(inline="always")
def fold_bound_m(m_n, radius, e_n):
    """Bound on the error of folding delta's linear term e.d into the series' numerator (``midpoint_form``):
    |2 sqrt(A^2 + |c - m| e.d) - 2 A - e.d| for A = |g - m|, |g - c| <= radius, |e| <= e_n, and the
    fraction x = |c - m| |e| r / (|c - m| - r)^2 that bound needs at most 1/2 (else 1.0, for no bound).

    2 A (sqrt(1 + x) - 1) - e.d with x = |c - m| e.d / A^2: its first-order part is e.d (|c - m| / A - 1),
    at most |e| r^2 / (|c - m| - r); the rest at most 2 A x^2 / 2^(3/2) for |x| <= 1/2."""
    near = m_n - radius
    x = m_n * e_n * radius / (near * near) if near > 0.0 else 1.0
    return e_n * radius * radius / near * (1.0 + 0.71 * m_n * m_n * e_n / (near * near)) if x <= 0.5 else 0.0, x


@numba.njit(inline="always")
def midpoint_form(ua0, ua1, ua2, ua, ub0, ub1, ub2, ub, radius, k):
    """How a profile whose TX no other profile shares is ranged over a block: (form, c0, c1, c2, e0, e1, e2,
    |c - m|) from the float64 vectors u_a, u_b from its TX and RX to the block's centre c.

    form 1: one series on num = c.d + d.d, doubled (``_midpoint_scales``), with c = 2 (c - m) + |c - m| e:
    delta's gradient e at c folded into the numerator (``fold_bound_m``); form 2: the series on
    c = 2 (c - m) plus e.d per pixel; form 0: neither within MIDPOINT_PHASE_RAD (the two series instead)."""
    um0, um1, um2 = 0.5 * (ua0 + ub0), 0.5 * (ua1 + ub1), 0.5 * (ua2 + ub2)
    um = math.sqrt(um0 * um0 + um1 * um1 + um2 * um2)
    half_baseline_sq = 0.25 * ((ua0 - ub0) ** 2 + (ua1 - ub1) ** 2 + (ua2 - ub2) ** 2)
    if not midpoint_applies(um, radius, half_baseline_sq, k):
        return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, um
    inv_a, inv_b, inv_m = 1.0 / ua, 1.0 / ub, 2.0 / um
    e0 = ua0 * inv_a + ub0 * inv_b - um0 * inv_m
    e1 = ua1 * inv_a + ub1 * inv_b - um1 * inv_m
    e2 = ua2 * inv_a + ub2 * inv_b - um2 * inv_m
    e_n = abs(e0) + abs(e1) + abs(e2)  # >= |e|, without a square root
    half_baseline = math.sqrt(half_baseline_sq) if half_baseline_sq > 0.0 else 0.0
    fold, x = fold_bound_m(um, radius, e_n)
    if (x <= 0.5 and k * (_midpoint_remainder_m(um, radius, half_baseline)[0] + fold) <= MIDPOINT_PHASE_RAD
            # the folded numerator reaches |c - m| |e| r further: the series' radius grows by |e| r / 2
            and series_applies(um, radius * (1.0 + 0.5 * e_n))):
        return 1, 2.0 * um0 + um * e0, 2.0 * um1 + um * e1, 2.0 * um2 + um * e2, 0.0, 0.0, 0.0, um
    return 2, 2.0 * um0, 2.0 * um1, 2.0 * um2, e0, e1, e2, um


@numba.njit(inline="always", fastmath=True)
def _range_offsets(u0, u1, u2, u_n, radius, dx, dy, dz, dd, out):
    """out[i] = |u + d_i| - |u| in float32, for the float64 vector u from an antenna to the block centre.

    With t = (2 u.d + d.d) / |u|^2, |u + d| - |u| = (2 u.d + d.d) / |u| g(t), g(t) = (sqrt(1 + t) - 1) / t:
    by g's Taylor series (11 multiply-adds, no square root or division) where every |d| <= radius keeps
    the series' error below SERIES_TOLERANCE_M, else as (2 u.d + d.d) / (|u + d| + |u|).
    """
    a0, a1, a2 = np.float32(2.0 * u0), np.float32(2.0 * u1), np.float32(2.0 * u2)
    if series_applies(u_n, radius):
        sc = _series_scales(u_n)
        for i in range(dx.size):
            out[i] = _series_offset(a0 * dx[i] + a1 * dy[i] + a2 * dz[i] + dd[i], sc)
    else:
        a_n, a_n2 = np.float32(u_n), np.float32(u_n * u_n)
        for i in range(dx.size):
            # |u + d|^2 = |u|^2 + (2 u.d + d.d): the sum's rounding only touches the denominator.
            num = a0 * dx[i] + a1 * dy[i] + a2 * dz[i] + dd[i]
            out[i] = num / (math.sqrt(a_n2 + num) + a_n)
