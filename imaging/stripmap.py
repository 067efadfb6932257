"""A SAR strip map that grows while the robot drives: streaming, tiled, aperture- and beam-limited backprojection.

Each radar frame is range-compressed, its antennas are placed from the trajectory, and it is backprojected
into the square tiles of a map in the world frame (a horizontal plane at ``z_m``). Tiles are created when a
frame first reaches them, so memory follows the area driven, not a fixed canvas. A pixel takes a frame
only when the frame's mean phase centre lies

* in front of it: look distance (along the horizontal boresight) within [range_min_m, range_max_m];
* within the beam: along-track offset at most look distance x tan(beam_half_angle_deg);
* within the aperture: along-track offset at most aperture_m / 2,

so each pixel integrates a synthetic aperture of ``aperture_m`` (to within the distance driven in one
frame, 2 cm at 0.4 m/s) centred on its broadside point, and the cost per frame follows the footprint, not
the map. The decision is per frame, not per chirp, so the selected pixels go through the ordinary
backprojection kernel (``imaging.backprojection``) in one call. Optionally ``presum`` consecutive chirps of each TX
(the same virtual channel) are averaged before range compression: the antenna moves between them, which
spreads the phase of a pixel seen at squint angle theta by 2 pi * 2 d sin(theta) / lambda over the group
(d the distance travelled); :func:`presum_phase_spread_rad` gives that bound so a caller can keep it small.

Pure computation: arrays and dataclasses in, arrays out. ``acquisition.workers`` runs it on the bus.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.backprojection import backproject
from imaging.core.config import require
from imaging.core.geometry import antenna_track
from imaging.core.rig import RadarConfig
from imaging.core.trajectory import Trajectory
from imaging.io.image_file import SarImage
from imaging.range_compression import range_compress

MODES = ("nearest", "linear", "exact")


@dataclasses.dataclass(frozen=True)
class StripMapConfig:
    """Map and integration settings (metres, degrees)."""

    pixel_m: float = 0.01
    tile_px: int = 64
    aperture_m: float = 0.3
    beam_half_angle_deg: float = 45.0
    range_min_m: float = 0.5
    range_max_m: float = 4.0
    z_m: float = 0.3
    presum: int = 1
    mode: str = "linear"
    oversample: int = 8
    window: str = "hann"
    #: Frames taken while the platform moves slower than this are left out: standing still they add no
    #: aperture, only the same unfocused footprint over and over.
    min_speed_mps: float = 0.05

    def __post_init__(self) -> None:
        require(self.pixel_m > 0, "pixel_m", "must be positive")
        require(self.tile_px >= 8, "tile_px", "must be at least 8")
        require(self.aperture_m > 0, "aperture_m", "must be positive")
        require(0 < self.beam_half_angle_deg < 90, "beam_half_angle_deg", "must be in (0, 90)")
        require(0 <= self.range_min_m < self.range_max_m, "range_max_m", "must exceed range_min_m >= 0")
        require(self.presum >= 1, "presum", "must be at least 1")
        require(self.mode in MODES, "mode", f"must be one of {MODES}")
        require(self.oversample >= 1, "oversample", "must be at least 1")
        require(self.min_speed_mps >= 0, "min_speed_mps", "must not be negative")

    @property
    def tile_m(self) -> float:
        return self.tile_px * self.pixel_m


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


@dataclasses.dataclass
class FrameFootprint:
    """What one frame touched: tile keys and the profile-pixel pairs evaluated."""

    tiles: list[tuple[int, int]]
    pixel_profile_pairs: int
    skipped: str = ""  # why the frame was left out, if it was


class StripMap:
    """The growing map: tiles of complex pixels keyed by (ix, iy), tile (ix, iy) covering
    x in [ix, ix + 1) * tile_m and y likewise."""

    def __init__(self, config: StripMapConfig = StripMapConfig()):
        self.config = config
        self.tiles: dict[tuple[int, int], np.ndarray] = {}
        self.frames = 0
        self.frames_standing = 0
        self.profiles = 0
        self._axis = (np.arange(config.tile_px) + 0.5) * config.pixel_m  # pixel centres inside a tile

    def tile_points(self, key: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """x and y of a tile's pixel centres, each [tile_px]."""
        t = self.config.tile_m
        return key[0] * t + self._axis, key[1] * t + self._axis

    def frame_profiles(self, radar: RadarConfig, tx_order: np.ndarray, adc: np.ndarray, frame_time_ns: int,
                       trajectory: Trajectory, presum: int | None = None):
        """Range profiles [P, bins] and TX/RX positions [P, 3] of one frame, pre-summed per TX (``presum``
        chirps, the configuration's by default)."""
        cfg = self.config
        presum = presum or cfg.presum
        wf = radar.waveform
        tx_order = np.asarray(tx_order)
        times = frame_time_ns + np.round(np.arange(wf.chirps_per_frame) * wf.chirp_interval_s * 1e9).astype(np.int64)
        samples, chirp_times, tx_index = [], [], []
        for tx in range(wf.n_tx):
            k = np.flatnonzero(tx_order == tx)
            n = k.size // presum * presum
            if n == 0:
                continue
            groups = k[:n].reshape(-1, presum)
            samples.append(adc[groups].sum(axis=1))  # [G, rx, samples]; a sum keeps the image scale of presum 1
            chirp_times.append(times[groups].mean(axis=1).round().astype(np.int64))
            tx_index.append(np.full(groups.shape[0], tx))
        samples = np.concatenate(samples)
        chirp_times = np.concatenate(chirp_times)
        tx_index = np.concatenate(tx_index)
        track = antenna_track(radar, trajectory, chirp_times, tx_index)
        n_rx = wf.n_rx
        profiles = range_compress(samples.reshape(-1, wf.samples_per_chirp), wf.f0_hz, wf.frequency_step_hz,
                                  window=cfg.window, oversample=cfg.oversample, keep_samples=cfg.mode == "exact",
                                  guarded=True)
        tx_m = np.repeat(track.tx_m, n_rx, axis=0)
        rx_m = track.rx_m.reshape(-1, 3)
        look = np.repeat(track.boresight[:, :2], n_rx, axis=0)
        look /= np.linalg.norm(look, axis=1, keepdims=True)
        return profiles, tx_m, rx_m, look

    def footprint_tiles(self, centre: np.ndarray, look: np.ndarray) -> list[tuple[int, int]]:
        """Tiles a frame can reach: the box around its phase centres' range-beam-aperture footprints."""
        cfg = self.config
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

    def footprint_mask(self, x: np.ndarray, y: np.ndarray, centre_xy: np.ndarray, look_xy: np.ndarray) -> np.ndarray:
        """Which pixels (x, y, any shape) a frame with mean phase centre ``centre_xy`` and horizontal
        look direction ``look_xy`` (unit) integrates into."""
        cfg = self.config
        dx = x - centre_xy[0]
        dy = y - centre_xy[1]
        ahead = dx * look_xy[0] + dy * look_xy[1]
        along = np.abs(dy * look_xy[0] - dx * look_xy[1])
        return ((ahead >= cfg.range_min_m) & (ahead <= cfg.range_max_m) & (along <= cfg.aperture_m / 2)
                & (along <= ahead * math.tan(math.radians(cfg.beam_half_angle_deg))))

    def add_frame(self, radar: RadarConfig, tx_order: np.ndarray, adc: np.ndarray, frame_time_ns: int,
                  trajectory: Trajectory, presum: int | None = None) -> FrameFootprint:
        """Backproject one frame (complex [chirps, rx, samples]) into the map; returns the tiles it changed.
        ``presum`` overrides the configuration's (a live map catching up sums more chirps per profile: the
        same image scale, fewer profiles, more phase spread across each sum)."""
        cfg = self.config
        wf = radar.waveform
        mid = frame_time_ns + wf.frame_duration_ns // 2
        if np.linalg.norm(trajectory.sample(np.array([mid])).velocity_mps[0, :2]) < cfg.min_speed_mps:
            self.frames_standing += 1
            return FrameFootprint([], 0, skipped="standing still")
        profiles, tx_m, rx_m, look = self.frame_profiles(radar, tx_order, adc, frame_time_ns, trajectory, presum)
        centre = 0.5 * (tx_m + rx_m)
        c_mean = centre.mean(axis=0)[:2]
        l_mean = look.mean(axis=0)
        l_mean /= np.linalg.norm(l_mean)
        n = cfg.tile_px
        touched, masks, points = [], [], []
        for key in self.footprint_tiles(c_mean[None], l_mean[None]):
            x, y = self.tile_points(key)
            gx, gy = np.meshgrid(x, y)
            mask = self.footprint_mask(gx, gy, c_mean, l_mean)
            if not mask.any():
                continue
            touched.append(key)
            masks.append(mask)
            points.append(np.stack([gx[mask], gy[mask], np.full(int(mask.sum()), cfg.z_m)], axis=1))
        self.frames += 1
        self.profiles += profiles.data.shape[0]
        if not touched:
            return FrameFootprint([], 0)
        pts = np.concatenate(points)
        values = backproject(profiles, tx_m, rx_m, pts, mode=cfg.mode)
        start = 0
        for key, mask in zip(touched, masks):
            tile = self.tiles.get(key)
            if tile is None:
                tile = self.tiles[key] = np.zeros((n, n), np.complex128)
            m = int(mask.sum())
            tile[mask] += values[start:start + m]
            start += m
        return FrameFootprint(touched, pts.shape[0] * profiles.data.shape[0])

    def mosaic(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The whole map as one array [ny, nx] (zeros where no tile is) with its x and y axes, metres."""
        if not self.tiles:
            raise ValueError("the strip map is empty: no frame has been added")
        keys = np.array(list(self.tiles))
        lo = keys.min(axis=0)
        hi = keys.max(axis=0)
        n = self.config.tile_px
        image = np.zeros(((hi[1] - lo[1] + 1) * n, (hi[0] - lo[0] + 1) * n), np.complex64)
        for (ix, iy), tile in self.tiles.items():
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
        meta = {"method": f"stripmap-tdbp-{cfg.mode}", "aperture_limit_m": cfg.aperture_m,
                "beam_half_angle_deg": cfg.beam_half_angle_deg, "presum": cfg.presum, "n_frames": self.frames,
                "frames_standing_still": self.frames_standing,
                "n_profiles": self.profiles, "tiles": len(self.tiles), "tile_px": cfg.tile_px, **(attrs or {})}
        return SarImage(image, x, y, np.array([cfg.z_m]), meta)
