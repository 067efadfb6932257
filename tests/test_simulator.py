import numpy as np
import pytest

from imaging.core.geometry import Vibration, antenna_track
from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns, StraightLine
from imaging.range_compression import range_compress
from imaging.sim.simulator import simulate_frames
from imaging.sim.targets import CornerReflector, PointTarget, Rod

C = 299_792_458.0


def model_samples(radar, trajectory, target_xyz, frame_time_ns, chirps, vibration=None):
    """The signal model of docs/signal-model.md evaluated literally: positions at every sample time t + n/fs."""
    wf = radar.waveform
    n = np.arange(wf.samples_per_chirp)
    out = []
    for k in chirps:
        t0 = frame_time_ns + int(round(k * wf.chirp_interval_s * 1e9))
        times = t0 + np.round(n / wf.sample_rate_hz * 1e9).astype(np.int64)
        tx_i = np.full(n.size, k % wf.n_tx)
        track = antenna_track(radar, trajectory, times, tx_i, vibration, 0)
        rows = []
        for j in range(wf.n_rx):
            r = np.linalg.norm(track.tx_m - target_xyz, axis=1) + np.linalg.norm(track.rx_m[:, j] - target_xyz, axis=1)
            rows.append(np.exp(2j * np.pi / C * (wf.f0_hz + wf.slope_hz_per_s * n / wf.sample_rate_hz) * r))
        out.append(rows)
    return np.array(out)


@pytest.mark.parametrize("trajectory", [
    StraightLine(start_m=(-0.3, -0.2, 0.0), speed_mps=1.0),
    PathWithTurns(segments=[("arc", 0.5, 90.0)], start_m=(0.0, 0.0, 0.0), speed_mps=1.0),
], ids=["straight", "turning"])
def test_samples_follow_the_signal_model(trajectory):
    radar = default_rig().radar("left_front")
    target = np.array([0.2, 1.8, 0.45])
    frame_time = 100_000_000
    sim = simulate_frames(radar, trajectory, [PointTarget(tuple(target))], np.array([frame_time]),
                          vibration=Vibration(7.0, 2e-4, 0.3))
    chirps = [0, 1, 5, 255]
    ref = model_samples(radar, trajectory, target, frame_time, chirps, Vibration(7.0, 2e-4, 0.3))
    # First-order motion within a chirp: phase error well below a milliradian.
    np.testing.assert_allclose(sim[0, chirps], ref, atol=2e-4)


def test_intra_chirp_motion_matters_at_speed():
    radar = default_rig().radar("left_front")
    traj = StraightLine(start_m=(-1.0, -0.2, 0.0), speed_mps=1.0)  # radar well off broadside: large range rate
    target = [PointTarget((0.0, 2.0, 0.3))]
    with_motion = simulate_frames(radar, traj, target, np.array([0]))
    frozen = simulate_frames(radar, traj, target, np.array([0]), intra_chirp_motion=False)
    ref = model_samples(radar, traj, np.array([0.0, 2.0, 0.3]), 0, [0])
    assert np.abs(with_motion[0, [0]] - ref).max() < 2e-4
    assert np.abs(frozen[0, [0]] - ref).max() > 1e-2


def test_range_profile_peaks_at_the_target_range():
    radar = default_rig().radar("left_front")
    wf = radar.waveform
    traj = StraightLine(start_m=(-0.15, -0.2, 0.0), speed_mps=0.0)
    adc = simulate_frames(radar, traj, [PointTarget((0.0, 2.5, 0.3))], np.array([0]))
    prof = range_compress(adc[0, 0, 0], wf.f0_hz, wf.frequency_step_hz, oversample=16)
    two_way = prof.range_axis_m[np.argmax(np.abs(prof.data))]
    assert two_way / 2 == pytest.approx(2.5, abs=prof.range_step_m)
    assert np.abs(prof.data).max() == pytest.approx(1.0, rel=1e-3)  # unit amplitude peaks at 1


def test_noise_has_the_stated_snr():
    radar = default_rig().radar("left_front")
    traj = StraightLine(speed_mps=0.0)
    noise = simulate_frames(radar, traj, [], np.array([0, 52_000_000]), snr_db=10.0, rng=np.random.default_rng(3))
    assert np.mean(np.abs(noise) ** 2) == pytest.approx(0.1, rel=0.02)
    assert abs(np.mean(noise)) < 3e-3


def test_rod_scattering_centre_faces_the_radar():
    rod = Rod(position_m=(0.0, 2.0), radius_m=0.05, z_min_m=0.0, z_max_m=1.0)
    tx = np.array([[0.0, 0.0, 0.3], [2.0, 2.0, 1.5]])
    rx = tx[:, None, :].copy()
    pos, amp = rod.scattering_centres(tx, rx)
    np.testing.assert_allclose(pos[0, 0], [0.0, 1.95, 0.3])
    np.testing.assert_allclose(pos[1, 0], [0.05, 2.0, 1.0])  # clamped to the top of the rod
    assert np.allclose(amp, -1.0)


def test_corner_reflector_pattern():
    cr = CornerReflector(position_m=(0.0, 2.0, 0.3), axis=(0.0, -1.0, 0.0), amplitude=1.0, half_power_angle_deg=20.0)
    angles = np.radians([0.0, 20.0, 100.0])
    tx = np.stack([2 * np.sin(angles), 2.0 - 2 * np.cos(angles), np.full(3, 0.3)], axis=1)
    _, amp = cr.scattering_centres(tx, tx[:, None, :])
    assert abs(amp[0, 0]) == pytest.approx(1.0)
    assert abs(amp[1, 0]) ** 2 == pytest.approx(10**-0.3, rel=1e-9)  # -3.0 dB at the stated angle
    assert abs(amp[2, 0]) == 0.0  # from behind
