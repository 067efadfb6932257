"""Sub-aperture images for autofocus: every slow-time group of profiles backprojected onto the estimation
pixels, and the entropy of their phase-corrected sum (with its exact gradient).

With ``B[q, g]`` the group images, the image for a track error delta is
``I_g(delta) = sum_q exp(j 2 k c_qg delta_q) B[q, g]`` where ``c`` (the cosine between the track error's
direction and the line of sight) is evaluated per tile of ``TILE`` pixels: its angle varies by well under a
degree across one. See ``imaging.autofocus`` for the model and docs/signal-model.md for the phase.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np

from imaging.backprojection import backproject
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.geometry import principal_axis

if TYPE_CHECKING:
    from imaging.autofocus.options import ProfileBlock

TILE = 256  # pixels of one tile (16 x 16 in patch order) that share one geometry factor per group


@dataclasses.dataclass
class GroupImages:
    """B [T, Q, TILE] complex64 (tile, group, pixel in tile), the geometry factor c [Q, T], group times [Q],
    pixel positions [T * TILE, 3] (padding pixels: weight 0), the carrier wavenumber k (rad/m)."""

    b: np.ndarray
    c: np.ndarray
    time_s: np.ndarray
    points_m: np.ndarray
    weight: np.ndarray
    k: float
    aperture_m: float
    antenna_centre_m: np.ndarray
    group_antenna_m: np.ndarray  # [Q, 3] mean antenna phase centre of each group
    range_resolution_m: float  # c / (2 B); one range line of the PGA window

    def image(self, phase: np.ndarray) -> np.ndarray:
        """I [T, TILE] for phases [Q, T]."""
        e = np.exp(1j * phase).astype(np.complex64).T  # [T, Q]
        return np.matmul(e[:, None, :], self.b)[:, 0, :]

    def phase(self, displacement_m: np.ndarray) -> np.ndarray:
        return 2.0 * self.k * self.c * displacement_m[:, None]


def _tiles(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points padded to whole tiles (the last point repeated, weight 0)."""
    n = points_m.shape[0]
    pad = (-n) % TILE
    weight = np.concatenate([np.ones(n, np.float32), np.zeros(pad, np.float32)])
    return np.concatenate([points_m, np.repeat(points_m[-1:], pad, axis=0)]), weight


def group_images(blocks: Iterable[ProfileBlock], points_m: np.ndarray, n_groups: int, t_range_s: tuple[float, float]) -> GroupImages:
    """Backproject every slow-time group onto ``points_m`` [G, 3] (in tile order: 256 consecutive points
    close together), one kernel call per (block, group)."""
    pts, weight = _tiles(np.ascontiguousarray(points_m, np.float64))
    edges = np.linspace(t_range_s[0], t_range_s[1], n_groups + 1)
    edges[-1] = np.nextafter(edges[-1], np.inf)
    b = np.zeros((n_groups, pts.shape[0]), np.complex64)
    count = np.zeros(n_groups)
    t_sum = np.zeros(n_groups)
    a_sum = np.zeros((n_groups, 3))
    u_sum = np.zeros((n_groups, 3))
    tmp = np.zeros(pts.shape[0], np.complex128)
    k = None
    bandwidth = None
    for blk in blocks:
        prof = blk.profiles
        bandwidth = prof.bandwidth_hz
        k = 2.0 * math.pi * prof.carrier_hz / SPEED_OF_LIGHT_MPS
        q_of = np.searchsorted(edges, blk.time_s, side="right") - 1
        inside = (q_of >= 0) & (q_of < n_groups)
        # Profiles come in time order, so a group is a run of consecutive profiles.
        change = np.flatnonzero(np.diff(q_of)) + 1
        starts = np.concatenate([[0], change])
        stops = np.concatenate([change, [q_of.size]])
        for a, z in zip(starts, stops):
            q = int(q_of[a])
            if not inside[a]:
                continue
            sub = dataclasses.replace(prof, data=prof.data[a:z], samples=None if prof.samples is None else prof.samples[a:z],
                                      rows=None if prof.rows is None else prof.rows[a:z])
            tmp[:] = 0
            ref = None if blk.reference_range_m is None else blk.reference_range_m[a:z]
            backproject(sub, blk.tx_m[a:z], blk.rx_m[a:z], pts, reference_range_m=ref, out=tmp)
            b[q] += tmp.astype(np.complex64)
            count[q] += z - a
            t_sum[q] += blk.time_s[a:z].sum()
            a_sum[q] += (0.5 * (blk.tx_m[a:z] + blk.rx_m[a:z])).sum(axis=0)
            u_sum[q] += blk.direction[a:z].sum(axis=0)
    keep = count > 0
    if keep.sum() < 4 or k is None:
        raise ValueError(f"autofocus needs profiles spread over time; {int(keep.sum())} of {n_groups} groups hold any")
    return assemble_group_images(b[keep], t_sum[keep] / count[keep], a_sum[keep] / count[keep, None], u_sum[keep], pts,
                                 weight, k, SPEED_OF_LIGHT_MPS / (2.0 * abs(bandwidth)) if bandwidth else 0.0)


