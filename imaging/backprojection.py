"""Time-domain backprojection over any set of grid points, with bistatic antennas per profile.

For every grid point g and profile p (one chirp at one RX):

    dr = |tx_p - g| + |rx_p - g| - r_ref_p
    image[g] += profile_p(dr) * exp(-j 2 pi f_c dr / c)

Positions are float64 (an image kilometres from the world origin, or a radar kilometres from its scene,
focuses as well as one near). The kernel works per block of grid points: the block's centre c and each
profile's antenna-to-centre vectors u and distances |u| are float64, computed once per (block, profile),
for a group of profiles at once, vectorised over them (``imaging.block_profiles``); per pixel, with d its small offset from c, the range differences come in float32 in the form

    |u + d| - |u| = (2 u.d + d.d) / (|u + d| + |u|)

whose every term is either small or needed only to relative precision, at twice float64's SIMD width.
Where the block is small against its distance from the antenna (almost always), that quotient is
|u| t g(t) with t = (2 u.d + d.d) / |u|^2 and g(t) = (sqrt(1 + t) - 1) / t by its Taylor series:
multiply-adds only, no square root or division per pixel (``imaging.range_offsets``). A profile whose TX
no other profile shares (a one-antenna pass) takes one such series per pixel, not two: on the midpoint of
its TX and RX, doubled, plus the linear part of what that leaves out (exact to -100 dB where a bound says
so, else the two series; see imaging/range_offsets.py).
What float32 does lose is in the pixel's range offset itself: its rounding, 2^-24 of the block's extent,
is a phase error of k times that. Blocks are therefore compact (a 2-D grid is walked in patches as long
as wide in metres, 16 x 16 points for square pixels, fewer on a coarse grid: ``patch_shape``), and a block
wider than ``PHASE_ROUNDING_RAD / (k 2^-24)`` (1 m at 77 GHz; of a scattered set) takes float64 geometry
(``_float64_block``), each block by its own extent. On the benchmark case the SER against the exact matched filter
is unchanged to 0.01 dB, near the origin and 5 km out. The float32 kernel's phase is reduced to whole turns,
with polynomials for half the angle and the double-angle formulas; a TX shared by consecutive profiles (the
RX channels of one chirp) is ranged once for all of them; each pixel's two neighbouring bins are gathered as
one 16-byte pair; and on a CPU with AVX-512 numba is told to use all 512 bits (see
``imaging.numba_target.prefer_full_width_vectors``) and the bins of 16 pixels (a 4 x 4 square of the patch)
are taken out of a two-register window by vector permutes, into planar arrays (``imaging.bin_gather``). The profile is sampled by one of three modes:

``nearest``  nearest bin of a (heavily) oversampled profile; cheapest per sample, needs a large oversampling.
``linear``   linear interpolation between bins (default; about 68 dB signal-to-error at 16x oversampling,
             12 dB more per doubling).
``exact``    the matched filter evaluated at the exact range (a DTFT over the raw samples): the gold standard,
             cost proportional to the samples per chirp.

The kernels run in parallel over blocks of grid points (or all on the calling thread: ``parallel=False``,
for callers that spread coarser work over the cores themselves); inside a block the loop runs over
profiles (one profile row stays in L1 cache) and then over the block's points (vectorised by LLVM).
"""

from __future__ import annotations

import math
import types
import warnings

import numba
import numpy as np
from numba.core.errors import NumbaPerformanceWarning

from imaging.bin_gather import PERMUTE_GATHER, _gather_accumulate, gather_planar
from imaging.block_profiles import (A_N, A_N2, B0, B1, B2, B_N, B_N2, CODE, E0, E1, E2, FORM_FOLDED, FORM_GRADIENT,
                                    FORM_MASK, FORM_RX_SERIES, FORM_TWO_SERIES, FRAC_C, IBASE, INT_TABLE_SIZE, LO,
                                    NEW_TX_OFFSETS, SB0, SB1, SV0, SV1, TABLE_PROFILES, TABLE_SIZE, TOP, TURNS_C,
                                    TX_SERIES, V0, V1, V2, block_profile_table, block_series_distances,
                                    profile_rows)
