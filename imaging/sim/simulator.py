"""Raw complex-baseband FMCW TDM-MIMO frames from a scene, per the signal model in docs/signal-model.md.

    s = A exp(j 2 pi / c (f0 + slope n / fs) r_ij(t + n / fs)),  r_ij = |p_tx - p| + |p_rx - p|

Every chirp has its own bistatic TX/RX positions from the trajectory, mount, array and vibration. Motion
within a chirp is taken to first order (range rate from antenna velocities), which is exact to well under
a micrometre over a 180 us chirp at robot speeds.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.core.constants import SPEED_OF_LIGHT_MPS, TAI_MINUS_UTC_NS
from imaging.core.geometry import Vibration, antenna_track, chirp_times_ns
from imaging.core.rig import RadarConfig
from imaging.core.trajectory import Trajectory
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


@numba.njit(parallel=True, cache=True)
def _synthesise(tx_m, tx_v, rx_m, rx_v, centres, amps, f0_hz, fstep_hz, fs_hz, motion, out):
    """Sum of target echoes. tx_m/tx_v [P,3]; rx_m/rx_v [P,R,3]; centres [T,P,R,3]; amps [T,P,R]; out [P,R,N]."""
    n_p, n_r, n_s = out.shape
    n_t = centres.shape[0]
    k0 = 2.0 * math.pi / SPEED_OF_LIGHT_MPS
    for p in numba.prange(n_p):
        acc = np.zeros(n_s, np.complex128)
        for j in range(n_r):
            acc[:] = 0.0
            for t in range(n_t):
                a = amps[t, p, j]
                if a == 0:
                    continue
                dtx0 = tx_m[p, 0] - centres[t, p, j, 0]
                dtx1 = tx_m[p, 1] - centres[t, p, j, 1]
                dtx2 = tx_m[p, 2] - centres[t, p, j, 2]
                drx0 = rx_m[p, j, 0] - centres[t, p, j, 0]
                drx1 = rx_m[p, j, 1] - centres[t, p, j, 1]
                drx2 = rx_m[p, j, 2] - centres[t, p, j, 2]
                rt = math.sqrt(dtx0 * dtx0 + dtx1 * dtx1 + dtx2 * dtx2)
                rr = math.sqrt(drx0 * drx0 + drx1 * drx1 + drx2 * drx2)
                r0 = rt + rr
                rdot = 0.0
                if motion:
                    rdot = (dtx0 * tx_v[p, 0] + dtx1 * tx_v[p, 1] + dtx2 * tx_v[p, 2]) / rt + (
                        drx0 * rx_v[p, j, 0] + drx1 * rx_v[p, j, 1] + drx2 * rx_v[p, j, 2]
                    ) / rr
                # phase(n) = k0 (f0 + fstep n)(r0 + rdot n / fs) = phi0 + b n + c n^2, by recurrence.
                phi0 = k0 * f0_hz * r0
                b = k0 * (fstep_hz * r0 + f0_hz * rdot / fs_hz)
                c = k0 * fstep_hz * rdot / fs_hz
                z = a * complex(math.cos(phi0), math.sin(phi0))
                w = complex(math.cos(b + c), math.sin(b + c))
                q = complex(math.cos(2.0 * c), math.sin(2.0 * c))
                for n in range(n_s):
                    acc[n] += z
                    z *= w
                    w *= q
            for n in range(n_s):
                out[p, j, n] = acc[n]


def simulate_frames(
    radar: RadarConfig,
    trajectory: Trajectory,
    targets,
    frame_time_ns: np.ndarray,
    *,
    vibration: Vibration | None = None,
    vibration_t0_ns: int = 0,
    snr_db: float | None = None,
    intra_chirp_motion: bool = True,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Simulate ADC frames of one radar.

    Parameters
    ----------
    radar : RadarConfig
    trajectory : Trajectory
        Body trajectory (world frame).
    targets : sequence
        Objects with ``scattering_centres(tx_m, rx_m)`` (see ``imaging.sim.targets``).
    frame_time_ns : ndarray, shape (F,)
        Start of each frame's first chirp, int64 ns.
    vibration : Vibration, optional
        Sensor displacement along boresight, phase referenced to ``vibration_t0_ns``.
    snr_db : float, optional
        Per-sample signal-to-noise ratio of an amplitude-1 return; None for no noise.
    intra_chirp_motion : bool
        Account for the antennas moving during a chirp.

    Returns
    -------
    ndarray, complex64, shape (F, chirps_per_frame, n_rx, samples_per_chirp)
    """
    wf = radar.waveform
    frame_time_ns = np.atleast_1d(np.asarray(frame_time_ns, np.int64))
    times = chirp_times_ns(frame_time_ns, wf.chirps_per_frame, wf.chirp_interval_s).ravel()
    tx_index = np.tile(np.asarray(wf.tdm_tx_order()), frame_time_ns.size)
    track = antenna_track(radar, trajectory, times, tx_index, vibration, vibration_t0_ns)
    n_p = times.size
    if targets:
        parts = [t.scattering_centres(track.tx_m, track.rx_m) for t in targets]
        centres = np.ascontiguousarray(np.stack([c for c, _ in parts]))
        amps = np.ascontiguousarray(np.stack([a for _, a in parts]).astype(np.complex128))
    else:
        centres = np.zeros((0, n_p, wf.n_rx, 3))
        amps = np.zeros((0, n_p, wf.n_rx), np.complex128)
    out = np.empty((n_p, wf.n_rx, wf.samples_per_chirp), np.complex64)
    _synthesise(
        np.ascontiguousarray(track.tx_m), np.ascontiguousarray(track.tx_velocity_mps),
        np.ascontiguousarray(track.rx_m), np.ascontiguousarray(track.rx_velocity_mps),
        centres, amps, wf.f0_hz, wf.frequency_step_hz, wf.sample_rate_hz, intra_chirp_motion, out,
    )
    if snr_db is not None:
        rng = rng or np.random.default_rng()
        sigma = math.sqrt(10.0 ** (-snr_db / 10.0) / 2.0)
        noise = rng.standard_normal(out.shape + (2,), dtype=np.float32) * np.float32(sigma)
        out += noise.view(np.complex64)[..., 0]
    return out.reshape(frame_time_ns.size, wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp)


