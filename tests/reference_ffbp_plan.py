"""The FFBP plan builder as it was before it placed a level's grids in one pass (one node at a time, ~50 small
numpy calls each): the reference ``imaging.factorized_backprojection.plan_factorized`` is checked against
(tests/test_ffbp_plan.py). Kept verbatim but for its imports; do not "improve" it."""

from __future__ import annotations

import math

import numpy as np

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.factorized_backprojection import MAX_GRID_PER_PIXEL, FactorizedOptions, FactorizedPlan, Subaperture
from imaging.ffbp_interpolation import BAND_MARGIN


def _horizontal_axis(m: np.ndarray, reference: np.ndarray | None) -> np.ndarray:
    """Principal horizontal direction of points m [P, 3] (sign as ``reference``)."""
    xy = m[:, :2] - m[:, :2].mean(axis=0)
    cov = xy.T @ xy
    if not np.any(cov):
        u = np.array([1.0, 0.0]) if reference is None else reference.copy()
    else:
        u = np.linalg.eigh(cov)[1][:, -1]
    if reference is not None and u @ reference < 0:
        u = -u
    return u / np.linalg.norm(u)


def _outline(x_m, y_m, n: int = 64) -> np.ndarray:
    """Points on the border of the image rectangle, [4n, 2]."""
    x0, x1, y0, y1 = x_m[0], x_m[-1], y_m[0], y_m[-1]
    s = np.linspace(0, 1, n)
    return np.concatenate([np.stack([x0 + (x1 - x0) * s, np.full(n, y0)], 1), np.stack([x0 + (x1 - x0) * s, np.full(n, y1)], 1),
                           np.stack([np.full(n, x0), y0 + (y1 - y0) * s], 1), np.stack([np.full(n, x1), y0 + (y1 - y0) * s], 1)])


