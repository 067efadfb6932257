"""Where a frame images: the tiles and pixels its range-beam-aperture footprint covers, and what one call
into the map touched (``FrameFootprint``)."""

from __future__ import annotations

import dataclasses
import math
import typing

import numba
import numpy as np

from imaging.stripmap.config import StripMapConfig
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


@dataclasses.dataclass
class FrameFootprint:
    """What one call (a frame, or a batch of a radar's frames) touched: tile keys and the profile-pixel
    pairs evaluated."""

    tiles: list[tuple[int, int]]
    pixel_profile_pairs: int
    skipped: str = ""  # why the frame was left out, if it was
    refocused: list[tuple[int, int]] = dataclasses.field(default_factory=list)  # tiles finished and refocused
    #: tiles finished and not yet refocused: a map that refocuses later (``StripMap(refocus_later=True)``)
    finished: list[tuple[int, int]] = dataclasses.field(default_factory=list)
    #: Frames whose data went into the map by this call: 1 for an imaged frame, with "ffbp" 0 while its block
    #: fills and the block's frames when it is imaged (also when a frame standing still closes a block).
    frames_imaged: int = 0
    frames_standing: int = 0  # frames of the call left out standing still



class TilesTaken(typing.NamedTuple):
    """The tiles frames image into (``StripMap._footprints``), with what imaging them needs: the frames'
    pixel masks [T, F, tile_px, tile_px] (rows along y), the tiles' pixel centres x [T, tile_px] and y
    [T, tile_px] (``StripMap.tile_points``'s, made once a frame), and how many new tiles ``max_tiles``
    refused."""

    keys: list
    masks: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    refused: int


def merged_footprints(footprints: list[FrameFootprint]) -> FrameFootprint:
    """One footprint for several calls: the tiles any changed, the sums of the counts; skipped only if every
    call was, for the last one's reason."""
    tiles, refocused, finished = [], [], []
    for f in footprints:
        tiles += [k for k in f.tiles if k not in tiles]
        refocused += [k for k in f.refocused if k not in refocused]
        finished += [k for k in f.finished if k not in finished]
    skipped = footprints[-1].skipped if all(f.skipped for f in footprints) else ""
    return FrameFootprint(tiles, sum(f.pixel_profile_pairs for f in footprints), skipped, refocused,
                          sum(f.frames_imaged for f in footprints), sum(f.frames_standing for f in footprints), finished)



def footprint_tiles(cfg: StripMapConfig, centre: np.ndarray, look: np.ndarray) -> list[tuple[int, int]]:
    """Tiles a frame can reach: the box around its phase centres' range-beam-aperture footprints."""
    half = min(cfg.aperture_m / 2, cfg.range_max_m * math.tan(math.radians(cfg.beam_half_angle_deg)))
    side = np.stack([-look[:, 1], look[:, 0]], axis=1)
    corners = []
    for ahead in (cfg.range_min_m, cfg.range_max_m):
        for s in (-half, half):
            corners.append(centre[:, :2] + ahead * look + s * side)
    pts = np.concatenate(corners)
    t = cfg.tile_m
    lo = np.floor(pts.min(axis=0) / t).astype(int)
    hi = np.floor(pts.max(axis=0) / t).astype(int)
    return [(ix, iy) for ix in range(lo[0], hi[0] + 1) for iy in range(lo[1], hi[1] + 1)]


def footprint_mask(cfg: StripMapConfig, x: np.ndarray, y: np.ndarray, centre_xy: np.ndarray,
                   look_xy: np.ndarray) -> np.ndarray:
    """Which pixels (x, y, any shape S) a frame with mean phase centre ``centre_xy`` and horizontal
    look direction ``look_xy`` (unit) integrates into: [*S]; for frames ``centre_xy``, ``look_xy``
    [F, 2], one mask per frame [F, *S]."""
    cx, cy, lx, ly = centre_xy[..., 0], centre_xy[..., 1], look_xy[..., 0], look_xy[..., 1]
    if np.ndim(cx):  # frames: their axis in front of the pixels'
        each = (-1,) + (1,) * max(np.ndim(x), np.ndim(y))
        cx, cy, lx, ly = (a.reshape(each) for a in (cx, cy, lx, ly))
    dx = x - cx
    dy = y - cy
    ahead = dx * lx + dy * ly
    along = np.abs(dy * lx - dx * ly)
    return ((ahead >= cfg.range_min_m) & (ahead <= cfg.range_max_m) & (along <= cfg.aperture_m / 2)
            & (along <= ahead * math.tan(math.radians(cfg.beam_half_angle_deg))))


def footprint_masks(cfg: StripMapConfig, x: np.ndarray, y: np.ndarray, centre_xy: np.ndarray,
                    look_xy: np.ndarray) -> np.ndarray:
    """``footprint_mask`` for T tiles at once, bit for bit: x [T, nx] and y [T, ny] the tiles' pixel centres,
    ``centre_xy``, ``look_xy`` [F, 2] the frames'; [T, F, ny, nx]. One pass per tile and frame instead of a
    dozen numpy passes (a live frame touches 10-20 tiles: the masks were a tenth of its CPU,
    benchmarks/stripmap_capacity.py)."""
    out = np.empty((x.shape[0], centre_xy.shape[0], y.shape[1], x.shape[1]), np.bool_)
    _footprint_masks(out, np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64),
                     np.ascontiguousarray(centre_xy, np.float64), np.ascontiguousarray(look_xy, np.float64),
                     float(cfg.range_min_m), float(cfg.range_max_m), cfg.aperture_m / 2,
                     math.tan(math.radians(cfg.beam_half_angle_deg)))
    return out


@numba.njit(cache=True, nogil=True)
def _footprint_masks(out, x, y, c, look, r_min, r_max, half_aperture, tan_beam):
    # the same operations in the same order as footprint_mask's numpy (no fastmath): the same pixels
    for t in range(out.shape[0]):
        for f in range(out.shape[1]):
            cx, cy, lx, ly = c[f, 0], c[f, 1], look[f, 0], look[f, 1]
            for i in range(out.shape[2]):
                dy = y[t, i] - cy
                for j in range(out.shape[3]):
                    dx = x[t, j] - cx
                    ahead = dx * lx + dy * ly
                    along = abs(dy * lx - dx * ly)
                    out[t, f, i, j] = (ahead >= r_min and ahead <= r_max and along <= half_aperture
                                       and along <= ahead * tan_beam)


def footprint_outline(cfg: StripMapConfig, c_mean: np.ndarray, l_mean: np.ndarray, per_side: int = 32) -> np.ndarray:
    """Points [M, 2] around the footprint of a block (the rectangle ``footprint_tiles`` spans)."""
    half = min(cfg.aperture_m / 2, cfg.range_max_m * math.tan(math.radians(cfg.beam_half_angle_deg)))
    ahead = np.linspace(cfg.range_min_m, cfg.range_max_m, per_side)
    along = np.linspace(-half, half, per_side)
    a = np.concatenate([ahead, ahead, np.full(per_side, cfg.range_min_m), np.full(per_side, cfg.range_max_m)])
    s = np.concatenate([np.full(per_side, -half), np.full(per_side, half), along, along])
    side = np.array([-l_mean[1], l_mean[0]])
    return c_mean + a[:, None] * l_mean + s[:, None] * side
