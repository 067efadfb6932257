"""Where FFBP's subapertures sit and how their polar grids are sized: many nodes a pass.

``imaging.factorized_backprojection.plan_factorized`` builds the tree (``imaging.ffbp_tree``); this module gives
its nodes their geometry. :func:`node_frames`: a node's centre, axis and normal from its phase centres, the
extreme ones its grid's bandwidths are taken over and the image's distance from its axis, for every node of
the plan at once. :func:`place_grids`: each node's polar grid, covering the plane points it serves (the
image's outline, or its parent's grid edge, :func:`grid_edges`) with the sampling the bandwidths of its
demodulated image there ask for, for every node of one step down the tree at once. The rules are the plan's
(that module's docstring, "Geometry"); only the bookkeeping is batched, and the loops over profiles, served
points, grid edges and point x phase-centre pairs are small numba passes (four kernels: each costs a cache load
in a process's first plan): no numpy temporaries of nodes x points. As numpy the served points' pass made
~26 MB a plan of the 2 m aperture (~6,500 pages), which the allocator may map afresh on every plan (glibc does
for blocks above its mmap threshold until the process has freed a large one, as in a fresh ``sarbot image``):
the plan's cost then hung on the cost of a new page (benchmarks/ffbp.py --plan records the faults,
docs/results/ffbp_plan.json; tests/test_ffbp_plan.py counts them).

Done a node at a time, as at first, the plan was ~50 small numpy calls a node, 0.44 s for the 2 m aperture's
383 nodes, more than FFBP's run of 0.33 s; batched a length or a step of the tree a pass, 0.029 s on the quiet
machine (docs/results/ffbp_plan.json), a third of it Python and numpy calls per node or per step. Now the
whole plan's frames are one pass, its grids' edges one numba pass a step, and the bandwidths' inner loop runs a
vector at a time: about half the CPU time of the batched planner, alternated in one process
(benchmarks/ffbp_plan_versions.py, docs/results/ffbp_plan_versions.json). tests/test_ffbp_plan.py checks the
plan against the node-at-a-time builder (to rounding) and against the batched one (to the bit).

Ragged sets (a node's phase centres, the plane points it serves) are padded: with copies of one of its own
points where only their minimum or maximum is taken (a copy changes neither), with a mask where their order
counts (every n-th point).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.ffbp_interpolation import BAND_MARGIN
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)

#: Points of a grid's edge per side (:func:`grid_edges`).
EDGE_POINTS = 64
#: Sample points of the served region's outline kept for the bandwidths (every n-th of them, about this many).
OUTLINE_SAMPLES = 48
#: Phase centres kept for the bandwidths besides the extremes: every (length / this)-th (a prime, so that
#: TDM's repeating channel order does not pick one channel).
CENTRE_STRIDE_DIVISOR = 23


def _dot2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a . b over a last axis of 2 (broadcast)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def track_axis(m: tuple) -> np.ndarray:
    """The horizontal principal direction of all phase centres (``m`` as for :func:`node_frames`), [2]
    (x where they all coincide)."""
    moments = np.empty((1, 6))
    _moments(*m, np.zeros(1, np.int64), np.full(1, m[0].size, np.int64), moments)
    cov = moments[0, [3, 4, 4, 5]].reshape(2, 2)
    u = np.linalg.eigh(cov)[1][:, -1] if np.any(cov) else np.array([1.0, 0.0])
    return u / np.linalg.norm(u)


def node_frames(m: tuple, starts: np.ndarray, lengths: np.ndarray, overall: np.ndarray, image_xy: np.ndarray):
    """Centre, axis, normal and extreme phase centres of nodes of ``lengths`` profiles from ``starts``, and
    the image's least distance from their axes.

    Parameters
    ----------
    m : tuple of three ndarray, shape (P,)
        x, y and z of the phase centres of all profiles (each contiguous: this pass reads every profile of
        every node, so the whole track once per level of the tree).
    starts, lengths : ndarray of int64, shape (N,)
        First profile and profile count of each node; node i holds [starts[i], starts[i] + lengths[i]).
        All nodes of a plan in one call: what costs here is per call (numpy's batched eigh and gathers,
        two passes' dispatch), not per node.
    overall : ndarray, shape (2,)
        The whole track's horizontal axis: a node's axis points its way.
    image_xy : ndarray, shape (K, 2)
        The served region's outline: a node's normal points towards its centre (the mean of the points).

    Returns
    -------
    centre (N, 3), axis (N, 2), normal (N, 2) and centres (N, 3, M), their x, y and z rows apart (so that
    the bandwidths' pass reads each contiguously, a vector at a time): the phase centres furthest along and
    across the axis (both ways, diagonally, and in height) and every ``length / 23``-th, repeats included;
    a node with fewer than M of them fills its row up with copies of its first (which change neither
    maximum its grid's bandwidths are taken as); and b_image (N,), the least distance of ``image_xy`` from
    each node's axis on the side of its normal (FFBP needs it positive: a side-looking pass), computed in
    the extremes' pass (as numpy, nodes x outline temporaries were ~700 fresh pages a plan).
    """
    n_nodes = len(starts)
    moments = np.empty((n_nodes, 6))
    _moments(*m, starts, lengths, moments)
    centre = moments[:, :3].copy()
    cov = moments[:, [3, 4, 4, 5]].reshape(-1, 2, 2)
    # The horizontal principal direction; a node whose phase centres coincide takes the track's.
    flat = ~cov.reshape(-1, 4).any(axis=1)
    cov[flat] = np.eye(2)
    u = np.linalg.eigh(cov)[1][..., :, -1]
    u[flat] = overall
    u *= np.where(_dot2(u, overall) < 0, -1.0, 1.0)[:, None]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
    normal *= np.where(_dot2(normal, image_xy.mean(axis=0) - centre[:, :2]) < 0, -1.0, 1.0)[:, None]
    picks, b_image = np.empty((n_nodes, 10), np.int64), np.empty(n_nodes)
    _extremes(*m, starts, lengths, u, normal, np.ascontiguousarray(image_xy[:, 0]), np.ascontiguousarray(image_xy[:, 1]),
              centre, picks, b_image)
    # Every step-th profile, np.arange(0, length, step) per node, padded with the first extreme.
    step = np.maximum(1, lengths // CENTRE_STRIDE_DIVISOR)
    count = -(-lengths // step)
    column = np.arange(int(count.max()))
    strided = np.where(column < count[:, None], column * step[:, None], picks[:, :1])
    chosen = starts[:, None] + np.concatenate([picks, strided], axis=1)
    centres = np.empty((chosen.shape[0], 3, chosen.shape[1]))
    for axis_, v in enumerate(m):
        np.take(v, chosen, out=centres[:, axis_])
    return centre, u, normal, centres, b_image


@numba.njit(cache=True, nogil=True)
def _moments(x, y, z, starts, lengths, out):
    """Per node (profiles [starts[i], starts[i] + lengths[i])): the mean of x, y, z and the sums of dx dx, dx dy,
    dy dy about it, into out[i] (two passes: the sums of squares about the mean, not about the origin)."""
    for i in range(starts.size):
        length = lengths[i]
        first, last = starts[i], starts[i] + length
        sx = sy = sz = 0.0
        for j in range(first, last):
            sx += x[j]
            sy += y[j]
            sz += z[j]
        cx, cy = sx / length, sy / length
        sxx = sxy = syy = 0.0
        for j in range(first, last):
            dx, dy = x[j] - cx, y[j] - cy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4], out[i, 5] = cx, cy, sz / length, sxx, sxy, syy


@numba.njit(cache=True, nogil=True)
def _extremes(x, y, z, starts, lengths, u, n, image_x, image_y, centre, out, b_image):
    """Per node, the offsets (from its first profile) of the least and the greatest s, p, s + p, s - p and z
    (s along its axis u, p along its normal n), the first of equals as np.argmin / np.argmax, into out[i];
    and the least p of the image's outline (image_x, image_y) about its centre, into b_image[i]."""
    for i in range(starts.size):
        least = np.inf
        for q in range(image_x.size):
            least = min(least, (image_x[q] - centre[i, 0]) * n[i, 0] + (image_y[q] - centre[i, 1]) * n[i, 1])
        b_image[i] = least
        first, length = starts[i], lengths[i]
        u0, u1, n0, n1 = u[i, 0], u[i, 1], n[i, 0], n[i, 1]
        s = x[first] * u0 + y[first] * u1
        p = x[first] * n0 + y[first] * n1
        lo_s = hi_s = s
        lo_p = hi_p = p
        lo_sum = hi_sum = s + p
        lo_diff = hi_diff = s - p
        lo_z = hi_z = z[first]
        out[i, :] = 0
        for j in range(1, length):
            s = x[first + j] * u0 + y[first + j] * u1
            p = x[first + j] * n0 + y[first + j] * n1
            if s < lo_s:
                lo_s, out[i, 0] = s, j
            if s > hi_s:
                hi_s, out[i, 1] = s, j
            if p < lo_p:
                lo_p, out[i, 2] = p, j
            if p > hi_p:
                hi_p, out[i, 3] = p, j
            if s + p < lo_sum:
                lo_sum, out[i, 4] = s + p, j
            if s + p > hi_sum:
                hi_sum, out[i, 5] = s + p, j
            if s - p < lo_diff:
                lo_diff, out[i, 6] = s - p, j
            if s - p > hi_diff:
                hi_diff, out[i, 7] = s - p, j
            if z[first + j] < lo_z:
                lo_z, out[i, 8] = z[first + j], j
            if z[first + j] > hi_z:
                hi_z, out[i, 9] = z[first + j], j


def plane_points(centre, axis, normal, r, alpha, z_m: float, b_min_m: float = 0.0):
    """``Subaperture.plane_points`` for N nodes at once: ``centre`` (N, 3), ``axis`` / ``normal`` (N, 2), r and
    alpha (N, ...) broadcast; the points' x and y and their distance b from the axis (at least ``b_min_m``)."""
    shape = (-1,) + (1,) * (np.ndim(r) - 1)
    h = (z_m - centre[:, 2]).reshape(shape)
    b = np.sqrt(np.maximum(r * r * (1 - alpha * alpha) - h * h, b_min_m ** 2))
    ar = alpha * r
    x = centre[:, 0].reshape(shape) + ar * axis[:, 0].reshape(shape) + b * normal[:, 0].reshape(shape)
    y = centre[:, 1].reshape(shape) + ar * axis[:, 1].reshape(shape) + b * normal[:, 1].reshape(shape)
    return x, y, b


def grid_edges(centre, axis, normal, r0_m, dr_m, a0, da, nr, na, z_m: float, copies: int = 1):
    """Points on the edge of N nodes' polar grids (their first and last rows at up to 64 columns, their
    first and last columns at up to 64 rows, in that order): x, y of shape [N copies, 4 EDGE_POINTS] (each
    node's ``copies`` times in a row, one for each of its children) and the mask of the points that are
    there (a grid with fewer rows or columns has fewer). One numba pass: as numpy broadcasts it was ~40
    calls a step down the tree, a tenth of a plan."""
    shape = (len(nr) * copies, 4 * EDGE_POINTS)
    x, y, valid = np.empty(shape), np.empty(shape), np.empty(shape, bool)
    scratch = np.empty((2, 2, EDGE_POINTS), np.int64)
    _grid_edges(centre, axis, normal, r0_m, dr_m, a0, da, nr, na, float(z_m), copies, scratch, x, y, valid)
    return x, y, valid


@numba.njit(cache=True, nogil=True)
def _grid_edges(centre, axis, normal, r0_m, dr_m, a0, da, nr, na, z_m, copies, scratch, x, y, valid):
    """:func:`grid_edges` into x, y and valid: per node, its up to EDGE_POINTS rows and columns
    (``np.unique(np.linspace(0, n - 1, EDGE_POINTS).astype(int))``, the linspace as numpy computes it; a
    repeat is there but not valid), the end rows over the columns, then the rows over the end columns,
    each point as ``Subaperture.plane_points`` computes it. ``scratch``: [2, 2, EDGE_POINTS] int64, the
    caller's (no arrays made in here: see _served_extent)."""
    last = EDGE_POINTS - 1
    for i in range(nr.size):
        row = i * copies
        h = z_m - centre[i, 2]
        for d in range(2):  # 0: the rows, 1: the columns, indices and whether each is the first of its value
            n = nr[i] if d == 0 else na[i]
            spacing = (n - 1) / last
            for j in range(EDGE_POINTS):
                scratch[d, 0, j] = int(j * spacing) if j < last else n - 1
                scratch[d, 1, j] = j == 0 or scratch[d, 0, j] != scratch[d, 0, j - 1]
        q = 0
        for part in range(2):  # [2, 64]: the end rows over the columns; [64, 2]: the rows over the end columns
            for outer in range(2 if part == 0 else EDGE_POINTS):
                for inner in range(EDGE_POINTS if part == 0 else 2):
                    if part == 0:
                        ir, ia, there = outer * (nr[i] - 1), scratch[1, 0, inner], scratch[1, 1, inner]
                    else:
                        ir, ia, there = scratch[0, 0, outer], inner * (na[i] - 1), scratch[0, 1, outer]
                    r = r0_m[i] + dr_m[i] * ir
                    alpha = a0[i] + da[i] * ia
                    b = math.sqrt(max(r * r * (1 - alpha * alpha) - h * h, 0.0))
                    ar = alpha * r
                    x[row, q] = centre[i, 0] + ar * axis[i, 0] + b * normal[i, 0]
                    y[row, q] = centre[i, 1] + ar * axis[i, 1] + b * normal[i, 1]
                    valid[row, q] = there != 0
                    q += 1
        for c in range(1, copies):  # (element by element: a slice is an array, which needs numba's runtime)
            for q in range(x.shape[1]):
                x[row + c, q], y[row + c, q], valid[row + c, q] = x[row, q], y[row, q], valid[row, q]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _served_extent(centre, axis, normal, centres, served_x, served_y, served, b_image, z_m, scratch, out):
    """Per node i: the range and alpha extremes of the plane points it serves (those at least half the image's
    distance ``b_image[i]`` from its axis) and its image's bandwidths there, r_min, r_max, a_min, a_max, f_r and
    f_a into out[i].

    The bandwidths are taken at every n-th served point (about OUTLINE_SAMPLES of them) and on a 5 x 5 grid
    of the (r, alpha) box, only where a point lies at least that half distance from the axis: a corner of the
    box can lie on the axis (b -> 0), where the derivatives diverge and would size the grid in the trillions.
    One pass a node, its points in two small buffers: as numpy arrays of a level's nodes x points these were
    ~26 MB of temporaries a plan, fresh pages from the OS wherever the allocator maps them anew. ``scratch``:
    [4, K + 25], the caller's (an array made in here would make loading this kernel from numba's cache several
    times dearer: it would need numba's runtime); [6, max(K + 25, M)], its last two rows the ratios of one
    point against each phase centre, computed a vector at a time (no branch in that loop: numpy's error
    model, no ZeroDivisionError check) before their maxima are taken in order."""
    n_served = served_x.shape[1]
    r_used, alpha_used, r_box, alpha_box, ratio_r, ratio_a = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4], scratch[5]  # noqa: E501
    n_centres = centres.shape[2]
    for i in range(centre.shape[0]):
        cx, cy, h = centre[i, 0], centre[i, 1], z_m - centre[i, 2]
        u0, u1, n0, n1 = axis[i, 0], axis[i, 1], normal[i, 0], normal[i, 1]
        half_b = 0.5 * b_image[i]
        r_min, r_max, a_min, a_max = np.inf, -np.inf, np.inf, -np.inf
        kept = 0
        for q in range(n_served):
            if not served[i, q]:
                continue
            rel_x, rel_y = served_x[i, q] - cx, served_y[i, q] - cy
            along, across = rel_x * u0 + rel_y * u1, rel_x * n0 + rel_y * n1
            if not across >= half_b:  # a parent's grid reaches further out in angle than the image
                continue
            r = math.sqrt(along * along + across * across + h * h)
            alpha = along / r
            r_min, r_max, a_min, a_max = min(r_min, r), max(r_max, r), min(a_min, alpha), max(a_max, alpha)
            kept += 1
        step = max(1, kept // OUTLINE_SAMPLES)
        used = seen = 0
        for q in range(n_served):
            if not served[i, q]:
                continue
            rel_x, rel_y = served_x[i, q] - cx, served_y[i, q] - cy
            along, across = rel_x * u0 + rel_y * u1, rel_x * n0 + rel_y * n1
            if not across >= half_b:
                continue
            seen += 1
            if (seen - 1) % step != 0:
                continue
            r = math.sqrt(along * along + across * across + h * h)
            alpha = along / r
            if not r * r * (1 - alpha * alpha) - h * h < half_b * half_b:
                r_used[used], alpha_used[used] = r, alpha
                used += 1
        # The box, as np.linspace(lo, hi, 5) computes it, row-major over (alpha, r).
        for j in range(4):
            r_box[j] = j * ((r_max - r_min) / 4) + r_min
            alpha_box[j] = j * ((a_max - a_min) / 4) + a_min
        r_box[4], alpha_box[4] = r_max, a_max
        for t in range(25):
            r, alpha = r_box[t % 5], alpha_box[t // 5]
            if not r * r * (1 - alpha * alpha) - h * h < half_b * half_b:
                r_used[used], alpha_used[used] = r, alpha
                used += 1
        # |d/dr| and |d/dalpha| of |g - m| - |g - c| over those points g(r, alpha) and the node's phase centres m,
        # the largest of each: with 2 / lambda they are its demodulated image's bandwidths. (Written out here:
        # a call of another kernel made loading this one from numba's cache 8x dearer.)
        f_r = f_a = 0.0
        for q in range(used):
            rq, aq = r_used[q], alpha_used[q]
            b = math.sqrt(max(rq * rq * (1 - aq * aq) - h * h, 1e-12))  # as Subaperture.plane_points, b >= 1e-6
            gx = cx + aq * rq * u0 + b * n0
            gy = cy + aq * rq * u1 + b * n1
            # d g / d r = alpha u + (r (1 - alpha^2) / b) n; d g / d alpha = r u - (alpha r^2 / b) n (horizontal).
            across_r, across_a = rq * (1 - aq * aq) / b, -(aq * rq * rq / b)
            drx, dry = aq * u0 + across_r * n0, aq * u1 + across_r * n1
            dax, day = rq * u0 + across_a * n0, rq * u1 + across_a * n1
            for k in range(n_centres):
                lx, ly, lz = gx - centres[i, 0, k], gy - centres[i, 1, k], z_m - centres[i, 2, k]
                inv = 1.0 / math.sqrt(lx * lx + ly * ly + lz * lz)
                ratio_r[k] = abs((lx * drx + ly * dry) * inv - 1.0)
                ratio_a[k] = abs((lx * dax + ly * day) * inv)
            for k in range(n_centres):
                f_r = max(f_r, ratio_r[k])
                f_a = max(f_a, ratio_a[k])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4], out[i, 5] = r_min, r_max, a_min, a_max, f_r, f_a


def place_grids(centre, axis, normal, centres, served_x, served_y, served, b_image, z_m: float, *, envelope: float,
                two_over_lambda: float, oversample_range, oversample_angle, half_taps):
    """Size N nodes' polar grids to cover the plane points they serve, with the taps to interpolate inside.

    Parameters
    ----------
    centre, axis, normal, centres
        The nodes' frames and phase centres (:func:`node_frames`).
    served_x, served_y, served : ndarray, shape (N, K)
        The points each node serves (the image's outline, or its parent's grid edge) and which are there.
    b_image : ndarray, shape (N,)
        The image's least distance from each node's axis (:func:`node_frames`, positive).
    envelope, two_over_lambda : float
        The profiles' band (cycles per metre of range) and 2 / the shortest wavelength.
    oversample_range, oversample_angle, half_taps : ndarray, shape (N,)
        Each node's grid sampling (``FactorizedOptions.sampling``).

    Returns
    -------
    (r0_m, dr_m, a0, da, nr, na), arrays of shape (N,) (as ``Subaperture``'s fields).
    """
    extent = np.empty((len(centre), 6))
    scratch = np.empty((6, max(served_x.shape[1] + 25, centres.shape[2])))
    _served_extent(centre, axis, normal, centres, served_x, served_y, served, b_image, float(z_m), scratch, extent)
    r_min, r_max, a_min, a_max, f_r, f_a = extent.T
    dr = 1.0 / (2 * (envelope + two_over_lambda * f_r) * BAND_MARGIN * oversample_range)
    da = np.minimum(1.0 / (2 * np.maximum(two_over_lambda * f_a, 1e-9) * BAND_MARGIN * oversample_angle), 0.1)
    # The merge and pixel kernels read taps/2 - 1 samples below the floor of a position and taps/2 above it.
    r0 = r_min - half_taps * dr
    nr = np.floor((r_max - r0) / dr).astype(int) + half_taps + 1
    a0 = np.maximum(a_min - half_taps * da, -1.0)
    na = np.floor((np.minimum(a_max, 1.0) - a0) / da).astype(int) + half_taps + 1
    return r0, dr, a0, da, nr, na


def load_passes() -> None:
    """Load this module's numba passes from numba's cache (or compile them) now, with the argument types a
    plan gives them, by placing two nodes of four phase centres: a process's first plan otherwise pays their
    cache loads (``imaging.kernel_import`` calls this on its background thread when ``sarbot image`` asks
    for FFBP)."""
    m = tuple(np.ascontiguousarray(v) for v in np.array([[0.0, 0.1, 0.2, 0.3], [0.0, 0.001, 0.0, 0.001], [0.3] * 4]))
    image_xy = np.array([[-0.5, 2.0], [0.5, 2.0], [0.5, 2.5], [-0.5, 2.5]])
    frames = node_frames(m, np.array([0, 2]), np.array([2, 2]), track_axis(m), image_xy)
    frames = [f[np.arange(2)] for f in frames]  # as the plan passes them: the nodes picked, contiguous copies
    tiled = (np.tile(image_xy[:, 0], (2, 1)), np.tile(image_xy[:, 1], (2, 1)), np.ones((2, 4), bool))
    ones = np.ones(2)
    grids = place_grids(*frames[:4], *tiled, frames[4], 0.0, envelope=1.0, two_over_lambda=500.0,
                        oversample_range=ones, oversample_angle=ones, half_taps=np.full(2, 3))
    grid_edges(*frames[:3], *grids, 0.0, copies=2)
