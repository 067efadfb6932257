"""The leaves of fast factorized backprojection (``imaging.factorized_backprojection``), a run of them in one call.

A leaf is the direct kernel's image of a short subaperture on its polar grid, demodulated (times
exp(+j k 2 r), r the range from the leaf's centre c). One numba call images a run of consecutive leaves (the
Python around one call a leaf held the GIL for much of a small leaf's time); the caller spreads runs over its
threads.

The kernel is the direct one's (``imaging.backprojection``: the same profile sampling, linear or nearest, the
same gather -- below -- and float32 phase in turns) with its geometry taken from the polar grid itself. A grid point g
lies at range r along the unit vector e from c, and a leaf's phase centres m lie within a few centimetres of c
(s = m - c), so

    |g - m| - r = (s.s - 2 r e.s) / (|g - m| + r)

is small, needed only to float32's relative precision, and its demodulated phase is k times it (the 2 k r
taken off before it is ever added). With t = (s.s - 2 r e.s) / r^2, a few hundredths, it is r t g(t) by g's
Taylor series (``imaging.backprojection._series_offset``): multiply-adds only, no square root or division,
where its error stays below SERIES_TOLERANCE_M (else the quotient itself). Per point only e, r, 1 / r and
1 / r^2 are kept (float32), per profile only s; a TX shared by consecutive profiles (the RX channels of one
chirp) is ranged once for all of them. The bin of a block's first row and the reference range's phase are
float64 per profile, as the direct kernel's block centre. Before this, the leaves ran the direct kernel's
float64 blocks (its float32 blocks, sized for a fine Cartesian grid, were slower still on a coarse polar one):
two float64 square roots and a float64 phase per backprojection, 1.2-1.5x this kernel's time on one thread.

A leaf's block of grid points spans several range rows, so each profile's gathers first touch 5-6 cache lines
of its row, lines no earlier block read (the next block lies at other ranges): each was a wait on memory, as
the rows of a leaf's 512 profiles do not stay in cache. The kernel prefetches them PREFETCH_AHEAD profiles
ahead (``imaging.core.prefetch``); benchmarks/ffbp_leaves.py times the kernel's parts.

The gather: where numba's target has AVX-512 (or AVX2) and the mode is linear, each profile's bins are gathered
as the direct kernel gathers them (``imaging.bin_gather``: 16 (8) consecutive grid points' bin pairs taken by vector
permutes from a window of 16 (8) bins, where their bins lie within it; else the scalar gather), the same values
bit for bit (tests/test_ffbp_leaves_gather.py). On the 2 m aperture every group of 16 fits (a block's points
run along a polar row, at most one row boundary a group): the leaves 1.07x on one thread, FFBP's run 1.07x on
2, on the quiet machine (benchmarks/ffbp_leaves_permute.py, docs/results/ffbp_leaves_permute.json).

Numba note: an inlined helper that is handed arrays inside a loop over points costs a reference count's
increment and decrement per point (here it made the loop 15x slower); the helpers below take and return
scalars there, and the array-taking ones run once a profile.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from imaging.backprojection import (_G, _TWO_PI, BLOCK, _gather_pairs_accumulate, _gather_planar_accumulate,
                                    guarded_rows, series_applies)
from imaging.bin_gather import PERMUTE_GATHER
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.prefetch import prefetch
from imaging.range_compression import RangeProfiles
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)

#: While a profile is gathered, the bins of the profile this many ahead are prefetched (1 to 8 measured alike:
#: benchmarks/ffbp_leaves.py).
PREFETCH_AHEAD = 2


@numba.njit(fastmath=True, cache=True, nogil=True)
def _polar_leaves_kernel(rows, r0, inv_dr, k, tx, rx, r_ref, linear, z, leaf_p0, leaf_p1, geometry, shape, offset,
                         out):
    """Leaf i: profiles [leaf_p0[i], leaf_p1[i]) of ``rows`` onto its polar grid (``geometry[i]`` as
    ``Subaperture.geometry``, ``shape[i]`` = (nr, na)), in blocks of BLOCK points (row-major), every profile
    over a block before the next block; its demodulated image, complex64 row-major, into
    out[offset[i]:offset[i] + nr na].

    Geometry relative to the leaf's centre c (see the module's docstring): per grid point its range r and unit
    vector e from c, per antenna its offset s from c, and |g - m| - r = (s.s - 2 r e.s) / (|g - m| + r)
    in float32, by g's series (``imaging.backprojection._series_offset``) where it converges."""
    for leaf in range(geometry.shape[0]):
        g = geometry[leaf]
        na = shape[leaf, 1]
        n = shape[leaf, 0] * na
        for g0 in range(0, n, BLOCK):
            _leaf_block(rows, r0, inv_dr, k, tx, rx, r_ref, linear, z, leaf_p0[leaf], leaf_p1[leaf], g, na, g0,
                        min(g0 + BLOCK, n) - g0, out[offset[leaf] + g0:])


