"""How the backprojection kernel walks a grid: in blocks of BLOCK points close together (patches, and
4 x 4 squares inside them), so that each block's float32 offsets stay small and 16 consecutive points' bins
lie close together (imaging/backprojection.py, imaging/bin_gather.py)."""

from __future__ import annotations

import functools
import math

import numpy as np

BLOCK = 256  # grid points per work item: the accumulators (2 KiB) stay in L1 beside a profile row
PATCH = 16  # a 2-D grid is walked in PATCH x PATCH squares: BLOCK points close together
SUB_PATCH = 4  # ... each in 4 x 4 squares: 16 consecutive points' bins lie close together (imaging/bin_gather.py)


@functools.lru_cache(maxsize=32)
def patch_order(shape: tuple[int, ...], width: int = PATCH, points: int = BLOCK, sub_patch: int = 1) -> np.ndarray | None:
    """The order that walks a grid of this shape ([..., ny, nx]) in patches of about ``points`` points,
    ``width`` columns wide (PATCH x PATCH squares by default), each layer in turn; None for a 1-D set of points or a grid
    within one patch (kept in the order given). Each patch row by row; with ``sub_patch`` s > 1, a block of
    ``points`` that is a whole patch in s x s squares (``_in_squares``; for the permute gather,
    imaging/bin_gather.py). Cached: ``form_image`` and the strip map backproject block after block onto the
    same grid, FFBP's leaves onto grids of a few shapes (callers only index with it)."""
    if len(shape) < 2:
        return None
    ny, nx = shape[-2], shape[-1]
    pw = max(1, min(width, nx))
    ph = max(1, points // pw)
    if nx <= pw and ny <= ph:
        return None
    # Rows of patches alternately left to right and right to left: a run of ``points`` that leaves a
    # patch (after a narrower one at the grid's edge) goes on into a neighbouring one, never across the
    # grid; the last, lower row of patches has wider ones, of about as many points.
    pieces, y0, backwards = [], 0, False
    while y0 < ny:
        h = min(ph, ny - y0)
        w = pw if h == ph else min(nx, -(-ph * pw // h))
        starts = range(0, nx, w)
        for x0 in reversed(starts) if backwards else starts:
            iy, ix = np.mgrid[y0:y0 + h, x0:min(x0 + w, nx)]
            pieces.append((iy * nx + ix).ravel())
        y0, backwards = y0 + h, not backwards
    layer = np.concatenate(pieces)
    layers = int(np.prod(shape[:-2], dtype=np.int64))
    order = (np.arange(layers)[:, None] * (ny * nx) + layer[None, :]).ravel()
    if sub_patch > 1:
        order = _in_squares(order, nx, points, sub_patch)
    order.flags.writeable = False  # shared by every call on this shape
    return order


def _in_squares(order: np.ndarray, nx: int, points: int, side: int) -> np.ndarray:
    """``order`` with each run of ``points`` (a block) that covers a whole rectangle of one layer, both its
    sides multiples of ``side``, walked in side x side squares, row by row: every block keeps its points,
    so the image stays the same bit for bit, and 16 consecutive points of a block lie close together."""
    n_full = order.size // points
    blocks = order[:n_full * points].reshape(n_full, points)
    rows, ix = np.divmod(blocks, nx)  # rows: layer * ny + row (a block within one layer spans few of them)
    y, x = rows - rows.min(axis=1, keepdims=True), ix - ix.min(axis=1, keepdims=True)
    h, w = y.max(axis=1) + 1, x.max(axis=1) + 1
    whole = (h * w == points) & (h % side == 0) & (w % side == 0)  # distinct points filling their box
    key = ((y // side) * (w[:, None] // side) + x // side) * side * side + (y % side) * side + x % side
    out = order.copy()
    out[:n_full * points].reshape(n_full, points)[whole] = np.take_along_axis(
        blocks, np.argsort(key, axis=1), axis=1)[whole]
    return out


#: Largest side of a patch: two of them stay within the float32 kernel's extent (1 m at 77 GHz).
PATCH_SIDE_MAX_M = 0.4


def patch_shape(grid_m: np.ndarray) -> tuple[int, int]:
    """(columns, points) of the patches to walk a grid [..., ny, nx, 3] in, the points also the kernel's
    block: BLOCK points (PATCH x PATCH for square pixels), fewer columns where columns lie farther apart
    than rows (an FFBP leaf's polar grid: few, widely spaced angles), and 64 or 16 points where a patch of
    BLOCK would be wider than PATCH_SIDE_MAX_M (a coarse grid). Compact blocks take the float32 kernel,
    and small ones its series for the range offsets."""
    if grid_m.ndim < 3 or grid_m.shape[-3] < 2 or grid_m.shape[-2] < 2:
        return PATCH, BLOCK
    g = grid_m.reshape(-1, *grid_m.shape[-3:])[0]
    sx = float(np.linalg.norm(g[0, 1] - g[0, 0]))
    sy = float(np.linalg.norm(g[1, 0] - g[0, 0]))
    if not (sx > 0.0 and sy > 0.0):
        return PATCH, BLOCK
    points = BLOCK
    while points > 16 and math.sqrt(points * sx * sy) > PATCH_SIDE_MAX_M:
        points //= 4
    return int(2 ** min(max(round(0.5 * math.log2(points * sy / sx)), 0), int(math.log2(points)))), points


def max_block_extent_m(gx: np.ndarray, gy: np.ndarray, gz: np.ndarray) -> float:
    """The largest extent (max over x, y, z of max - min) of any BLOCK of consecutive points."""
    n = gx.size
    pad = (-n) % BLOCK
    worst = 0.0
    for v in (gx, gy, gz):
        blocks = np.concatenate([v, np.full(pad, v[-1])]).reshape(-1, BLOCK)
        worst = max(worst, float((blocks.max(axis=1) - blocks.min(axis=1)).max()))
    return worst
