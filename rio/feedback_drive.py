"""A simulated drive for the map's feedback into the odometry (``rio.map_feedback``), and the loop that runs it.

The robot stands 2 s, then drives straight at 0.4 m/s past point targets on both sides; the two front radars
(looking left and right) give raw frames for the strip map, all four give detections for the odometry. The
radars' Doppler reads ``doppler_scale_error`` too low (a systematic along-track velocity error the IMU cannot
tell from a slower drive), so the odometry comes up short along the track; that is what the map can see (the
azimuth defocus of a wrong speed). ``run_feedback_loop`` runs odometry and map together in time: the filter
runs ``step_s`` at a time, the frames its poses cover are imaged on them, the tiles refocused meanwhile
become measurements (with ``feedback``) before the filter goes on, so later frames are imaged on the
corrected trajectory. Shared by tests/test_map_feedback.py and benchmarks/map_feedback.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns, SampledTrajectory
from imaging.sim.detection_simulator import DetectionModel, room_scatterers, simulate_scan
from imaging.sim.imu_simulator import ImuErrors, simulate_imu
from imaging.sim.scene import DEFAULT_START_TIME_NS as T0
from imaging.sim.simulator import simulate_frames
from imaging.sim.targets import PointTarget
from imaging.stripmap import StripMap, StripMapConfig

from .calibration_drive import SIM_EKF
from .map_feedback import LookVelocityMeasurement, MapFeedback, MapFeedbackConfig, velocity_error_from_tiles
from .odometry import RadarScan, RioOptions
from .streaming import StreamingRio

IMAGING_RADARS = ("left_front", "right_front")
START_DELAY_S = 2.0
SPEED_MPS = 0.4
#: The map: a 0.6 m aperture, where a 2 % speed error bends the track error of a target 1.5 m away by about
#: 1 mm (3 rad of phase) at the ends; refocus by the entropy model.
MAP_CONFIG = StripMapConfig(pixel_m=0.01, tile_px=32, aperture_m=0.6, beam_half_angle_deg=45.0, range_min_m=0.6,
                            range_max_m=2.5, presum=4, refocus="entropy", refocus_groups_per_frame=2)


#: The map as imaged, for its sharpness: pixels finer than the cross-range resolution (5 mm at 1.5 m), so a
#: peak is not lost between two (at 1 cm a sharp target's sampled peak falls below a blurred one's).
PLAIN_PIXEL_M = 0.004


@dataclasses.dataclass
class FeedbackDrive:
    """What the loop needs: the truth, IMU samples, Doppler scans (with the scale error), raw frames of the
    imaging radars (name -> (times [F], frames [F, chirps, rx, samples])) and the point targets."""

    truth: PathWithTurns
    imu: tuple[np.ndarray, np.ndarray, np.ndarray]
    scans: list[RadarScan]
    frames: dict[str, tuple[np.ndarray, np.ndarray]]
    targets_m: np.ndarray
    duration_s: float


def simulate_feedback_drive(length_m: float = 6.0, seed: int = 0, doppler_scale_error: float = 0.02,
                            snr_db: float = 0.0, with_frames: bool = True) -> FeedbackDrive:
    """Simulate the drive: ``length_m`` straight at ``SPEED_MPS`` after ``START_DELAY_S`` standing, a target
    every 0.64 m on both sides (1.2 or 1.6 m from the radars), frames at ``snr_db`` per sample (none without
    ``with_frames``: the odometry alone)."""
    rng = np.random.default_rng(seed)
    rig = default_rig()
    truth = PathWithTurns(segments=[("straight", length_m)], speed_mps=SPEED_MPS, accel_mps2=0.5,
                          start_delay_s=START_DELAY_S, t0_ns=T0)
    duration_s = START_DELAY_S + length_m / SPEED_MPS + 2.0
    imu = simulate_imu(truth, rig.imu, T0, T0 + int(duration_s * 1e9), rng=rng,
                       errors=ImuErrors(gyro_bias_radps=(0.002, -0.003, 0.001), accel_bias_mps2=(0.05, -0.04, 0.03)))
    static = room_scatterers(size_m=(length_m + 8.0, 8.0), centre_m=(length_m / 2, 0.0), spacing_m=0.5, clutter=60, rng=rng)
    scans = []
    for r in rig.radars:
        for k in range(int(duration_s / 0.052)):
            t = T0 + int((k + 0.5) * 0.052e9)
            sc = simulate_scan(r, truth, t, static, [], DetectionModel(detection_probability=0.5), rng, T0)
            scans.append(RadarScan(t, r.name, r.mount, sc.xyz_m, sc.doppler_mps * (1.0 - doppler_scale_error)))
    # At the centres of the map's tiles, every other tile along the track, from where the speed is steady
    # (a tile's refocus sees its scatterer whole; the fit takes the velocity error as constant over a tile).
    tile_m = MAP_CONFIG.tile_m
    xs = (np.arange(math.ceil(0.9 / tile_m), math.floor((length_m - 0.3) / tile_m), 2) + 0.5) * tile_m
    frames, targets = {}, []
    for name in IMAGING_RADARS:
        radar = rig.radar(name)
        sign = 1.0 if radar.mount.translation_m[1] > 0 else -1.0
        rows = rng.integers(4, 6, xs.size)  # 1.2 or 1.6 m from the radar
        pts = [(float(x), float(sign * (iy + 0.5) * tile_m), float(MAP_CONFIG.z_m)) for x, iy in zip(xs, rows)]
        targets.extend(pts)
        if not with_frames:
            continue
        wf = radar.waveform
        n = int(duration_s / wf.frame_interval_s) - 1
        times = T0 + np.round(np.arange(n) * wf.frame_interval_s * 1e9).astype(np.int64)
        moving = times > T0 + int((START_DELAY_S - 0.5) * 1e9)
        times = times[moving]
        adc = simulate_frames(radar, truth, [PointTarget(p) for p in pts], times, snr_db=snr_db, rng=rng)
        frames[name] = (times, adc)
    return FeedbackDrive(truth, (imu.time_ns, imu.accel_mps2, imu.gyro_radps), scans, frames, np.array(targets), duration_s)


@dataclasses.dataclass
class LoopResult:
    """The odometry's trajectory, the map as it was imaged (no refocus: how each tile started), the refocusing
    map, the feedback's log (None without feedback), and each set of tiles refocused together with the
    measurements read off it (``tile_sets``: pairs (tiles, measurements), as the filter was given them)."""

    trajectory: SampledTrajectory
    plain_map: StripMap
    refocus_map: StripMap | None
    feedback: MapFeedback | None
    tile_sets: list = dataclasses.field(default_factory=list)


def run_feedback_loop(drive: FeedbackDrive, feedback: bool, step_s: float = 0.25,
                      map_config: StripMapConfig = MAP_CONFIG, feedback_config: MapFeedbackConfig = MapFeedbackConfig(),
                      trajectory=None) -> LoopResult:
    """Odometry and map in time, with or without the map's measurements going into the filter.

    With ``trajectory`` given (the truth, say), the map is imaged on it and no odometry runs: the reference."""
    rig = default_rig()
    plain = StripMap(dataclasses.replace(map_config, refocus="none", pixel_m=PLAIN_PIXEL_M, range_min_m=1.0,
                                         range_max_m=1.9, tile_px=int(round(map_config.tile_m / PLAIN_PIXEL_M))))
    refocusing = StripMap(map_config) if feedback else None
    loop = MapFeedback(feedback_config) if feedback else None
    rio = StreamingRio(RioOptions(ekf=SIM_EKF), imu_rate_hz=400.0)
    t_imu, acc, gyr = drive.imu
    scans = sorted(drive.scans, key=lambda s: s.time_ns)
    poses: list = []
    next_frame = {name: 0 for name in drive.frames}
    used: set = set()
    tile_sets: list = []
    end_ns = T0 + int(drive.duration_s * 1e9)
    i_imu = j_scan = 0
    t = T0
    while t < end_ns:
        t = min(t + int(step_s * 1e9), end_ns)
        if trajectory is None:
            k = int(np.searchsorted(t_imu, t, side="right"))
            while j_scan < len(scans) and scans[j_scan].time_ns <= t:
                poses.append(rio.add_scan(loop.correct_scan(scans[j_scan]) if loop is not None else scans[j_scan]))
                j_scan += 1
            poses.append(rio.add_imu(t_imu[i_imu:k], acc[i_imu:k], gyr[i_imu:k]))
            i_imu = k
            if sum(len(p) for p in poses) < 2:
                continue
            traj = SampledTrajectory.from_batches(poses)
        else:
            traj = trajectory
        covered = int(traj.time_ns[-1]) if trajectory is None else t
        for name, (times, adc) in drive.frames.items():
            radar = rig.radar(name)
            frame_ns = int(radar.waveform.frame_duration_ns)
            order = np.asarray(radar.waveform.tdm_tx_order())
            while next_frame[name] < times.size and times[next_frame[name]] + frame_ns <= covered:
                f = next_frame[name]
                plain.add_frame(radar, order, adc[f], int(times[f]), traj)
                if refocusing is not None:
                    refocusing.add_frame(radar, order, adc[f], int(times[f]), traj)
                next_frame[name] += 1
        if refocusing is not None and trajectory is None and rio.ekf is not None:
            fresh = [key for key in refocusing.refocus_geometry if key not in used]
            used.update(fresh)
            tiles = [(refocusing.refocus_results[key].track_error, refocusing.refocus_geometry[key]) for key in fresh]
            if tiles:
                loop.note_poses(traj.time_ns, traj.velocity_mps)
                measurements = velocity_error_from_tiles(tiles, loop.config)
                tile_sets.append((tiles, measurements))
                loop.apply_measurements(rio.ekf, measurements)
    if trajectory is None:
        poses.append(rio.finish())
        traj = SampledTrajectory.from_batches(poses)
    return LoopResult(traj, plain, refocusing, loop, tile_sets)


def target_peaks_db(strip_map: StripMap, targets_m: np.ndarray, radius_m: float = 0.15) -> np.ndarray:
    """Each target's peak in ``strip_map`` (dB of |value|; NaN where the map has no pixel near it): the
    brightest pixel within ``radius_m`` of where the target is (the odometry's error moves it a little)."""
    out = np.full(len(targets_m), np.nan)
    for i, p in enumerate(targets_m):
        best = 0.0
        for key, tile in strip_map.tiles.items():
            x, y = strip_map.tile_points(key)
            if x.min() - radius_m > p[0] or x.max() + radius_m < p[0] or y.min() - radius_m > p[1] or y.max() + radius_m < p[1]:
                continue
            near = (np.abs(x[None, :] - p[0]) <= radius_m) & (np.abs(y[:, None] - p[1]) <= radius_m)
            if near.any():
                best = max(best, float(np.abs(tile[near]).max()))
        if best > 0:
            out[i] = 20 * np.log10(best)
    return out


def odometry_with_truth_measurements(drive, sigma_mps: float | None, every_s: float = 1.6, span_s: float = 1.5,
                                     seed: int = 0, learn_scale: bool = True):
    """The streaming odometry over ``drive`` (its IMU and scans only); with ``sigma_mps``, every ``every_s``
    while driving, a map measurement of the along-track velocity error over the last ``span_s`` (the truth's,
    plus noise of that sigma), as the map's tiles would give it: the filter's side of the feedback alone.
    Returns the position error at the end (truth minus odometry) and the ``MapFeedback``."""
    rng = np.random.default_rng(seed)
    rio = StreamingRio(RioOptions(ekf=SIM_EKF))
    feedback = MapFeedback(MapFeedbackConfig(learn_doppler_scale=learn_scale))
    t_imu, acc, gyr = drive.imu
    scans = sorted(drive.scans, key=lambda s: s.time_ns)
    poses, i, j = [], 0, 0
    t = int(t_imu[0])
    while t < t_imu[-1]:
        t += int(every_s * 1e9)
        while j < len(scans) and scans[j].time_ns <= t:
            poses.append(rio.add_scan(feedback.correct_scan(scans[j])))
            j += 1
        k = int(np.searchsorted(t_imu, t, side="right"))
        poses.append(rio.add_imu(t_imu[i:k], acc[i:k], gyr[i:k]))
        i = k
        done = [p for p in poses if len(p)]
        if sigma_mps is None or not done:
            continue
        times = np.concatenate([p.time_ns for p in done])
        centre = int(times[-1] - span_s / 2 * 1e9)
        velocity = np.concatenate([p.velocity_mps for p in done])
        true_v = drive.truth.sample(np.array([centre])).velocity_mps[0]
        if true_v[0] < 0.3:
            continue
        error = true_v[0] - velocity[np.searchsorted(times, centre), 0] + rng.normal(0, sigma_mps)
        feedback.apply_measurements(rio.ekf, [LookVelocityMeasurement(centre, span_s, np.array([1.0, 0, 0]), error,
                                                                      sigma_mps, ("left_front", "right_front"), 2)])
    poses.append(rio.finish())
    done = [p for p in poses if len(p)]
    times = np.concatenate([p.time_ns for p in done])
    position = np.concatenate([p.position_m for p in done])
    return drive.truth.sample(times[-1:]).position_m[0] - position[-1], feedback
