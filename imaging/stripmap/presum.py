"""Pre-summing: consecutive chirps of each TX (the same virtual channel) added before range compression,
and the phase spread the antenna's motion between them costs at the widest squint."""

from __future__ import annotations

import dataclasses
import functools
import math

import numba
import numpy as np

from imaging.core.rig import RadarConfig
from imaging.stripmap.config import StripMapConfig
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


def presum_phase_spread_rad(config: StripMapConfig, radar: RadarConfig, speed_mps: float) -> float:
    """Largest phase spread within one pre-summed group, rad: 2 pi * 2 d sin(theta_max) / lambda with d the
    distance the antenna moves over ``presum`` chirps of one TX and theta_max the widest squint a pixel
    is integrated at (beam or aperture, whichever is narrower, at the nearest range)."""
    wf = radar.waveform
    d = speed_mps * (config.presum - 1) * wf.n_tx * wf.chirp_interval_s
    lim = min(config.aperture_m / 2, max(config.range_min_m, 1e-3) * math.tan(math.radians(config.beam_half_angle_deg)))
    sin_theta = lim / math.hypot(lim, max(config.range_min_m, 1e-3))
    return 2 * math.pi * 2 * d * sin_theta / wf.wavelength_m


def max_presum(config: StripMapConfig, radar: RadarConfig, speed_mps: float, max_spread_rad: float = math.pi / 4) -> int:
    """The largest pre-summing factor (dividing the chirps per TX) whose phase spread stays within
    ``max_spread_rad`` (pi/4: under 3 % amplitude loss at the widest squint)."""
    per_tx = radar.waveform.chirps_per_tx
    best = 1
    for p in range(1, per_tx + 1):
        if per_tx % p == 0 and presum_phase_spread_rad(dataclasses.replace(config, presum=p), radar, speed_mps) <= max_spread_rad:
            best = p
    return best


def presum_chirps(adc: np.ndarray, tx_order: np.ndarray, n_tx: int, presum: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sums of ``presum`` consecutive chirps of each TX (the same virtual channel).

    Parameters
    ----------
    adc : ndarray, shape (chirps, rx, samples) complex, or (chirps, rx, samples, 2) int16 I/Q pairs
        One frame. I/Q pairs are summed as they are and only the sums converted (the live map takes them
        straight off the bus: converting the whole frame first cost more than the sums).
    tx_order : ndarray, shape (chirps,)
        TX of each chirp.
    n_tx : int
    presum : int
        Chirps per sum; a TX's last chirps short of a whole group are left out.

    Returns
    -------
    samples : ndarray, shape (G, rx, samples), complex (complex64 from I/Q pairs)
        The sums, TX by TX, each TX's in time order.
    groups : ndarray, shape (G, presum), int
        The chirps of each sum.
    tx_index : ndarray, shape (G,), int
    """
    tx_order = np.asarray(tx_order)
    # the same for every frame of a radar: made once (a live frame's pre-summing was half this bookkeeping)
    groups, tx_index = chirp_groups(tx_order.astype(np.int64).tobytes(), n_tx, presum)
    pairs = not np.iscomplexobj(adc)
    if pairs and adc.shape[-1:] != (2,):
        raise ValueError(f"a frame is complex [chirps, rx, samples] or I/Q pairs [..., 2]; got {adc.dtype} {adc.shape}")
    if pairs:
        # One pass over the frame's int16 straight into the float32 sums (exact, |sum| < 2^24 for presum < 512,
        # so in any order): numpy's reshape, sum and copy into place were a tenth of a live frame's CPU.
        sums = np.empty((groups.shape[0], *adc.shape[1:]), np.float32)
        _sum_pairs(sums.reshape(groups.shape[0], -1), adc.reshape(adc.shape[0], -1), groups)
        return sums.view(np.complex64)[..., 0], groups, tx_index
    per_tx = tx_order.size // n_tx
    g = per_tx // presum
    if tx_order.size == n_tx * per_tx and np.array_equal(tx_order, np.tile(np.arange(n_tx), per_tx)):
        # TXs in turn: chirp (j * presum + i) * n_tx + tx, so the groups are a reshape, with no gather.
        sums = adc[:g * presum * n_tx].reshape(g, presum, n_tx, *adc.shape[1:]).sum(axis=1)
        sums = sums.swapaxes(0, 1).reshape(n_tx * g, *adc.shape[1:])
    else:
        sums = adc[groups].sum(axis=1)
    return sums, groups, tx_index


@functools.lru_cache(maxsize=64)
def chirp_groups(tx_order: bytes, n_tx: int, presum: int) -> tuple[np.ndarray, np.ndarray]:
    """``presum_chirps``' groups [G, presum] and their TX [G] for the TX order (int64 bytes); read-only arrays,
    shared by every call with the same arguments."""
    order = np.frombuffer(tx_order, np.int64)
    groups, tx_index = [], []
    for tx in range(n_tx):
        k = np.flatnonzero(order == tx)
        n = k.size // presum * presum
        if n:
            groups.append(k[:n].reshape(-1, presum))
            tx_index.append(np.full(n // presum, tx))
    if not groups:
        raise ValueError(f"presum {presum}: more chirps than any TX sends in a frame")
    groups, tx_index = np.concatenate(groups), np.concatenate(tx_index)
    groups.flags.writeable = tx_index.flags.writeable = False
    return groups, tx_index


def group_offsets_ns(groups: np.ndarray, chirps_per_frame: int, chirp_interval_s: float) -> np.ndarray:
    """Each group's time from its frame's start, int64 ns [G]: the mean of its chirps' start offsets, rounded.
    Made once per ``chirp_groups`` result and waveform (read-only, shared)."""
    return _group_offsets_ns(groups.tobytes(), groups.shape[1], chirps_per_frame, chirp_interval_s)


@functools.lru_cache(maxsize=64)
def _group_offsets_ns(groups: bytes, presum: int, chirps_per_frame: int, chirp_interval_s: float) -> np.ndarray:
    offsets_ns = np.round(np.arange(chirps_per_frame) * chirp_interval_s * 1e9).astype(np.int64)
    out = offsets_ns[np.frombuffer(groups, np.int64).reshape(-1, presum)].mean(axis=1).round().astype(np.int64)
    out.flags.writeable = False
    return out


@numba.njit(cache=True, nogil=True)
def _sum_pairs(out, adc, groups):
    """out[g] = the sum of adc[c] over the chirps c of group g (rows flattened: rx x samples x I/Q)."""
    for g in range(groups.shape[0]):
        row = out[g]
        row[:] = 0.0
        for i in range(groups.shape[1]):
            src = adc[groups[g, i]]
            for k in range(row.size):
                row[k] += src[k]