def _extreme_points(m: np.ndarray, u: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The phase centres furthest along and across the axis (both ways, and diagonally), and every
    ``len/23``-th (a prime stride, so that TDM's repeating channel order does not pick one channel)."""
    s, p = m[:, :2] @ u, m[:, :2] @ n
    picks = [f(v) for v in (s, p, s + p, s - p, m[:, 2]) for f in (np.argmin, np.argmax)]
    stride = max(1, m.shape[0] // 23)
    return m[np.unique(np.concatenate([picks, np.arange(0, m.shape[0], stride)]))]


def _polar_derivatives(node: Subaperture, m: np.ndarray, r: np.ndarray, alpha: np.ndarray, z_m: float):
    """|d/dr| and |d/dalpha| of |g - m| - |g - c| over points g(r, alpha) of the plane and phase centres m,
    largest of each: with 2 / lambda they are the demodulated image's bandwidths."""
    u = np.array([*node.axis, 0.0])
    n = np.array([*node.normal, 0.0])
    g, b = node.plane_points(r, alpha, z_m, b_min_m=1e-6)
    dg_dr = alpha[:, None] * u + (r * (1 - alpha ** 2) / b)[:, None] * n
    dg_da = r[:, None] * u - (alpha * r * r / b)[:, None] * n
    los = g[:, None, :] - m[None, :, :]
    los /= np.linalg.norm(los, axis=-1, keepdims=True)  # [Q, M, 3] unit vectors from the phase centres
    f_r = np.abs(np.einsum("qmk,qk->qm", los, dg_dr) - 1.0).max()
    f_a = np.abs(np.einsum("qmk,qk->qm", los, dg_da)).max()
    return float(f_r), float(f_a)


def plan_factorized_reference(tx_m: np.ndarray, rx_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: float,
                    carrier_hz: float, bandwidth_hz: float, options: FactorizedOptions = FactorizedOptions(),
                    outline_xy: np.ndarray | None = None) -> FactorizedPlan:
    """Build the subaperture trees and every node's polar grid.

    Parameters
    ----------
    tx_m, rx_m : ndarray, shape (P, 3)
        Antenna positions of the profiles, in time order (a subaperture is a run of consecutive profiles).
    x_m, y_m : ndarray
        The image's pixel centres along x and y (increasing), metres.
    z_m : float
        Height of the image plane.
    carrier_hz, bandwidth_hz : float
        The profiles' carrier (``RangeProfiles.carrier_hz``) and swept bandwidth, which with the geometry
        set the range and angle sampling.
    outline_xy : ndarray, shape (M, 2), optional
        Points of the plane around the pixels whose values matter, when that is less than the whole grid
        (the strip map's footprint, a rotated rectangle inside its tiles' bounding box). The polar grids
        cover it and it alone must lie to one side of the track; the other pixels get values of no use.
        By default the grid's outline.
    """
    o = options
    tx = np.asarray(tx_m, np.float64).reshape(-1, 3)
    rx = np.asarray(rx_m, np.float64).reshape(-1, 3)
    if tx.shape != rx.shape or tx.shape[0] == 0:
        raise ValueError(f"need P > 0 TX and RX positions of shape (P, 3); got {tx.shape} and {rx.shape}")
    x_m, y_m = np.asarray(x_m, np.float64).ravel(), np.asarray(y_m, np.float64).ravel()
    if x_m.size < 1 or y_m.size < 1 or np.any(np.diff(x_m) <= 0) or np.any(np.diff(y_m) <= 0):
        raise ValueError("x_m and y_m must be increasing pixel centres")
    if not (bandwidth_hz > 0 and carrier_hz > bandwidth_hz / 2):
        raise ValueError(f"bandwidth {bandwidth_hz} Hz and carrier {carrier_hz} Hz do not describe a radar")
    m = 0.5 * (tx + rx)
    image_xy = _outline(x_m, y_m) if outline_xy is None else np.asarray(outline_xy, np.float64).reshape(-1, 2)
    centre_xy = image_xy.mean(axis=0)
    overall = _horizontal_axis(m, None)
    two_over_lambda = 2 * (carrier_hz + bandwidth_hz / 2) / SPEED_OF_LIGHT_MPS
    envelope = bandwidth_hz / SPEED_OF_LIGHT_MPS  # the range profile's band, cycles per metre of range
    n_pix = x_m.size * y_m.size

    def build(start: int, stop: int) -> Subaperture:
        n_leaf = -(-(stop - start) // o.leaf_profiles)
        children: tuple = ()
        if n_leaf > 1:
            mid = start + (n_leaf // 2) * o.leaf_profiles
            children = (build(start, mid), build(mid, stop))
        mm = m[start:stop]
        c = mm.mean(axis=0)
        u = _horizontal_axis(mm, overall)
        n = np.array([-u[1], u[0]])
        if n @ (centre_xy - c[:2]) < 0:
            n = -n
        return Subaperture(start, stop, 1 + max(ch.level for ch in children) if children else 0, c, u, n, children)

    def place(node: Subaperture, needed_xy: np.ndarray) -> None:
        """Size ``node``'s grid to cover the plane points ``needed_xy`` [M, 2] (the image's outline, or
        the outline of its parent's grid) with the taps to interpolate anywhere inside."""
        c, u, n = node.centre_m, node.axis, node.normal
        oversample_range, oversample_angle, taps = o.sampling(leaf=not node.children)
        half_taps = taps // 2
        h = z_m - c[2]
        b_image = float(((image_xy - c[:2]) @ n).min())
        if b_image <= 0:
            raise ValueError("the image must lie to one side of the radar's track (FFBP images a side-looking pass); "
                             f"the track of profiles {node.start}-{node.stop} passes {-b_image:.3f} m inside it")
        rel = needed_xy - c[:2]
        # A parent's grid reaches further out in angle than the image; near the track no pixel needs it.
        rel = rel[rel @ n >= 0.5 * b_image]
        along = rel @ u
        r = np.sqrt(along ** 2 + (rel @ n) ** 2 + h ** 2)
        alpha = along / r
        # Bandwidths from the geometry itself (at the outline, and inside it on a coarse grid), so that a
        # long subaperture's range curvature or a bent track widens the grid instead of aliasing it.
        rq, aq = np.meshgrid(np.linspace(r.min(), r.max(), 5), np.linspace(alpha.min(), alpha.max(), 5))
        edge = slice(None, None, max(1, r.size // 48))
        rs, as_ = np.concatenate([r[edge], rq.ravel()]), np.concatenate([alpha[edge], aq.ravel()])
        # Only where the grid is needed: a corner of the (r, alpha) box can lie on the axis (b -> 0), where
        # the derivatives diverge and would size the grid in the trillions.
        near = rs ** 2 * (1 - as_ ** 2) - h ** 2 < (0.5 * b_image) ** 2
        rs, as_ = rs[~near], as_[~near]
        centres = _extreme_points(m[node.start:node.stop], u, n)
        f_r, f_a = _polar_derivatives(node, centres, rs, as_, z_m)
        dr = 1.0 / (2 * (envelope + two_over_lambda * f_r) * BAND_MARGIN * oversample_range)
        da = min(1.0 / (2 * max(two_over_lambda * f_a, 1e-9) * BAND_MARGIN * oversample_angle), 0.1)
        node.dr_m, node.da = dr, da
        # The merge and pixel kernels read taps/2 - 1 samples below the floor of a position and taps/2 above it.
        node.r0_m = float(r.min() - half_taps * dr)
        node.nr = int(math.floor((r.max() - node.r0_m) / dr)) + half_taps + 1
        node.a0 = float(max(alpha.min() - half_taps * da, -1.0))
        node.na = int(math.floor((min(alpha.max(), 1.0) - node.a0) / da)) + half_taps + 1

    def grid_edge(node: Subaperture, per_side: int = 64) -> np.ndarray:
        ir = np.unique(np.linspace(0, node.nr - 1, per_side).astype(int))
        ia = np.unique(np.linspace(0, node.na - 1, per_side).astype(int))
        ends_r, ends_a = np.array([0, node.nr - 1]), np.array([0, node.na - 1])
        return np.concatenate([node.polar_points(z_m, ends_r, ia).reshape(-1, 3),
                               node.polar_points(z_m, ir, ends_a).reshape(-1, 3)])[:, :2]

    def place_subtree(node: Subaperture) -> None:
        edge = grid_edge(node)
        for child in node.children:
            place(child, edge)
            place_subtree(child)

    def choose_roots(node: Subaperture) -> list:
        """Merge up to ``node`` only while its grid costs less than interpolating its children at the pixels."""
        place(node, image_xy)
        if node.children and 2 * node.nr * node.na > n_pix:
            return [r for child in node.children for r in choose_roots(child)]
        if not node.children and (node.stop - node.start) * node.nr * node.na + n_pix * o.sampling(True)[2] ** 2 > (node.stop - node.start) * n_pix:
            node.direct = True  # cheaper straight onto the pixels
        return [node]

    whole = build(0, tx.shape[0])
    roots = choose_roots(whole)
    for root in roots:
        place_subtree(root)
    k = 2 * math.pi * carrier_hz / SPEED_OF_LIGHT_MPS
    plan = FactorizedPlan(roots, x_m, y_m, float(z_m), o, k)
    # Phase centres all but on the image's edge, or a track bent towards it, can ask a subtree for polar grids
    # far beyond the pixels (a live strip map once asked for 7e11 samples): then the profiles go straight
    # onto the pixels, which is never dearer than that.
    cost = plan.cost()
    largest = max((n.nr * n.na for n in plan.nodes() if not n.direct), default=0)
    operations = cost["leaf_backprojections"] + cost["multiply_adds"]
    if largest > MAX_GRID_PER_PIXEL * max(n_pix, 4096) or operations > cost["direct_backprojections"]:
        whole.children, whole.level, whole.direct = (), 0, True
        plan = FactorizedPlan([whole], x_m, y_m, float(z_m), o, k)
    return plan
