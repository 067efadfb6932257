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
Several frames of one radar can go in together (``StripMap.add_frames``): each keeps its own pixels, so the
map is the same, and what a frame costs besides the kernel (antenna placement, range compression, footprint,
tile updates) is shared; a live map behind takes its queued frames that way.

With ``refocus`` ("pga" or "entropy") a tile is refocused on its strongest scatterers once the radar has
passed it: while it is being imaged each frame goes in as ``refocus_groups_per_frame`` slow-time group
images (the same kernel calls, split by chirp time), which are exactly what ``imaging.autofocus`` estimates
a track error from; the refocused tile is their phase-corrected sum, with no second pass over the data.
The group images of a tile are kept until then (``refocus_groups_per_frame`` x pixels x 8 bytes a frame).
With ``refocus_imu_aided`` the samples of an IMU on a radar's own mount (``add_radar_imu``) correct the
tile first, as ``sarbot image --imu-aided`` does: its high-passed boresight acceleration, integrated twice
over the groups' times, is the track error of that radar's groups, and autofocus (if any) estimates what
is left.

With ``algorithm`` "ffbp" (for long apertures) the frames of each radar are imaged in blocks of
``ffbp_block_frames``: a block is one short subaperture, imaged by fast factorized backprojection
(``imaging.factorized_backprojection``: each frame onto a coarse polar grid, merged pairwise, interpolated
once onto the pixels) instead of every profile onto every pixel. The cost per block is about that of the
polar grids plus taps^2 per pixel, against profiles x pixels, so the gain grows with the footprint's pixels
and the block's profiles (5x at a 0.3 m aperture, 13x at 2 m, at 4 mm pixels: ``benchmarks/stripmap_ffbp.py``).
What it costs: the aperture window is decided per block (its mean phase centre) instead of per frame, so a
pixel's aperture is ``aperture_m`` to within a block's travel rather than a frame's; a block's tiles change
when the block is complete (a block's duration later); the block's profiles are held until then; and each
block adds the plan's interpolation error (``ffbp_error_bound_db``, the worst over the blocks, in the map's
attrs). Refocusing needs each frame's slow-time group images, which a block does not have: it is refused.

Pure computation: arrays and dataclasses in, arrays out. ``acquisition.workers`` runs it on the bus.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.backprojection import backproject, patch_order
from imaging.core.config import require
from imaging.core.geometry import antenna_track
from imaging.core.rig import RadarConfig
from imaging.core.trajectory import Trajectory
from imaging.io.image_file import SarImage
from imaging.range_compression import range_compress