from imaging.core.constants import BACKPROJECTION_MODES, SPEED_OF_LIGHT_MPS
from imaging.numba_target import (  # noqa: F401 - compiled_target re-exported
    compiled_target, prefer_full_width_vectors, skip_extension_search)
from imaging.patches import (  # noqa: F401 - re-exported: callers walk their grids as the kernel does
    BLOCK, PATCH, PATCH_SIDE_MAX_M, SUB_PATCH, max_block_extent_m, patch_order, patch_shape)
from imaging.range_compression import RangeProfiles
from imaging.range_offsets import (  # noqa: F401 - _G, SERIES_TOLERANCE_M, midpoint_form and series_applies re-exported
    _G, MIDPOINT_PHASE_RAD, SERIES_TOLERANCE_M, _series_offset, midpoint_form, series_applies)

# Before any kernel compiles: 512-bit vectors where the CPU has AVX-512 (see imaging/numba_target.py).
prefer_full_width_vectors()
skip_extension_search()  # and no search of every installed distribution for numba extensions


MODES = BACKPROJECTION_MODES
#: The float32 kernel's budget for the phase error of rounding a pixel's range offset (-80 dB).
PHASE_ROUNDING_RAD = 1e-4
PROFILE_CHUNK = 256  # profiles per parallel sweep over the grid (their rows stay in L2/L3)

_TWO_PI = 2.0 * math.pi


@numba.njit(inline="always", fastmath=True)
def _cos_sin(phase):
    """(cos, sin) of a float64 phase of any size, to float32 accuracy (~1e-7).

    Pure arithmetic, no branches or table look-ups, so that LLVM vectorises the pixel loop: reduce to
    half the angle in [-pi/2, pi/2] (float64, exact enough kilometres out), Taylor polynomials in float32,
    then the double-angle formulas.
    """
    turns = phase * (1.0 / _TWO_PI)
    turns = turns - np.floor(turns + 0.5)
    y = np.float32(turns * math.pi)
    y2 = y * y
    sy = y * (np.float32(1.0) + y2 * (np.float32(-1.0 / 6) + y2 * (np.float32(1.0 / 120) + y2 * (
        np.float32(-1.0 / 5040) + y2 * (np.float32(1.0 / 362880) + y2 * np.float32(-1.0 / 39916800))))))
    cy = np.float32(1.0) + y2 * (np.float32(-0.5) + y2 * (np.float32(1.0 / 24) + y2 * (np.float32(-1.0 / 720) + y2 * (
        np.float32(1.0 / 40320) + y2 * (np.float32(-1.0 / 3628800) + y2 * np.float32(1.0 / 479001600))))))
    return cy * cy - sy * sy, np.float32(2.0) * sy * cy


#: Least-squares (near-minimax) coefficients of sin(pi y) (odd, degree 7) and cos(pi y) (even, degree 8) on
#: |y| <= 1/2: errors 6e-7 and 9e-8, so 3e-6 at most for the angle after the double-angle step.
_SIN_PI = (3.1415820364977014, -5.167143349808762, 2.5419041841694723, -0.5546496042867805)
_COS_PI = (0.9999999535337868, -4.934792869002285, 4.058412154164911, -1.3318819051181183, 0.2197006919966666)


@numba.njit(inline="always", fastmath=True)
def _cos_sin_turns(t):
    """(cos, sin) of 2 pi t for a float32 t in turns, to 3e-6 plus t's own float32 rounding (|t| 2^-24 turns).

    Fifteen vector operations, no branches: the nearest whole turn taken off (|y| <= 1/2), sin and cos of
    pi y (half the angle) by polynomials, then the double-angle formulas -- cheaper than reducing to half
    turns and restoring a sign (the float64 kernel's ``_cos_sin`` reduces that way).
    Errors below 1e-5 are 100 dB under the image: the linear interpolation's own error is 68 dB down.
    """
    y = t - np.float32(np.rint(t))
    y2 = y * y
    s = y * (np.float32(_SIN_PI[0]) + y2 * (np.float32(_SIN_PI[1]) + y2 * (np.float32(_SIN_PI[2]) + y2 * np.float32(_SIN_PI[3]))))
    c = np.float32(_COS_PI[0]) + y2 * (np.float32(_COS_PI[1]) + y2 * (np.float32(_COS_PI[2]) + y2 * (
        np.float32(_COS_PI[3]) + y2 * np.float32(_COS_PI[4]))))
    s2 = s + s
    return np.float32(1.0) - s2 * s, s2 * c


