"""The backprojection kernel for blocks of points that are rectangles of a regular planar grid.

A block of ``imaging.backprojection``'s kernel is, on an image grid, a patch of h rows by w columns: its
points are c + a e_x + b e_y, c the patch's centre, e_x and e_y the grid's steps, a and b the (half-)integer
column and row offsets. For an antenna at u from c (R = |u|, n = u / R), with p = n.d and q = |d|^2 of the
offset d, and w = q - p^2,

    |u + d| - |u| = p + w / (2 R) - p w / (2 R^2) - w (w - 4 p^2) / (8 R^3) + O(R (|d| / R)^5)

(the binomial series of sqrt(1 + 2p/R + q/R^2), by orders of |d|). p and q are polynomials in (a, b), so a
profile's range offset over the whole patch is one polynomial of degree 4 in (a, b), its 14 coefficients
computed once per (block, profile) in float64 (``_add_antenna``). The pixel loop then runs over a patch's
columns, 16 float32 lanes wide, with per column the five polynomials in b that (a, b)'s polynomial is at
that a (computed once per (block, profile) for the w columns): Horner's rule in b, four multiply-adds per
pixel for both antennas together, instead of about 25 for two square roots' worth of series.
The truncation is bounded by R (2/9) (|d| / R)^5 / (1 - |d| / R) (the series' coefficients are Gegenbauer
polynomials C_m^(-1/2), at most 2 / (2m - 1) in size); a (block, profile) where that exceeds
LATTICE_TOLERANCE_M is left to the general kernel (``done`` stays 0 for its block).

The polynomial is evaluated in bins of the profile, relative to a window of the profile's row that the
block can reach (|offset| <= 2 |d|max for the two antennas): the window is copied once per (block, profile)
as (value, next value - value) pairs, so that a pixel's gather is one 16-byte load from L1 at a position
that needs no clamping, and its linear interpolation one multiply-add per component. The phase in turns
is an affine function of that position.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.backprojection import _TWO_PI, _cos_sin_turns, _serial

#: The truncation error allowed for the lattice polynomial, metres of range (1.6e-5 rad at 77 GHz, -96 dB).
LATTICE_TOLERANCE_M = 1e-8


@numba.njit(inline="always")
def lattice_applies(u_n, radius):
    """Whether the degree-4 polynomial holds |u + d| - |u| within LATTICE_TOLERANCE_M for every |d| <= radius
    from a block centre ``u_n`` metres from the antenna."""
    eps = radius / u_n
    return eps < 0.25 and u_n * (2.0 / 9.0) * eps ** 5 / (1.0 - eps) <= LATTICE_TOLERANCE_M


@numba.njit(inline="always")
def _antenna_coefficients(u0, u1, u2, u_n, ex, ey, aa, ab, bb):
    """The coefficients of |u + a e_x + b e_y| - |u| (to fourth order, see the module's docstring) on
    a, b, a^2, ab, b^2, a^3, a^2 b, a b^2, b^3, a^4, a^3 b, a^2 b^2, a b^3, b^4; ``aa``, ``ab``, ``bb``
    are e_x.e_x, e_x.e_y, e_y.e_y."""
    al = (u0 * ex[0] + u1 * ex[1] + u2 * ex[2]) / u_n
    be = (u0 * ey[0] + u1 * ey[1] + u2 * ey[2]) / u_n
    h1 = 0.5 / u_n
    h2 = h1 / u_n
    h3 = 0.25 * h2 / u_n
    w20 = aa - al * al
    w11 = 2.0 * (ab - al * be)
    w02 = bb - be * be
    v20 = w20 - 4.0 * al * al
    v11 = w11 - 8.0 * al * be
    v02 = w02 - 4.0 * be * be
    return (al, be, h1 * w20, h1 * w11, h1 * w02,
            -h2 * al * w20, -h2 * (al * w11 + be * w20), -h2 * (al * w02 + be * w11), -h2 * be * w02,
            -h3 * w20 * v20, -h3 * (w20 * v11 + w11 * v20), -h3 * (w20 * v02 + w11 * v11 + w02 * v20),
            -h3 * (w11 * v02 + w02 * v11), -h3 * w02 * v02)


@numba.njit(inline="always")
def _f32(c0, c1, c2, c3, c4, scale):
    """Five coefficients times ``scale``, in float32."""
    return (np.float32(c0 * scale), np.float32(c1 * scale), np.float32(c2 * scale), np.float32(c3 * scale),
            np.float32(c4 * scale))


@numba.njit(inline="always", fastmath=True)
def _window(row, j0, win):
    """win[m] = (row[j0 + m], row[j0 + m + 1]), zero outside the row."""
    n = row.size
    for m in range(win.shape[0]):
        j = j0 + m
        win[m, 0] = row[j] if 0 <= j < n else np.complex64(0)
        win[m, 1] = row[j + 1] if 0 <= j + 1 < n else np.complex64(0)


@numba.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _bp_lattice_blocks(rows, p0, p1, r0, inv_dr, k, tx, rx, r_ref, gx, gy, gz, block, blk_w, blk_h, ex, ey, out,
                       done):
    """Profiles p0..p1-1 of rows [P, n_bins + 3] (``imaging.backprojection``'s guarded layout), linear
    interpolation, onto every block of ``block`` consecutive points that is a patch of blk_h[b] rows by
    blk_w[b] columns (0: not one) of the lattice with steps ``ex``, ``ey``, added to ``out``; done[b] = 1
    for each block so imaged, 0 for those left to the general kernel."""
    n_g = gx.size
    n_blocks = (n_g + block - 1) // block
    aa = ex[0] * ex[0] + ex[1] * ex[1] + ex[2] * ex[2]
    ab = ex[0] * ey[0] + ex[1] * ey[1] + ex[2] * ey[2]
    bb = ey[0] * ey[0] + ey[1] * ey[1] + ey[2] * ey[2]
    k_turns = k / _TWO_PI
    turns_per_bin = np.float32(k_turns / inv_dr)
    for blk in numba.prange(n_blocks):
        done[blk] = 0
        w, h = blk_w[blk], blk_h[blk]
        g0 = blk * block
        if w == 0 or w * h != min(block, n_g - g0):
            continue
        g1 = g0 + w * h - 1
        cx, cy, cz = 0.5 * (gx[g0] + gx[g1]), 0.5 * (gy[g0] + gy[g1]), 0.5 * (gz[g0] + gz[g1])
        ha, hb = 0.5 * (w - 1), 0.5 * (h - 1)
        hb32 = np.float32(hb)
        radius = 0.0
        for sa, sb in ((ha, hb), (ha, -hb)):
            r2 = 0.0
            for t in range(3):
                r2 += (sa * ex[t] + sb * ey[t]) ** 2
            radius = max(radius, math.sqrt(r2))
        usable = True
        for p in range(p0, p1):
            ua = math.sqrt((cx - tx[p, 0]) ** 2 + (cy - tx[p, 1]) ** 2 + (cz - tx[p, 2]) ** 2)
            ub = math.sqrt((cx - rx[p, 0]) ** 2 + (cy - rx[p, 1]) ** 2 + (cz - rx[p, 2]) ** 2)
            if not (lattice_applies(ua, radius) and lattice_applies(ub, radius)):
                usable = False
                break
        if not usable:
            continue
        span = 2.0 * radius * inv_dr  # bins a pixel's offset can reach from the centre's
        length = int(2.0 * span) + 5
        win = np.empty((length, 2), np.complex64)
        win_pairs = win.reshape(-1).view(np.complex128)  # (value, difference) as one 16-byte item
        a_col = np.empty(w, np.float32)
        for cc in range(w):
            a_col[cc] = np.float32(cc - ha)
        p_0 = np.empty(w, np.float32)  # per column, the coefficients of b^0 .. b^3 (b^4's is one number)
        p_1 = np.empty(w, np.float32)
        p_2 = np.empty(w, np.float32)
        p_3 = np.empty(w, np.float32)
        nb = w * h
        acc_re = np.zeros(nb, np.float32)
        acc_im = np.zeros(nb, np.float32)
        idx = np.empty(nb, np.uint32)
        frac = np.empty(nb, np.float32)
        turns = np.empty(nb, np.float32)
        pairs = np.empty(2 * nb, np.complex64)
        pairs16 = pairs.view(np.complex128)
        ct = _antenna_coefficients(1.0, 0.0, 0.0, 1.0, ex, ey, aa, ab, bb)  # typed; replaced at p0
        for p in range(p0, p1):
            ua0, ua1, ua2 = cx - tx[p, 0], cy - tx[p, 1], cz - tx[p, 2]
            ub0, ub1, ub2 = cx - rx[p, 0], cy - rx[p, 1], cz - rx[p, 2]
            ua = math.sqrt(ua0 * ua0 + ua1 * ua1 + ua2 * ua2)
            ub = math.sqrt(ub0 * ub0 + ub1 * ub1 + ub2 * ub2)
            # A TX shared with the previous profile (the RX channels of one chirp) has the same coefficients.
            if p == p0 or tx[p, 0] != tx[p - 1, 0] or tx[p, 1] != tx[p - 1, 1] or tx[p, 2] != tx[p - 1, 2]:
                ct = _antenna_coefficients(ua0, ua1, ua2, ua, ex, ey, aa, ab, bb)
            cr = _antenna_coefficients(ub0, ub1, ub2, ub, ex, ey, aa, ab, bb)
            # The centre's bin in float64; the window starts a bin below anything the block reaches.
            pos_c = (ua + ub - r_ref[p] - r0) * inv_dr + 1.0
            j0 = int(math.floor(pos_c - span)) - 1
            tc = k_turns * (ua + ub - r_ref[p])
            tc -= math.floor(tc + 0.5)
            fc = pos_c - j0
            # The polynomial in bins of the window, float32: per column, its coefficients on b^0 .. b^4.
            c10, c01, c20, c11, c02 = _f32(ct[0] + cr[0], ct[1] + cr[1], ct[2] + cr[2], ct[3] + cr[3], ct[4] + cr[4], inv_dr)
            c30, c21, c12, c03, c40 = _f32(ct[5] + cr[5], ct[6] + cr[6], ct[7] + cr[7], ct[8] + cr[8], ct[9] + cr[9], inv_dr)
            c31, c22, c13, c04, c00 = _f32(ct[10] + cr[10], ct[11] + cr[11], ct[12] + cr[12], ct[13] + cr[13], fc / inv_dr,
                                           inv_dr)
            for cc in range(w):
                a = a_col[cc]
                p_0[cc] = c00 + a * (c10 + a * (c20 + a * (c30 + a * c40)))
                p_1[cc] = c01 + a * (c11 + a * (c21 + a * c31))
                p_2[cc] = c02 + a * (c12 + a * c22)
                p_3[cc] = c03 + a * c13
            t0 = np.float32(tc - fc * (k_turns / inv_dr))
            # Column by column (the block's arrays column-major): the column's polynomial in b is four
            # numbers, so the vectorised loop over its rows reads no memory.
            for cc in range(w):
                q0, q1, q2, q3 = p_0[cc], p_1[cc], p_2[cc], p_3[cc]
                i0 = cc * h
                for r in range(h):
                    b = np.float32(r) - hb32
                    lp = q0 + b * (q1 + b * (q2 + b * (q3 + b * c04)))
                    j = np.uint32(lp)  # lp >= 1: truncation is the floor
                    idx[i0 + r] = j
                    frac[i0 + r] = lp - np.float32(j)
                    turns[i0 + r] = t0 + turns_per_bin * lp
            row = rows[p]
            if j0 >= 0 and j0 + length <= row.size:  # the block's bins within the row: gather from it
                base = np.uint32(j0)
                for i in range(nb):  # scalar: LLVM does not vectorise the gather
                    j = base + idx[i]
                    pairs[2 * i] = row[j]
                    pairs[2 * i + 1] = row[j + np.uint32(1)]
            else:  # from a copy of the bins, zero outside the row (a block beyond the range axis)
                _window(row, j0, win)
                for i in range(nb):
                    pairs16[i] = win_pairs[idx[i]]
            for i in range(nb):
                cs, sn = _cos_sin_turns(turns[i])
                t = frac[i]
                v = pairs[2 * i]
                d = pairs[2 * i + 1]
                vr = v.real + t * (d.real - v.real)
                vi = v.imag + t * (d.imag - v.imag)
                acc_re[i] += vr * cs + vi * sn
                acc_im[i] += vi * cs - vr * sn
        for r in range(h):
            for cc in range(w):
                out[g0 + r * w + cc] += complex(acc_re[cc * h + r], acc_im[cc * h + r])
        done[blk] = 1


_bp_lattice_blocks_serial = _serial(_bp_lattice_blocks, fastmath=True)


def lattice_steps(grid_m: np.ndarray, tolerance_m: float = 1e-9) -> tuple[np.ndarray, np.ndarray] | None:
    """(e_x, e_y), the steps between a grid's columns and rows, if every layer of the grid [..., ny, nx, 3]
    is a regular lattice with those steps (within ``tolerance_m``); else None."""
    if grid_m.ndim < 3 or grid_m.shape[-3] < 2 or grid_m.shape[-2] < 2:
        return None
    g = grid_m.reshape(-1, *grid_m.shape[-3:])
    ny, nx = g.shape[1], g.shape[2]
    ex = (g[0, 0, -1] - g[0, 0, 0]) / (nx - 1)
    ey = (g[0, -1, 0] - g[0, 0, 0]) / (ny - 1)
    lattice = g[:, :1, :1] + np.arange(nx)[None, None, :, None] * ex + np.arange(ny)[None, :, None, None] * ey
    if not np.abs(g - lattice).max() <= tolerance_m:
        return None
    return np.ascontiguousarray(ex), np.ascontiguousarray(ey)


class LatticePlan:
    """Which blocks of a patch-ordered grid are lattice patches, and how to image a chunk of profiles with
    them: the lattice kernel on those, the general kernel on the rest (``run``)."""

    def __init__(self, ex: np.ndarray, ey: np.ndarray, blk_w: np.ndarray, blk_h: np.ndarray, block: int):
        self.ex, self.ey, self.blk_w, self.blk_h, self.block = ex, ey, blk_w, blk_h, block
        self.done = np.zeros(blk_w.size, np.uint8)

    def run(self, args: tuple, general, general_tail: tuple, acc: np.ndarray, parallel: bool) -> None:
        """``args`` = (rows, p0, p1, r0, inv_dr, k, tx, rx, r_ref, gx, gy, gz); ``general(*args, *general_tail,
        out)`` images the points of the blocks the lattice kernel left."""
        kernel = _bp_lattice_blocks if parallel else _bp_lattice_blocks_serial
        kernel(*args, self.block, self.blk_w, self.blk_h, self.ex, self.ey, acc, self.done)
        if self.done.all():
            return
        n_g = acc.size
        left = np.flatnonzero(np.repeat(self.done == 0, self.block)[:n_g])
        gx, gy, gz = (g[left] for g in args[9:12])
        part = np.zeros(left.size, np.complex128)
        general(*args[:9], gx, gy, gz, *general_tail, part)
        acc[left] += part


def lattice_plan(grid_m: np.ndarray, pieces: list, block: int) -> LatticePlan | None:
    """The plan for a grid [..., ny, nx, 3] walked in ``pieces`` ((y0, h, x0, w) per patch of a layer, in
    order, see ``imaging.backprojection.patch_order``) with blocks of ``block`` points; None where the grid
    is no regular lattice."""
    steps = lattice_steps(grid_m)
    if steps is None:
        return None
    layers = int(np.prod(grid_m.shape[:-3], dtype=np.int64))
    n_points = layers * grid_m.shape[-3] * grid_m.shape[-2]
    n_blocks = -(-n_points // block)
    blk_w = np.zeros(n_blocks, np.int64)
    blk_h = np.zeros(n_blocks, np.int64)
    offset = 0
    for _ in range(layers):
        for _y0, h, _x0, w in pieces:
            if h * w == min(block, n_points - offset) and offset % block == 0:
                blk_w[offset // block], blk_h[offset // block] = w, h
            offset += h * w
    if not blk_w.any():
        return None
    return LatticePlan(*steps, blk_w, blk_h, block)
