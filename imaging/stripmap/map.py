"""The growing strip map (``StripMap``): frames in, tiles of complex pixels out (see ``imaging.stripmap``)."""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np

from imaging.backprojection import backproject
from imaging.core.geometry import antenna_track
from imaging.core.rig import RadarConfig
from imaging.core.trajectory import SampledTrajectory, Trajectory
from imaging.io.image_file import SarImage
from imaging.profiles import chirp_profiles
from imaging.stripmap.config import StripMapConfig
from imaging.stripmap.footprint import (FrameFootprint, TilesTaken, footprint_mask, footprint_masks,
                                        footprint_outline, footprint_tiles, merged_footprints)
from imaging.stripmap.polar import (beams_at_masked, beams_at_points, frame_axes, frame_beams, frame_beams_over,
                                    masked_extent)
from imaging.stripmap.placement import place_profiles
from imaging.stripmap.presum import group_offsets_ns, presum_chirps
from imaging.stripmap.refocus import TileRefocus
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


#: The most frames ``StripMap.add_frames`` takes at once (each pixel notes which of them take it in one int64).
MAX_BATCH_FRAMES = 62

#: "polar" images a frame of more profiles than this through its beams, one of this many or fewer directly:
#: the beams' fixed cost (their compression, the pass over the pixels) is then more than the kernel's
#: pixels x profiles (on the soak's scene both cost 3.2-3.4 ms a frame at 64, 8 together; at 128 the beams
#: 1.6x less, at 32 the kernel 1.4x less: benchmarks/stripmap_polar.py). A live map catching up (pre-summing
#: 4x the reference radar's default and beyond) so goes direct.
POLAR_MIN_PROFILES = 64

#: The most pixels a map's mosaic (and its file) holds: 2 GB of complex64.
MOSAIC_MAX_PIXELS = 1 << 28


@numba.njit(cache=True, nogil=True)
def _add_at_pixels(tile, pixels, values, start):
    """tile[pixels] += values[start:start + count(pixels)], row by row (a boolean mask's order)."""
    n = start
    for i in range(pixels.shape[0]):
        for j in range(pixels.shape[1]):
            if pixels[i, j]:
                tile[i, j] += values[n]
                n += 1