@numba.njit(inline="always", fastmath=True)
def _place(i, ddr, place, idx, frac, pixel_turns):
    """Pixel i's bin (idx, frac) and phase in turns from its range offset ``ddr`` to the block centre, whose
    bin and phase ``place`` holds: (frac_c, 1 / bin, lo, top, ibase, turns_c, k in turns, linear)."""
    frac_c, inv32, lo, top, ibase, turns_c, k_turns32, linear = place
    # Position relative to the centre's bin (+1 guard bin in base); clamped onto the guard bins.
    lp = frac_c + ddr * inv32
    lp = lp if lp > lo else lo
    lp = lp if lp < top else top
    if linear:
        fl = np.floor(lp)
        idx[i] = np.uint32(ibase + np.int32(fl))
        frac[i] = lp - fl
    else:
        idx[i] = np.uint32(ibase + np.int32(np.floor(lp + np.float32(0.5))))
    pixel_turns[i] = turns_c + k_turns32 * ddr


@numba.njit(inline="always", fastmath=True)
def _gather_planar_accumulate(row, idx, frac, turns, planar, acc_re, acc_im):
    """``_gather_pairs_accumulate``, linear, where the CPU has AVX2 or AVX-512: each pixel's two neighbouring bins
    into planar [4, nb] float32 (a.re, a.im, b.re, b.im), by vector permutes where 8 or 16 pixels' bins lie close
    together (imaging/bin_gather.py), then the same interpolation and accumulation of the same values."""
    gather_planar(row, idx, planar)
    for i in range(idx.size):
        c, s = _cos_sin_turns(turns[i])
        t = frac[i]
        vr = planar[0, i] + t * (planar[2, i] - planar[0, i])
        vi = planar[1, i] + t * (planar[3, i] - planar[1, i])
        acc_re[i] += vr * c + vi * s
        acc_im[i] += vi * c - vr * s


@numba.njit(inline="always", fastmath=True)
def _gather_pairs_accumulate(row, idx, frac, turns, pairs, acc_re, acc_im, linear):
    """The second and third passes of a (block, profile) of the float32 kernel: gather each pixel's two
    neighbouring bins side by side into ``pairs`` [nb, 2] (one 16-byte load and store per pixel; scalar,
    LLVM will not vectorise a gather here), then interpolate and accumulate value * exp(-j 2 pi turns)
    (vectorised; the sin and cos are made here, from one stored phase, rather than stored and loaded)."""
    nb = idx.size
    if linear:
        for i in range(nb):
            j = idx[i]
            pairs[i, 0] = row[j]
            pairs[i, 1] = row[j + np.uint32(1)]
        for i in range(nb):
            c, s = _cos_sin_turns(turns[i])
            t = frac[i]
            a = pairs[i, 0]
            b = pairs[i, 1]
            vr = a.real + t * (b.real - a.real)
            vi = a.imag + t * (b.imag - a.imag)
            acc_re[i] += vr * c + vi * s
            acc_im[i] += vi * c - vr * s
    else:
        for i in range(nb):
            pairs[i, 0] = row[idx[i]]
        for i in range(nb):
            c, s = _cos_sin_turns(turns[i])
            a = pairs[i, 0]
            acc_re[i] += a.real * c + a.imag * s
            acc_im[i] += a.imag * c - a.real * s