#: TAI - UTC (s): the PTP time base runs ahead of the hosts' CLOCK_REALTIME by this much.
#: Simulated delay between the end of a frame and the kernel receiving its last datagram.
RECEIVE_LATENCY_NS = 1_000_000


def simulate_recording(scene, path, *, frames_per_block: int = 16, progress=None, overwrite: bool = False):
    """Simulate ``scene`` into a recording file (schema v1, with ``/truth``).

    Parameters
    ----------
    scene : imaging.sim.scene.Scene
    path : str or Path
        Output file.
    frames_per_block : int
        Frames simulated and written at a time (bounds memory).
    progress : callable(done, total), optional
        Called after every block with frames done and frames in total.

    Returns
    -------
    dict
        Frames written per radar.
    """
    from imaging.core.samples import complex_to_iq
    from imaging.io.recording import RecordingWriter
    from imaging.sim.scene import frame_times_ns

    radars = [scene.rig.radar(name) for name in scene.radars]
    times = {r.name: frame_times_ns(scene, r.name) for r in radars}
    total = sum(t.size for t in times.values())
    done = 0
    rng = np.random.default_rng(scene.seed)
    detections = scene.detection_model is not None
    counts = scene.adc_counts_per_unit
    with RecordingWriter(path, radars, imu=scene.rig.imu if scene.imu else None, truth=True, overwrite=overwrite,
                         adc_dtype="complex64" if counts is None else "int16",
                         wire_format="detections" if detections else "simulated",
                         detections=scene.radars if detections else ()) as writer:
        # The hardware trigger marks the first chirp of the run.
        writer.append_trigger(scene.start_time_ns, "radar_first_chirp")
        for r in radars:
            ft = times[r.name]
            wf = r.waveform
            frame_end = wf.frame_duration_ns
            host = ft + frame_end + RECEIVE_LATENCY_NS - TAI_MINUS_UTC_NS
            if detections:
                _simulate_scans(writer, scene, r, ft, frame_end, host, rng)
                done += ft.size
                if progress is not None:
                    progress(done, total)
                continue
            for b in range(0, ft.size, frames_per_block):
                block = ft[b:b + frames_per_block]
                adc = simulate_frames(
                    r, scene.trajectory, scene.targets, block,
                    vibration=scene.vibration, vibration_t0_ns=scene.start_time_ns, snr_db=scene.snr_db,
                    intra_chirp_motion=scene.intra_chirp_motion, rng=rng,
                )
                if counts is not None:  # what the radar's ADC would deliver
                    adc = complex_to_iq(adc, counts)
                writer.append_frames(r.name, adc, block, np.arange(b, b + block.size), host[b:b + block.size])
                writer.flush()
                done += block.size
                if progress is not None:
                    progress(done, total)
        end_ns = scene.start_time_ns + int(scene.duration_s * 1e9)
        for r in radars:
            if r.imu is not None:
                from imaging.sim.imu_simulator import simulate_radar_imu

                ri = simulate_radar_imu(scene.trajectory, r, scene.start_time_ns, end_ns, vibration=scene.vibration,
                                        vibration_t0_ns=scene.start_time_ns, rng=rng)
                writer.append_radar_imu(r.name, ri.time_ns, ri.gyro_radps, ri.accel_mps2, ri.counter,
                                        ri.time_ns + 200_000 - TAI_MINUS_UTC_NS)
        if scene.imu:
            from imaging.sim.imu_simulator import simulate_imu

            imu = simulate_imu(scene.trajectory, scene.rig.imu, scene.start_time_ns, end_ns, errors=scene.imu_errors, rng=rng)
            writer.append_imu(imu.time_ns, imu.gyro_radps, imu.accel_mps2, imu.counter,
                              imu.time_ns + 200_000 - TAI_MINUS_UTC_NS)
            from imaging.sim.robot_base_can import simulate_base_can

            can = simulate_base_can(scene.trajectory, scene.start_time_ns, end_ns, trigger_time_ns=scene.start_time_ns)
            writer.append_can(can["time_ns"], can["arbitration_id"], can["dlc"], can["data"])
        step_ns = int(round(1e9 / scene.truth_rate_hz))
        truth_times = np.arange(scene.start_time_ns, end_ns + step_ns, step_ns, dtype=np.int64)
        writer.append_truth(scene.trajectory.sample(truth_times))
    return {name: t.size for name, t in times.items()}


def _simulate_scans(writer, scene, radar, frame_times, frame_end_ns, host, rng) -> None:
    from imaging.sim.detection_simulator import simulate_scan

    static = scene.static_points_m if scene.static_points_m is not None else np.zeros((0, 3))
    if scene.targets:
        extra = [np.asarray(t.position_m, float) for t in scene.targets if len(getattr(t, "position_m", ())) == 3]
        static = np.concatenate([static, np.asarray(extra).reshape(-1, 3)])
    writer.append_scans(radar.name, frame_times, np.arange(frame_times.size), host)
    for k, ft in enumerate(frame_times):
        mid = int(ft + frame_end_ns // 2)  # a scan's measurements describe the middle of the frame
        scan = simulate_scan(radar, scene.trajectory, mid, static, scene.people, scene.detection_model, rng, scene.start_time_ns)
        d = scan.doppler_mps.size
        writer.append_detections(radar.name, np.full(d, mid), np.full(d, k), scan.xyz_m, scan.doppler_mps, scan.snr_db)
