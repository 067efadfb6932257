"""Fast factorized backprojection (FFBP) onto a horizontal image plane, with its error bound.

Direct backprojection costs P x N (profiles x pixels). FFBP (Ulander, Hellsten and Stenström, IEEE TAES
39(3), 2003) instead splits the aperture into short subapertures of consecutive profiles and merges them
pairwise up a balanced tree:

* **Leaves.** A subaperture of ``leaf_profiles`` profiles is short, so its image varies slowly in angle:
  the ordinary kernel (``imaging.backprojection``) images it onto a coarse polar grid around its centre c,
  range r = |g - c| and alpha = cos(angle to the subaperture's axis u) = u . (g - c) / r. The grid holds
  the image times exp(+j k 2r) ("demodulated"): baseband in range (the profile's bandwidth) and, in
  alpha, within +-(2 / lambda) x the subaperture's half-length, so that it can be interpolated.
* **Merges.** A parent (twice the aperture, so a finer grid in alpha) takes each grid point g, finds it in each child's polar coordinates, interpolates the child there and re-references
  the phase from the child's centre to its own: ``D_parent(g) = sum D_child(g) exp(-j k 2 (|g - c_child| -
  |g - c_parent|))``.
* **Pixels.** Each root is interpolated at every pixel and given back its phase ``exp(-j k 2 |g - c|)``.
  Merging stops where a parent's grid would cost more than that: near the aperture a subaperture as long
  as the range has range curvature, which needs a fine range grid.

So the cost is P x (leaf grid) + levels x (grid samples) x 2 x taps^2 + N x taps^2, nearly independent of
N x P: the longer the aperture and the larger the image, the larger the gain.

Geometry. Positions are float64 world coordinates. Each subaperture's axis is the horizontal principal
direction of its antennas' phase centres (so a curved drive is followed piecewise); the image must lie on
one side of every axis (a side-looking radar). A grid's range and alpha spacing come from the largest
derivatives of |g - m| - |g - c| over its phase centres m and the region it covers, so range curvature,
vibration or a bend widen the grid rather than alias it. The plan computes these for many nodes a pass
(``imaging.ffbp_placement``: every node's frame in one, then the grids of one step down the tree; the tree
itself as arrays, ``imaging.ffbp_tree``), a fraction of the run's time; it can still be reused for images of
the same geometry (``plan_factorized`` / ``run_factorized``).

Interpolation. Separable, ``taps`` x ``taps`` per sample, with coefficients that minimise the squared error
over the band the grid is oversampled for (the optimum for band-limited signals, Knab's kind of
interpolator), tabulated at 2048 fractional shifts. :func:`interpolation_error` gives the worst error of a
tone anywhere in that band; :attr:`FactorizedPlan.error_bound_db` adds it up along the tree. The leaves'
grids are sampled coarser (1.5x over Nyquist against 2x) and read with more taps (8 against 6): a leaf's grid
costs a backprojection per profile (512 of them) and point, a merged grid only taps^2 multiply-adds per child
and point, so this trades a third of the leaves' work for a little more in the first merge
(benchmarks/ffbp.py charts the settings' speed against their error).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numba
import numpy as np

from imaging.backprojection import backproject
from imaging.core.config import require
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.grid import Grid
from imaging.ffbp_leaves import image_leaves, load_kernel
from imaging.ffbp_merge import _merge_rows, _to_plane, _to_plane_rows  # noqa: F401 - _to_plane: tests use it
from imaging.ffbp_placement import grid_edges, node_frames, place_grids, track_axis
from imaging.ffbp_tasks import Pool, leaf_runs, row_ranges
from imaging.ffbp_tree import Tree, split_tree
from imaging.ffbp_interpolation import (  # noqa: F401 - part of this module's interface
    BAND_MARGIN,
    TABLE_SHIFTS,
    interpolation_error,
    interpolation_rms_error,
    interpolation_table,
)
from imaging.range_compression import RangeProfiles

#: A plan whose largest polar grid exceeds this many samples per pixel has gone astray: it goes direct.
MAX_GRID_PER_PIXEL = 4


@dataclasses.dataclass(frozen=True)
class FactorizedOptions:
    """FFBP settings.

    ``leaf_profiles``: profiles per leaf subaperture (the reference radar's 16 channels x 32 chirps is 512).
    ``oversample_range`` / ``oversample_angle``: grid oversampling over Nyquist. ``taps``: interpolation
    taps per dimension (even). ``leaf_oversample`` / ``leaf_taps``: the same for the leaves' grids, in range
    and angle (None: as the others). A leaf's grid costs a backprojection per profile and point, a merged
    grid ``taps``^2 multiply-adds per child and point: so the leaves' grids are coarse and read with more
    taps. ``mode``: the direct kernel's interpolation for the leaves.
    """

    leaf_profiles: int = 512
    oversample_range: float = 2.0
    oversample_angle: float = 2.0
    taps: int = 6
    leaf_oversample: float | None = 1.5
    leaf_taps: int | None = 8
    mode: str = "linear"

    def __post_init__(self) -> None:
        require(self.leaf_profiles >= 1, "leaf_profiles", f"must be at least 1, got {self.leaf_profiles}")
        require(1.2 <= self.oversample_range <= 16, "oversample_range", f"must be in [1.2, 16], got {self.oversample_range}")
        require(1.2 <= self.oversample_angle <= 16, "oversample_angle", f"must be in [1.2, 16], got {self.oversample_angle}")
        require(self.taps in (2, 4, 6, 8, 10, 12), "taps", f"must be an even number from 2 to 12, got {self.taps}")
        require(self.leaf_oversample is None or 1.2 <= self.leaf_oversample <= 16, "leaf_oversample",
                f"must be in [1.2, 16], got {self.leaf_oversample}")
        require(self.leaf_taps in (None, 2, 4, 6, 8, 10, 12), "leaf_taps", f"must be an even number from 2 to 12, got {self.leaf_taps}")
        require(self.mode in ("nearest", "linear", "exact"), "mode", f"must be nearest, linear or exact, got {self.mode!r}")

    def sampling(self, leaf: bool) -> tuple[float, float, int]:
        """(oversample in range, oversample in angle, taps) of a leaf's grid or of a merged one."""
        if not leaf:
            return self.oversample_range, self.oversample_angle, self.taps
        return (self.leaf_oversample or self.oversample_range, self.leaf_oversample or self.oversample_angle,
                self.leaf_taps or self.taps)


# -- the plan: the tree, each subaperture's polar grid -------------------------------------------------------
@dataclasses.dataclass
class Subaperture:
    """One node of the tree: profiles [start, stop), its polar grid and where it sits."""

    start: int
    stop: int
    level: int  # 0 for leaves
    centre_m: np.ndarray  # [3]
    axis: np.ndarray  # [2], horizontal unit vector along the subaperture
    normal: np.ndarray  # [2], horizontal unit vector towards the image
    children: tuple = ()
    r0_m: float = 0.0
    dr_m: float = 0.0
    a0: float = 0.0
    da: float = 0.0
    nr: int = 0
    na: int = 0
    direct: bool = False  # a leaf backprojected straight onto the pixels

    @property
    def geometry(self) -> np.ndarray:
        c, u, n = self.centre_m, self.axis, self.normal
        return np.array([c[0], c[1], c[2], u[0], u[1], n[0], n[1], self.r0_m, self.dr_m, self.a0, self.da])

    def plane_points(self, r: np.ndarray, alpha: np.ndarray, z_m: float, b_min_m: float = 0.0):
        """The points of the plane z_m at range r and alpha (broadcast), [..., 3], and their distance b
        from the axis (at least ``b_min_m``; points off the plane, never used, are put there)."""
        h = z_m - self.centre_m[2]
        b = np.sqrt(np.maximum(r * r * (1 - alpha * alpha) - h * h, b_min_m ** 2))
        xy = self.centre_m[:2] + (alpha * r)[..., None] * self.axis + b[..., None] * self.normal
        return np.concatenate([xy, np.full(xy.shape[:-1] + (1,), z_m)], axis=-1), b

    def polar_points(self, z_m: float, ir: np.ndarray | None = None, ia: np.ndarray | None = None) -> np.ndarray:
        """World points of its grid (rows ``ir``, columns ``ia``; all by default), [nr, na, 3]."""
        ir = np.arange(self.nr) if ir is None else ir
        ia = np.arange(self.na) if ia is None else ia
        return self.plane_points((self.r0_m + self.dr_m * ir)[:, None], (self.a0 + self.da * ia)[None, :], z_m)[0]


@dataclasses.dataclass
class FactorizedPlan:
    """The subaperture trees for one set of antenna positions and one image plane.

    ``roots`` are interpolated onto the pixels and summed. Merging stops where a parent's grid would cost
    more than interpolating its two children at the pixels: near the aperture, where the subaperture is as
    long as the range, its image's range curvature needs a fine range grid. A root may be a leaf marked
    ``direct`` (so small an image that the leaf's profiles go straight onto the pixels).
    """

    roots: list
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: float
    options: FactorizedOptions
    wavenumber: float  # k = 2 pi f_c / c (the phase is k x two-way range)

    @property
    def levels(self) -> int:
        """Merges on the longest path from a leaf to a root."""
        return max(r.level for r in self.roots)

    @property
    def direct_only(self) -> bool:
        """Every profile goes straight onto the pixels (FFBP would cost more here): no interpolation error."""
        return all(r.direct for r in self.roots)

    def nodes(self):
        stack = list(self.roots)
        while stack:
            node = stack.pop()
            yield node
            stack.extend(node.children)

    @property
    def grid_samples(self) -> int:
        """Polar grid samples over all subapertures."""
        return sum(n.nr * n.na for n in self.nodes() if not n.direct)

    @property
    def error_bound_db(self) -> float:
        """Worst-case error of a pixel relative to the sum of the magnitudes behind it, dB: every merge
        and the final step interpolate once in range and once in angle (each at most
        :func:`interpolation_error` for data within the band its grid is sampled for), and the errors add
        coherently along the ``levels + 1`` interpolations between a leaf and a pixel, the first of them
        reading the leaf's grid (``FactorizedOptions.sampling``). The leaves' own
        error is the direct kernel's."""
        if self.direct_only:
            return -math.inf
        growth = 1.0
        for leaf, steps in ((True, 1), (False, self.levels)):
            osr, osa, taps = self.options.sampling(leaf)
            er, ea = interpolation_error(taps, osr), interpolation_error(taps, osa)
            growth *= (1 + er + ea + er * ea) ** steps
        return float(20 * np.log10(growth - 1))

    @property
    def error_estimate_db(self) -> float:
        """Expected error energy relative to the image's, dB: the interpolations' RMS errors
        (:func:`interpolation_rms_error`, data spread evenly over the band) adding in power over the
        ``2 (levels + 1)`` one-dimensional interpolations between a leaf and a pixel (two of them reading the
        leaf's grid). Measured errors sit
        near it (tests and benchmarks/ffbp.py); the bound above is what no band-limited input exceeds."""
        if self.direct_only:
            return -math.inf
        power = 0.0
        for leaf, steps in ((True, 1), (False, self.levels)):
            osr, osa, taps = self.options.sampling(leaf)
            power += steps * (interpolation_rms_error(taps, osr) ** 2 + interpolation_rms_error(taps, osa) ** 2)
        return float(10 * np.log10(power))

    def cost(self) -> dict:
        """Operation counts: backprojections (profile x point) at the leaves, interpolated samples in the
        merges and at the pixels (taps^2 multiply-adds each, ``leaf_taps``^2 where a leaf's grid is read;
        all of them in ``multiply_adds``), against the direct kernel's profile x pixel count."""
        n_pix = self.x_m.size * self.y_m.size
        nodes = list(self.nodes())
        leaves = [n for n in nodes if not n.children]
        taps2 = {leaf: self.options.sampling(leaf)[2] ** 2 for leaf in (True, False)}
        merged = sum(n.nr * n.na * len(n.children) for n in nodes if n.children)
        merge_mac = sum(n.nr * n.na * taps2[not c.children] for n in nodes for c in n.children)
        pixel_mac = n_pix * sum(taps2[not r.children] for r in self.roots if not r.direct)
        return {"leaf_backprojections": int(sum((n.stop - n.start) * (n_pix if n.direct else n.nr * n.na) for n in leaves)),
                "merge_interpolations": int(merged),
                "pixel_interpolations": int(n_pix * sum(not r.direct for r in self.roots)),
                "taps_squared": self.options.taps ** 2, "leaf_taps_squared": taps2[True],
                "multiply_adds": int(merge_mac + pixel_mac), "roots": len(self.roots), "levels": self.levels,
                "direct_backprojections": int(self.roots[-1].stop - self.roots[0].start) * n_pix}


def _outline(x_m, y_m, n: int = 64) -> np.ndarray:
    """Points on the border of the image rectangle, [4n, 2]."""
    x0, x1, y0, y1 = x_m[0], x_m[-1], y_m[0], y_m[-1]
    s = np.linspace(0, 1, n)
    return np.concatenate([np.stack([x0 + (x1 - x0) * s, np.full(n, y0)], 1), np.stack([x0 + (x1 - x0) * s, np.full(n, y1)], 1),
                           np.stack([np.full(n, x0), y0 + (y1 - y0) * s], 1), np.stack([np.full(n, x1), y0 + (y1 - y0) * s], 1)])


def _midpoints(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """0.5 (a + b), contiguous, in one new array (not three: a plan's arrays are fresh pages where the
    allocator maps them anew)."""
    out = np.add(a, b)
    out *= 0.5
    return out


def _subapertures(tree: Tree, centre, axis, normal, grids: tuple, direct: np.ndarray) -> list:
    """The tree's nodes as Subaperture objects (children made before their parents), in the tree's order."""
    start, stop, left, right, level = (v.tolist() for v in (tree.start, tree.stop, tree.left, tree.right, tree.level))
    r0, dr, a0, da, nr, na = (v.tolist() for v in grids)
    direct = direct.tolist()
    nodes: list = [None] * tree.size
    for i in range(tree.size - 1, -1, -1):
        children = () if left[i] < 0 else (nodes[left[i]], nodes[right[i]])
        nodes[i] = Subaperture(start[i], stop[i], level[i], centre[i], axis[i], normal[i], children,
                               r0[i], dr[i], a0[i], da[i], nr[i], na[i], direct[i])
    return nodes


def plan_factorized(tx_m: np.ndarray, rx_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: float,
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
    columns = tuple(_midpoints(tx[:, i], rx[:, i]) for i in range(3))  # the phase centres' x, y and z
    overall = track_axis(columns)
    two_over_lambda = 2 * (carrier_hz + bandwidth_hz / 2) / SPEED_OF_LIGHT_MPS
    envelope = bandwidth_hz / SPEED_OF_LIGHT_MPS  # the range profile's band, cycles per metre of range
    n_pix = x_m.size * y_m.size

    # The tree as arrays (imaging.ffbp_tree), every node's frame in one pass (imaging.ffbp_placement), each
    # step's grids placed in one pass into the arrays below; the Subaperture objects are made at the end.
    tree = split_tree(tx.shape[0], o.leaf_profiles)
    leaf = tree.left < 0
    centre, axis, normal, centres, b_image = node_frames(columns, tree.start, tree.stop - tree.start, overall, image_xy)
    sampling = np.array([o.sampling(leaf=False), o.sampling(leaf=True)])[leaf.astype(np.int64)]
    half_taps = sampling[:, 2].astype(int) // 2
    r0, dr, a0, da = (np.zeros(tree.size) for _ in range(4))
    nr, na = np.zeros(tree.size, np.int64), np.zeros(tree.size, np.int64)

    def place(batch: np.ndarray, served_x: np.ndarray, served_y: np.ndarray, served: np.ndarray) -> None:
        """Size the grids of the nodes ``batch`` to cover the plane points each serves ([N, K], where
        ``served``: the image's outline, or the edge of its parent's grid), in one pass."""
        outside = b_image[batch] <= 0
        if np.any(outside):
            i = batch[int(np.flatnonzero(outside)[0])]
            raise ValueError("the image must lie to one side of the radar's track (FFBP images a side-looking pass); "
                             f"the track of profiles {tree.start[i]}-{tree.stop[i]} passes {-b_image[i]:.3f} m inside it")
        grids = place_grids(centre[batch], axis[batch], normal[batch], centres[batch], served_x, served_y, served,
                            b_image[batch], z_m, envelope=envelope, two_over_lambda=two_over_lambda,
                            oversample_range=sampling[batch, 0], oversample_angle=sampling[batch, 1],
                            half_taps=half_taps[batch])
        for field, values in zip((r0, dr, a0, da, nr, na), grids):
            field[batch] = values

    # The roots: merge up to a node only while its grid costs less than interpolating its children at the
    # pixels; a step down the tree at a time, each step's nodes placed (on the image's outline) in one pass.
    roots, candidates = [], np.zeros(1, np.int64)
    outline_x, outline_y = image_xy[:, 0], image_xy[:, 1]
    leaf_taps2 = o.sampling(True)[2] ** 2
    direct = np.zeros(tree.size, bool)
    while candidates.size:
        shape = (candidates.size, image_xy.shape[0])
        # (tiled, not broadcast: the arrays of the steps below, so that the pass has one compiled signature)
        place(candidates, np.tile(outline_x, (shape[0], 1)), np.tile(outline_y, (shape[0], 1)), np.ones(shape, bool))
        deeper = []
        for i in candidates.tolist():  # a few nodes a step (Python's integers: a grid gone astray is huge)
            grid, length = int(nr[i]) * int(na[i]), int(tree.stop[i] - tree.start[i])
            if not leaf[i] and 2 * grid > n_pix:
                deeper += [tree.left[i], tree.right[i]]
                continue
            if leaf[i] and length * grid + n_pix * leaf_taps2 > length * n_pix:
                direct[i] = True  # cheaper straight onto the pixels
            roots.append(i)
        candidates = np.array(deeper, np.int64)
    roots = np.array(sorted(roots, key=lambda i: tree.start[i]), np.int64)
    # Below the roots, each child's grid covers its parent's: a step down the trees at a time.
    parents = roots[~leaf[roots]]
    while parents.size:
        edge = grid_edges(centre[parents], axis[parents], normal[parents], r0[parents], dr[parents], a0[parents],
                          da[parents], nr[parents], na[parents], z_m, copies=2)
        children = np.stack([tree.left[parents], tree.right[parents]], axis=1).ravel()
        place(children, *edge)
        parents = children[~leaf[children]]
    nodes = _subapertures(tree, centre, axis, normal, (r0, dr, a0, da, nr, na), direct)
    whole, roots = nodes[0], [nodes[i] for i in roots.tolist()]
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


# -- running it ------------------------------------------------------------------------------------------
def _slice(profiles: RangeProfiles | list, start: int, stop: int) -> RangeProfiles:
    """Profiles [start, stop) of one RangeProfiles, or of a list of them in order (blocks as
    ``imaging.image_formation`` makes them): a view within one block, a copy across blocks."""
    if isinstance(profiles, RangeProfiles):
        rows = None if profiles.rows is None else profiles.rows[start:stop]
        samples = None if profiles.samples is None else profiles.samples.reshape(profiles.data.shape[0], -1)[start:stop]
        return dataclasses.replace(profiles, data=profiles.data[start:stop], rows=rows, samples=samples)
    pieces, offset = [], 0
    for block in profiles:
        n = block.data.shape[0]
        if offset < stop and offset + n > start:
            pieces.append(_slice(block, max(start - offset, 0), min(stop - offset, n)))
        offset += n
    if len(pieces) == 1:
        return pieces[0]
    samples = None if any(p.samples is None for p in pieces) else np.concatenate([p.samples for p in pieces])
    return dataclasses.replace(pieces[0], data=np.concatenate([p.data for p in pieces]), rows=None, samples=samples)


def _count(profiles: RangeProfiles | list) -> int:
    return profiles.data.shape[0] if isinstance(profiles, RangeProfiles) else sum(p.data.shape[0] for p in profiles)


def run_factorized(plan: FactorizedPlan, profiles: RangeProfiles, tx_m: np.ndarray, rx_m: np.ndarray,
                   reference_range_m: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
    """Form the image of ``plan`` from ``profiles`` (those the plan was made for: one RangeProfiles, or a
    list of them in time order), complex128 [ny, nx] (accumulated into ``out`` if given)."""
    o = plan.options
    tx = np.asarray(tx_m, np.float64).reshape(-1, 3)
    rx = np.asarray(rx_m, np.float64).reshape(-1, 3)
    if _count(profiles) != tx.shape[0] or plan.roots[-1].stop != tx.shape[0] or plan.roots[0].start != 0:
        raise ValueError(f"{_count(profiles)} profiles and {tx.shape[0]} antenna positions; the plan is for {plan.roots[-1].stop}")
    load_kernel()  # once a process, whatever the plan (see imaging.ffbp_leaves.load_kernel)
    # (range, angle) tables for reading a leaf's grid (True) or a merged one.
    tables = {leaf: (interpolation_table(o.sampling(leaf)[2], o.sampling(leaf)[0]),
                     interpolation_table(o.sampling(leaf)[2], o.sampling(leaf)[1])) for leaf in (True, False)}
    k, z = plan.wavenumber, plan.z_m
    shape = (plan.y_m.size, plan.x_m.size)
    if out is None:
        out = np.zeros(shape, np.complex128)
    elif out.shape != shape or out.dtype != np.complex128:
        raise ValueError(f"out must be complex128 of shape {shape}, got {out.dtype} {out.shape}")

    def direct(node: Subaperture, points: np.ndarray, out=None, parallel: bool = False) -> np.ndarray:
        """The direct kernel (on this thread unless ``parallel``): the node's profiles onto ``points``."""
        a, b = node.start, node.stop
        ref = None if reference_range_m is None else reference_range_m[a:b]
        return backproject(_slice(profiles, a, b), tx[a:b], rx[a:b], points, reference_range_m=ref, mode=o.mode,
                           out=out, parallel=parallel)

    images: dict[int, np.ndarray] = {}  # id(node) -> its demodulated polar image, until its parent has it

    def leaf(node: Subaperture) -> None:
        img = direct(node, node.polar_points(z))
        r = node.r0_m + node.dr_m * np.arange(node.nr)
        images[id(node)] = (img * np.exp(2j * k * r)[:, None]).astype(np.complex64)

    # Where a list of profile blocks is given, a call takes leaves of one block (its rows a view, not a copy
    # of the run's profiles); a leaf across two blocks goes alone (a copy of its own profiles).
    edges = None if isinstance(profiles, RangeProfiles) else np.cumsum([0] + [p.data.shape[0] for p in profiles])

    def leaf_run(run: list) -> None:
        """Consecutive leaves in one call of the leaf kernel (its GIL-free time is all of the work)."""
        def source(i: int, node: Subaperture) -> int:
            if edges is None:
                return 0
            first, last = np.searchsorted(edges, [node.start, node.stop - 1], "right")
            return int(first) if first == last else -1 - i  # across two blocks: alone

        for first, last in _equal_runs([source(i, n) for i, n in enumerate(run)]):
            part = run[first:last]
            a, b = part[0].start, part[-1].stop
            ref = None if reference_range_m is None else reference_range_m[a:b]
            for node, img in zip(part, image_leaves(part, _slice(profiles, a, b), tx[a:b], rx[a:b], ref, a, z, o.mode)):
                images[id(node)] = img

    def merge(node: Subaperture, i0: int, i1: int) -> None:
        d, g = images[id(node)], node.geometry
        for child in node.children:
            _merge_rows(d, i0, i1, g, images[id(child)], child.geometry, z, k, *tables[not child.children])

    roots = [r for r in plan.roots if not r.direct]

    def to_pixels(i0: int, i1: int) -> None:
        for root in roots:
            _to_plane_rows(out, i0, i1, plan.x_m, plan.y_m, z, images[id(root)], root.geometry, k, *tables[not root.children])

    # Coarse work, level by level: every leaf is one task, every merge and the pixels are cut into row
    # ranges; the tasks of a level go to a pool of numba's thread count, each run on one thread. A core taken
    # by another process then only takes fewer tasks: nothing waits for it but the level's last task.
    # (Parallel regions inside each small step, as before, made every step wait for the slowest core.)
    threads = max(1, numba.get_num_threads())
    nodes = [n for root in roots for n in _subtree(root)]
    levels = sorted({n.level for n in nodes})
    with Pool(threads) as pool:
        for level in levels:
            at = [n for n in nodes if n.level == level]
            if level == 0 and o.mode == "exact":
                pool.run([functools.partial(leaf, n) for n in at])
                continue
            if level == 0:
                pool.run([functools.partial(leaf_run, run) for run in leaf_runs(at, threads)])
                continue
            for n in at:
                images[id(n)] = np.zeros((n.nr, n.na), np.complex64)
            pool.run([functools.partial(merge, n, i0, i1) for n in at for i0, i1 in row_ranges(n.nr, n.na, threads)])
            for n in at:
                for child in n.children:
                    del images[id(child)]
        pool.run([functools.partial(to_pixels, i0, i1) for i0, i1 in row_ranges(shape[0], shape[1], threads)])
    # Profiles that go straight onto the pixels: one call of the direct kernel, itself parallel.
    direct_roots = [r for r in plan.roots if r.direct]
    if direct_roots:
        pixels = Grid(plan.x_m, plan.y_m, np.array([z])).points()
        for root in direct_roots:
            direct(root, pixels, out=out, parallel=True)
    return out


def _equal_runs(values: list) -> list:
    """(first, last + 1) of each run of equal consecutive values."""
    edges = [0] + [i for i in range(1, len(values)) if values[i] != values[i - 1]] + [len(values)]
    return list(zip(edges[:-1], edges[1:]))


def _subtree(node: Subaperture):
    yield node
    for child in node.children:
        yield from _subtree(child)


def backproject_factorized(profiles: RangeProfiles, tx_m: np.ndarray, rx_m: np.ndarray, x_m: np.ndarray,
                           y_m: np.ndarray, z_m: float, *, reference_range_m: np.ndarray | None = None,
                           options: FactorizedOptions = FactorizedOptions(),
                           bandwidth_hz: float | None = None) -> np.ndarray:
    """Backproject range profiles onto the horizontal plane grid (x_m, y_m, z_m) by FFBP.

    The same inputs as :func:`imaging.backprojection.backproject`, with the grid given by its axes;
    returns complex128 [ny, nx]. ``bandwidth_hz`` defaults to ``profiles.bandwidth_hz``. Error: see
    :attr:`FactorizedPlan.error_bound_db` (``plan_factorized`` with the same arguments).
    """
    bw = bandwidth_hz or profiles.bandwidth_hz
    if not bw:
        raise ValueError("the profiles do not say their bandwidth: pass bandwidth_hz")
    plan = plan_factorized(tx_m, rx_m, x_m, y_m, z_m, profiles.carrier_hz, bw, options)
    return run_factorized(plan, profiles, tx_m, rx_m, reference_range_m)