@numba.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _bp_interp_blocks(rows, p0, p1, r0, inv_dr, k, tx, rx, r_ref, gx, gy, gz, linear, max_extent_m, block, out):
    """Profiles p0..p1-1 of rows [P, n_bins + 3] (complex64, one zero guard bin before, two after) onto the
    points (gx, gy, gz), added to out, in parallel over blocks of ``block`` consecutive points: with the
    block-relative float32 geometry of the module's docstring where the block is no wider than
    ``max_extent_m`` (PHASE_ROUNDING_RAD / (k 2^-24)), else in float64 (``_float64_block``). Each block's
    per-profile scalars come from one vectorised pass over the profiles (imaging/block_profiles.py)."""
    n_g = gx.size
    hi = np.float64(rows.shape[1] - 2)
    n_blocks = (n_g + block - 1) // block
    inv32 = np.float32(inv_dr)
    k_turns32 = np.float32(k / _TWO_PI)
    midpoint_tol_m = MIDPOINT_PHASE_RAD / k
    groups = profile_rows(tx, rx, r_ref, p0, p1)  # of TABLE_PROFILES profiles
    for blk in numba.prange(n_blocks):
        g0 = blk * block
        nb = min(g0 + block, n_g) - g0
        acc_re = np.zeros(nb, np.float32)
        acc_im = np.zeros(nb, np.float32)
        idx = np.empty(nb, np.uint32)
        frac = np.empty(nb, np.float32)
        pixel_turns = np.empty(nb, np.float32)  # each pixel's phase, in turns
        pairs = np.empty((nb, 2), np.complex64)
        planar = np.empty((4, nb), np.float32)  # the same, planar, for the permute gather
        da = np.empty(nb, np.float32)
        x_lo, x_hi = gx[g0:g0 + nb].min(), gx[g0:g0 + nb].max()
        y_lo, y_hi = gy[g0:g0 + nb].min(), gy[g0:g0 + nb].max()
        z_lo, z_hi = gz[g0:g0 + nb].min(), gz[g0:g0 + nb].max()
        if max(x_hi - x_lo, y_hi - y_lo, z_hi - z_lo) > max_extent_m:
            _float64_block(rows, p0, p1, r0, inv_dr, k, tx, rx, r_ref, gx[g0:g0 + nb], gy[g0:g0 + nb], gz[g0:g0 + nb],
                           linear, acc_re, acc_im)
            for i in range(nb):
                out[g0 + i] += complex(acc_re[i], acc_im[i])
            continue
        cx, cy, cz = 0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi), 0.5 * (z_lo + z_hi)
        dx = np.empty(nb, np.float32)
        dy = np.empty(nb, np.float32)
        dz = np.empty(nb, np.float32)
        dd = np.empty(nb, np.float32)
        for i in range(nb):
            dx[i] = np.float32(gx[g0 + i] - cx)
            dy[i] = np.float32(gy[g0 + i] - cy)
            dz[i] = np.float32(gz[g0 + i] - cz)
            dd[i] = dx[i] * dx[i] + dy[i] * dy[i] + dz[i] * dz[i]
        radius = math.sqrt(np.float64(dd.max()))
        table = np.empty(TABLE_SIZE, np.float32)
        ints = np.empty(INT_TABLE_SIZE, np.int32)
        u_one, u_mid = block_series_distances(radius)
        for g in range(groups.shape[0]):
            q0 = p0 + g * TABLE_PROFILES
            n_q = min(TABLE_PROFILES, p1 - q0)
            block_profile_table(cx, cy, cz, radius, u_one, u_mid, groups[g], n_q, r0, inv_dr, hi, k, midpoint_tol_m, table,
                                ints)
            for j in range(n_q):
                # ``linear`` as a constant in each call: LLVM left the branch in the pixel loops, computing
                # both modes' bins and storing one under a mask (5 of 31 instructions of the folded loop).
                if linear:
                    _place_block_profile(table, j, ints[IBASE + j], ints[CODE + j], inv32, k_turns32, True, dx, dy, dz,
                                         dd, da, idx, frac, pixel_turns)
                else:
                    _place_block_profile(table, j, ints[IBASE + j], ints[CODE + j], inv32, k_turns32, False, dx, dy, dz,
                                         dd, da, idx, frac, pixel_turns)
                if linear and PERMUTE_GATHER:
                    _gather_planar_accumulate(rows[q0 + j], idx, frac, pixel_turns, planar, acc_re, acc_im)
                else:
                    _gather_pairs_accumulate(rows[q0 + j], idx, frac, pixel_turns, pairs, acc_re, acc_im, linear)
        for i in range(nb):
            out[g0 + i] += complex(acc_re[i], acc_im[i])


