"""The strip map's settings: map geometry, integration, refocus and algorithm (``StripMapConfig``)."""

from __future__ import annotations

import dataclasses
import math

from imaging.core.config import require
from imaging.core.constants import BACKPROJECTION_MODES
from imaging.core.rig import RadarConfig

MODES = BACKPROJECTION_MODES
ALGORITHMS = ("polar", "direct", "ffbp")

#: Limits of a map pixel, m: a tenth of a millimetre is far below the radar's resolution (a pixel of a
#: nanometre would take minutes to refuse later, tile by tile); a metre above what a map shows.
MIN_PIXEL_M = 1e-4
MAX_PIXEL_M = 1.0


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
    #: Refocus a finished tile on its strongest scatterers: an autofocus method ("none", "pga", "entropy" or
    #: one registered: imaging.autofocus.METHODS).
    refocus: str = "none"
    refocus_groups_per_frame: int = 4
    #: Correct a finished tile by the IMU on each radar's own mount first (``StripMap.add_radar_imu``); also
    #: with ``refocus`` "none", then the IMU's correction alone.
    refocus_imu_aided: bool = False
    #: Sensor time of a radar IMU's samples kept for that (a tile's groups must lie within it).
    radar_imu_keep_s: float = 60.0
    #: The most tiles the map holds (64 KB each at 64 px: 1 GB for the default). A frame that needs a tile
    #: beyond it goes into the tiles it has, or is left out (counted): a long drive, or an odometry gone
    #: astray on a starved machine (tiles kilometres apart), must not take the machine's memory.
    max_tiles: int = 16384
    #: "polar" (each frame through its own few beams, then once per pixel: ``imaging.stripmap.polar``; a
    #: refocusing map images directly, for each frame's group images), "direct" (every profile onto every pixel
    #: of its footprint) or "ffbp" (blocks of frames by fast factorized backprojection: for long apertures;
    #: see the package's docstring).
    algorithm: str = "polar"
    #: Frames of one radar imaged together with "ffbp" (a block's travel is the aperture window's step).
    ffbp_block_frames: int = 8

    def __post_init__(self) -> None:
        for name in ("pixel_m", "aperture_m", "beam_half_angle_deg", "range_min_m", "range_max_m", "z_m", "min_speed_mps",
                     "radar_imu_keep_s"):
            require(math.isfinite(getattr(self, name)), name, f"must be finite, got {getattr(self, name)}")
        require(MIN_PIXEL_M <= self.pixel_m <= MAX_PIXEL_M, "pixel_m",
                f"{self.pixel_m} m is outside the limits {MIN_PIXEL_M:g} to {MAX_PIXEL_M:g} m")
        require(self.tile_px >= 8, "tile_px", "must be at least 8")
        require(self.aperture_m > 0, "aperture_m", "must be positive")
        require(0 < self.beam_half_angle_deg < 90, "beam_half_angle_deg", "must be in (0, 90)")
        require(0 <= self.range_min_m < self.range_max_m, "range_max_m", "must exceed range_min_m >= 0")
        require(self.presum >= 1, "presum", "must be at least 1")
        require(self.mode in MODES, "mode", f"must be one of {MODES}")
        require(self.oversample >= 1, "oversample", "must be at least 1")
        require(self.min_speed_mps >= 0, "min_speed_mps", "must not be negative")
        from imaging.autofocus import METHODS

        require(self.refocus in METHODS, "refocus", f"must be one of {', '.join(METHODS)}, got {self.refocus!r}")
        require(1 <= self.refocus_groups_per_frame <= 64, "refocus_groups_per_frame", "must be 1 to 64")
        require(self.max_tiles >= 1, "max_tiles", f"must be at least 1, got {self.max_tiles}")
        require(not self.refocuses or self.tile_px % 16 == 0, "tile_px",
                f"must be a multiple of 16 to refocus tiles, got {self.tile_px}")
        require(self.radar_imu_keep_s > 0, "radar_imu_keep_s", "must be positive")
        require(self.algorithm in ALGORITHMS, "algorithm", f"must be one of {', '.join(ALGORITHMS)}, got {self.algorithm!r}")
        require(1 <= self.ffbp_block_frames <= 256, "ffbp_block_frames", f"must be 1 to 256, got {self.ffbp_block_frames}")
        require(self.algorithm != "ffbp" or not self.refocuses, "algorithm",
                "ffbp images blocks of frames and cannot refocus (refocus needs each frame's group images); "
                "use direct to refocus")
        require(self.algorithm != "ffbp" or self.range_min_m > 0, "range_min_m",
                "must be positive with ffbp (the polar grids need the footprint off the track)")

    @property
    def refocuses(self) -> bool:
        """Whether finished tiles are refocused (by autofocus, the radars' IMUs or both)."""
        return self.refocus != "none" or self.refocus_imu_aided

    @property
    def images_by_beams(self) -> bool:
        """Whether frames go through their beams ("polar"): not when refocusing (each frame's group images
        come from the direct kernel), in "nearest" or "exact" mode (the beams are read linearly), with pixels
        at the radar (``range_min_m`` 0) or beyond 70 degrees off broadside (the beams' angle, its sine,
        flattens towards 90 degrees)."""
        return (self.algorithm == "polar" and not self.refocuses and self.mode == "linear" and self.range_min_m > 0
                and self.beam_half_angle_deg <= 70.0)

    @property
    def tile_m(self) -> float:
        return self.tile_px * self.pixel_m



def ffbp_block_travel_m(config: StripMapConfig, radar: RadarConfig, speed_mps: float) -> float:
    """How far the radar moves over one "ffbp" block, m: the step by which a pixel's aperture window is
    decided (a pixel integrates ``aperture_m`` to within about that; keep it a small fraction of it)."""
    return speed_mps * config.ffbp_block_frames * radar.waveform.frame_interval_s