def assemble_group_images(b: np.ndarray, time_s: np.ndarray, antenna_m: np.ndarray, direction: np.ndarray,
                          points_m: np.ndarray, weight: np.ndarray, k: float, range_resolution_m: float) -> GroupImages:
    """GroupImages from group images ``b`` [Q, G] on ``points_m`` [G, 3] (whole tiles in tile order, G a
    multiple of TILE; ``weight`` 0 for padding), the groups' times [Q], antenna phase centres [Q, 3] and
    track-error directions [Q, 3] (any length)."""
    n_t = points_m.shape[0] // TILE
    u = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    centres = points_m.reshape(n_t, TILE, 3).mean(axis=1)  # [T, 3]
    los = centres[None, :, :] - antenna_m[:, None, :]
    c = np.einsum("qk,qtk->qt", u, los) / np.linalg.norm(los, axis=2)
    bt = np.ascontiguousarray(b.reshape(b.shape[0], n_t, TILE).transpose(1, 0, 2))
    extent = antenna_m - antenna_m.mean(axis=0)
    length_m = float(np.ptp(extent @ principal_axis(extent)))
    return GroupImages(bt, c, np.asarray(time_s, float), points_m, weight, k, length_m,
                       antenna_m.mean(axis=0), antenna_m, range_resolution_m)


# -- image sharpness -------------------------------------------------------------------------------------
def image_entropy(image: np.ndarray) -> float:
    """Shannon entropy (nats) of an image's normalised intensity; lower is sharper."""
    w = np.abs(np.asarray(image)) ** 2
    s = w.sum()
    if s <= 0:
        return 0.0
    p = w.ravel() / s
    p = p[p > 0]
    return float(-(p * np.log(p)).sum())


def entropy_and_gradient(g: GroupImages, phase: np.ndarray) -> tuple[float, np.ndarray]:
    """Entropy of the group images' sum under ``phase`` [Q, T] and its gradient dE/dphase [Q, T]."""
    e = np.exp(1j * phase).astype(np.complex64)
    img = np.matmul(e.T[:, None, :], g.b)[:, 0, :] * g.weight.reshape(-1, TILE)
    w = (img.real.astype(np.float64) ** 2 + img.imag.astype(np.float64) ** 2)
    s = w.sum()
    p = w / s
    logp = np.log(np.maximum(p, 1e-300))
    ent = float(-(p * logp).sum())
    d = ((logp + ent) / s * np.conj(img)).astype(np.complex64)  # [T, TILE]
    bd = np.matmul(g.b, d[:, :, None])[:, :, 0]  # [T, Q]
    grad = 2.0 * np.imag(e * bd.T)
    return ent, grad

def peak_power(g: GroupImages, phase: np.ndarray) -> float:
    """Power of the brightest estimation pixel of the group images' sum under ``phase`` [Q, T]."""
    img = g.image(phase) * g.weight.reshape(-1, TILE)
    return float(np.max(img.real.astype(np.float64) ** 2 + img.imag.astype(np.float64) ** 2))


def resolution_m(g: GroupImages) -> float:
    """Cross-range resolution lambda r / (2 La) at the estimation pixels' centre."""
    centre = g.points_m[g.weight > 0].mean(axis=0)
    r = float(np.linalg.norm(centre - g.antenna_centre_m))
    return (math.pi / g.k) * r / (2.0 * max(g.aperture_m, 1e-9))

