"""Forming an image from a recording: read frames, range-compress, place antennas, backproject."""

from __future__ import annotations

import collections
import dataclasses
import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from imaging.core.constants import BACKPROJECTION_MODES
from imaging.core.errors import SarbotError
from imaging.core.geometry import antenna_track, chirp_times_ns, principal_axis
from imaging.core.grid import Grid
from imaging.core.rig import RadarConfig
from imaging.core.stage_clock import StageClock, timed
from imaging.core.trajectory import Trajectory
from imaging.frame_blocks import frame_blocks
from imaging.io.image_file import SarImage
from imaging.io.recording import Recording
from imaging.profiles import chirp_profiles
from imaging.row_buffers import RowBuffers

log = logging.getLogger(f"sarbot.{__name__}")

#: How an image is formed: "direct" (every profile onto every pixel) or "ffbp" (fast factorized
#: backprojection, a horizontal plane only; holds all the profiles in memory; imaging.factorized_backprojection).
ALGORITHMS = ("direct", "ffbp")
#: How profiles are sampled (imaging.core.constants: options are checked without importing the kernels, which
#: a command imports while its first blocks are read, ``form_image``).
MODES = BACKPROJECTION_MODES
#: Blocks ``form_image`` range-compresses ahead of its first backprojection while the kernels are made
#: ready on another thread (imaging.kernel_import): each block's profiles are about 180 MB on the
#: benchmark's radar (8 frames of 1,024 profiles of 2,803 complex64 bins).
COMPRESS_AHEAD = 3


@dataclasses.dataclass
class ImagingOptions:
    """How to form an image. ``tx``/``rx``: channel indices to use (None: all)."""

    mode: str = "linear"
    window: str = "hann"
    oversample: int = 16
    tx: tuple[int, ...] | None = None
    rx: tuple[int, ...] | None = None
    frames_per_block: int = 8  # range compression of the next block overlaps the backprojection of this one
    algorithm: str = "direct"  # one of ALGORITHMS
    #: Slow-time taper: each profile weighted by this window at its bistatic phase centre's place along the
    #: aperture (imaging.core.windows.window_at). "rectangular" (no taper) keeps the sinc's -13.3 dB side
    #: lobes; a taper lowers them and widens the main lobe by the window's width factor.
    aperture_window: str = "rectangular"

    def __post_init__(self) -> None:
        from imaging.core.config import require
        from imaging.core.windows import WINDOWS

        require(self.mode in MODES, "mode", f"must be {', '.join(MODES[:-1])} or {MODES[-1]}, got {self.mode!r}")
        require(self.window in WINDOWS, "window", f"must be one of {', '.join(WINDOWS)}, got {self.window!r}")
        require(self.aperture_window in WINDOWS, "aperture_window",
                f"must be one of {', '.join(WINDOWS)}, got {self.aperture_window!r}")
        require(1 <= self.oversample <= 1024, "oversample", f"must be 1 to 1024, got {self.oversample}")
        require(self.frames_per_block >= 1, "frames_per_block", f"must be at least 1, got {self.frames_per_block}")
        require(self.algorithm in ALGORITHMS, "algorithm",
                f"must be {', '.join(ALGORITHMS[:-1])} or {ALGORITHMS[-1]}, got {self.algorithm!r}")


def frame_profiles(adc, frame_time_ns, radar: RadarConfig, trajectory: Trajectory, tx_order, options: ImagingOptions,
                   time_window_ns: tuple[int, int] | None = None, track_error=None, row_buffers=None,
                   image_box_m=None):
    """Range profiles and bistatic antenna positions of a block of frames.

    Parameters
    ----------
    adc : ndarray, complex, shape (F, chirps, n_rx, samples)
    frame_time_ns : ndarray, shape (F,)
    tx_order : ndarray, shape (chirps,)
        TX index of each chirp within a frame.
    time_window_ns : (start, stop), optional
        Keep only chirps starting in [start, stop).
    track_error : imaging.core.track_error.TrackError, optional
        A displacement of the radar along its boresight the trajectory does not know (from autofocus).
    row_buffers : RowBuffers, optional
        Buffers of earlier blocks to write the profiles into (see ``RowBuffers``).
    image_box_m : (lo, hi), optional
        A box holding every pixel the profiles will be backprojected onto (metres, 3 each): only the range
        bins it needs are made (``imaging.profiles.chirp_profiles``).

    Returns
    -------
    ChirpProfiles
        ``imaging.profiles.chirp_profiles`` of the selected chirps and channels: profiles [P, bins], tx_m,
        rx_m [P, 3], chirp times [P], the antennas' track.
    """
    wf = radar.waveform
    times, tx_index, keep, rx_sel = _selected_chirps(frame_time_ns, wf, tx_order, options, time_window_ns)
    samples = adc.reshape(adc.shape[0] * wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp)[keep][:, rx_sel, :]
    return chirp_profiles(samples, times[keep], tx_index[keep], radar, trajectory, window=options.window,
                          oversample=options.oversample, keep_samples=options.mode == "exact", rx=rx_sel,
                          track_error=track_error, workers=-1, rows_out=None if row_buffers is None else row_buffers.take,
                          image_box_m=image_box_m)


