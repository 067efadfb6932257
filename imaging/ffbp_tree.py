"""The shape of FFBP's subaperture tree as arrays: every node's profiles, children and level, a step down the
tree a numpy pass (``imaging.factorized_backprojection.plan_factorized`` places the nodes with these arrays and
makes its ``Subaperture`` objects only at the end).

A node of profiles [start, stop) holds ceil((stop - start) / leaf_profiles) leaves; one of more than one
leaf splits after the first half of them (rounded down), so the last leaf alone may be short.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Tree:
    """N nodes, the root first and each step down the tree after the one above it (parents before children).

    ``start``, ``stop``: profiles [start, stop) of each node, (N,) int64. ``left``, ``right``: its children's
    indices, -1 for a leaf. ``level``: merges on the longest path down to a leaf (0 for a leaf).
    ``depth_edges``: the nodes of depth d (steps from the root) are [depth_edges[d], depth_edges[d + 1]).
    """

    start: np.ndarray
    stop: np.ndarray
    left: np.ndarray
    right: np.ndarray
    level: np.ndarray
    depth_edges: np.ndarray

    @property
    def size(self) -> int:
        return int(self.start.size)


def split_tree(profiles: int, leaf_profiles: int) -> Tree:
    """The tree over ``profiles`` profiles in leaves of ``leaf_profiles`` (the last one may be short)."""
    starts, stops, lefts, rights, edges = [], [], [], [], [0]
    start, stop = np.zeros(1, np.int64), np.full(1, profiles, np.int64)
    while start.size:
        leaves = -(-(stop - start) // leaf_profiles)
        splits = leaves > 1
        mid = start + (leaves // 2) * leaf_profiles
        first_child = edges[-1] + start.size + 2 * (np.cumsum(splits) - 1)  # children in the order of parents
        starts.append(start)
        stops.append(stop)
        lefts.append(np.where(splits, first_child, -1))
        rights.append(np.where(splits, first_child + 1, -1))
        edges.append(edges[-1] + start.size)
        start = np.stack([start[splits], mid[splits]], axis=1).ravel()
        stop = np.stack([mid[splits], stop[splits]], axis=1).ravel()
    left, right = np.concatenate(lefts), np.concatenate(rights)
    level = np.zeros(left.size, np.int64)
    for d in range(len(edges) - 2, -1, -1):  # bottom-up: children sit in the steps below
        i = np.arange(edges[d], edges[d + 1])
        i = i[left[i] >= 0]
        level[i] = 1 + np.maximum(level[left[i]], level[right[i]])
    return Tree(np.concatenate(starts), np.concatenate(stops), left, right, level, np.array(edges))
