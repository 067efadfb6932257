"""The leaves of fast factorized backprojection (``imaging.factorized_backprojection``), a run of them in one call.

A leaf is the direct kernel's image of a short subaperture on its polar grid, demodulated (times
exp(+j k 2 r), r the range from the leaf's centre). Imaged one leaf at a time through
:func:`imaging.backprojection.backproject`, the Python around each call (the profiles' slice, the grid's
points and their order, the demodulation) held the GIL for a good part of the kernel's own time on a small
leaf, so that a second thread mostly waited for it. Here one numba call images a run of consecutive leaves:
it makes each leaf's grid points itself, patch by patch, runs the direct kernel's block function
(:func:`imaging.backprojection.interp_block`, so the same float32 / float64 geometry and the same accuracy)
on each patch and writes the demodulated samples into the leaf's image. The caller spreads runs over its
threads.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from imaging.backprojection import (BLOCK, PROFILE_CHUNK, _bp_interp_blocks_serial, guarded_rows,
                                    patch_order)
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.range_compression import RangeProfiles


@numba.njit(fastmath=True, cache=True, nogil=True)
def _leaves_kernel(rows, r0, inv_dr, k, tx, rx, r_ref, linear, max_extent_m, z, leaf_p0, leaf_p1, geometry, shape,
                   block, order, offset, chunk, out):
    """Leaf i: profiles [leaf_p0[i], leaf_p1[i]) of ``rows`` onto its polar grid (``geometry[i]`` as
    ``Subaperture.geometry``, ``shape[i]`` = (nr, na)), its points walked in the order
    order[offset[i]:offset[i] + nr na] in blocks of ``block[i]``, ``chunk`` profiles at a time; its
    demodulated image, complex64 row-major, into out[offset[i]:offset[i] + nr na]."""
    for leaf in range(geometry.shape[0]):
        g = geometry[leaf]
        na = shape[leaf, 1]
        n = shape[leaf, 0] * na
        at = order[offset[leaf]:offset[leaf] + n]
        h = z - g[2]
        gx = np.empty(n)
        gy = np.empty(n)
        gz = np.full(n, z)
        for q in range(n):
            # Subaperture.plane_points: the point of the plane z at range r and cosine alpha.
            r = g[7] + (at[q] // na) * g[8]
            alpha = g[9] + (at[q] % na) * g[10]
            b = math.sqrt(max(r * r * (1.0 - alpha * alpha) - h * h, 0.0))
            gx[q] = g[0] + alpha * r * g[3] + b * g[5]
            gy[q] = g[1] + alpha * r * g[4] + b * g[6]
        image = np.zeros(n, np.complex128)
        for p0 in range(leaf_p0[leaf], leaf_p1[leaf], chunk):
            _bp_interp_blocks_serial(rows, p0, min(p0 + chunk, leaf_p1[leaf]), r0, inv_dr, k, tx, rx, r_ref,
                                     gx, gy, gz, linear, max_extent_m, block[leaf], image)
        for q in range(n):
            ph = 2.0 * k * (g[7] + (at[q] // na) * g[8])
            out[offset[leaf] + at[q]] = np.complex64(image[q] * complex(math.cos(ph), math.sin(ph)))


def leaf_patch(node, z_m: float) -> tuple[int, int]:
    """(columns, points) of the patches and blocks a leaf's polar grid is walked in: always BLOCK points
    (the kernel's vectorised loops need them; ``imaging.backprojection.patch_shape`` shrinks a coarse
    grid's blocks to 16), as square in metres as the grid's spacing allows, so that a block's profile bins
    stay few."""
    g = node.polar_points(z_m, np.arange(min(2, node.nr)), np.arange(min(2, node.na)))
    if g.shape[0] < 2 or g.shape[1] < 2:
        return 1, BLOCK
    sx, sy = float(np.linalg.norm(g[0, 1] - g[0, 0])), float(np.linalg.norm(g[1, 0] - g[0, 0]))
    if not (sx > 0.0 and sy > 0.0):
        return 1, BLOCK
    return int(2 ** min(max(round(0.5 * math.log2(BLOCK * sy / sx)), 0), int(math.log2(BLOCK)))), BLOCK


def image_leaves(leaves: list, profiles: RangeProfiles, tx_m: np.ndarray, rx_m: np.ndarray,
                 reference_range_m: np.ndarray | None, first_profile: int, z_m: float, mode: str,
                 chunk: int = PROFILE_CHUNK) -> list:
    """Demodulated polar images (complex64 [nr, na] each) of consecutive leaves (``Subaperture`` s with their
    grids placed) in one call of the kernel.

    ``profiles``, ``tx_m``, ``rx_m`` and ``reference_range_m`` (or None) hold the profiles from
    ``first_profile`` on (the leaves' ``start``/``stop`` count from the whole pass's first); ``mode`` is
    "linear" or "nearest" (the direct kernel's, see ``imaging.backprojection``); ``chunk`` profiles are
    swept over all of a leaf's blocks at a time (their rows stay in cache).
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
    blocks, orders = [], []
    for leaf in leaves:
        width, points = leaf_patch(leaf, z_m)
        order = patch_order((leaf.nr, leaf.na), width, points)
        orders.append(np.arange(leaf.nr * leaf.na) if order is None else order)
        blocks.append(points)
    p0 = np.array([leaf.start - first_profile for leaf in leaves], np.int64)
    p1 = np.array([leaf.stop - first_profile for leaf in leaves], np.int64)
    if p0.size and (p0.min() < 0 or p1.max() > n_p):
        raise ValueError(f"leaves need profiles {p0.min() + first_profile}-{p1.max() + first_profile}; "
                         f"given {first_profile}-{first_profile + n_p}")
    out = np.empty(int(sizes.sum()), np.complex64)
    # max_extent_m 0: every block in float64 (see the module's docstring).
    _leaves_kernel(guarded_rows(profiles), profiles.range_start_m, 1.0 / profiles.range_step_m, k, tx, rx, r_ref,
                   mode == "linear", 0.0, float(z_m), p0, p1, geometry, shape,
                   np.array(blocks, np.int64), np.concatenate(orders).astype(np.int64), offset, chunk, out)
    return [out[o:o + s].reshape(nr, na) for o, s, (nr, na) in zip(offset, sizes, shape)]


@functools.lru_cache(maxsize=1)
def load_kernel() -> None:
    """Compile (or load from numba's cache) the leaf kernel now, once a process: a live worker warms up on a
    block too small for leaves, and its first real block then stalled for the load (0.5 s on a busy
    machine), enough for the strip map to fall behind and pre-sum."""
    _leaves_kernel(np.zeros((1, 4), np.complex64), 0.0, 1.0, 1.0, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1), True,
                   0.0, 0.0, np.zeros(1, np.int64), np.ones(1, np.int64), np.ones((1, 11)), np.ones((1, 2), np.int64),
                   np.full(1, BLOCK, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64), PROFILE_CHUNK,
                   np.zeros(1, np.complex64))