class StripMap:
    """The growing map: tiles of complex pixels keyed by (ix, iy), tile (ix, iy) covering
    x in [ix, ix + 1) * tile_m and y likewise.

    ``refocus_later``: a refocusing map does not refocus the tiles a frame finishes within ``add_frames``
    but names them (``FrameFootprint.finished``) for the caller to refocus when it has the time
    (``refocus_tiles``): a live map's imaging must not wait behind a tile's autofocus."""

    def __init__(self, config: StripMapConfig = StripMapConfig(), refocus_later: bool = False):
        self.config = config
        self.refocus_later = refocus_later
        self.tiles: dict[tuple[int, int], np.ndarray] = {}
        self.frames = 0
        self.frames_standing = 0
        self.frames_off_map = 0  # every tile they needed was beyond max_tiles
        self.tiles_refused = 0  # new tiles not made for max_tiles (a frame may have imaged into others)
        self.mosaic_tiles_left_out = 0  # by the last mosaic: tiles outside its window
        self.profiles = 0
        self._axis = (np.arange(config.tile_px) + 0.5) * config.pixel_m  # pixel centres inside a tile
        self._refocus = TileRefocus(config)  # the tiles' group images and radar IMUs, refocus only
        #: "ffbp": radar -> the frames of its block so far, (profiles, tx_m, rx_m, look)
        self._blocks: dict[str, list] = {}
        self.ffbp_blocks = 0
        self.ffbp_blocks_direct = 0  # blocks FFBP could not take or not save on (a sharp turn): imaged directly
        self.ffbp_levels = 0  # the most merges in a block's tree
        self.ffbp_error_bound_db = -math.inf  # the worst block's
        self.ffbp_error_estimate_db = -math.inf

    def tile_points(self, key: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """x and y of a tile's pixel centres, each [tile_px]."""
        t = self.config.tile_m
        return key[0] * t + self._axis, key[1] * t + self._axis

    def frame_profiles(self, radar: RadarConfig, tx_order: np.ndarray, adc: np.ndarray, frame_time_ns: int,
                       trajectory: Trajectory, presum: int | None = None):
        """Range profiles [P, bins] and TX/RX positions [P, 3] of one frame (complex [chirps, rx, samples] or
        int16 I/Q pairs [..., 2]), pre-summed per TX (``presum`` chirps, the configuration's by default)."""
        return self.frames_profiles(radar, tx_order, [adc], [frame_time_ns], trajectory, presum)

    def frames_profiles(self, radar: RadarConfig, tx_order: np.ndarray, adcs, frame_times_ns, trajectory: Trajectory,
                        presum: int | None = None, weight: float = 1.0, sum_rx: bool = False, compress: bool = True):
        """As :meth:`frame_profiles`, for several frames of one radar at once (their profiles one after the
        other): one antenna placement and one range compression for all of them (``imaging.profiles.chirp_profiles``,
        as a one-shot image forms its profiles). ``weight`` scales the
        profiles, ``sum_rx`` sums each TX's RX channels into one (see :meth:`add_frames`). ``compress`` False:
        the fast-time samples [P, samples] in place of the profiles (the "polar" path compresses beams)."""
        cfg = self.config
        presum = presum or cfg.presum
        wf = radar.waveform
        samples, chirp_times, tx_index = [], [], []
        for adc, frame_time_ns in zip(adcs, frame_times_ns):
            # a sum, not a mean, keeps the image scale of presum 1
            sums, groups, tx = presum_chirps(adc, tx_order, wf.n_tx, presum)
            samples.append(sums)
            # offsets averaged apart from the frame time: float64 has 256 ns steps at 1e18 ns of PTP time
            chirp_times.append(int(frame_time_ns) + group_offsets_ns(groups, wf.chirps_per_frame, wf.chirp_interval_s))
            tx_index.append(tx)
        samples = samples[0] if len(samples) == 1 else np.concatenate(samples)
        if sum_rx:
            samples = samples.sum(axis=1, keepdims=True)
        if weight != 1.0:
            samples *= np.float32(weight)  # the sums are this call's own arrays; compression is linear
        chirp_times, tx_index = np.concatenate(chirp_times), np.concatenate(tx_index)
        if not compress and isinstance(trajectory, SampledTrajectory):  # the live map's: placed in one kernel call
            tx_m, rx_m, look = place_profiles(radar, trajectory, chirp_times, tx_index, sum_rx)
            return samples.reshape(-1, samples.shape[-1]), tx_m, rx_m, look, np.repeat(chirp_times, samples.shape[1])
        if not compress:  # "polar": the frame's beams are formed from the samples (imaging.stripmap.polar)
            track = antenna_track(radar, trajectory, chirp_times, tx_index)
            rx_m = track.rx_m.mean(axis=1, keepdims=True) if sum_rx else track.rx_m
            n = samples.shape[1]
            look = np.repeat(track.boresight[:, :2], n, axis=0)
            look /= np.linalg.norm(look, axis=1, keepdims=True)
            return (samples.reshape(-1, samples.shape[-1]), np.repeat(track.tx_m, n, axis=0), rx_m.reshape(-1, 3), look,
                    np.repeat(chirp_times, n))
        # an RX sum is placed at its channels' centroid: for a symmetric row of them the sum's phase is the
        # centroid's, and its amplitude their array factor (-0.3 dB 4.3 degrees off boresight for 4 at lambda/2)
        formed = chirp_profiles(samples, chirp_times, tx_index, radar, trajectory,
                                window=cfg.window, oversample=cfg.oversample, keep_samples=cfg.mode == "exact",
                                rx_centroid=sum_rx)
        look = np.repeat(formed.track.boresight[:, :2], samples.shape[1], axis=0)
        look /= np.linalg.norm(look, axis=1, keepdims=True)
        return formed.profiles, formed.tx_m, formed.rx_m, look, formed.time_ns

    def footprint_tiles(self, centre: np.ndarray, look: np.ndarray) -> list[tuple[int, int]]:
        """Tiles a frame can reach (``imaging.stripmap.footprint.footprint_tiles``)."""
        return footprint_tiles(self.config, centre, look)

    def footprint_mask(self, x: np.ndarray, y: np.ndarray, centre_xy: np.ndarray, look_xy: np.ndarray) -> np.ndarray:
        """Which pixels a frame (or frames) integrates into (``imaging.stripmap.footprint.footprint_mask``)."""
        return footprint_mask(self.config, x, y, centre_xy, look_xy)

    def _footprint(self, c_mean: np.ndarray, l_mean: np.ndarray) -> tuple[list, list, int]:
        """The tiles a frame (or block) with mean phase centre ``c_mean`` [2] and look ``l_mean`` [2] images
        into, each with its pixel mask [tile_px, tile_px] (rows along y), within ``max_tiles``; and how many
        new tiles that limit refused."""
        taken = self._footprints(c_mean[None], l_mean[None])
        return taken.keys, list(taken.masks[:, 0]), taken.refused

    def _footprints(self, centres: np.ndarray, looks: np.ndarray) -> TilesTaken:
        """The tiles F frames (``centres``, ``looks`` [F, 2]) image into, within ``max_tiles``, with the
        frames' pixel masks and the tiles' pixel centres (``imaging.stripmap.footprint.TilesTaken``)."""
        cfg = self.config
        n = cfg.tile_px
        keys = self.footprint_tiles(centres, looks)
        if not keys:
            return TilesTaken([], np.zeros((0, centres.shape[0], n, n), bool), np.zeros((0, n)), np.zeros((0, n)), 0)
        # Every tile's pixel centres in one operation, the numbers tile_points gives: an int key times tile_m,
        # plus the axis; they were a tile_points call per tile, here and again for the beams.
        k = np.array(keys, np.int64)
        x = k[:, :1] * cfg.tile_m + self._axis
        y = k[:, 1:] * cfg.tile_m + self._axis
        masks = footprint_masks(cfg, x, y, centres, looks)
        room = cfg.max_tiles - len(self.tiles)
        kept, refused = [], 0
        for i in np.flatnonzero(masks.any(axis=(1, 2, 3))):
            if keys[i] not in self.tiles:
                if room <= 0:
                    refused += 1
                    continue
                room -= 1
            kept.append(i)
        self.tiles_refused += refused
        return TilesTaken([keys[i] for i in kept], masks[kept], x[kept], y[kept], refused)

    def _tile(self, key: tuple[int, int]) -> np.ndarray:
        tile = self.tiles.get(key)
        if tile is None:
            n = self.config.tile_px
            tile = self.tiles[key] = np.zeros((n, n), np.complex128)
        return tile

    def add_frame(self, radar: RadarConfig, tx_order: np.ndarray, adc: np.ndarray, frame_time_ns: int,
                  trajectory: Trajectory, presum: int | None = None) -> FrameFootprint:
        """Backproject one frame (complex [chirps, rx, samples], or int16 I/Q pairs [..., 2] as received)
        into the map; returns the tiles it changed.
        ``presum`` overrides the configuration's (a live map catching up sums more chirps per profile: the
        same image scale, fewer profiles, more phase spread across each sum). With ``algorithm`` "ffbp" the
        frame joins its radar's block, imaged when the block is full (or a frame standing still ends it)."""
        return self.add_frames(radar, tx_order, [adc], [frame_time_ns], trajectory, presum)

    def add_frames(self, radar: RadarConfig, tx_order: np.ndarray, adcs, frame_times_ns, trajectory: Trajectory,
                   presum: int | None = None, weight: float = 1.0, sum_rx: bool = False) -> FrameFootprint:
        """Backproject consecutive frames of one radar together: the same map as :meth:`add_frame` frame by
        frame (to float rounding), for less work per frame.

        Each frame still chooses its own pixels (its mean phase centre and look), so every pixel keeps the
        aperture window of frame-by-frame imaging; what the frames share is the work per call: one antenna
        placement, one range compression, one pass over the tiles, and one kernel call per set of frames that
        take the same pixels (all of them in the middle of the footprint, fewer at its leading and trailing
        edges). That work dominates once the chirps are pre-summed as far as they go, as in a live map far
        behind. Frames standing still are left out (``frames_standing`` of the result). With "ffbp" or
        refocusing the frames go in one by one (a block is already a batch; refocusing keeps each frame's
        own group images).

        Parameters
        ----------
        adcs : sequence of ndarray, each as ``add_frame``'s ``adc``
            At most ``MAX_BATCH_FRAMES``.
        frame_times_ns : sequence of int, the frames' start times, ns
        weight : float
            Scales the frames' contributions: a live map far behind that images only one frame of a radar in
            ``k`` weights those it images by ``k``, so the map keeps the scale of every frame imaged.
        sum_rx : bool
            Sum each TX's RX channels into one profile placed at their centroid: a quarter of the profiles for
            four RX. The sum is a beam along the array (half-power +-13 degrees for 4 RX at lambda/2): within
            the aperture's angles (+-4.3 degrees at 2 m for 0.3 m) it costs a pixel little; a catch-up step.
        """
        cfg = self.config
        wf = radar.waveform
        ffbp = cfg.algorithm == "ffbp"
        if len(adcs) != len(frame_times_ns) or not 1 <= len(adcs) <= MAX_BATCH_FRAMES:
            raise ValueError(f"add_frames: {len(adcs)} frames and {len(frame_times_ns)} frame times "
                             f"(1 to {MAX_BATCH_FRAMES} of each)")
        if len(adcs) > 1 and (ffbp or cfg.refocuses):
            return merged_footprints([self.add_frames(radar, tx_order, [a], [t], trajectory, presum, weight, sum_rx)
                            for a, t in zip(adcs, frame_times_ns)])
        mid = np.asarray(frame_times_ns, np.int64) + wf.frame_duration_ns // 2
        moving = np.linalg.norm(trajectory.velocity(mid)[:, :2], axis=1) >= cfg.min_speed_mps
        standing = int(np.count_nonzero(~moving))
        self.frames_standing += standing
        if not moving.any():
            ended = self._image_block(radar.name) if ffbp else FrameFootprint([], 0)
            return dataclasses.replace(ended, skipped="standing still", frames_standing=standing)
        n_frames = int(np.count_nonzero(moving))
        p = presum or cfg.presum
        per_frame = wf.n_tx * (wf.chirps_per_tx // p) * (1 if sum_rx else wf.n_rx)
        polar = cfg.images_by_beams and per_frame > POLAR_MIN_PROFILES
        profiles, tx_m, rx_m, look, times = self.frames_profiles(
            radar, tx_order, [a for a, m in zip(adcs, moving) if m],
            [t for t, m in zip(frame_times_ns, moving) if m], trajectory, presum, weight, sum_rx, compress=not polar)
        if ffbp:
            block = self._blocks.setdefault(radar.name, [])
            block.append((profiles, tx_m, rx_m, look))
            if len(block) < cfg.ffbp_block_frames:
                return FrameFootprint([], 0)
            return self._image_block(radar.name)
        # Each frame's mean phase centre and look decide its pixels, as if imaged alone.
        rows = profiles.shape[0] if polar else profiles.data.shape[0]
        per = rows // n_frames
        centres = (0.5 * (tx_m + rx_m))[:, :2].reshape(n_frames, per, 2).mean(axis=1)
        looks = look.reshape(n_frames, per, 2).mean(axis=1)
        looks /= np.linalg.norm(looks, axis=1, keepdims=True)
        taken = self._footprints(centres, looks)
        touched, masks = taken.keys, taken.masks
        if taken.refused and not touched:
            self.frames_off_map += n_frames
            return FrameFootprint([], 0, skipped="map full", frames_standing=standing)
        self.frames += n_frames
        self.profiles += rows
        finished = self._refocus.finished(set(touched), radar.name) if cfg.refocuses else []
        refocused = [] if self.refocus_later else self.refocus_tiles(finished)
        finished = finished if self.refocus_later else []
        if not touched:
            return FrameFootprint([], 0, refocused=refocused, frames_imaged=n_frames, frames_standing=standing,
                                  finished=finished)
        if polar and n_frames == 1:  # a live map keeping up: its beams read at the masked pixels, no list of them
            where = list(zip(masks[:, 0], np.count_nonzero(masks[:, 0], axis=(1, 2)).tolist()))
            values, groups = [self._polar_masked(radar, profiles, tx_m, rx_m, looks[0], taken)], []
        else:
            values, groups, where = self._pixel_values(radar, profiles, tx_m, rx_m, look, looks, times, frame_times_ns,
                                                       taken, n_frames, per, polar)
        self._add_to_tiles(touched, where, values)
        if cfg.refocuses:
            start = 0
            for key, (pixels, m) in zip(touched, where):
                self._refocus.keep(key, groups, values, pixels, start, m, radar.name)
                start += m
        pairs = int(np.count_nonzero(masks)) * per  # each frame's pixels times its profiles
        return FrameFootprint(touched, pairs, refocused=refocused, frames_imaged=n_frames, frames_standing=standing,
                              finished=finished)

    def _add_to_tiles(self, touched: list, where: list, values: list) -> None:
        """Add each of ``values`` (the frames' values at their pixels, tile by tile, row by row) to the tiles:
        tile ``touched[i]`` takes the next ``where[i]`` = (pixels [tile_px, tile_px], count) of them. numpy's
        ``tile[pixels] += v`` per tile, the same sums, in one kernel call per tile instead of three passes over
        the mask (a gather, the sum, a scatter): 1.2x less CPU in a live frame (benchmarks/stripmap_capacity.py)."""
        for v in values:
            v = np.ascontiguousarray(v, np.complex128)  # numpy's += took complex64 values to complex128 too
            start = 0
            for key, (pixels, m) in zip(touched, where):
                _add_at_pixels(self._tile(key), np.ascontiguousarray(pixels), v, start)
                start += m

    def _pixel_values(self, radar, profiles, tx_m, rx_m, look, looks, times, frame_times_ns, taken: TilesTaken,
                      n_frames: int, per: int, polar: bool):
        """The frames' values at every pixel any of them takes, tile by tile ([values], their group images when
        refocusing, and per tile (its pixels taken, how many))."""
        cfg, wf = self.config, radar.waveform
        # Every pixel any frame takes, tile by tile, and which of the frames take it (bit f: frame f).
        bit = np.int64(1) << np.arange(n_frames, dtype=np.int64)
        points, takers, where = [], [], []
        for mask, x, y in zip(taken.masks, taken.x_m, taken.y_m):
            pixels = mask[0] if n_frames == 1 else mask.any(axis=0)
            iy, ix = np.nonzero(pixels)
            points.append(np.stack([x[ix], y[iy], np.full(iy.size, cfg.z_m)], axis=1))
            if n_frames > 1:
                takers.append(bit @ mask[:, iy, ix])
            where.append((pixels, iy.size))
        pts = np.concatenate(points)
        if polar:
            values, groups = [self._polar_takers(radar, profiles, tx_m, rx_m, looks, pts,
                                                 np.concatenate(takers) if n_frames > 1 else None, per)], []
        elif not cfg.refocuses and n_frames == 1:
            values, groups = [backproject(profiles, tx_m, rx_m, pts, mode=cfg.mode)], []
        elif not cfg.refocuses:
            values, groups = [self._backproject_takers(profiles, tx_m, rx_m, pts, np.concatenate(takers), per)], []
        else:  # one frame (add_frames refocuses frame by frame)
            values, groups = self._refocus.group_values(profiles, tx_m, rx_m, look, times, int(frame_times_ns[0]), wf, pts)
        return values, groups, where

    def _polar_masked(self, radar: RadarConfig, samples: np.ndarray, tx_m, rx_m, look_xy: np.ndarray,
                      taken: TilesTaken) -> np.ndarray:
        """One frame through its beams onto the pixels its masks in ``taken`` take, in their pixel list's order
        (``_polar_takers`` for one frame, without the list of points)."""
        wf, cfg = radar.waveform, self.config
        masks = taken.masks[:, 0]
        axes = frame_axes(tx_m, rx_m, look_xy)
        extent = masked_extent(axes[0], axes[1], taken.x_m, taken.y_m, cfg.z_m, masks)
        beams = frame_beams_over(samples, tx_m, rx_m, extent, cfg.z_m, wf.f0_hz, wf.frequency_step_hz, cfg.window,
                                 cfg.oversample, look_xy, axes)
        return beams_at_masked(beams, taken.x_m, taken.y_m, cfg.z_m, masks)

    def _backproject_takers(self, profiles, tx_m, rx_m, pts: np.ndarray, takers: np.ndarray, per: int) -> np.ndarray:
        """Backproject each pixel of ``pts`` from the frames its ``takers`` bits name (frame f: profiles
        f * per to (f + 1) * per): one kernel call per distinct set of frames."""
        values = np.zeros(pts.shape[0], np.complex128)
        codes, inverse = np.unique(takers, return_inverse=True)
        for c, code in enumerate(codes):
            frames = [f for f in range(MAX_BATCH_FRAMES) if int(code) >> f & 1]
            first, last = frames[0], frames[-1] + 1
            if len(frames) == last - first:  # consecutive frames, as along a track: views, no copy
                rows = slice(first * per, last * per)
            else:  # a turn can leave a frame out between two that take the pixel
                rows = np.concatenate([np.arange(f * per, (f + 1) * per) for f in frames])
            sub = dataclasses.replace(profiles, data=profiles.data[rows],
                                      rows=profiles.rows[rows] if isinstance(rows, slice) and profiles.rows is not None else None,
                                      samples=None if profiles.samples is None else profiles.samples[rows])
            sel = np.flatnonzero(inverse == c)
            values[sel] = backproject(sub, tx_m[rows], rx_m[rows], pts[sel], mode=self.config.mode)
        return values

    def _polar_takers(self, radar: RadarConfig, samples: np.ndarray, tx_m, rx_m, looks: np.ndarray, pts: np.ndarray,
                      takers: np.ndarray | None, per: int) -> np.ndarray:
        """Image each frame (rows f * per to (f + 1) * per of ``samples``) through its own beams onto the
        pixels of ``pts`` its ``takers`` bit names (all of them for one frame; ``imaging.stripmap.polar``)."""
        wf, cfg = radar.waveform, self.config
        values = np.zeros(pts.shape[0], np.complex128)
        for f in range(looks.shape[0]):
            sel = slice(None) if takers is None else np.flatnonzero(takers >> f & 1)
            rows = slice(f * per, (f + 1) * per)
            mine = pts[sel]
            if mine.shape[0] == 0:
                continue
            beams = frame_beams(samples[rows], tx_m[rows], rx_m[rows], mine, wf.f0_hz, wf.frequency_step_hz,
                                cfg.window, cfg.oversample, looks[f])
            values[sel] += beams_at_points(beams, mine)
        return values

    def flush(self) -> FrameFootprint:
        """Image every radar's unfinished block ("ffbp"; at the end of a run); the tiles changed and the
        frames imaged."""
        tiles, pairs, frames = [], 0, 0
        for name in list(self._blocks):
            done = self._image_block(name)
            tiles += [k for k in done.tiles if k not in tiles]
            pairs += done.pixel_profile_pairs
            frames += done.frames_imaged
        return FrameFootprint(tiles, pairs, frames_imaged=frames)
    def _image_block(self, name: str) -> FrameFootprint:
        """Image radar ``name``'s block ("ffbp") into the tiles of its footprint."""
        from imaging.factorized_backprojection import FactorizedOptions, plan_factorized, run_factorized

        block = self._blocks.pop(name, None)
        if not block:
            return FrameFootprint([], 0)
        cfg = self.config
        profiles = [b[0] for b in block]
        tx_m = np.concatenate([b[1] for b in block])
        rx_m = np.concatenate([b[2] for b in block])
        look = np.concatenate([b[3] for b in block])
        c_mean = (0.5 * (tx_m + rx_m)).mean(axis=0)[:2]
        l_mean = look.mean(axis=0)
        l_mean /= np.linalg.norm(l_mean)
        touched, masks, refused = self._footprint(c_mean, l_mean)
        if refused and not touched:
            self.frames_off_map += len(block)
            return FrameFootprint([], 0, skipped="map full")
        count = sum(p.data.shape[0] for p in profiles)
        self.frames += len(block)
        self.profiles += count
        self.ffbp_blocks += 1
        if not touched:
            return FrameFootprint([], 0, frames_imaged=len(block))
        # Global pixel indices of the footprint's pixels: tile (ix, iy) holds pixels ix * tile_px + j.
        n = cfg.tile_px
        where = [np.nonzero(mask) for mask in masks]
        gy = np.concatenate([key[1] * n + iy for key, (iy, _) in zip(touched, where)])
        gx = np.concatenate([key[0] * n + ix for key, (_, ix) in zip(touched, where)])
        gx0, gy0 = int(gx.min()), int(gy.min())
        x = (np.arange(gx0, int(gx.max()) + 1) + 0.5) * cfg.pixel_m
        y = (np.arange(gy0, int(gy.max()) + 1) + 0.5) * cfg.pixel_m
        try:
            plan = plan_factorized(tx_m, rx_m, x, y, cfg.z_m, profiles[0].carrier_hz, profiles[0].bandwidth_hz,
                                   FactorizedOptions(leaf_profiles=profiles[0].data.shape[0], mode=cfg.mode),
                                   outline_xy=footprint_outline(cfg, c_mean, l_mean))
        except ValueError:  # a block whose track bends into its own footprint: no polar grid fits
            plan = None
        if plan is None or plan.direct_only:  # no grid fits, or FFBP would cost more than this
            self.ffbp_blocks_direct += 1
            pts = np.stack([(gx + 0.5) * cfg.pixel_m, (gy + 0.5) * cfg.pixel_m, np.full(gx.size, cfg.z_m)], axis=1)
            values = np.zeros(gx.size, np.complex128)
            first = 0
            for p in profiles:
                last = first + p.data.shape[0]
                backproject(p, tx_m[first:last], rx_m[first:last], pts, mode=cfg.mode, out=values)
                first = last
        else:
            self.ffbp_levels = max(self.ffbp_levels, plan.levels)
            self.ffbp_error_bound_db = max(self.ffbp_error_bound_db, plan.error_bound_db)
            self.ffbp_error_estimate_db = max(self.ffbp_error_estimate_db, plan.error_estimate_db)
            values = run_factorized(plan, profiles, tx_m, rx_m)[gy - gy0, gx - gx0]
        start = 0
        for key, (iy, ix) in zip(touched, where):
            self._tile(key)[iy, ix] += values[start:start + iy.size]
            start += iy.size
        return FrameFootprint(touched, gx.size * count, frames_imaged=len(block))
    # -- refocus (imaging.stripmap.refocus) ---------------------------------------------------------------
    @property
    def refocus_results(self) -> dict:
        """Tile -> the AutofocusResult of its refocus."""
        return self._refocus.results

    @property
    def refocus_geometry(self) -> dict:
        """Tile -> where its refocus looked (``imaging.stripmap.refocus.ScattererGeometry``), for every tile in
        ``refocus_results`` whose estimate was applied."""
        return self._refocus.geometry

    @property
    def tiles_without_radar_imu(self) -> int:
        """IMU-aided refocus: tiles whose groups no radar IMU covered."""
        return self._refocus.tiles_without_radar_imu

    def add_radar_imu(self, radar: str, time_ns: np.ndarray, accel_mps2: np.ndarray) -> None:
        """Samples of the IMU on ``radar``'s own mount: times [N] int64 ns, specific force [N, 3] in the radar's
        axes (x the boresight). Kept for ``radar_imu_keep_s``, for ``refocus_imu_aided``."""
        self._refocus.add_radar_imu(radar, time_ns, accel_mps2)

    def refocus_tile(self, key: tuple[int, int]) -> bool:
        """Refocus one tile from its group images (and drop them); True if the tile's image changed."""
        return self._refocus.refocus_tile(key, self.tiles, self.tile_points)

    @property
    def tiles_to_refocus(self) -> int:
        """Tiles holding group images: being imaged, or finished and not yet refocused."""
        return len(self._refocus.groups)

    def refocus_tiles(self, keys) -> list[tuple[int, int]]:
        """Refocus finished tiles (``FrameFootprint.finished``); returns those whose image changed."""
        return self._refocus.refocus(keys, self.tiles, self.tile_points)

    def refocus_pending(self) -> list[tuple[int, int]]:
        """Refocus every tile still being imaged (at the end of a run); returns those whose image changed."""
        return self._refocus.pending(self.tiles, self.tile_points)


    def mosaic(self, max_pixels: int = MOSAIC_MAX_PIXELS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The whole map as one array [ny, nx] (zeros where no tile is) with its x and y axes, metres.

        The array spans the tiles' bounding box. Where that would exceed ``max_pixels`` (tiles far apart: an
        odometry gone astray), it is the window of at most that many pixels, as square as the tiles allow,
        around the tiles less the 1 % farthest out, or their median; ``mosaic_tiles_left_out`` then says how
        many tiles it left out.
        """
        if not self.tiles:
            raise ValueError("the strip map is empty: no frame has been added")
        keys = np.array(list(self.tiles))
        lo = keys.min(axis=0)
        hi = keys.max(axis=0)
        n = self.config.tile_px
        budget = max(1, max_pixels // (n * n))  # tiles in the window
        span = hi - lo + 1
        if int(span[0]) * int(span[1]) > budget:
            # The tiles' own extent without the 1 % farthest out on either side; if that is still too big, the
            # largest window the limit allows around their median.
            lo = np.percentile(keys, 1, axis=0, method="higher").astype(int)
            hi = np.percentile(keys, 99, axis=0, method="lower").astype(int)
            span = hi - lo + 1
        if int(span[0]) * int(span[1]) > budget:
            wx = min(int(span[0]), max(1, math.isqrt(budget)))
            wy = min(int(span[1]), budget // wx)
            wx = min(int(span[0]), budget // wy)  # a narrow map gives the other axis what it does not need
            side = np.array([wx, wy])
            centre = np.median(keys, axis=0).astype(int)
            lo = np.clip(centre - side // 2, lo, hi - side + 1)
            hi = lo + side - 1
        inside = [(k, t) for k, t in self.tiles.items() if lo[0] <= k[0] <= hi[0] and lo[1] <= k[1] <= hi[1]]
        self.mosaic_tiles_left_out = len(self.tiles) - len(inside)
        image = np.zeros(((hi[1] - lo[1] + 1) * n, (hi[0] - lo[0] + 1) * n), np.complex64)
        for (ix, iy), tile in inside:
            r = (iy - lo[1]) * n
            c = (ix - lo[0]) * n
            image[r:r + n, c:c + n] = tile
        x = lo[0] * self.config.tile_m + (np.arange(image.shape[1]) + 0.5) * self.config.pixel_m
        y = lo[1] * self.config.tile_m + (np.arange(image.shape[0]) + 0.5) * self.config.pixel_m
        return image, x, y

    def to_image(self, attrs: dict | None = None) -> SarImage:
        """The map in the image schema (``imaging.io.image_file``)."""
        image, x, y = self.mosaic()
        cfg = self.config
        method = "ffbp" if cfg.algorithm == "ffbp" else "polar" if cfg.images_by_beams else "tdbp"
        meta = {"method": f"stripmap-{method}-{cfg.mode}", "aperture_limit_m": cfg.aperture_m,
                "beam_half_angle_deg": cfg.beam_half_angle_deg, "presum": cfg.presum, "n_frames": self.frames,
                "frames_standing_still": self.frames_standing, "frames_off_map": self.frames_off_map,
                "tiles_refused": self.tiles_refused, "tiles_left_out": self.mosaic_tiles_left_out,
                "n_profiles": self.profiles, "tiles": len(self.tiles), "tile_px": cfg.tile_px}
        if cfg.algorithm == "ffbp":
            meta.update(ffbp_block_frames=cfg.ffbp_block_frames, ffbp_blocks=self.ffbp_blocks,
                        ffbp_blocks_direct=self.ffbp_blocks_direct, ffbp_levels=self.ffbp_levels,
                        ffbp_error_bound_db=self.ffbp_error_bound_db, ffbp_error_estimate_db=self.ffbp_error_estimate_db)
        meta.update(attrs or {})
        return SarImage(image, x, y, np.array([cfg.z_m]), meta)