@numba.njit(inline="always", fastmath=True)
def _place_block_profile(t, j, ibase, code, inv32, k_turns32, linear, dx, dy, dz, dd, da, idx, frac, pixel_turns):
    """The first pass of a (block, profile): each pixel's range offset from the block centre in the form
    ``code`` says, with profile j's coefficients in ``t`` (block_profile_table's table), then its bin
    and phase (``_place``). ``da`` holds the TX's offsets, computed where NEW_TX_OFFSETS says and kept for
    the profiles that share the TX."""
    place = (t[FRAC_C + j], inv32, t[LO + j], t[TOP + j], ibase, t[TURNS_C + j], k_turns32, linear)
    form = code & FORM_MASK
    nb = dx.size
    v0, v1, v2 = t[V0 + j], t[V1 + j], t[V2 + j]
    b0, b1, b2 = t[B0 + j], t[B1 + j], t[B2 + j]
    sv = (t[SV0 + j], t[SV1 + j], np.float32(_G[0]), np.float32(_G[1]), np.float32(_G[2]), np.float32(_G[3]),
          np.float32(_G[4]), np.float32(_G[5]))
    sb = (t[SB0 + j], t[SB1 + j], np.float32(_G[0]), np.float32(_G[1]), np.float32(_G[2]), np.float32(_G[3]),
          np.float32(_G[4]), np.float32(_G[5]))
    if form == FORM_FOLDED:
        # One series per pixel on the TX-RX midpoint, doubled, delta's gradient folded into its
        # numerator; delta(c) is in the centre's range (see imaging/range_offsets.py).
        for i in range(nb):
            _place(i, _series_offset(v0 * dx[i] + v1 * dy[i] + v2 * dz[i] + dd[i], sv), place, idx, frac, pixel_turns)
    elif form == FORM_GRADIENT:  # the same with delta's gradient term per pixel, where folding it would cost accuracy
        f0, f1, f2 = t[E0 + j], t[E1 + j], t[E2 + j]
        for i in range(nb):
            num_m = v0 * dx[i] + v1 * dy[i] + v2 * dz[i] + dd[i]
            _place(i, _series_offset(num_m, sv) + (f0 * dx[i] + f1 * dy[i] + f2 * dz[i]), place, idx, frac,
                   pixel_turns)
    elif form == FORM_TWO_SERIES:
        # Both antennas in one pass where delta bends too much for the midpoint form, the TX's offsets not stored.
        for i in range(nb):
            num_a = v0 * dx[i] + v1 * dy[i] + v2 * dz[i] + dd[i]
            num_b = b0 * dx[i] + b1 * dy[i] + b2 * dz[i] + dd[i]
            _place(i, _series_offset(num_a, sv) + _series_offset(num_b, sb), place, idx, frac, pixel_turns)
    else:
        # A TX shared with the previous profile (the RX channels of one chirp) has the same offsets.
        if code & NEW_TX_OFFSETS:
            if code & TX_SERIES:
                for i in range(nb):
                    da[i] = _series_offset(v0 * dx[i] + v1 * dy[i] + v2 * dz[i] + dd[i], sv)
            else:
                a_n, a_n2 = t[A_N + j], t[A_N2 + j]
                for i in range(nb):
                    # |u + d|^2 = |u|^2 + (2 u.d + d.d): the sum's rounding only touches the denominator.
                    num = v0 * dx[i] + v1 * dy[i] + v2 * dz[i] + dd[i]
                    da[i] = num / (math.sqrt(a_n2 + num) + a_n)
        if form == FORM_RX_SERIES:
            for i in range(nb):
                num_b = b0 * dx[i] + b1 * dy[i] + b2 * dz[i] + dd[i]
                _place(i, da[i] + _series_offset(num_b, sb), place, idx, frac, pixel_turns)
        else:
            b_n, b_n2 = t[B_N + j], t[B_N2 + j]
            for i in range(nb):
                num_b = b0 * dx[i] + b1 * dy[i] + b2 * dz[i] + dd[i]
                _place(i, da[i] + num_b / (math.sqrt(b_n2 + num_b) + b_n), place, idx, frac, pixel_turns)


