"""imaging/ffbp_placement.py as it was when FFBP's plan placed a step of the tree a pass (the batched planner,
before the planner that places every node's frame in one pass): the placement tests/reference_ffbp_plan_batched.py
uses. Kept verbatim but for this docstring; do not "improve" it."""

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
    _moments(*m, np.zeros(1, np.int64), m[0].size, moments)
    cov = moments[0, [3, 4, 4, 5]].reshape(2, 2)
    u = np.linalg.eigh(cov)[1][:, -1] if np.any(cov) else np.array([1.0, 0.0])
    return u / np.linalg.norm(u)


def node_frames(m: tuple, starts: np.ndarray, length: int, overall: np.ndarray, centre_xy: np.ndarray):
    """Centre, axis, normal and extreme phase centres of nodes of ``length`` profiles from ``starts``.

    Parameters
    ----------
    m : tuple of three ndarray, shape (P,)
        x, y and z of the phase centres of all profiles (each contiguous: this pass reads every profile of
        every node, so the whole track once per level of the tree).
    starts : ndarray of int, shape (N,)
        First profile of each node; node i holds profiles [starts[i], starts[i] + length).
    overall : ndarray, shape (2,)
        The whole track's horizontal axis: a node's axis points its way.
    centre_xy : ndarray, shape (2,)
        The served region's centre: a node's normal points towards it.

    Returns
    -------
    centre (N, 3), axis (N, 2), normal (N, 2) and centres (N, M, 3): the phase centres furthest along and
    across the axis (both ways, diagonally, and in height) and every ``length / 23``-th, repeats included.
    """
    n_nodes = len(starts)
    moments = np.empty((n_nodes, 6))
    _moments(*m, starts, length, moments)
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
    normal *= np.where(_dot2(normal, centre_xy - centre[:, :2]) < 0, -1.0, 1.0)[:, None]
    picks = np.empty((n_nodes, 10), np.int64)
    _extremes(*m, starts, length, u, normal, picks)
    stride = np.arange(0, length, max(1, length // CENTRE_STRIDE_DIVISOR))
    chosen = starts[:, None] + np.concatenate([picks, np.broadcast_to(stride, (n_nodes, stride.size))], axis=1)
    return centre, u, normal, np.stack([v[chosen] for v in m], axis=-1)


@numba.njit(cache=True, nogil=True)
def _moments(x, y, z, starts, length, out):
    """Per node (profiles [starts[i], starts[i] + length)): the mean of x, y, z and the sums of dx dx, dx dy,
    dy dy about it, into out[i] (two passes: the sums of squares about the mean, not about the origin)."""
    for i in range(starts.size):
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
def _extremes(x, y, z, starts, length, u, n, out):
    """Per node, the offsets (from its first profile) of the least and the greatest s, p, s + p, s - p and z
    (s along its axis u, p along its normal n), the first of equals as np.argmin / np.argmax, into out[i]."""
    for i in range(starts.size):
        first = starts[i]
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


def _edge_indices(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per node, ``np.unique(np.linspace(0, n - 1, EDGE_POINTS).astype(int))`` as [N, EDGE_POINTS] indices
    (the linspace as numpy computes it) and a mask of the first of each run of equal ones."""
    index = np.arange(EDGE_POINTS, dtype=np.float64)[None, :] * ((n - 1) / (EDGE_POINTS - 1))[:, None]
    index[:, -1] = n - 1
    index = index.astype(int)
    first = np.ones(index.shape, bool)
    first[:, 1:] = index[:, 1:] != index[:, :-1]
    return index, first


def grid_edges(centre, axis, normal, r0_m, dr_m, a0, da, nr, na, z_m: float):
    """Points on the edge of N nodes' polar grids (their first and last rows at up to 64 columns, their
    first and last columns at up to 64 rows, in that order): x, y of shape [N, 4 EDGE_POINTS] and the mask
    of the points that are there (a grid with fewer rows or columns has fewer)."""
    ir, first_r = _edge_indices(nr)
    ia, first_a = _edge_indices(na)
    ends_r = np.stack([np.zeros_like(nr), nr - 1], axis=1)
    ends_a = np.stack([np.zeros_like(na), na - 1], axis=1)
    # [N, 2, 64]: the end rows over the columns; [N, 64, 2]: the rows over the end columns (row-major, as
    # the order of the points counts where every n-th is taken).
    rows = [(ends_r[:, :, None], ia[:, None, :], np.broadcast_to(first_a[:, None, :], (len(nr), 2, EDGE_POINTS))),
            (ir[:, :, None], ends_a[:, None, :], np.broadcast_to(first_r[:, :, None], (len(nr), EDGE_POINTS, 2)))]
    xs, ys, valid = [], [], []
    for i_r, i_a, there in rows:
        r = r0_m[:, None, None] + dr_m[:, None, None] * i_r
        alpha = a0[:, None, None] + da[:, None, None] * i_a
        r, alpha = np.broadcast_arrays(r, alpha)
        x, y, _ = plane_points(centre, axis, normal, r, alpha, z_m)
        xs.append(x.reshape(len(nr), -1))
        ys.append(y.reshape(len(nr), -1))
        valid.append(there.reshape(len(nr), -1))
    return np.concatenate(xs, axis=1), np.concatenate(ys, axis=1), np.concatenate(valid, axis=1)


@numba.njit(cache=True, nogil=True)
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
    times dearer: it would need numba's runtime)."""
    n_served = served_x.shape[1]
    r_used, alpha_used, r_box, alpha_box = scratch[0], scratch[1], scratch[2], scratch[3]
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
            for k in range(centres.shape[1]):
                lx, ly, lz = gx - centres[i, k, 0], gy - centres[i, k, 1], z_m - centres[i, k, 2]
                inv = 1.0 / math.sqrt(lx * lx + ly * ly + lz * lz)
                f_r = max(f_r, abs((lx * drx + ly * dry) * inv - 1.0))
                f_a = max(f_a, abs((lx * dax + ly * day) * inv))
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4], out[i, 5] = r_min, r_max, a_min, a_max, f_r, f_a


def image_distance(centre: np.ndarray, normal: np.ndarray, image_xy: np.ndarray) -> np.ndarray:
    """The least distance of the image's outline ``image_xy`` [M, 2] from N nodes' axes, on the side of their
    normals, [N]: FFBP needs it positive (a side-looking pass)."""
    return ((image_xy[None, :, 0] - centre[:, None, 0]) * normal[:, None, 0]
            + (image_xy[None, :, 1] - centre[:, None, 1]) * normal[:, None, 1]).min(axis=1)


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
        The image's least distance from each node's axis (:func:`image_distance`, positive).
    envelope, two_over_lambda : float
        The profiles' band (cycles per metre of range) and 2 / the shortest wavelength.
    oversample_range, oversample_angle, half_taps : ndarray, shape (N,)
        Each node's grid sampling (``FactorizedOptions.sampling``).

    Returns
    -------
    (r0_m, dr_m, a0, da, nr, na), arrays of shape (N,) (as ``Subaperture``'s fields).
    """
    extent = np.empty((len(centre), 6))
    scratch = np.empty((4, served_x.shape[1] + 25))
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