@numba.njit(fastmath=True, cache=True, nogil=True)
def _leaf_block(rows, r0, inv_dr, k, tx, rx, r_ref, linear, z, p0, p1, g, na, g0, nb, out):
    """Points g0..g0+nb-1 of a leaf's grid (``g`` as ``Subaperture.geometry``, ``na`` columns): profiles p0..p1-1
    onto them, demodulated, into out[:nb]. A function of its own, not inlined: LLVM vectorised its loops
    inside the whole kernel 5-20x worse (the direct kernel's float32 blocks, run serially, show the same)."""
    hi = np.float64(rows.shape[1] - 2)  # largest position: j + 1 stays inside the trailing guard
    inv32 = np.float32(inv_dr)
    k_turns = k / _TWO_PI
    k_turns32 = np.float32(k_turns)
    h = z - g[2]
    r_min = g[7]  # the nearest row: where g's series converges most slowly
    i_first = g0 // na
    r_first = g[7] + i_first * g[8]
    ex = np.empty(nb, np.float32)
    ey = np.empty(nb, np.float32)
    ez = np.empty(nb, np.float32)
    two_r = np.empty(nb, np.float32)
    inv_r = np.empty(nb, np.float32)
    inv_r2 = np.empty(nb, np.float32)
    r_bins = np.empty(nb, np.float32)  # 2 (r - r_first) in bins: small, a fine float32 position
    for i in range(nb):
        row = (g0 + i) // na
        r = g[7] + row * g[8]
        alpha = g[9] + ((g0 + i) % na) * g[10]
        # Subaperture.plane_points: the point of the plane z at range r and cosine alpha, over r.
        b = math.sqrt(max(r * r * (1.0 - alpha * alpha) - h * h, 0.0)) / r
        ex[i] = np.float32(alpha * g[3] + b * g[5])
        ey[i] = np.float32(alpha * g[4] + b * g[6])
        ez[i] = np.float32(h / r)
        two_r[i] = np.float32(2.0 * r)
        inv_r[i] = np.float32(1.0 / r)
        inv_r2[i] = np.float32(1.0 / (r * r))
        r_bins[i] = np.float32(2.0 * (row - i_first) * g[8] * inv_dr)
    acc_re = np.zeros(nb, np.float32)
    acc_im = np.zeros(nb, np.float32)
    idx = np.empty(nb, np.uint32)
    frac = np.empty(nb, np.float32)
    turns = np.empty(nb, np.float32)
    pairs = np.empty((nb, 2), np.complex64)
    planar = np.empty((4, nb), np.float32)  # the same, planar, for the permute gather
    da = np.empty(nb, np.float32)
    c_0, c_1, c_2, c_3, c_4, c_5 = (np.float32(_G[0]), np.float32(_G[1]), np.float32(_G[2]), np.float32(_G[3]),
                                    np.float32(_G[4]), np.float32(_G[5]))
    for p in range(p0, p1):
        # The block's first row's bin and the phase in float64; per point only what its offset adds,
        # in float32.
        pos_c = (2.0 * r_first - r_ref[p] - r0) * inv_dr + 1.0
        base = np.floor(pos_c)
        frac_c = np.float32(pos_c - base)
        lo = np.float32(-base)
        top = np.float32(hi - base)
        ibase = np.int32(base)
        t_ref = -k_turns * r_ref[p]
        turns_c = np.float32(t_ref - np.floor(t_ref + 0.5))
        # A TX shared with the previous profile (the RX channels of one chirp) has the same offsets.
        if p == p0 or tx[p, 0] != tx[p - 1, 0] or tx[p, 1] != tx[p - 1, 1] or tx[p, 2] != tx[p - 1, 2]:
            _offsets_from_centre(tx[p, 0] - g[0], tx[p, 1] - g[1], tx[p, 2] - g[2], r_min, ex, ey, ez, two_r,
                                 inv_r, inv_r2, da)
        # The RX's offsets and the points' bins and phases in one pass (as the direct kernel's float32 blocks).
        s0, s1, s2 = rx[p, 0] - g[0], rx[p, 1] - g[1], rx[p, 2] - g[2]
        sb = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        b0, b1, b2, ssb = np.float32(s0), np.float32(s1), np.float32(s2), np.float32(sb * sb)
        if series_applies(r_min, sb):
            for i in range(nb):
                num = ssb - two_r[i] * (ex[i] * b0 + ey[i] * b1 + ez[i] * b2)
                t = num * inv_r2[i]
                d = da[i] + (num * inv_r[i]) * (c_0 + t * (c_1 + t * (c_2 + t * (c_3 + t * (c_4 + t * c_5)))))
                idx[i], frac[i], turns[i] = _place_polar(d, r_bins[i], frac_c, inv32, lo, top, ibase, turns_c, k_turns32, linear)
        else:
            for i in range(nb):
                num = ssb - two_r[i] * (ex[i] * b0 + ey[i] * b1 + ez[i] * b2)
                r32 = np.float32(0.5) * two_r[i]
                d = da[i] + num / (math.sqrt(r32 * r32 + num) + r32)
                idx[i], frac[i], turns[i] = _place_polar(d, r_bins[i], frac_c, inv32, lo, top, ibase, turns_c, k_turns32, linear)
        if p + PREFETCH_AHEAD < p1:
            _prefetch_bins(rows, p + PREFETCH_AHEAD, idx)
        if linear and PERMUTE_GATHER:
            _gather_planar_accumulate(rows[p], idx, frac, turns, planar, acc_re, acc_im)
        else:
            _gather_pairs_accumulate(rows[p], idx, frac, turns, pairs, acc_re, acc_im, linear)
    for i in range(nb):
        out[i] = np.complex64(complex(acc_re[i], acc_im[i]))