@numba.njit(inline="always", fastmath=True)
def _float64_block(rows, p0, p1, r0, inv_dr, k, tx, rx, r_ref, bx, by, bz, linear, acc_re, acc_im):
    """Profiles p0..p1-1 onto the points (bx, by, bz) of one block, float64 geometry and phase, into
    (acc_re, acc_im): for a block too wide for the float32 geometry (a scattered set of points).

    Three passes per profile, because LLVM will not vectorise a loop that gathers on this CPU: geometry
    and phase (vectorised), the gather (scalar, loads and stores only), interpolation and accumulation
    (vectorised).
    """
    nb = bx.size
    hi = np.float64(rows.shape[1] - 2)  # largest position: j + 1 stays inside the trailing guard
    idx = np.empty(nb, np.uint32)  # unsigned: no negative-index wrap-around code in the gather
    frac = np.empty(nb, np.float32)
    cos_ = np.empty(nb, np.float32)
    sin_ = np.empty(nb, np.float32)
    v0 = np.empty(nb, np.complex64)
    v1 = np.empty(nb, np.complex64)
    for p in range(p0, p1):
        # ``linear`` as a constant in each call: a run-time branch inside the loop had LLVM store the bins of
        # both modes under masks (``vpmaskmovd``, slow on AMD's cores).
        if linear:
            _float64_place(bx, by, bz, tx, rx, r_ref, p, r0, inv_dr, hi, k, True, idx, frac, cos_, sin_)
        else:
            _float64_place(bx, by, bz, tx, rx, r_ref, p, r0, inv_dr, hi, k, False, idx, frac, cos_, sin_)
        _gather_accumulate(rows[p], idx, frac, cos_, sin_, v0, v1, acc_re, acc_im, linear)


@numba.njit(inline="always", fastmath=True)
def _float64_place(bx, by, bz, tx, rx, r_ref, p, r0, inv_dr, hi, k, linear, idx, frac, cos_, sin_):
    """``_float64_block``'s first pass for profile p: each point's bin (idx, frac: clamped onto the guard bins,
    at most ``hi``) and the cos and sin of its phase (float64 geometry)."""
    tx0, tx1, tx2 = tx[p, 0], tx[p, 1], tx[p, 2]
    rx0, rx1, rx2 = rx[p, 0], rx[p, 1], rx[p, 2]
    ref = r_ref[p]
    for i in range(bx.size):
        a0 = bx[i] - tx0
        a1 = by[i] - tx1
        a2 = bz[i] - tx2
        b0 = bx[i] - rx0
        b1 = by[i] - rx1
        b2 = bz[i] - rx2
        dr = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) + math.sqrt(b0 * b0 + b1 * b1 + b2 * b2) - ref
        # +1: the leading guard bin; points outside the range axis land on zero guard bins.
        pos = (dr - r0) * inv_dr + 1.0
        pos = pos if pos > 0.0 else 0.0
        pos = pos if pos < hi else hi
        if linear:
            fl = np.floor(pos)
            idx[i] = np.uint32(fl)
            frac[i] = np.float32(pos - fl)
        else:
            idx[i] = np.uint32(pos + 0.5)
        c, s = _cos_sin(k * dr)
        cos_[i] = c
        sin_[i] = s


