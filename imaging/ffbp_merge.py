"""The merge and pixel kernels of fast factorized backprojection (``imaging.factorized_backprojection``):
interpolating a subaperture's demodulated polar image at points of its parent's grid or of the image plane,
with the phase re-referenced to the parent's centre or restored.

A child's image is interpolated separably, ``taps`` x ``taps`` samples weighted by the tabulated coefficients
of ``imaging.ffbp_interpolation``; outside its grid (or too near its edge for all taps) it is 0.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.backprojection import _cos_sin
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


@numba.njit(fastmath=True, cache=True, nogil=True)
def _merge_rows(out, i0, i1, pg, child, cg, z, k, tab_r, tab_a):
    """Add one child's contribution to rows i0..i1-1 of the parent's demodulated polar image ``out`` [nr, na].

    Serial: ``run_factorized`` hands row ranges of every merge of a level to its own threads. The child's
    spacings are inverted once, the taps summed in float32 and the phase's sine and cosine are the direct
    kernel's polynomials (libm's took a third of the time); the sampling is written out here and in
    ``_to_plane_rows``, not an inlined helper handed the arrays at every sample (1.35x slower)."""
    na = out.shape[1]
    h = z - pg[2]
    taps = tab_r.shape[1]
    nf = tab_r.shape[0] - 1
    nrc, nac = child.shape[0], child.shape[1]
    inv_dr, inv_da = 1.0 / cg[8], 1.0 / cg[10]
    for i in range(i0, i1):
        r = pg[7] + i * pg[8]
        for j in range(na):
            along = (pg[9] + j * pg[10]) * r
            b2 = r * r - along * along - h * h
            if b2 <= 0.0:
                continue
            b = math.sqrt(b2)
            dx = pg[0] + along * pg[3] + b * pg[5] - cg[0]
            dy = pg[1] + along * pg[4] + b * pg[6] - cg[1]
            dz = z - cg[2]
            rc = math.sqrt(dx * dx + dy * dy + dz * dz)
            fr = (rc - cg[7]) * inv_dr
            fa = ((dx * cg[3] + dy * cg[4]) / rc - cg[9]) * inv_da
            ir = math.floor(fr)
            ia = math.floor(fa)
            r0 = int(ir) - taps // 2 + 1
            a0 = int(ia) - taps // 2 + 1
            if r0 < 0 or a0 < 0 or r0 + taps > nrc or a0 + taps > nac:
                continue  # outside the child's grid (or too near its edge for all taps): 0
            wr = int((fr - ir) * nf + 0.5)
            wa = int((fa - ia) * nf + 0.5)
            acc_re = np.float32(0.0)
            acc_im = np.float32(0.0)
            for a in range(taps):
                row_re = np.float32(0.0)
                row_im = np.float32(0.0)
                for t in range(taps):
                    v = child[r0 + a, a0 + t]
                    w = tab_a[wa, t]
                    row_re += v.real * w
                    row_im += v.imag * w
                w = tab_r[wr, a]
                acc_re += row_re * w
                acc_im += row_im * w
            c, s = _cos_sin(-2.0 * k * (rc - r))
            out[i, j] += np.complex64(complex(acc_re * c - acc_im * s, acc_re * s + acc_im * c))


@numba.njit(fastmath=True, cache=True, nogil=True)
def _to_plane_rows(out, i0, i1, x, y, z, d, g, k, tab_r, tab_a):
    """Add the root's image at the pixels (x[j], y[i], z), rows i0..i1-1, to ``out`` [ny, nx], its phase
    restored (sampled as in ``_merge_rows``)."""
    taps = tab_r.shape[1]
    nf = tab_r.shape[0] - 1
    nr, na = d.shape[0], d.shape[1]
    inv_dr, inv_da = 1.0 / g[8], 1.0 / g[10]
    dz = z - g[2]
    for i in range(i0, i1):
        dy = y[i] - g[1]
        for j in range(x.size):
            dx = x[j] - g[0]
            rc = math.sqrt(dx * dx + dy * dy + dz * dz)
            fr = (rc - g[7]) * inv_dr
            fa = ((dx * g[3] + dy * g[4]) / rc - g[9]) * inv_da
            ir = math.floor(fr)
            ia = math.floor(fa)
            r0 = int(ir) - taps // 2 + 1
            a0 = int(ia) - taps // 2 + 1
            if r0 < 0 or a0 < 0 or r0 + taps > nr or a0 + taps > na:
                continue  # outside the root's grid (or too near its edge for all taps): 0
            wr = int((fr - ir) * nf + 0.5)
            wa = int((fa - ia) * nf + 0.5)
            acc_re = np.float32(0.0)
            acc_im = np.float32(0.0)
            for a in range(taps):
                row_re = np.float32(0.0)
                row_im = np.float32(0.0)
                for t in range(taps):
                    v = d[r0 + a, a0 + t]
                    w = tab_a[wa, t]
                    row_re += v.real * w
                    row_im += v.imag * w
                w = tab_r[wr, a]
                acc_re += row_re * w
                acc_im += row_im * w
            c, s = _cos_sin(-2.0 * k * rc)
            out[i, j] += complex(acc_re * c - acc_im * s, acc_re * s + acc_im * c)


def _to_plane(out, x, y, z, d, g, k, tab_r, tab_a):
    """Add the root's image at all pixels (x[j], y[i], z) to ``out`` [ny, nx], its phase restored."""
    _to_plane_rows(out, 0, y.size, x, y, z, d, g, k, tab_r, tab_a)
