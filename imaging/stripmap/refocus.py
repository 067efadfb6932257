"""Refocusing a strip map's tiles once the radar has passed them: each frame's slow-time group images kept
per tile while it is imaged, the radars' own IMUs' samples, and the refocus of a finished tile from them
(``imaging.autofocus.estimate_on_group_images``; see the package's docstring)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.backprojection import backproject, patch_order
from imaging.core.track_error import TrackError, remove_line
from imaging.stripmap.config import StripMapConfig
from imaging.stripmap.group_grid import estimation_group_images


@dataclasses.dataclass(frozen=True)
class ScattererGeometry:
    """Where a tile's refocus looked: its brightest scatterer and, at the groups that saw it (those of its
    track error), each group's time (s from ``time_origin_ns``), antenna phase centre [Q, 3] and the direction
    [Q, 3] the track error displaces the antennas along (the horizontal boresight), world frame, radar names."""

    scatterer_m: np.ndarray
    time_s: np.ndarray
    antenna_m: np.ndarray
    direction: np.ndarray
    radars: tuple[str, ...]
    time_origin_ns: int


class TileRefocus:
    """The refocus state of one map: what it keeps of the tiles being imaged, and what it found.

    ``tiles`` (the map's tile dict, refocused in place) and ``tile_points`` (tile key -> pixel centres x, y)
    are the map's, passed in where a tile is refocused."""

    def __init__(self, config: StripMapConfig):
        self.config = config
        #: tile -> its group images while it is being imaged: lists of time (s from the first frame), antenna
        #: phase centre [3], look direction [3], group image [tile_px^2] complex64, radar name
        self.groups: dict[tuple[int, int], list] = {}
        #: tiles ``finished`` named and not yet refocused: a frame that misses them again does not name them again
        self.awaiting: set[tuple[int, int]] = set()
        #: radar -> chunks of (time_ns [N], boresight specific force [N]) of the IMU on its mount (IMU-aided)
        self.radar_imu: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.tiles_without_radar_imu = 0  # IMU-aided refocus: tiles whose groups no radar IMU covered
        self.t0_ns: int | None = None
        self.k = 0.0
        self.range_resolution_m = 0.0
        self.results: dict[tuple[int, int], object] = {}  # tile -> AutofocusResult of the refocus
        #: tile -> where its refocus looked (``ScattererGeometry``): what turns the track error into a
        #: velocity error of the trajectory (rio.map_feedback)
        self.geometry: dict[tuple[int, int], ScattererGeometry] = {}

    def keep(self, key: tuple[int, int], groups: list, values: list, taken: np.ndarray, start: int, count: int,
             radar_name: str) -> None:
        """Keep a frame's group images of tile ``key``: ``values[q][start:start + count]`` are group q's values at
        the tile's pixels ``taken`` [tile_px, tile_px]."""
        n = self.config.tile_px
        for (t_s, antenna, direction), v in zip(groups, values):
            image = np.zeros(n * n, np.complex64)
            image[taken.ravel()] = v[start:start + count]
            self.groups.setdefault(key, []).append((t_s, antenna, direction, image, radar_name))

    def group_values(self, profiles, tx_m, rx_m, look, times, frame_time_ns, wf, pts) -> tuple[list, list]:
        """The frame backprojected onto ``pts`` as ``refocus_groups_per_frame`` slow-time groups (their sum
        is the frame's image), and each group's time (s from the first frame), phase centre and look
        direction."""
        from imaging.core.constants import SPEED_OF_LIGHT_MPS

        if self.t0_ns is None:
            self.t0_ns = int(frame_time_ns)
        self.k = 2 * math.pi * profiles.carrier_hz / SPEED_OF_LIGHT_MPS
        self.range_resolution_m = SPEED_OF_LIGHT_MPS / (2 * profiles.bandwidth_hz) if profiles.bandwidth_hz else 0.0
        n_groups = self.config.refocus_groups_per_frame
        group = np.minimum(((times - frame_time_ns) / wf.frame_duration_ns * n_groups).astype(int), n_groups - 1)
        values, groups = [], []
        for q in range(n_groups):
            idx = np.flatnonzero(group == q)
            if idx.size == 0:
                continue
            sub = dataclasses.replace(profiles, data=profiles.data[idx], rows=None,
                                      samples=None if profiles.samples is None else profiles.samples[idx])
            values.append(backproject(sub, tx_m[idx], rx_m[idx], pts, mode=self.config.mode))
            centre = 0.5 * (tx_m[idx] + rx_m[idx])
            direction = np.concatenate([look[idx].mean(axis=0), [0.0]])
            groups.append(((times[idx].mean() - self.t0_ns) * 1e-9, centre.mean(axis=0), direction))
        return values, groups

    def finished(self, still_imaged: set, radar: str | None = None) -> list[tuple[int, int]]:
        """The tiles no longer reached by the frames (of ``radar``: a tile another radar is imaging is not
        passed because this one's frame missed it), each named once until it is refocused (``refocus``)."""
        done = [key for key in self.groups if key not in still_imaged and key not in self.awaiting
                and (radar is None or self.groups[key][-1][4] == radar)]
        self.awaiting.update(done)
        return done

    def refocus(self, keys, tiles: dict, tile_points) -> list[tuple[int, int]]:
        """Refocus the tiles ``keys`` (from ``finished``); returns those whose image changed."""
        return [key for key in keys if self.refocus_tile(key, tiles, tile_points)]

    def finish(self, still_imaged: set, tiles: dict, tile_points, radar: str | None = None) -> list[tuple[int, int]]:
        """Refocus the tiles no longer reached by the frames (``finished``) at once; returns those whose image
        changed."""
        return self.refocus(self.finished(still_imaged, radar), tiles, tile_points)

    def pending(self, tiles: dict, tile_points) -> list[tuple[int, int]]:
        """Refocus every tile still being imaged or waiting for its refocus (at the end of a run); returns
        those whose image changed."""
        return self.refocus(list(self.groups), tiles, tile_points)

    def add_radar_imu(self, radar: str, time_ns: np.ndarray, accel_mps2: np.ndarray) -> None:
        """Samples of the IMU on ``radar``'s own mount: times [N] int64 ns, specific force [N, 3] in the radar's
        axes (x the boresight). Kept for ``radar_imu_keep_s``, for ``refocus_imu_aided``."""
        t = np.asarray(time_ns, np.int64)
        if t.size == 0:
            return
        chunks = self.radar_imu.setdefault(radar, [])
        chunks.append((t.copy(), np.asarray(accel_mps2, np.float64)[:, 0].copy()))
        oldest = int(t[-1]) - int(self.config.radar_imu_keep_s * 1e9)
        while len(chunks) > 1 and chunks[0][0][-1] < oldest:
            chunks.pop(0)

    def radar_imu_track(self, radars: np.ndarray, time_s: np.ndarray) -> np.ndarray | None:
        """Track error [Q] of groups of ``radars`` [Q] at ``time_s`` [Q] (s from the first frame) by each radar's
        own IMU; zero for groups of a radar whose IMU does not cover them. None where no group is covered."""
        from imaging.imu_aided import boresight_track_from_imu

        out = np.zeros(time_s.size)
        covered = False
        for name in np.unique(radars):
            chunks = self.radar_imu.get(str(name))
            if not chunks:
                continue
            mine = radars == name
            t_ns = self.t0_ns + np.round(time_s[mine] * 1e9).astype(np.int64)
            t = np.concatenate([c[0] for c in chunks])
            a = np.concatenate([c[1] for c in chunks])
            if t[0] > t_ns.min() or t[-1] < t_ns.max():
                continue  # the IMU's samples do not span the groups (kept too short, or not yet arrived)
            try:
                te = boresight_track_from_imu(t, np.column_stack([a, np.zeros_like(a), np.zeros_like(a)]),
                                              (int(t_ns.min()), int(t_ns.max())), self.t0_ns)
            except ValueError:
                continue
            out[mine] = te.at(time_s[mine])
            covered = True
        return out if covered else None

    def refocus_tile(self, key: tuple[int, int], tiles: dict, tile_points) -> bool:
        """Refocus one tile from its group images (and drop them); True if the tile's image changed.

        With ``refocus_imu_aided`` the radars' own IMUs correct the groups first; autofocus (``refocus``)
        then estimates the rest where the tile has a scatterer to focus on, whole within it."""
        from imaging.autofocus import (AutofocusOptions, AutofocusResult, assemble_group_images, estimate_on_group_images,
                                       nothing_to_focus_on)

        cfg = self.config
        groups = self.groups.pop(key, [])
        self.awaiting.discard(key)
        options = AutofocusOptions(method=cfg.refocus)
        tile = tiles.get(key)
        if len(groups) < 8 or tile is None:
            return False
        autofocus = cfg.refocus != "none" and not nothing_to_focus_on(tile, options)
        # A tile whose brightest pixel is on its border holds the tail of a scatterer in a neighbour: that
        # neighbour's refocus is the one that sees the scatterer whole.
        iy, ix = np.unravel_index(int(np.argmax(np.abs(tile))), tile.shape)
        if min(iy, ix) < 2 or max(iy, ix) > tile.shape[0] - 3:
            autofocus = False
        time_s = np.array([g[0] for g in groups])
        imu = self.radar_imu_track(np.array([g[4] for g in groups]), time_s) if cfg.refocus_imu_aided else None
        if cfg.refocus_imu_aided and imu is None:
            self.tiles_without_radar_imu += 1
        if not autofocus and imu is None:
            return False
        n = cfg.tile_px
        order = patch_order((n, n))
        order = np.arange(n * n) if order is None else order
        x, y = tile_points(key)
        gx, gy = np.meshgrid(x, y)
        pts = np.stack([gx.ravel(), gy.ravel(), np.full(n * n, self.config.z_m)], axis=1)[order]
        b = np.stack([g[3][order] for g in groups])
        antenna, direction = np.array([g[1] for g in groups]), np.array([g[2] for g in groups])
        g = assemble_group_images(b, time_s, antenna, direction, pts, np.ones(n * n, np.float32), self.k,
                                  self.range_resolution_m)
        brightest = int(np.argmax(np.abs(b).sum(axis=0)))
        seen = np.abs(b[:, brightest]) > 0
        # Pixels coarser than the aperture's resolution alias its ends onto each other, and autofocus on them
        # reads a wrong speed as a sawtooth (see imaging.stripmap.group_grid): it estimates on finer pixels.
        fine = estimation_group_images(np.stack([g[3] for g in groups]).reshape(-1, n, n), x, y, self.config.z_m,
                                       time_s, antenna, direction, self.k, self.range_resolution_m, pts[brightest],
                                       seen) if autofocus else None
        estimating = g if fine is None else fine
        if imu is not None:
            # The IMU's correction, applied to the group images as autofocus's own would be: what autofocus
            # then sees is the residual.
            for h in {id(g): g, id(estimating): estimating}.values():
                h.b *= np.exp(1j * h.phase(imu)).T[:, :, None].astype(np.complex64)
        if autofocus:
            result = estimate_on_group_images(estimating, options)
        else:
            zero = TrackError(time_s, np.zeros(time_s.size), "none")
            why = "autofocus off" if cfg.refocus == "none" else "no scatterer whole within the tile to focus on"
            result = AutofocusResult(zero, 0.0, 0.0, False, int(n * n), time_s.size, 0, why)
        if imu is None and not result.applied:
            self.results[key] = result
            return False
        residual = result.track_error.displacement_m if result.applied else np.zeros(time_s.size)
        focused = g.image(g.phase(residual)).ravel()
        if imu is not None:
            method = "imu" + (f"+{cfg.refocus}" if result.applied else "")
            result = dataclasses.replace(result, applied=True, track_error=TrackError(
                time_s, remove_line(time_s, imu + residual), method, result.track_error.model if result.applied else None))
        # What the estimate says of the track holds where the tile's brightest pixel was integrated (its own
        # aperture); elsewhere in the tile's time span the groups carry little and the estimate is free.
        te = result.track_error
        if seen.sum() >= 4:
            te = dataclasses.replace(te, time_s=te.time_s[seen], displacement_m=remove_line(te.time_s[seen], te.displacement_m[seen]))
        else:
            seen = np.ones(time_s.size, bool)
        self.geometry[key] = ScattererGeometry(pts[brightest].copy(), time_s[seen], np.array([g[1] for g in groups])[seen],
                                               np.array([g[2] for g in groups])[seen],
                                               tuple(str(g[4]) for g, s in zip(groups, seen) if s), int(self.t0_ns))
        self.results[key] = dataclasses.replace(result, track_error=dataclasses.replace(te, time_origin_ns=self.t0_ns))
        out = np.zeros(n * n, np.complex128)
        out[order] = focused
        tiles[key] = out.reshape(n, n)
        return True