@numba.njit(inline="always")
def _prefetch_bins(rows, p, idx):
    """Prefetch row p's cache lines over the bins idx.min() .. idx.max() + 1 (this profile's, which a later
    profile's differ from by a fraction of a bin): a block's gathers first touch these lines, 5-6 of them a
    profile on a leaf's polar grid, each a wait on memory otherwise."""
    lo = idx[0]
    hi = idx[0]
    for i in range(idx.size):
        lo = min(lo, idx[i])
        hi = max(hi, idx[i])
    last = min(np.int64(hi) + 1, rows.shape[1] - 1)
    for j in range(np.int64(lo), last + 1, 8):  # 8 complex64 a 64-byte line
        prefetch(rows, p, j)
    prefetch(rows, p, last)


@numba.njit(inline="always", fastmath=True)
def _offsets_from_centre(s0, s1, s2, r_min, ex, ey, ez, two_r, inv_r, inv_r2, out):
    """out[i] = |g_i - m| - r_i for points g_i at range r_i along the unit vector e_i from the leaf's centre
    and an antenna m at s from it, float32: (s.s - 2 r e.s) / (|g - m| + r), by g's series where it
    converges for every point (r >= r_min)."""
    s = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    a0, a1, a2, ss = np.float32(s0), np.float32(s1), np.float32(s2), np.float32(s * s)
    if series_applies(r_min, s):
        c_0, c_1, c_2, c_3, c_4, c_5 = (np.float32(_G[0]), np.float32(_G[1]), np.float32(_G[2]),
                                        np.float32(_G[3]), np.float32(_G[4]), np.float32(_G[5]))
        for i in range(out.size):
            num = ss - two_r[i] * (ex[i] * a0 + ey[i] * a1 + ez[i] * a2)
            t = num * inv_r2[i]
            out[i] = (num * inv_r[i]) * (c_0 + t * (c_1 + t * (c_2 + t * (c_3 + t * (c_4 + t * c_5)))))
    else:
        for i in range(out.size):
            num = ss - two_r[i] * (ex[i] * a0 + ey[i] * a1 + ez[i] * a2)
            r32 = np.float32(0.5) * two_r[i]
            out[i] = num / (math.sqrt(r32 * r32 + num) + r32)