MODES = ("nearest", "linear", "exact")
ALGORITHMS = ("direct", "ffbp")


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
    #: Refocus a finished tile on its strongest scatterers: "none", "pga" or "entropy" (imaging.autofocus).
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
    #: "direct" (every profile onto every pixel of its footprint) or "ffbp" (blocks of frames by fast
    #: factorized backprojection: for long apertures; see the module's docstring).
    algorithm: str = "direct"
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
        require(self.refocus in ("none", "pga", "entropy"), "refocus", f"must be none, pga or entropy, got {self.refocus!r}")
        require(1 <= self.refocus_groups_per_frame <= 64, "refocus_groups_per_frame", "must be 1 to 64")
        require(self.max_tiles >= 1, "max_tiles", f"must be at least 1, got {self.max_tiles}")
        require(not self.refocuses or self.tile_px % 16 == 0, "tile_px",
                f"must be a multiple of 16 to refocus tiles, got {self.tile_px}")
        require(self.radar_imu_keep_s > 0, "radar_imu_keep_s", "must be positive")
        require(self.algorithm in ALGORITHMS, "algorithm", f"must be direct or ffbp, got {self.algorithm!r}")
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
    groups, tx_index = [], []
    for tx in range(n_tx):
        k = np.flatnonzero(tx_order == tx)
        n = k.size // presum * presum
        if n:
            groups.append(k[:n].reshape(-1, presum))
            tx_index.append(np.full(n // presum, tx))
    if not groups:
        raise ValueError(f"presum {presum}: more chirps than any TX sends in a frame")
    groups, tx_index = np.concatenate(groups), np.concatenate(tx_index)
    pairs = not np.iscomplexobj(adc)
    if pairs and adc.shape[-1:] != (2,):
        raise ValueError(f"a frame is complex [chirps, rx, samples] or I/Q pairs [..., 2]; got {adc.dtype} {adc.shape}")
    dtype = np.float32 if pairs else None  # float32 sums of int16 are exact (|sum| < 2^24 for presum < 512)
    per_tx = tx_order.size // n_tx
    g = per_tx // presum
    if tx_order.size == n_tx * per_tx and np.array_equal(tx_order, np.tile(np.arange(n_tx), per_tx)):
        # TXs in turn: chirp (j * presum + i) * n_tx + tx, so the groups are a reshape, with no gather.
        sums = adc[:g * presum * n_tx].reshape(g, presum, n_tx, *adc.shape[1:]).sum(axis=1, dtype=dtype)
        sums = sums.swapaxes(0, 1).reshape(n_tx * g, *adc.shape[1:])
    else:
        sums = adc[groups].sum(axis=1, dtype=dtype)
    if pairs:
        sums = np.ascontiguousarray(sums).view(np.complex64)[..., 0]
    return sums, groups, tx_index


def ffbp_block_travel_m(config: StripMapConfig, radar: RadarConfig, speed_mps: float) -> float:
    """How far the radar moves over one "ffbp" block, m: the step by which a pixel's aperture window is
    decided (a pixel integrates ``aperture_m`` to within about that; keep it a small fraction of it)."""
    return speed_mps * config.ffbp_block_frames * radar.waveform.frame_interval_s


@dataclasses.dataclass
class FrameFootprint:
    """What one call (a frame, or a batch of a radar's frames) touched: tile keys and the profile-pixel
    pairs evaluated."""

    tiles: list[tuple[int, int]]
    pixel_profile_pairs: int
    skipped: str = ""  # why the frame was left out, if it was
    refocused: list[tuple[int, int]] = dataclasses.field(default_factory=list)  # tiles finished and refocused
    #: Frames whose data went into the map by this call: 1 for an imaged frame, with "ffbp" 0 while its block
    #: fills and the block's frames when it is imaged (also when a frame standing still closes a block).
    frames_imaged: int = 0
    frames_standing: int = 0  # frames of the call left out standing still


def _merged(footprints: list[FrameFootprint]) -> FrameFootprint:
    """One footprint for several calls: the tiles any changed, the sums of the counts; skipped only if every
    call was, for the last one's reason."""
    tiles, refocused = [], []
    for f in footprints:
        tiles += [k for k in f.tiles if k not in tiles]
        refocused += [k for k in f.refocused if k not in refocused]
    skipped = footprints[-1].skipped if all(f.skipped for f in footprints) else ""
    return FrameFootprint(tiles, sum(f.pixel_profile_pairs for f in footprints), skipped, refocused,
                          sum(f.frames_imaged for f in footprints), sum(f.frames_standing for f in footprints))


#: The most frames ``StripMap.add_frames`` takes at once (each pixel notes which of them take it in one int64).
MAX_BATCH_FRAMES = 62

#: The most pixels a map's mosaic (and its file) holds: 2 GB of complex64.
MOSAIC_MAX_PIXELS = 1 << 28


class StripMap:
    """The growing map: tiles of complex pixels keyed by (ix, iy), tile (ix, iy) covering
    x in [ix, ix + 1) * tile_m and y likewise."""

    def __init__(self, config: StripMapConfig = StripMapConfig()):
        self.config = config
        self.tiles: dict[tuple[int, int], np.ndarray] = {}
        self.frames = 0
        self.frames_standing = 0
        self.frames_off_map = 0  # every tile they needed was beyond max_tiles
        self.tiles_refused = 0  # new tiles not made for max_tiles (a frame may have imaged into others)
        self.mosaic_tiles_left_out = 0  # by the last mosaic: tiles outside its window
        self.profiles = 0
        self._axis = (np.arange(config.tile_px) + 0.5) * config.pixel_m  # pixel centres inside a tile
        #: tile -> its group images while it is being imaged (refocus only): lists of time (s from the first
        #: frame), antenna phase centre [3], look direction [3], group image [tile_px^2] complex64, radar name
        self._groups: dict[tuple[int, int], list] = {}
        #: radar -> chunks of (time_ns [N], boresight specific force [N]) of the IMU on its mount (IMU-aided)
        self._radar_imu: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.tiles_without_radar_imu = 0  # IMU-aided refocus: tiles whose groups no radar IMU covered
        self._t0_ns: int | None = None
        self._k = 0.0
        self._range_resolution_m = 0.0
        self.refocus_results: dict[tuple[int, int], object] = {}  # tile -> AutofocusResult of the refocus
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
                        presum: int | None = None, weight: float = 1.0, sum_rx: bool = False):
        """As :meth:`frame_profiles`, for several frames of one radar at once (their profiles one after the
        other): one antenna placement and one range compression for all of them. ``weight`` scales the
        profiles, ``sum_rx`` sums each TX's RX channels into one (see :meth:`add_frames`)."""
        cfg = self.config
        presum = presum or cfg.presum
        wf = radar.waveform
        offsets_ns = np.round(np.arange(wf.chirps_per_frame) * wf.chirp_interval_s * 1e9).astype(np.int64)
        samples, chirp_times, tx_index = [], [], []
        for adc, frame_time_ns in zip(adcs, frame_times_ns):
            # a sum, not a mean, keeps the image scale of presum 1
            sums, groups, tx = presum_chirps(adc, tx_order, wf.n_tx, presum)
            samples.append(sums)
            # offsets averaged apart from the frame time: float64 has 256 ns steps at 1e18 ns of PTP time
            chirp_times.append(int(frame_time_ns) + offsets_ns[groups].mean(axis=1).round().astype(np.int64))
            tx_index.append(tx)
        samples = samples[0] if len(samples) == 1 else np.concatenate(samples)
        if sum_rx:
            samples = samples.sum(axis=1, keepdims=True)
        if weight != 1.0:
            samples *= np.float32(weight)  # the sums are this call's own arrays; compression is linear
        chirp_times, tx_index = np.concatenate(chirp_times), np.concatenate(tx_index)
        track = antenna_track(radar, trajectory, chirp_times, tx_index)
        n_rx = 1 if sum_rx else wf.n_rx
        # an RX sum is placed at its channels' centroid: for a symmetric row of them the sum's phase is the
        # centroid's, and its amplitude their array factor (-0.3 dB 4.3 degrees off boresight for 4 at lambda/2)
        rx_track = track.rx_m.mean(axis=1, keepdims=True) if sum_rx else track.rx_m
        profiles = range_compress(samples.reshape(-1, wf.samples_per_chirp), wf.f0_hz, wf.frequency_step_hz,
                                  window=cfg.window, oversample=cfg.oversample, keep_samples=cfg.mode == "exact",
                                  guarded=True)
        tx_m = np.repeat(track.tx_m, n_rx, axis=0)
        rx_m = rx_track.reshape(-1, 3)
        look = np.repeat(track.boresight[:, :2], n_rx, axis=0)
        look /= np.linalg.norm(look, axis=1, keepdims=True)
        return profiles, tx_m, rx_m, look, np.repeat(chirp_times, n_rx)

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
        """Which pixels (x, y, any shape S) a frame with mean phase centre ``centre_xy`` and horizontal
        look direction ``look_xy`` (unit) integrates into: [*S]; for frames ``centre_xy``, ``look_xy``
        [F, 2], one mask per frame [F, *S]."""
        cfg = self.config
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

    def _footprint(self, c_mean: np.ndarray, l_mean: np.ndarray) -> tuple[list, list, int]:
        """The tiles a frame (or block) with mean phase centre ``c_mean`` [2] and look ``l_mean`` [2] images
        into, each with its pixel mask [tile_px, tile_px] (rows along y), within ``max_tiles``; and how many
        new tiles that limit refused."""
        touched, masks, refused = self._footprints(c_mean[None], l_mean[None])
        return touched, [m[0] for m in masks], refused

    def _footprints(self, centres: np.ndarray, looks: np.ndarray) -> tuple[list, list, int]:
        """As ``_footprint`` for F frames (``centres``, ``looks`` [F, 2]): the tiles any of them images into,
        each with the frames' pixel masks [F, tile_px, tile_px]."""
        cfg = self.config
        touched, masks = [], []
        room = cfg.max_tiles - len(self.tiles)
        refused = 0
        for key in self.footprint_tiles(centres, looks):
            x, y = self.tile_points(key)
            if len(centres) == 1:  # the common case, without a frame axis to broadcast over
                mask = self.footprint_mask(x[None, :], y[:, None], centres[0], looks[0])[None]
            else:
                mask = self.footprint_mask(x[None, :], y[:, None], centres, looks)
            if not mask.any():
                continue
            if key not in self.tiles:
                if room <= 0:
                    refused += 1
                    continue
                room -= 1
            touched.append(key)
            masks.append(mask)
        self.tiles_refused += refused
        return touched, masks, refused

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
            return _merged([self.add_frames(radar, tx_order, [a], [t], trajectory, presum, weight, sum_rx)
                            for a, t in zip(adcs, frame_times_ns)])
        mid = np.asarray(frame_times_ns, np.int64) + wf.frame_duration_ns // 2
        moving = np.linalg.norm(trajectory.sample(mid).velocity_mps[:, :2], axis=1) >= cfg.min_speed_mps
        standing = int(np.count_nonzero(~moving))
        self.frames_standing += standing
        if not moving.any():
            ended = self._image_block(radar.name) if ffbp else FrameFootprint([], 0)
            return dataclasses.replace(ended, skipped="standing still", frames_standing=standing)
        n_frames = int(np.count_nonzero(moving))
        profiles, tx_m, rx_m, look, times = self.frames_profiles(
            radar, tx_order, [a for a, m in zip(adcs, moving) if m],
            [t for t, m in zip(frame_times_ns, moving) if m], trajectory, presum, weight, sum_rx)
        if ffbp:
            block = self._blocks.setdefault(radar.name, [])
            block.append((profiles, tx_m, rx_m, look))
            if len(block) < cfg.ffbp_block_frames:
                return FrameFootprint([], 0)
            return self._image_block(radar.name)
        # Each frame's mean phase centre and look decide its pixels, as if imaged alone.
        per = profiles.data.shape[0] // n_frames
        centres = (0.5 * (tx_m + rx_m))[:, :2].reshape(n_frames, per, 2).mean(axis=1)
        looks = look.reshape(n_frames, per, 2).mean(axis=1)
        looks /= np.linalg.norm(looks, axis=1, keepdims=True)
        touched, masks, refused = self._footprints(centres, looks)
        if refused and not touched:
            self.frames_off_map += n_frames
            return FrameFootprint([], 0, skipped="map full", frames_standing=standing)
        self.frames += n_frames
        self.profiles += profiles.data.shape[0]
        refocused = self._finish_tiles(set(touched)) if cfg.refocuses else []
        if not touched:
            return FrameFootprint([], 0, refocused=refocused, frames_imaged=n_frames, frames_standing=standing)
        # Every pixel any frame takes, tile by tile, and which of the frames take it (bit f: frame f).
        bit = np.int64(1) << np.arange(n_frames, dtype=np.int64)
        points, takers, where = [], [], []
        for key, mask in zip(touched, masks):
            x, y = self.tile_points(key)
            taken = mask[0] if n_frames == 1 else mask.any(axis=0)
            iy, ix = np.nonzero(taken)
            points.append(np.stack([x[ix], y[iy], np.full(iy.size, cfg.z_m)], axis=1))
            if n_frames > 1:
                takers.append(bit @ mask[:, iy, ix])
            where.append((taken, iy.size))
        pts = np.concatenate(points)
        if not cfg.refocuses and n_frames == 1:
            values, groups = [backproject(profiles, tx_m, rx_m, pts, mode=cfg.mode)], []
        elif not cfg.refocuses:
            values, groups = [self._backproject_takers(profiles, tx_m, rx_m, pts, np.concatenate(takers), per)], []
        else:  # one frame (add_frames refocuses frame by frame)
            values, groups = self._group_values(profiles, tx_m, rx_m, look, times, int(frame_times_ns[0]), wf, pts)
        n = cfg.tile_px
        start = 0
        for key, (taken, m) in zip(touched, where):
            tile = self._tile(key)
            for v in values:
                tile[taken] += v[start:start + m]  # a boolean mask: faster here than the indices
            if cfg.refocuses:
                for (t_s, antenna, direction), v in zip(groups, values):
                    image = np.zeros(n * n, np.complex64)
                    image[taken.ravel()] = v[start:start + m]
                    self._groups.setdefault(key, []).append((t_s, antenna, direction, image, radar.name))
            start += m
        pairs = sum(int(np.count_nonzero(m)) for m in masks) * per  # each frame's pixels times its profiles
        return FrameFootprint(touched, pairs, refocused=refocused, frames_imaged=n_frames, frames_standing=standing)

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

    def _footprint_outline(self, c_mean: np.ndarray, l_mean: np.ndarray, per_side: int = 32) -> np.ndarray:
        """Points [M, 2] around the footprint of a block (the rectangle ``footprint_tiles`` spans)."""
        cfg = self.config
        half = min(cfg.aperture_m / 2, cfg.range_max_m * math.tan(math.radians(cfg.beam_half_angle_deg)))
        ahead = np.linspace(cfg.range_min_m, cfg.range_max_m, per_side)
        along = np.linspace(-half, half, per_side)
        a = np.concatenate([ahead, ahead, np.full(per_side, cfg.range_min_m), np.full(per_side, cfg.range_max_m)])
        s = np.concatenate([np.full(per_side, -half), np.full(per_side, half), along, along])
        side = np.array([-l_mean[1], l_mean[0]])
        return c_mean + a[:, None] * l_mean + s[:, None] * side

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
                                   outline_xy=self._footprint_outline(c_mean, l_mean))
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

    def _group_values(self, profiles, tx_m, rx_m, look, times, frame_time_ns, wf, pts) -> tuple[list, list]:
        """The frame backprojected onto ``pts`` as ``refocus_groups_per_frame`` slow-time groups (their sum
        is the frame's image), and each group's time (s from the first frame), phase centre and look
        direction."""
        from imaging.core.constants import SPEED_OF_LIGHT_MPS

        if self._t0_ns is None:
            self._t0_ns = int(frame_time_ns)
        self._k = 2 * math.pi * profiles.carrier_hz / SPEED_OF_LIGHT_MPS
        self._range_resolution_m = SPEED_OF_LIGHT_MPS / (2 * profiles.bandwidth_hz) if profiles.bandwidth_hz else 0.0
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
            groups.append(((times[idx].mean() - self._t0_ns) * 1e-9, centre.mean(axis=0), direction))
        return values, groups

    def _finish_tiles(self, still_imaged: set) -> list[tuple[int, int]]:
        """Refocus the tiles no longer reached by the frames; returns those whose image changed."""
        done = [key for key in self._groups if key not in still_imaged]
        return [key for key in done if self.refocus_tile(key)]

    def refocus_pending(self) -> list[tuple[int, int]]:
        """Refocus every tile still being imaged (at the end of a run); returns those whose image changed."""
        return self._finish_tiles(set())

    def add_radar_imu(self, radar: str, time_ns: np.ndarray, accel_mps2: np.ndarray) -> None:
        """Samples of the IMU on ``radar``'s own mount: times [N] int64 ns, specific force [N, 3] in the radar's
        axes (x the boresight). Kept for ``radar_imu_keep_s``, for ``refocus_imu_aided``."""
        t = np.asarray(time_ns, np.int64)
        if t.size == 0:
            return
        chunks = self._radar_imu.setdefault(radar, [])
        chunks.append((t.copy(), np.asarray(accel_mps2, np.float64)[:, 0].copy()))
        oldest = int(t[-1]) - int(self.config.radar_imu_keep_s * 1e9)
        while len(chunks) > 1 and chunks[0][0][-1] < oldest:
            chunks.pop(0)

    def _radar_imu_track(self, radars: np.ndarray, time_s: np.ndarray) -> np.ndarray | None:
        """Track error [Q] of groups of ``radars`` [Q] at ``time_s`` [Q] (s from the first frame) by each radar's
        own IMU; zero for groups of a radar whose IMU does not cover them. None where no group is covered."""
        from imaging.imu_aided import boresight_track_from_imu

        out = np.zeros(time_s.size)
        covered = False
        for name in np.unique(radars):
            chunks = self._radar_imu.get(str(name))
            if not chunks:
                continue
            mine = radars == name
            t_ns = self._t0_ns + np.round(time_s[mine] * 1e9).astype(np.int64)
            t = np.concatenate([c[0] for c in chunks])
            a = np.concatenate([c[1] for c in chunks])
            if t[0] > t_ns.min() or t[-1] < t_ns.max():
                continue  # the IMU's samples do not span the groups (kept too short, or not yet arrived)
            try:
                te = boresight_track_from_imu(t, np.column_stack([a, np.zeros_like(a), np.zeros_like(a)]),
                                              (int(t_ns.min()), int(t_ns.max())), self._t0_ns)
            except ValueError:
                continue
            out[mine] = te.at(time_s[mine])
            covered = True
        return out if covered else None

    def refocus_tile(self, key: tuple[int, int]) -> bool:
        """Refocus one tile from its group images (and drop them); True if the tile's image changed.

        With ``refocus_imu_aided`` the radars' own IMUs correct the groups first; autofocus (``refocus``)
        then estimates the rest where the tile has a scatterer to focus on, whole within it."""
        from imaging.autofocus import (AutofocusOptions, AutofocusResult, TrackError, assemble_group_images,
                                       estimate_on_group_images, nothing_to_focus_on, remove_line)

        cfg = self.config
        groups = self._groups.pop(key, [])
        options = AutofocusOptions(method=cfg.refocus)
        tile = self.tiles.get(key)
        if len(groups) < 8 or tile is None:
            return False
        autofocus = cfg.refocus != "none" and not nothing_to_focus_on(tile, options)
        # A tile whose brightest pixel is on its border holds the tail of a scatterer in a neighbour: that
        # neighbour's refocus is the one that sees the scatterer whole.
        iy, ix = np.unravel_index(int(np.argmax(np.abs(tile))), tile.shape)
        if min(iy, ix) < 2 or max(iy, ix) > tile.shape[0] - 3:
            autofocus = False
        time_s = np.array([g[0] for g in groups])
        imu = self._radar_imu_track(np.array([g[4] for g in groups]), time_s) if cfg.refocus_imu_aided else None
        if cfg.refocus_imu_aided and imu is None:
            self.tiles_without_radar_imu += 1
        if not autofocus and imu is None:
            return False
        n = cfg.tile_px
        order = patch_order((n, n))
        order = np.arange(n * n) if order is None else order
        x, y = self.tile_points(key)
        gx, gy = np.meshgrid(x, y)
        pts = np.stack([gx.ravel(), gy.ravel(), np.full(n * n, self.config.z_m)], axis=1)[order]
        b = np.stack([g[3][order] for g in groups])
        g = assemble_group_images(b, time_s, np.array([g[1] for g in groups]),
                                  np.array([g[2] for g in groups]), pts, np.ones(n * n, np.float32), self._k,
                                  self._range_resolution_m)
        if imu is not None:
            # The IMU's correction, applied to the group images as autofocus's own would be: what autofocus
            # then sees is the residual.
            g.b *= np.exp(1j * g.phase(imu)).T[:, :, None].astype(np.complex64)
        if autofocus:
            result = estimate_on_group_images(g, options)
        else:
            zero = TrackError(time_s, np.zeros(time_s.size), "none")
            why = "autofocus off" if cfg.refocus == "none" else "no scatterer whole within the tile to focus on"
            result = AutofocusResult(zero, 0.0, 0.0, False, int(n * n), time_s.size, 0, why)
        if imu is None and not result.applied:
            self.refocus_results[key] = result
            return False
        residual = result.track_error.displacement_m if result.applied else np.zeros(time_s.size)
        focused = g.image(g.phase(residual)).ravel()
        if imu is not None:
            method = "imu" + (f"+{cfg.refocus}" if result.applied else "")
            result = dataclasses.replace(result, applied=True, track_error=TrackError(
                time_s, remove_line(time_s, imu + residual), method, result.track_error.model if result.applied else None))
        # What the estimate says of the track holds where the tile's brightest pixel was integrated (its own
        # aperture); elsewhere in the tile's time span the groups carry little and the estimate is free.
        brightest = int(np.argmax(np.abs(b).sum(axis=0)))
        seen = np.abs(b[:, brightest]) > 0
        te = result.track_error
        if seen.sum() >= 4:
            te = dataclasses.replace(te, time_s=te.time_s[seen], displacement_m=remove_line(te.time_s[seen], te.displacement_m[seen]))
        self.refocus_results[key] = dataclasses.replace(result, track_error=dataclasses.replace(te, time_origin_ns=self._t0_ns))
        out = np.zeros(n * n, np.complex128)
        out[order] = focused
        self.tiles[key] = out.reshape(n, n)
        return True

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
        meta = {"method": f"stripmap-{'ffbp' if cfg.algorithm == 'ffbp' else 'tdbp'}-{cfg.mode}", "aperture_limit_m": cfg.aperture_m,
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