@numba.njit(parallel=True, fastmath=False, cache=True, nogil=True)
def _bp_exact(samples, f0, fstep, tx, rx, r_ref, gx, gy, gz, out):
    n_p, n_s = samples.shape
    n_g = gx.size
    kc = _TWO_PI / SPEED_OF_LIGHT_MPS
    for g in numba.prange(n_g):
        acc = 0j
        for p in range(n_p):
            a0 = gx[g] - tx[p, 0]
            a1 = gy[g] - tx[p, 1]
            a2 = gz[g] - tx[p, 2]
            b0 = gx[g] - rx[p, 0]
            b1 = gy[g] - rx[p, 1]
            b2 = gz[g] - rx[p, 2]
            dr = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) + math.sqrt(b0 * b0 + b1 * b1 + b2 * b2) - r_ref[p]
            # sum_n x_n exp(-j 2 pi (f0 + n fstep) dr / c), by a rotating phasor
            ph0 = kc * f0 * dr
            dph = kc * fstep * dr
            z = complex(math.cos(ph0), -math.sin(ph0))
            w = complex(math.cos(dph), -math.sin(dph))
            s = 0j
            for n in range(n_s):
                s += samples[p, n] * z
                z *= w
            acc += s
        out[g] += acc


def _serial(kernel, fastmath: bool):
    """``kernel`` compiled to run on the calling thread alone, cached under a name of its own (numba's cache
    key ignores ``parallel``), through numba's parallel pipeline with every transformation off: compiled
    as a plain njit function the float32 block kernel took about 115 cycles per backprojection on one
    thread against 5 for this (nothing runs in parallel: numba warns so, hence the filter)."""
    f = kernel.py_func
    copy = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial", f.__defaults__, f.__closure__)
    copy.__qualname__ = f.__qualname__ + "_serial"
    return numba.njit(fastmath=fastmath, cache=True, nogil=True, parallel=_NO_PARFORS)(copy)


_NO_PARFORS = dict.fromkeys(("comprehension", "reduction", "setitem", "numpy", "stencil", "fusion", "inplace_binop",
                             "prange"), False)
warnings.filterwarnings("ignore", "(?s).*The keyword argument 'parallel=True' was specified", NumbaPerformanceWarning)


# The same kernels on the calling thread alone, for callers that spread coarser work over the cores
# themselves (FFBP's leaves): one parallel region per small call waits on every core at its end, and on a
# machine where another process holds a core that wait is a scheduler time slice per call.
_bp_interp_blocks_serial = _serial(_bp_interp_blocks, fastmath=True)
_bp_exact_serial = _serial(_bp_exact, fastmath=False)


def _guarded(data: np.ndarray) -> np.ndarray:
    """Profiles as complex64 [P, bins + 3] with zero guard bins (one before, two after).

    Outside its range axis a profile is zero; the guards let the kernel clamp instead of branch.
    """
    n_p, n_b = data.shape
    rows = np.zeros((n_p, n_b + 3), np.complex64)
    rows[:, 1:n_b + 1] = data
    return rows


def guarded_rows(profiles: RangeProfiles) -> np.ndarray:
    """The profiles in the kernels' layout (``_guarded``): their ``rows`` where range compression wrote
    them so (``guarded=True``), else one copy."""
    rows, data = profiles.rows, profiles.data
    if rows is None or rows.shape != (data.shape[0], data.shape[1] + 3) or not np.shares_memory(rows, data):
        rows = _guarded(data)
    return rows


def _as_points(grid_m: np.ndarray):
    grid = np.asarray(grid_m, dtype=np.float64)
    if grid.ndim < 1 or grid.shape[-1] != 3:
        raise ValueError(f"grid points must have shape [..., 3], got {grid.shape}")
    flat = grid.reshape(-1, 3)
    if flat.shape[0] == 0:
        raise ValueError("the grid has no points")
    return grid.shape[:-1], np.ascontiguousarray(flat[:, 0]), np.ascontiguousarray(flat[:, 1]), np.ascontiguousarray(flat[:, 2])


