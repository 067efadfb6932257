"""The FFBP plan builder as it was before it gave every node its frame in one pass and kept the tree in arrays
(imaging.factorized_backprojection.plan_factorized at be1579c: the nodes of one length a pass, each step down
the tree placed a pass, the bookkeeping a Python loop over nodes): the reference the planner is checked
against, to the bit (tests/test_ffbp_plan.py). Kept verbatim but for its imports; do not "improve" it."""

from __future__ import annotations

import math

import numpy as np

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.factorized_backprojection import MAX_GRID_PER_PIXEL, FactorizedOptions, FactorizedPlan, Subaperture, _midpoints, _outline
from reference_ffbp_placement_batched import grid_edges, image_distance, node_frames, place_grids, track_axis


def plan_factorized_batched(tx_m: np.ndarray, rx_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: float,
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
    image_xy = _outline(x_m, y_m) if outline_xy is None else np.asarray(outline_xy, np.float64).reshape(-1, 2)
    centre_xy = image_xy.mean(axis=0)
    columns = tuple(_midpoints(tx[:, i], rx[:, i]) for i in range(3))  # the phase centres' x, y and z
    overall = track_axis(columns)
    two_over_lambda = 2 * (carrier_hz + bandwidth_hz / 2) / SPEED_OF_LIGHT_MPS
    envelope = bandwidth_hz / SPEED_OF_LIGHT_MPS  # the range profile's band, cycles per metre of range
    n_pix = x_m.size * y_m.size

    def build(start: int, stop: int) -> Subaperture:
        n_leaf = -(-(stop - start) // o.leaf_profiles)
        children: tuple = ()
        if n_leaf > 1:
            mid = start + (n_leaf // 2) * o.leaf_profiles
            children = (build(start, mid), build(mid, stop))
        return Subaperture(start, stop, 1 + max(ch.level for ch in children) if children else 0, None, None, None, children)

    # Every node's frame, the nodes of one length in one pass (imaging.ffbp_placement).
    whole = build(0, tx.shape[0])
    by_length: dict = {}
    stack = [whole]
    while stack:
        node = stack.pop()
        by_length.setdefault(node.stop - node.start, []).append(node)
        stack.extend(node.children)
    extremes = {}  # id(node) -> the phase centres its grid's bandwidths are taken over
    for length, group in by_length.items():
        frames = node_frames(columns, np.array([nd.start for nd in group]), length, overall, centre_xy)
        for i, node in enumerate(group):
            node.centre_m, node.axis, node.normal = frames[0][i], frames[1][i], frames[2][i]
            extremes[id(node)] = frames[3][i]

    def place(batch: list, served_x: np.ndarray, served_y: np.ndarray, served: np.ndarray) -> None:
        """Size the grids of the nodes ``batch`` to cover the plane points each serves ([N, K], where
        ``served``: the image's outline, or the edge of its parent's grid), in one pass."""
        centre = np.stack([nd.centre_m for nd in batch])
        normal = np.stack([nd.normal for nd in batch])
        b_image = image_distance(centre, normal, image_xy)
        if np.any(b_image <= 0):
            i = int(np.flatnonzero(b_image <= 0)[0])
            raise ValueError("the image must lie to one side of the radar's track (FFBP images a side-looking pass); "
                             f"the track of profiles {batch[i].start}-{batch[i].stop} passes {-b_image[i]:.3f} m inside it")
        sampling = np.array([o.sampling(leaf=not nd.children) for nd in batch])
        longest = max(extremes[id(nd)].shape[0] for nd in batch)
        centres = np.stack([np.concatenate([e, np.repeat(e[:1], longest - e.shape[0], axis=0)])
                            for e in (extremes[id(nd)] for nd in batch)])  # padded with a copy: same maxima
        grids = place_grids(centre, np.stack([nd.axis for nd in batch]), normal, centres, served_x, served_y, served,
                            b_image, z_m, envelope=envelope, two_over_lambda=two_over_lambda,
                            oversample_range=sampling[:, 0], oversample_angle=sampling[:, 1],
                            half_taps=sampling[:, 2].astype(int) // 2)
        for i, node in enumerate(batch):
            node.r0_m, node.dr_m, node.a0, node.da = (float(v[i]) for v in grids[:4])
            node.nr, node.na = int(grids[4][i]), int(grids[5][i])

    # The roots: merge up to a node only while its grid costs less than interpolating its children at the
    # pixels; a step down the tree at a time, each step's nodes placed (on the image's outline) in one pass.
    roots, candidates = [], [whole]
    outline_x, outline_y = image_xy[:, 0], image_xy[:, 1]
    while candidates:
        shape = (len(candidates), image_xy.shape[0])
        # (tiled, not broadcast: the arrays of the steps below, so that the pass has one compiled signature)
        place(candidates, np.tile(outline_x, (shape[0], 1)), np.tile(outline_y, (shape[0], 1)), np.ones(shape, bool))
        deeper = []
        for node in candidates:
            if node.children and 2 * node.nr * node.na > n_pix:
                deeper.extend(node.children)
                continue
            leaf_cost = (node.stop - node.start) * node.nr * node.na + n_pix * o.sampling(True)[2] ** 2
            if not node.children and leaf_cost > (node.stop - node.start) * n_pix:
                node.direct = True  # cheaper straight onto the pixels
            roots.append(node)
        candidates = deeper
    roots.sort(key=lambda nd: nd.start)
    # Below the roots, each child's grid covers its parent's: a step down the trees at a time.
    parents = [r for r in roots if r.children]
    while parents:
        edge = grid_edges(*(np.stack([getattr(p, f) for p in parents]) for f in ("centre_m", "axis", "normal")),
                          *(np.array([getattr(p, f) for p in parents]) for f in ("r0_m", "dr_m", "a0", "da", "nr", "na")), z_m)
        of_parent = np.repeat(np.arange(len(parents)), [len(p.children) for p in parents])
        children = [c for p in parents for c in p.children]
        place(children, *(e[of_parent] for e in edge))
        parents = [c for c in children if c.children]
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