def _selected_chirps(frame_time_ns, wf, tx_order, options: ImagingOptions, time_window_ns):
    """The chirps of frames the options and the time window select: every chirp's start time [C] and TX
    index [C], which of them to keep [C] (bool), and the RX channels to use."""
    times = chirp_times_ns(frame_time_ns, wf.chirps_per_frame, wf.chirp_interval_s).ravel()
    tx_index = np.tile(np.asarray(tx_order), len(frame_time_ns))
    keep = np.ones(times.size, bool)
    if options.tx is not None:
        keep &= np.isin(tx_index, options.tx)
    if time_window_ns is not None:
        keep &= (times >= time_window_ns[0]) & (times < time_window_ns[1])
    rx_sel = np.arange(wf.n_rx) if options.rx is None else np.asarray(options.rx)
    return times, tx_index, keep, rx_sel


def _main_direction(phase_centres_m: np.ndarray) -> np.ndarray:
    """``principal_axis`` of phase centres [N, 3], from at most about 8192 of them (the track's direction
    needs no more)."""
    return principal_axis(phase_centres_m[:: max(1, phase_centres_m.shape[0] // 4096)])


def _parse_frames(frames, n_frames: int, path) -> slice:
    if isinstance(frames, slice):
        start, stop, _ = frames.indices(n_frames)
        if frames.start is not None and not 0 <= frames.start < n_frames:
            raise SarbotError(f"{path}: frames {frames.start}:{frames.stop} out of range (the radar has {n_frames} frames)")
        if frames.stop is not None and frames.stop > n_frames:
            raise SarbotError(f"{path}: frames {frames.start}:{frames.stop} out of range (the radar has {n_frames} frames)")
        if stop <= start:
            raise SarbotError(f"{path}: frames {frames.start}:{frames.stop} select no frame")
        return slice(start, stop)
    raise TypeError("frames must be a slice")


@dataclasses.dataclass
class ApertureTaper:
    """A slow-time window over a synthetic aperture: the aperture runs from ``start_m`` to ``stop_m`` along
    ``axis`` (its phase centres' main direction, a unit vector, world frame)."""

    axis: np.ndarray
    start_m: float
    stop_m: float
    window: str

    def weights(self, phase_centres_m: np.ndarray) -> np.ndarray:
        """The window at each phase centre ([P, 3], metres): float32 [P]; the aperture's ends get the window's
        ends, a point aperture weight 1."""
        from imaging.core.windows import window_at

        span = self.stop_m - self.start_m
        if span <= 0:
            return np.ones(phase_centres_m.shape[0], np.float32)
        u = np.clip((phase_centres_m @ self.axis - self.start_m) / span, 0.0, 1.0)
        return window_at(self.window, u).astype(np.float32)

    def apply(self, profiles, phase_centres_m: np.ndarray) -> None:
        """Weight each profile (row of ``profiles.data``, and its kept samples) in place."""
        w = self.weights(phase_centres_m)[:, None]
        if profiles.rows is not None:
            profiles.rows *= w  # data is a view of it
        else:
            profiles.data *= w
        if profiles.samples is not None:
            profiles.samples *= w


class _BlockReader:
    """One radar's selected valid frames, read and range-compressed ``options.frames_per_block`` at a time."""

    def __init__(self, recording: Recording, radar_name: str, trajectory: Trajectory | None, frames: slice,
                 options: ImagingOptions, time_window_ns, track_error, clock: StageClock | None = None,
                 row_buffers: RowBuffers | None = None) -> None:
        self.recording, self.radar_name, self.options, self.clock = recording, radar_name, options, clock
        self.row_buffers = row_buffers
        self.image_box_m = None  # a box holding every pixel to be imaged (form_image's direct kernel), or None
        self.time_window_ns, self.track_error = time_window_ns, track_error
        self.radar = recording.radar(radar_name)
        if trajectory is None:
            trajectory = recording.truth()
            if trajectory is None:
                raise SarbotError(f"{recording.path}: no /truth trajectory in this recording; give a trajectory file")
        self.trajectory = trajectory
        self.sel = _parse_frames(frames, recording.n_frames(radar_name), recording.path)
        wf = self.radar.waveform
        for name, chans, n in (("tx", options.tx, wf.n_tx), ("rx", options.rx, wf.n_rx)):
            if chans is not None and (len(chans) == 0 or min(chans) < 0 or max(chans) >= n):
                raise SarbotError(f"{name} channels {list(chans)} out of range: radar {radar_name} has {n}")
        self.tx_order = recording.tdm_tx_order(radar_name)
        valid = recording.valid(radar_name, self.sel)
        if not np.all(valid):
            log.warning("radar %s: leaving out %d invalid frame(s)", radar_name, int(np.sum(~valid)))
        self.frame_indices = np.arange(self.sel.start, self.sel.stop)[valid]
        self.taper = None if options.aperture_window == "rectangular" else self._aperture_taper()

    def _aperture_taper(self) -> "ApertureTaper":
        """Where the aperture lies: the phase centres of every chirp to be imaged, before any is read."""
        wf, options = self.radar.waveform, self.options
        if self.frame_indices.size == 0:
            return ApertureTaper(np.array([1.0, 0.0, 0.0]), 0.0, 0.0, options.aperture_window)
        frame_times = self.recording.frame_time_ns(self.radar_name, self.sel)[self.frame_indices - self.sel.start]
        times, tx_index, keep, rx_sel = _selected_chirps(frame_times, wf, self.tx_order, options, self.time_window_ns)
        if not keep.any():
            return ApertureTaper(np.array([1.0, 0.0, 0.0]), 0.0, 0.0, options.aperture_window)
        track = antenna_track(self.radar, self.trajectory, times[keep], tx_index[keep])
        centres = (0.5 * (track.tx_m[:, None, :] + track.rx_m[:, rx_sel, :])).reshape(-1, 3)
        axis = _main_direction(centres)
        along = centres @ axis
        return ApertureTaper(axis, float(along.min()), float(along.max()), options.aperture_window)

    def block(self, b: int, n_frames: int | None = None):
        """Read and range-compress the block of ``n_frames`` (``options.frames_per_block`` by default)
        starting at the b-th selected frame: frame_profiles' result, its profiles tapered along the
        aperture if the options ask for it."""
        idx = self.frame_indices[b:b + (n_frames or self.options.frames_per_block)]
        block = slice(int(idx[0]), int(idx[-1]) + 1)
        with timed(self.clock, "compress_thread.read_frames"):
            adc = self.recording.adc(self.radar_name, block)
            ftimes = self.recording.frame_time_ns(self.radar_name, block)
        keep = np.isin(np.arange(block.start, block.stop), idx)
        with timed(self.clock, "compress_thread.range_compress_and_place"):
            result = frame_profiles(adc[keep], ftimes[keep], self.radar, self.trajectory, self.tx_order, self.options,
                                    self.time_window_ns, self.track_error, self.row_buffers, self.image_box_m)
        if self.taper is not None:
            profiles, tx_m, rx_m = result[:3]
            self.taper.apply(profiles, 0.5 * (tx_m + rx_m))
        return result

    def profile_blocks(self, time_origin_ns: int):
        """Every block as an autofocus ProfileBlock (direction: the radar's boresight at each chirp)."""
        from imaging.autofocus import ProfileBlock

        n_rx = self.radar.waveform.n_rx if self.options.rx is None else len(self.options.rx)
        for b in range(0, self.frame_indices.size, self.options.frames_per_block):
            profiles, tx_m, rx_m, times, track = self.block(b)
            if profiles.data.shape[0]:
                yield ProfileBlock(profiles, tx_m, rx_m, (times - np.int64(time_origin_ns)) * 1e-9,
                                   np.repeat(track.boresight, n_rx, axis=0))


def form_image(
    recording: Recording,
    radar_name: str,
    grid: Grid,
    trajectory: Trajectory | None = None,
    frames: slice = slice(None),
    options: ImagingOptions | None = None,
    time_window_ns: tuple[int, int] | None = None,
    progress=None,
    track_error=None,
    clock: StageClock | None = None,
) -> SarImage:
    """Backproject one radar's frames onto ``grid``.

    Frames flagged invalid in the recording (data lost on the wire) are left out and logged. The image
    attributes record what theory needs: aperture length, look direction, speed, wavelength, bandwidth.
    ``track_error`` (from autofocus) moves the radar along its boresight by that much at every chirp.
    ``clock`` (``imaging.core.stage_clock.StageClock``), if given, gets the wall time of each stage: this
    thread's (``wait_for_block``, ``kernel_import_wait``, ``backproject``, ...) add up to the call's; the
    range-compression thread's (``compress_thread.*``) overlap them.
    """
    from imaging import kernel_import

    options = options or ImagingOptions()
    ffbp = options.algorithm == "ffbp"
    row_buffers = None if ffbp else RowBuffers()  # FFBP holds every block's profiles to the end
    with timed(clock, "open_frames"):
        reader = _BlockReader(recording, radar_name, trajectory, frames, options, time_window_ns, track_error, clock,
                              row_buffers)
    sel, frame_indices, trajectory, wf = reader.sel, reader.frame_indices, reader.trajectory, reader.radar.waveform
    if not ffbp:  # only the bins the grid needs (imaging.range_window); FFBP's grids reach beyond it
        reader.image_box_m = (np.array([grid.x_m.min(), grid.y_m.min(), grid.z_m.min()]),
                              np.array([grid.x_m.max(), grid.y_m.max(), grid.z_m.max()]))
    image = np.zeros(grid.shape, np.complex128)
    mids, tracks_times, speeds = [], [], []
    boresights = []
    n_profiles = 0
    starts, ends = frame_blocks(frame_indices.size, options.frames_per_block)

    def prepare(n):
        return reader.block(starts[n], ends[n] - starts[n])

    if ffbp and grid.z_m.size > 1:
        raise SarbotError("fast factorized backprojection images a horizontal plane; the grid is a volume (use the direct algorithm)")
    points = None if ffbp else grid.points()
    held: list = []  # ffbp: every block's (profiles, tx, rx), imaged at the end
    with ThreadPoolExecutor(1, thread_name_prefix="range-compress") as pool:
        ahead = collections.deque([pool.submit(prepare, 0)] if starts else [])  # blocks submitted, in order
        submitted = len(ahead)
        for n in range(len(starts)):
            with timed(clock, "wait_for_block"):
                profiles, tx_m, rx_m, times, track = ahead.popleft().result()
            if not ahead and submitted < len(starts):
                ahead.append(pool.submit(prepare, submitted))
                submitted += 1
            if n == 0 and not ffbp:
                with timed(clock, "kernel_import_wait"):
                    # While the kernels are made ready on another thread (a new process's numba import
                    # and cache load, imaging.kernel_import), the other core range-compresses blocks
                    # ahead rather than idle; at most COMPRESS_AHEAD of them are held.
                    while kernel_import.in_progress() and submitted < len(starts) and len(ahead) < COMPRESS_AHEAD:
                        ahead[-1].result()
                        if kernel_import.in_progress():
                            ahead.append(pool.submit(prepare, submitted))
                            submitted += 1
                    from imaging.backprojection import backproject
            if profiles.data.shape[0] and profiles.data.size:
                if ffbp:
                    held.append((profiles, tx_m, rx_m))
                else:
                    with timed(clock, "backproject"):
                        backproject(profiles, tx_m, rx_m, points, mode=options.mode, out=image)
                    row_buffers.give(profiles.rows)  # for a later block's profiles
                with timed(clock, "antenna_summary"):
                    n_profiles += profiles.data.shape[0]
                    mids.append(0.5 * (tx_m + rx_m))
                    tracks_times.append(times)
                    boresights.append(track.boresight)
                    speeds.append(np.linalg.norm(trajectory.sample(track.time_ns).velocity_mps, axis=1))
            with timed(clock, "free_block"):
                del profiles  # before the next block's are made: at most two blocks in memory after the first
            if progress is not None:
                progress(ends[n], frame_indices.size)
    if n_profiles == 0:
        raise SarbotError(f"{recording.path}: radar {radar_name}: no chirp falls in the selected frames and time window")
    extra = _image_factorized(held, grid, options, image) if ffbp else {}
    with timed(clock, "attributes"):
        return _with_attributes(image, grid, recording, radar_name, sel, trajectory, options, extra, wf, frame_indices,
                                n_profiles, mids, boresights, speeds)


def _with_attributes(image, grid, recording, radar_name, sel, trajectory, options, extra, wf, frame_indices, n_profiles,
                     mids, boresights, speeds) -> SarImage:
    """The SarImage of ``form_image``: the image and what theory needs to know of it (docs/formats/image.md)."""
    ffbp = options.algorithm == "ffbp"
    mid = np.concatenate(mids)
    attrs = {
        "radar": radar_name,
        "frames": f"{sel.start}:{sel.stop}",
        "trajectory_source": getattr(trajectory, "source", "unknown"),
        "method": f"{'ffbp' if ffbp else 'tdbp'}-{options.mode}",
        **extra,
        "window": options.window,
        "aperture_window": options.aperture_window,
        "oversample": options.oversample,
        "wavelength_m": wf.wavelength_m,
        "centre_frequency_hz": wf.centre_frequency_hz,
        "bandwidth_hz": wf.sampled_bandwidth_hz,
        "n_frames": int(frame_indices.size),
        "n_profiles": int(n_profiles),
        "aperture_length_m": aperture_length_m(mid),
        "look_direction": _horizontal_unit(np.concatenate(boresights).mean(axis=0)),
        "aperture_centre_m": mid.mean(axis=0),
        "speed_mps": float(np.concatenate(speeds).mean()),
        "source_file": str(recording.path),
    }
    return SarImage(image, grid.x_m, grid.y_m, grid.z_m if grid.z_m.size > 1 else grid.z_m[:1], attrs)


def _image_factorized(held: list, grid: Grid, options: ImagingOptions, image: np.ndarray) -> dict:
    """FFBP of the held blocks onto the plane grid, into ``image``; the plan's error figures for the attrs."""
    from imaging.factorized_backprojection import FactorizedOptions, plan_factorized, run_factorized

    blocks = [p for p, _, _ in held]
    tx = np.concatenate([t for _, t, _ in held])
    rx = np.concatenate([r for _, _, r in held])
    try:
        plan = plan_factorized(tx, rx, grid.x_m, grid.y_m, float(grid.z_m[0]), blocks[0].carrier_hz,
                               blocks[0].bandwidth_hz, FactorizedOptions(mode=options.mode))
    except ValueError as e:
        raise SarbotError(f"fast factorized backprojection: {e}") from None
    run_factorized(plan, blocks, tx, rx, out=image)
    return {"ffbp_levels": plan.levels, "ffbp_error_bound_db": plan.error_bound_db,
            "ffbp_error_estimate_db": plan.error_estimate_db}


def focus_image(
    recording: Recording,
    radar_name: str,
    grid: Grid,
    trajectory: Trajectory | None = None,
    frames: slice = slice(None),
    options: ImagingOptions | None = None,
    autofocus=None,
    time_window_ns: tuple[int, int] | None = None,
    progress=None,
    imu_aided: bool = False,
) -> SarImage:
    """``form_image``, then autofocus: the radar's track error along its boresight estimated from the image
    (``imaging.autofocus``) and the image formed again on the corrected track.

    ``autofocus`` is an ``AutofocusOptions`` (method "none": no estimate). With ``imu_aided`` the
    displacement measured by the IMU on the radar's own mount (``imaging.imu_aided``) corrects the track
    first, and autofocus estimates what is left. The track error goes into the image:
    ``SarImage.track_error`` (``/autofocus`` in the file) and attributes ``autofocus``,
    ``autofocus_entropy_before``/``_after``, ``autofocus_applied``, ``imu_aided``, and under the default
    decision the consistency of the half-band estimates (``autofocus_consistency_*``, docs/formats/image.md).
    """
    from imaging.autofocus import AutofocusOptions, estimate_track_error, image_entropy
    from imaging.imu_aided import boresight_track_from_imu, combined

    autofocus = autofocus or AutofocusOptions()
    options = options or ImagingOptions()
    reader = _BlockReader(recording, radar_name, trajectory, frames, options, time_window_ns, None)
    frame_times = recording.frame_time_ns(radar_name, reader.sel)
    origin = int(frame_times[0])
    wf = reader.radar.waveform
    span = [origin, int(frame_times[-1]) + wf.frame_duration_ns]
    if time_window_ns is not None:
        span = [max(span[0], time_window_ns[0]), min(span[1], time_window_ns[1])]
    imu_track = None
    if imu_aided:
        samples = recording.radar_imu(radar_name)
        if samples is None:
            raise SarbotError(f"{recording.path}: radar {radar_name} has no IMU of its own (a rig declares one as "
                              f"[radar.{radar_name}.imu])")
        try:
            imu_track = boresight_track_from_imu(samples["time_ns"], samples["accel_mps2"], tuple(span), origin)
        except ValueError as exc:
            raise SarbotError(f"{recording.path}: radar {radar_name}: {exc}") from None
    stages = 1 if autofocus.method == "none" else 3
    frames_total = [1]

    def stage(k):
        """Progress of stage k of form, estimate, form again, in frames of all three."""
        def report(done, total):
            frames_total[0] = total
            progress(k * total + done, stages * total)
        return None if progress is None else report

    img = form_image(recording, radar_name, grid, trajectory, frames, options, time_window_ns, stage(0), imu_track)
    img.attrs["imu_aided"] = int(imu_aided)
    img.track_error = imu_track
    if autofocus.method == "none":
        return img
    reader.track_error = imu_track
    result = estimate_track_error(lambda: reader.profile_blocks(origin), img.image, grid.points(), autofocus,
                                  time_range_s=((span[0] - origin) * 1e-9, (span[1] - origin) * 1e-9))
    result.track_error.time_origin_ns = origin
    if progress is not None:
        progress(2 * frames_total[0], 3 * frames_total[0])
    track = result.track_error if imu_track is None else combined(imu_track, result.track_error)
    if result.applied:
        focused = form_image(recording, radar_name, grid, trajectory, frames, options, time_window_ns, stage(2),
                             track_error=track)
        # The estimate was judged on its pixels; the whole image must be sharper too, or it is not used.
        if image_entropy(focused.image) < image_entropy(img.image):
            focused.attrs["imu_aided"] = int(imu_aided)
            img = focused
        else:
            result.applied = False
            result.note = "the corrected image was not sharper than the plain one; left unapplied"
    img.attrs.update({"autofocus": autofocus.method, "autofocus_applied": int(result.applied),
                      "autofocus_entropy_before": result.entropy_before, "autofocus_entropy_after": result.entropy_after,
                      "autofocus_groups": result.groups, "autofocus_pixels": result.pixels})
    if result.consistency is not None:  # the half-band estimates compared (imaging.autofocus.consistency)
        img.attrs.update(result.consistency.as_attrs())
    img.track_error = track if result.applied else (imu_track or result.track_error)
    return img


def choose_radar(recording: Recording, radar: str | None) -> str:
    """``radar`` (checked against the recording), or the recording's only radar."""
    if radar is None:
        if len(recording.radar_names) != 1:
            raise SarbotError(f"{recording.path}: several radars ({', '.join(recording.radar_names)}); choose one with --radar")
        radar = recording.radar_names[0]
    recording.radar(radar)  # checks the name
    return radar


def image_recording(recording: Recording, radar: str | None, grid_spec: str, trajectory: str = "truth",
                    frames: slice = slice(None), options: ImagingOptions | None = None, progress=None,
                    autofocus=None, imu_aided: bool = False, aperture_m: float | None = None,
                    clock: StageClock | None = None) -> SarImage:
    """What ``sarbot image`` (and every job of ``sarbot batch``) forms: ``radar`` (None: the only one),
    on ``trajectory`` ("truth" or a trajectory file), on the grid ``x0:x1:dx,y0:y1:dy[,z]`` whose height
    defaults to the radar's mean height over the recording; autofocused with ``autofocus``
    (``AutofocusOptions``) unless it is None or its method "none", the track first corrected by the radar's
    own IMU with ``imu_aided``; only the central ``aperture_m`` of the frames' track if given
    (``central_aperture``). ``clock``: the stages of a plain image's formation (``form_image``)."""
    from imaging.io.trajectory_file import read_trajectory

    radar = choose_radar(recording, radar)
    traj = recording.truth() if trajectory == "truth" else read_trajectory(trajectory)
    if traj is None:
        raise SarbotError(f"{recording.path}: no /truth in this recording; give --trajectory FILE")
    mount_z = float(recording.radar(radar).mount.translation_m[2])
    z0 = float(np.mean(traj.position_m[:, 2])) + mount_z if hasattr(traj, "position_m") else 0.0
    grid = Grid.parse(grid_spec, default_z_m=z0)
    window = None
    if aperture_m is not None:
        frames, window = central_aperture(recording, radar, traj, frames, aperture_m)
    if imu_aided or autofocus is not None and autofocus.method != "none":
        return focus_image(recording, radar, grid, traj, frames, options, autofocus, time_window_ns=window,
                           progress=progress, imu_aided=imu_aided)
    return form_image(recording, radar, grid, traj, frames, options, time_window_ns=window, progress=progress, clock=clock)


def check_aperture_m(aperture_m: float) -> None:
    """A synthetic aperture asked for must be a positive, finite length (SarbotError otherwise)."""
    if not (np.isfinite(aperture_m) and aperture_m > 0):
        raise SarbotError(f"aperture {aperture_m} m: must be a positive length")


def central_aperture(recording: Recording, radar_name: str, trajectory: Trajectory, frames: slice,
                     aperture_m: float) -> tuple[slice, tuple[int, int]]:
    """The chirps of ``frames`` whose bistatic phase centres (every RX of the chirp's TX) lie within
    ``aperture_m`` / 2 of the middle of those the frames cover, along their main direction (the length
    ``aperture_length_m`` gives the image): the frames holding them and their time window (``form_image``'s
    ``time_window_ns``). An aperture longer than the frames cover is an error."""
    check_aperture_m(aperture_m)
    sel = _parse_frames(frames, recording.n_frames(radar_name), recording.path)
    config = recording.radar(radar_name)
    wf = config.waveform
    times = chirp_times_ns(recording.frame_time_ns(radar_name, sel), wf.chirps_per_frame, wf.chirp_interval_s).ravel()
    tx_index = np.tile(np.asarray(recording.tdm_tx_order(radar_name)), sel.stop - sel.start)
    track = antenna_track(config, trajectory, times, tx_index)
    centres = 0.5 * (track.tx_m[:, None, :] + track.rx_m)  # [chirps, rx, 3]
    flat = centres.reshape(-1, 3)
    along = centres @ _main_direction(flat)
    lo, hi = along.min(axis=1), along.max(axis=1)
    length = float(hi.max() - lo.min())
    if length < aperture_m:
        raise SarbotError(f"{recording.path}: radar {radar_name}, frames {sel.start}:{sel.stop}: the track is "
                          f"{length:.3f} m long, shorter than the aperture of {aperture_m} m asked for")
    middle = 0.5 * (hi.max() + lo.min())
    inside = (lo >= middle - aperture_m / 2) & (hi <= middle + aperture_m / 2)
    # The longest run of chirps all inside: the TX lead or trail one another along the track, so a window
    # from the first chirp inside to the last would take in other TXs' chirps beyond the ends.
    edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.view(np.int8), [0]])))
    if edges.size == 0:
        raise SarbotError(f"aperture {aperture_m} m: shorter than one chirp's phase centres span; nothing to image")
    starts, stops = edges[0::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    first, last = int(starts[k]), int(stops[k]) - 1
    per_frame = wf.chirps_per_frame
    window = (int(times[first]), int(times[last]) + 1)
    return slice(sel.start + first // per_frame, sel.start + last // per_frame + 1), window


def image_title(img: SarImage) -> str:
    """The PNG title of an image formed from a recording."""
    return f"{img.attrs['radar']} frames {img.attrs['frames']} ({img.attrs['method']})"


def _horizontal_unit(v: np.ndarray) -> np.ndarray:
    h = np.array([v[0], v[1], 0.0])
    return h / np.linalg.norm(h)


def aperture_length_m(phase_centres_m: np.ndarray) -> float:
    """Length of a synthetic aperture: extent of the phase centres along their main direction, plus the
    mean spacing of distinct positions (N samples spaced d make an aperture N*d long)."""
    if phase_centres_m.shape[0] < 2:
        return 0.0
    c = phase_centres_m - phase_centres_m.mean(axis=0)
    along = np.sort(c @ principal_axis(c))
    extent = along[-1] - along[0]
    distinct = np.unique(np.round(along, 9))
    return float(extent + (extent / (distinct.size - 1) if distinct.size > 1 else 0.0))