@numba.njit(inline="always", fastmath=True)
def _place_polar(d, r_bins, frac_c, inv32, lo, top, ibase, turns_c, k_turns32, linear):
    """A point's bin (index, fraction) and demodulated phase in turns from its offset ``d`` = |g - tx| + |g - rx|
    - 2 r and its bin past its block's first row's, ``r_bins``. Scalars in and out: an array handed to an
    inlined function in a loop costs a reference count's increment and decrement every iteration (the loop then
    ran 15x slower, serially compiled)."""
    lp = frac_c + r_bins + d * inv32
    lp = lp if lp > lo else lo
    lp = lp if lp < top else top
    if linear:
        fl = np.floor(lp)
        return np.uint32(ibase + np.int32(fl)), lp - fl, turns_c + k_turns32 * d
    return np.uint32(ibase + np.int32(np.floor(lp + np.float32(0.5)))), np.float32(0.0), turns_c + k_turns32 * d


def image_leaves(leaves: list, profiles: RangeProfiles, tx_m: np.ndarray, rx_m: np.ndarray,
                 reference_range_m: np.ndarray | None, first_profile: int, z_m: float, mode: str,
                 ) -> list:
    """Demodulated polar images (complex64 [nr, na] each) of consecutive leaves (``Subaperture`` s with their
    grids placed) in one call of the kernel.

    ``profiles``, ``tx_m``, ``rx_m`` and ``reference_range_m`` (or None) hold the profiles from
    ``first_profile`` on (the leaves' ``start``/``stop`` count from the whole pass's first); ``mode`` is
    "linear" or "nearest" (the direct kernel's, see ``imaging.backprojection``).
    """
    if mode not in ("linear", "nearest"):
        raise ValueError(f"leaves are imaged in mode linear or nearest, not {mode!r}")
    n_p = profiles.data.shape[0]
    tx = np.ascontiguousarray(tx_m, np.float64).reshape(-1, 3)
    rx = np.ascontiguousarray(rx_m, np.float64).reshape(-1, 3)
    r_ref = np.zeros(n_p) if reference_range_m is None else np.ascontiguousarray(reference_range_m, np.float64)
    k = 2.0 * math.pi * profiles.carrier_hz / SPEED_OF_LIGHT_MPS
    geometry = np.array([leaf.geometry for leaf in leaves]).reshape(-1, 11)
    shape = np.array([(leaf.nr, leaf.na) for leaf in leaves], np.int64).reshape(-1, 2)
    sizes = shape[:, 0] * shape[:, 1]
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    p0 = np.array([leaf.start - first_profile for leaf in leaves], np.int64)
    p1 = np.array([leaf.stop - first_profile for leaf in leaves], np.int64)
    if p0.size and (p0.min() < 0 or p1.max() > n_p):
        raise ValueError(f"leaves need profiles {p0.min() + first_profile}-{p1.max() + first_profile}; "
                         f"given {first_profile}-{first_profile + n_p}")
    out = np.empty(int(sizes.sum()), np.complex64)
    _polar_leaves_kernel(guarded_rows(profiles), profiles.range_start_m, 1.0 / profiles.range_step_m, k, tx, rx, r_ref,
                         mode == "linear", float(z_m), p0, p1, geometry, shape, offset, out)
    return [out[o:o + s].reshape(nr, na) for o, s, (nr, na) in zip(offset, sizes, shape)]


@functools.lru_cache(maxsize=1)
def load_kernel() -> None:
    """Compile (or load from numba's cache) the leaf kernel now, once a process: a live worker warms up on a
    block too small for leaves, and its first real block then stalled for the load (0.5 s on a busy
    machine), enough for the strip map to fall behind and pre-sum."""
    geometry = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.1, 0.0, 0.1]])
    _polar_leaves_kernel(np.zeros((1, 4), np.complex64), 0.0, 1.0, 1.0, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1),
                         True, 0.0, np.zeros(1, np.int64), np.ones(1, np.int64), geometry, np.ones((1, 2), np.int64),
                         np.zeros(1, np.int64), np.zeros(1, np.complex64))