def backproject(
    profiles: RangeProfiles,
    tx_m: np.ndarray,
    rx_m: np.ndarray,
    grid_m: np.ndarray,
    *,
    reference_range_m: np.ndarray | None = None,
    mode: str = "linear",
    out: np.ndarray | None = None,
    parallel: bool = True,
) -> np.ndarray:
    """Backproject range profiles onto grid points.

    Parameters
    ----------
    profiles : RangeProfiles
        ``data`` of shape (P, n_bins): one profile per (chirp, RX). ``mode="exact"`` uses ``samples``.
    tx_m, rx_m : ndarray, shape (P, 3)
        World positions (float64, metres) of the transmitting and receiving antenna of each profile.
    grid_m : ndarray, shape (..., 3)
        Grid points in the world frame; a plane, a volume or any scattered set.
    reference_range_m : ndarray, shape (P,), optional
        Two-way range each profile's axis is relative to (motion-compensated phase histories); 0 by default.
    mode : {"nearest", "linear", "exact"}
    out : ndarray, complex128, shape grid_m.shape[:-1], optional
        Accumulate into this image (streaming use); a new one otherwise.
    parallel : bool
        False: run on the calling thread only (numba's threads untouched), for callers that run many such
        calls side by side in threads of their own (``imaging.factorized_backprojection``).

    Returns
    -------
    ndarray, complex128, shape grid_m.shape[:-1]
    """
    if mode not in MODES:
        raise ValueError(f"unknown backprojection mode {mode!r}; known: {', '.join(MODES)}")
    shape, gx, gy, gz = _as_points(grid_m)
    data = profiles.data
    n_p = data.shape[0]
    tx = np.ascontiguousarray(tx_m, dtype=np.float64).reshape(-1, 3)
    rx = np.ascontiguousarray(rx_m, dtype=np.float64).reshape(-1, 3)
    if data.ndim != 2 or tx.shape[0] != n_p or rx.shape[0] != n_p:
        raise ValueError(f"need profiles [P, bins] with P TX and RX positions; got {data.shape}, {tx.shape}, {rx.shape}")
    r_ref = np.zeros(n_p) if reference_range_m is None else np.ascontiguousarray(reference_range_m, dtype=np.float64)
    if out is None:
        out = np.zeros(shape, np.complex128)
    elif out.shape != shape or out.dtype != np.complex128:
        raise ValueError(f"out must be complex128 of shape {shape} (the grid's), got {out.dtype} {out.shape}")
    # The kernels write through a flat view; a non-contiguous ``out`` (a slice of a larger image) has none,
    # so they accumulate into a contiguous buffer that is added to it at the end.
    flat_out = out.reshape(-1) if out.flags.c_contiguous else np.zeros(out.size, np.complex128)
    if mode == "exact":
        if profiles.samples is None:
            raise ValueError("mode 'exact' needs the raw samples: range_compress(..., keep_samples=True)")
        samples = np.ascontiguousarray(profiles.samples.reshape(n_p, -1), dtype=np.complex128)
        (_bp_exact if parallel else _bp_exact_serial)(samples, profiles.f0_hz, profiles.frequency_step_hz, tx, rx, r_ref, gx, gy, gz, flat_out)
    else:
        k = 2.0 * math.pi * profiles.carrier_hz / SPEED_OF_LIGHT_MPS
        rows = guarded_rows(profiles)
        width, block = patch_shape(np.asarray(grid_m))
        order = patch_order(shape, width, block, SUB_PATCH)
        if order is not None:
            gx, gy, gz = gx[order], gy[order], gz[order]
        kernel = _bp_interp_blocks if parallel else _bp_interp_blocks_serial
        max_extent_m = PHASE_ROUNDING_RAD / (k * 2.0 ** -24)
        acc = flat_out if order is None else np.zeros(flat_out.size, np.complex128)
        # Profiles in chunks, all grid blocks per chunk: the chunk's rows stay in cache while every block
        # reads them, instead of every block streaming all profiles from memory.
        for p0 in range(0, n_p, PROFILE_CHUNK):
            kernel(rows, p0, min(p0 + PROFILE_CHUNK, n_p), profiles.range_start_m, 1.0 / profiles.range_step_m, k,
                   tx, rx, r_ref, gx, gy, gz, mode == "linear", max_extent_m, block, acc)
        if order is not None:
            flat_out[order] += acc
    if not out.flags.c_contiguous:
        out += flat_out.reshape(shape)
    return out
