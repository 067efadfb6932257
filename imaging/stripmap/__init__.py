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

By default (``algorithm`` "polar") a frame's profiles do not go onto the pixels one by one: a frame is a
tiny aperture (a few centimetres), so its image is first formed on a few beams across the footprint's
angles, from its raw chirps in one matrix product, each beam range-compressed, and every pixel then reads
the beams around its angle once (``imaging.stripmap.polar``): the same pixels and aperture window, the
direct kernel's map to about -55 dB, for less work per frame. A frame pre-summed down to a few profiles (a
live map catching up), refocusing maps and the "nearest" and "exact" modes go through the direct kernel.

With ``refocus`` ("pga" or "entropy") a tile is refocused on its strongest scatterers once the radar has
passed it: while it is being imaged each frame goes in as ``refocus_groups_per_frame`` slow-time group
images (the same kernel calls, split by chirp time), which are exactly what ``imaging.autofocus`` estimates
a track error from; the refocused tile is their phase-corrected sum, with no second pass over the data.
The group images of a tile are kept until then (``refocus_groups_per_frame`` x pixels x 8 bytes a frame).
With ``refocus_imu_aided`` the samples of an IMU on a radar's own mount (``add_radar_imu``) correct the
tile first, as ``sarbot image --imu-aided`` does: its high-passed boresight acceleration, integrated twice
over the groups' times, is the track error of that radar's groups, and autofocus (if any) estimates what
is left. Where the map's pixels are coarser than the aperture's cross-range resolution (1 cm against 5 mm for
0.6 m at 1.5 m), autofocus estimates on the group images resampled onto finer pixels
(``imaging.stripmap.group_grid``): on the map's own, the aperture's ends alias onto each other and a wrong
speed read as a sawtooth of one-pixel ramps.

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

Modules, one idea each: ``config`` (``StripMapConfig``), ``presum`` (chirp sums and their phase spread),
``footprint`` (where a frame images), ``polar`` (a frame through its beams), ``refocus`` (the tiles' group
images and their refocus), ``map`` (``StripMap``). Every public name is importable from ``imaging.stripmap``.
"""

from imaging.stripmap.config import ALGORITHMS, MAX_PIXEL_M, MIN_PIXEL_M, MODES, StripMapConfig, ffbp_block_travel_m
from imaging.stripmap.footprint import FrameFootprint
from imaging.stripmap.map import MAX_BATCH_FRAMES, MOSAIC_MAX_PIXELS, StripMap
from imaging.stripmap.presum import max_presum, presum_chirps, presum_phase_spread_rad

__all__ = ["ALGORITHMS", "MAX_BATCH_FRAMES", "MODES", "MOSAIC_MAX_PIXELS", "FrameFootprint", "StripMap",
           "StripMapConfig", "ffbp_block_travel_m", "max_presum", "presum_chirps", "presum_phase_spread_rad"]
