"""What a radar's calibration does to its images: point targets seen by one radar along the TRUE trajectory with
its TRUE mount and clock (raw FMCW frames, imaging.sim.simulator), imaged by backprojection on the trajectory,
mount and time offset an odometry run believes (the true rig's, the wrong rig's, the wrong rig calibrated
online), over apertures where the robot turns and speeds up (a mount or clock error there bends the track the
image is formed on; on a straight pass at constant speed it only moves the image). Shared by
tests/test_calibration.py and benchmarks/calibration_stripmap.py; see docs/signal-model.md.

Each image is formed in its run's own frame, about where that run believes the targets are relative to the robot
at the aperture's middle: the odometry's slow drift (which moves the whole map, not one aperture's focus) is
taken out, what is left is how well the aperture's track and the antennas on it agree with the truth.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.backprojection import backproject
from imaging.core.geometry import chirp_times_ns
from imaging.core.rig import Mount, RadarConfig
from imaging.core.trajectory import Trajectory
from imaging.core.windows import half_power_width
from imaging.metrics import cut, find_peak, sidelobe_levels
from imaging.profiles import chirp_profiles
from imaging.sim.simulator import simulate_frames
from imaging.sim.targets import PointTarget


@dataclasses.dataclass(frozen=True)
class BelievedRig:
    """What one run believes of a radar: the body trajectory, the radar's mount and its clock's offset (radar
    stamp minus IMU time, s: a frame stamped t was measured at t - time_offset_s)."""

    trajectory: Trajectory
    mount: Mount
    time_offset_s: float = 0.0


@dataclasses.dataclass(frozen=True)
class Aperture:
    """A stretch of the drive one radar images: its frames' true start times [F] (ns) and the targets."""

    radar: RadarConfig  # the true radar (its true mount)
    frame_time_ns: np.ndarray
    targets: tuple[PointTarget, ...]

    @property
    def middle_ns(self) -> int:
        return int(self.frame_time_ns[self.frame_time_ns.size // 2])


def turning_aperture_starts_ns(trajectory: Trajectory, start_ns: int, stop_ns: int, step_s: float = 0.01,
                               yaw_rate_radps: float = 0.5) -> np.ndarray:
    """Times the robot sets off from a stop into a turn (speed through 0.02 m/s upward with the yaw rate
    above ``yaw_rate_radps`` within the next half second): where it speeds up and turns at once."""
    t = np.arange(start_ns, stop_ns, int(step_s * 1e9), dtype=np.int64)
    s = trajectory.sample(t)
    speed = np.linalg.norm(s.velocity_mps, axis=1)
    yaw_rate = np.abs(s.angular_velocity_body_radps[:, 2])
    half = int(0.5 / step_s)
    starts = np.flatnonzero((speed[:-1] < 0.02) & (speed[1:] >= 0.02)) + 1
    return np.array([t[k] for k in starts if k + half < t.size and yaw_rate[k + half] > yaw_rate_radps], np.int64)


def place_targets(radar: RadarConfig, trajectory: Trajectory, time_ns: int, ranges_m=(1.0, 1.5, 2.0),
                  across_m=(0.3, 0.0, -0.3)) -> tuple[PointTarget, ...]:
    """Point targets level with the radar at ``time_ns``: along its boresight at ``ranges_m``, each moved
    across it by the matching ``across_m``."""
    s = trajectory.sample(np.array([time_ns], np.int64))
    rot = s.rotation.as_matrix()[0]
    centre = s.position_m[0] + rot @ radar.mount.translation_m
    look = rot @ radar.mount.boresight_body
    look[2] = 0.0
    look /= np.linalg.norm(look)
    side = np.array([-look[1], look[0], 0.0])
    return tuple(PointTarget(tuple(centre + r * look + a * side)) for r, a in zip(ranges_m, across_m))


def radar_frames(aperture: Aperture, truth: Trajectory, seed: int = 0, snr_db: float | None = 10.0) -> np.ndarray:
    """Raw frames [F, chirps, rx, samples] of the aperture's radar along the true trajectory."""
    return simulate_frames(aperture.radar, truth, aperture.targets, aperture.frame_time_ns, snr_db=snr_db,
                           rng=np.random.default_rng(seed))


def _to_believed(point_m: np.ndarray, truth: Trajectory, believed: Trajectory, time_ns: int) -> np.ndarray:
    """A world point where ``believed`` has it: the same place relative to the robot at ``time_ns``."""
    t = np.array([time_ns], np.int64)
    a, b = truth.sample(t), believed.sample(t)
    local = a.rotation.as_matrix()[0].T @ (np.asarray(point_m, float) - a.position_m[0])
    return b.position_m[0] + b.rotation.as_matrix()[0] @ local


def form_aperture_image(aperture: Aperture, adc: np.ndarray, stamp_offset_s: float, truth: Trajectory,
                        believed: BelievedRig, half_size_m: float = 0.12, coarse_pixel_m: float = 0.0015,
                        fine_half_size_m: float = 0.004, fine_pixel_m: float = 0.0004,
                        presum: int = 4) -> dict:
    """Backproject one aperture as ``believed`` has it.

    Parameters
    ----------
    adc : ndarray, shape (F, chirps, rx, samples)
        ``radar_frames`` of the aperture.
    stamp_offset_s : float
        How late the radar's clock truly is: its frames carry ``frame_time_ns + stamp_offset_s``.
    believed : BelievedRig
        The trajectory, mount and time offset to image with.
    half_size_m, coarse_pixel_m : float
        A square patch about each target, where ``believed`` puts it relative to the robot (wide enough for a
        wrong rig's error), for the shape of its response.
    fine_half_size_m, fine_pixel_m : float
        A small patch about that patch's highest pixel, for the peak itself (the image's phase turns once
        every half wavelength along range: its amplitude is sampled finely, not interpolated).
    presum : int
        Chirps of one TX summed (coherently, consecutive) before imaging: fewer profiles, the same aperture.

    Returns
    -------
    dict
        "patches": per target the complex image [ny, nx] with its "x_m", "y_m" axes, "expected_m" (x, y) and
        "fine_image" (the small patch about the peak),
        "look" (x, y) the radar's look direction at the middle (believed).
    """
    radar = dataclasses.replace(aperture.radar, mount=believed.mount)
    wf = radar.waveform
    stamps = aperture.frame_time_ns + int(round(stamp_offset_s * 1e9))
    times = chirp_times_ns(stamps - int(round(believed.time_offset_s * 1e9)), wf.chirps_per_frame,
                           wf.chirp_interval_s).ravel()
    tx_order = np.tile(np.asarray(wf.tdm_tx_order()), stamps.size)
    samples = adc.reshape(-1, wf.n_rx, wf.samples_per_chirp)
    if presum > 1:  # the TDM order repeats every n_tx chirps: sum each TX's `presum` consecutive chirps
        n = samples.shape[0] // (wf.n_tx * presum) * wf.n_tx * presum
        shape = (-1, presum, wf.n_tx)
        per_chirp = (wf.n_rx, wf.samples_per_chirp)
        samples = samples[:n].reshape(*shape, *per_chirp).sum(axis=1).reshape(-1, *per_chirp)
        times = times[:n].reshape(shape)[:, presum // 2].ravel()
        tx_order = tx_order[:n].reshape(shape)[:, 0].ravel()
    cp = chirp_profiles(samples, times, tx_order, radar, believed.trajectory, window="hann", oversample=8,
                        keep_samples=False)
    middle = aperture.middle_ns
    s = believed.trajectory.sample(np.array([middle], np.int64))
    look = (s.rotation.as_matrix()[0] @ believed.mount.boresight_body)[:2]
    patches = []
    for target in aperture.targets:
        expected = _to_believed(target.position_m, truth, believed.trajectory, middle)
        # coarse and wide (a wrong rig's offset) for the response's shape; fine about its highest pixel for the peak
        coarse = _patch(cp, expected[:2], expected[2], half_size_m, coarse_pixel_m)
        (iy, ix), _ = find_peak(coarse["image"], coarse["x_m"], coarse["y_m"])
        fine = _patch(cp, (coarse["x_m"][ix], coarse["y_m"][iy]), expected[2], fine_half_size_m, fine_pixel_m)
        patches.append({**coarse, "fine_image": fine["image"], "expected_m": expected[:2]})
    return {"patches": patches, "look": look / np.linalg.norm(look)}


def _patch(cp, centre_xy, z_m: float, half_size_m: float, pixel_m: float) -> dict:
    axis = np.arange(-half_size_m, half_size_m + pixel_m / 2, pixel_m)
    x, y = centre_xy[0] + axis, centre_xy[1] + axis
    grid = np.stack(np.broadcast_arrays(x[None, :], y[:, None], z_m), axis=-1)
    return {"image": backproject(cp.profiles, cp.tx_m, cp.rx_m, grid), "x_m": x, "y_m": y}


def target_quality(patch: dict, look_xy) -> dict:
    """How sharp one target's image is: its peak amplitude, the width of its main lobe (the diameter of a
    disc of the area above -3 dB about the peak: a turning aperture's response is no ellipse along range and
    cross range), its half-power widths along range and cross range and the PSLR of those cuts (None where a
    cut has no side lobe), and the peak's distance from where the run expects the target (m, in the run's own
    frame)."""
    from scipy import ndimage

    x, y = patch["x_m"], patch["y_m"]
    amplitude = np.abs(patch["image"])  # smooth where the complex image turns every 2 mm: its cuts, not the image's
    (iy, ix), (px, py) = find_peak(amplitude, x, y)
    labels, _ = ndimage.label(amplitude >= amplitude[iy, ix] / np.sqrt(2))
    area = np.count_nonzero(labels == labels[iy, ix]) * abs((x[1] - x[0]) * (y[1] - y[0]))
    look = np.asarray(look_xy, float) / np.linalg.norm(look_xy)
    out = {"peak": float(np.abs(patch["fine_image"]).max()), "width_m": float(2 * np.sqrt(area / np.pi)),
           "offset_m": float(np.hypot(px - patch["expected_m"][0], py - patch["expected_m"][1]))}
    half = 0.5 * (x[-1] - x[0]) - max(abs(px - 0.5 * (x[0] + x[-1])), abs(py - 0.5 * (y[0] + y[-1])))
    for name, d in (("range", look), ("cross_range", np.array([-look[1], look[0]]))):
        s, v = cut(amplitude, x, y, (px, py), d, max(half, 0.01), 801)
        out[f"{name}_width_m"] = half_power_width(v, spacing=s[1] - s[0])
        pslr = sidelobe_levels(v)[0]
        out[f"{name}_pslr_db"] = float(pslr) if np.isfinite(pslr) else None  # None: no side lobe along the cut
    return out


def runs_of(radar_name: str, truth: Trajectory, true_rig: Trajectory, wrong_rig: Trajectory, calibrated) -> dict:
    """The images to compare, each a (how late the radar's frames are stamped (s), BelievedRig) pair:

    - "truth": the true trajectory, mount and clock (the best any odometry could do),
    - "true_rig": the odometry on the true rig file's scans, its mounts, the clock on time,
    - "wrong_rig": the odometry on the wrong rig file, its mounts, the late clock taken as on time,
    - "calibrated": the odometry with calibration on (``calibrated``, a rio.calibration.CalibrationResult)
      on the wrong rig file's scans, the refined mount and time offset,
    - "calibrated_clock_ignored": as "calibrated" but the radar's frames placed at their stamps (the
      refined mount, the time offset not applied: sarbot's imaging does not apply a rig's time offset yet;
      only for the late radar),
    - "wrong_mount_true_odometry": the true rig's odometry imaged with the wrong mount and clock (what the
      wrong rig file costs the image by itself, without what it costs the odometry).

    The rig, the mount errors and the late radar are rio.calibration_drive's.
    """
    from imaging.core.rig import default_rig

    from .calibration_drive import LATE_RADAR, LATE_S, wrong_mount

    radar = default_rig().radar(radar_name)
    late = LATE_S if radar_name == LATE_RADAR else 0.0
    refined = calibrated.radars[radar_name]
    return {"truth": (0.0, BelievedRig(truth, radar.mount, 0.0)),
            "true_rig": (0.0, BelievedRig(true_rig, radar.mount, 0.0)),
            "wrong_rig": (late, BelievedRig(wrong_rig, wrong_mount(radar.mount), 0.0)),
            "calibrated": (late, BelievedRig(calibrated.rio.trajectory, refined.refined_mount(),
                                             refined.refined_time_offset_s())),
            "wrong_mount_true_odometry": (late, BelievedRig(true_rig, wrong_mount(radar.mount), 0.0)),
            **({"calibrated_clock_ignored": (late, BelievedRig(calibrated.rio.trajectory, refined.refined_mount()))}
               if late else {})}


def compare_runs(aperture: Aperture, truth: Trajectory, runs: dict, seed: int = 0, keep_images: bool = False) -> dict:
    """Every run's image of the aperture's targets measured (``target_quality``): {run: [per target]}; with
    ``keep_images`` each entry also holds its "patch"."""
    adc = radar_frames(aperture, truth, seed)
    out = {}
    for name, (stamp_offset_s, believed) in runs.items():
        formed = form_aperture_image(aperture, adc, stamp_offset_s, truth, believed)
        out[name] = [{**target_quality(p, formed["look"]), **({"patch": p} if keep_images else {})}
                     for p in formed["patches"]]
    return out
