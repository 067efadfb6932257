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
of the Hessian of |.|, whose fourth derivative is at most 3 / |w|^3). The gradient e is then folded into the
series' numerator (2 (c - m) + |c - m| e).d + d.d, within ``fold_bound_m``: one series per pixel and nothing
else. ``midpoint_form`` decides per (block, profile): folded where both bounds together are within
MIDPOINT_PHASE_RAD of phase, else e.d added per pixel where delta's bound alone is, else the two series, one
per antenna. For a monostatic pair (TX at RX, as TX 0 and RX 0 of the default array) delta is zero.

Numba caches a kernel by its own file's time stamp, not by these helpers' (inlined into it); the cache folder
is therefore keyed by all of imaging's sources (``imaging.jit_cache``), so editing this module recompiles them.
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
def _midpoint_scales(inv_m):
    """``_series_scales`` of the midpoint 1 / inv_m metres away, the range doubled (2 |g - m| - 2 |c - m|) in
    the first scale: ``_series_offset`` then gives both antennas' offset but for delta's."""
    return (np.float32(2.0 * inv_m), np.float32(inv_m * inv_m), np.float32(_G[0]), np.float32(_G[1]),
            np.float32(_G[2]), np.float32(_G[3]), np.float32(_G[4]), np.float32(_G[5]))


@numba.njit(inline="always", fastmath=True)
def _series_offset(num, sc):
    """|u + d| - |u| from num = 2 u.d + d.d by g's series (see ``_range_offsets``); ``sc`` from ``_series_scales``."""
    t = num * sc[1]
    return (num * sc[0]) * (sc[2] + t * (sc[3] + t * (sc[4] + t * (sc[5] + t * (sc[6] + t * sc[7])))))


def midpoint_remainder_bound_m(m_n: float, radius: float, half_baseline_m: float) -> float:
    """Bound on |delta(c + d) - delta(c) - grad delta(c).d| for |d| <= radius, the block centre c m_n metres
    from the antennas' midpoint, half_baseline_m half their distance (see the module's docstring); inf where
    the ball around c comes within b of m."""
    near = m_n - radius - half_baseline_m
    return 1.5 * radius ** 2 * half_baseline_m ** 2 / near ** 3 if near > 0.0 else math.inf


def fold_bound_m(m_n: float, radius: float, e_n: float) -> tuple[float, float]:
    """Bound on the error of folding delta's linear term e.d into the series' numerator (``midpoint_form``):
    |2 sqrt(A^2 + |c - m| e.d) - 2 A - e.d| for A = |g - m|, |g - c| <= radius, |e| <= e_n; and the fraction
    x = |c - m| |e| r / (|c - m| - r)^2, which the bound needs at most 1/2.

    2 A (sqrt(1 + x) - 1) - e.d with x = |c - m| e.d / A^2: its first-order part is e.d (|c - m| / A - 1),
    at most |e| r^2 / (|c - m| - r); the rest at most 2 A x^2 / 2^(3/2) for |x| <= 1/2."""
    near = m_n - radius
    x = m_n * e_n * radius / near ** 2 if near > 0.0 else math.inf
    return e_n * radius ** 2 / near * (1.0 + 0.71 * m_n ** 2 * e_n / near ** 2) if x <= 0.5 else math.inf, x


#: Largest |e| (1-norm) folded: the series then covers a radius 1 % larger (its numerator reaches
#: |c - m| |e| r further), so one least distance per block serves every profile (``series_min_distance``).
FOLD_GRADIENT_MAX = 0.02


@numba.njit(inline="always")
def series_min_distance(radius):
    """The least distance (to 1e-7 of it, from above) at which ``series_applies`` holds for this radius: it
    holds for every distance beyond (t_max and the error both fall with it). Once per block, so that each
    profile compares instead of evaluating the condition."""
    if radius <= 0.0:
        return 0.0
    lo, hi = radius, 8.0 * radius
    while not series_applies(hi, radius):
        lo, hi = hi, 2.0 * hi
    while hi - lo > 1e-7 * hi:
        mid = 0.5 * (lo + hi)
        if series_applies(mid, radius):
            hi = mid
        else:
            lo = mid
    return hi


@numba.njit(inline="always")
def midpoint_form(ua0, ua1, ua2, ua, ub0, ub1, ub2, ub, radius, half_baseline, u_series, tol_m):
    """How a profile whose TX no other profile shares is ranged over a block: (form, c0, c1, c2, e0, e1, e2,
    1 / |c - m|) from the float64 vectors u_a, u_b from its TX and RX to the block's centre c, half the
    antennas' distance, ``series_min_distance(radius (1 + FOLD_GRADIENT_MAX / 2))`` and the error allowed
    (MIDPOINT_PHASE_RAD / k, metres).

    form 1: one series on num = c.d + d.d, doubled (``_midpoint_scales``), with c = 2 (c - m) + |c - m| e:
    delta's gradient e at c folded into the numerator; form 2: the series on c = 2 (c - m) plus e.d per
    pixel; form 0: neither within tol_m (the two series instead). The bounds (``midpoint_remainder_bound_m``,
    ``fold_bound_m``) are multiplied out over near^3, near = |c - m| - r - b (below both of theirs), so that
    no division decides; |e| is taken as its 1-norm (no square root)."""
    um0, um1, um2 = 0.5 * (ua0 + ub0), 0.5 * (ua1 + ub1), 0.5 * (ua2 + ub2)
    um = math.sqrt(um0 * um0 + um1 * um1 + um2 * um2)
    near = um - radius - half_baseline
    if not (um >= u_series and near > 0.0):
        return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    inv_a, inv_b, inv_m = 1.0 / ua, 1.0 / ub, 1.0 / um
    e0 = ua0 * inv_a + ub0 * inv_b - 2.0 * um0 * inv_m
    e1 = ua1 * inv_a + ub1 * inv_b - 2.0 * um1 * inv_m
    e2 = ua2 * inv_a + ub2 * inv_b - 2.0 * um2 * inv_m
    e_n = abs(e0) + abs(e1) + abs(e2)
    r2, near2 = radius * radius, near * near
    allowed = tol_m * near2 * near
    delta = 1.5 * r2 * half_baseline * half_baseline  # times 1 / near^3: midpoint_remainder_bound_m
    if (e_n <= FOLD_GRADIENT_MAX and 2.0 * um * e_n * radius <= near2
            and delta + r2 * e_n * (near2 + 0.71 * um * um * e_n) <= allowed):  # + fold_bound_m
        return 1, 2.0 * um0 + um * e0, 2.0 * um1 + um * e1, 2.0 * um2 + um * e2, 0.0, 0.0, 0.0, inv_m
    if delta <= allowed:
        return 2, 2.0 * um0, 2.0 * um1, 2.0 * um2, e0, e1, e2, inv_m
    return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


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
