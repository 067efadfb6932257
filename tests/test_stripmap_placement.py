"""The live map's cheaper frame (wave 3l): its antennas placed by one kernel (imaging.stripmap.placement), the
beams' signals formed by one (imaging.stripmap.polar._beam_signals), each against the plain numpy it replaced,
and the map they make against the map that numpy made on a small case."""

import dataclasses

import numpy as np
import pytest
from conftest import RADAR, point_pass

import imaging.stripmap.map as stripmap_map
import imaging.stripmap.polar as polar
from imaging.core.geometry import antenna_track
from imaging.core.rig import CalibrationPrior, default_rig
from imaging.core.trajectory import PathWithTurns, SampledTrajectory, Trajectory
from imaging.io.recording import Recording
from imaging.pocketfft import fft_in_place
from imaging.range_compression import range_compress
from imaging.sim.simulator import simulate_recording
from imaging.stripmap import StripMap, StripMapConfig
from imaging.stripmap.placement import place_profiles


def turning_trajectory() -> SampledTrajectory:
    """Poses at 400 Hz along a straight and a turn, with a wobble in roll and pitch (every axis of the slerp)."""
    drive = PathWithTurns(segments=[("straight", 0.5), ("arc", 0.8, 60.0)], speed_mps=0.4, t0_ns=10**18)
    t = drive.t0_ns + np.arange(0, 3_000_000_000, 2_500_000, dtype=np.int64)
    s = drive.sample(t)
    rng = np.random.default_rng(3)
    wobble = rng.normal(0, 0.01, (t.size, 4)) * [1, 1, 0, 0]
    q = s.orientation_xyzw + wobble
    return SampledTrajectory(t, s.position_m, q / np.linalg.norm(q, axis=1, keepdims=True), s.velocity_mps)


@pytest.mark.parametrize("sum_rx", [False, True])
@pytest.mark.parametrize("offset_s", [0.0, 0.0013])
def test_place_profiles_is_antenna_tracks(sum_rx, offset_s):
    """Every profile's TX and RX position and horizontal look as antenna_track places them (repeated per RX
    channel, or at the channels' centroid), times before and after the poses included (held there), with a
    radar clock offset."""
    traj = turning_trajectory()
    radar = default_rig().radar(RADAR)
    if offset_s:
        radar = dataclasses.replace(radar, calibration=CalibrationPrior(time_offset_s=offset_s))
    rng = np.random.default_rng(4)
    times = np.sort(rng.integers(traj.t0_ns - 10**8, int(traj.time_ns[-1]) + 10**8, 64))
    tx_index = rng.integers(0, radar.waveform.n_tx, times.size)
    tx_m, rx_m, look = place_profiles(radar, traj, times, tx_index, sum_rx)
    track = antenna_track(radar, traj, times, tx_index)
    n = 1 if sum_rx else track.rx_m.shape[1]
    want_rx = track.rx_m.mean(axis=1) if sum_rx else track.rx_m.reshape(-1, 3)
    want_look = np.repeat(track.boresight[:, :2], n, axis=0)
    want_look /= np.linalg.norm(want_look, axis=1, keepdims=True)
    assert tx_m.shape == rx_m.shape == (times.size * n, 3) and look.shape == (times.size * n, 2)
    np.testing.assert_allclose(tx_m, np.repeat(track.tx_m, n, axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(rx_m, want_rx, rtol=0, atol=1e-12)
    np.testing.assert_allclose(look, want_look, rtol=0, atol=1e-12)
    assert np.abs(tx_m - rx_m).max() > 1e-3  # the antennas are apart: the check above can tell them


def beam_signals_numpy(z: np.ndarray, dk: np.ndarray, turn: np.ndarray, k_c: float) -> np.ndarray:
    """frame_beams_over's signals as main computed them, from the product z [3 x beams, n]."""
    b = turn.size
    zt, d = z.T, dk[:, None]
    main = (zt[:, :b] - 1j * d * zt[:, b:2 * b]) * turn
    slope = (1 + d / np.float32(k_c)) * zt[:, 2 * b:] * turn
    return np.ascontiguousarray(np.concatenate([main, slope], axis=1).T)


def padded(signals, w, m, n_fft):
    """Signals [rows, n] windowed and placed as range_compress places them: sample i at i - m modulo n_fft."""
    out = np.zeros((signals.shape[0], n_fft), np.complex64)
    out[:, (np.arange(signals.shape[1]) - m) % n_fft] = signals * w
    return out


def test_beam_signals_are_numpys():
    """The kernel's signals as numpy makes them, windowed and centred in the zero-padded rows; and those rows'
    FFT is range_compress's profiles of the unwindowed signals, bit for bit."""
    rng = np.random.default_rng(5)
    beams, n, oversample = 7, 33, 8
    z = (rng.normal(size=(3 * beams, n)) + 1j * rng.normal(size=(3 * beams, n))).astype(np.complex64)
    dk = (0.1 * (np.arange(n) - n // 2)).astype(np.float32)
    turn = np.exp(-1j * rng.uniform(0, 6, beams)).astype(np.complex64)
    w, m = polar._window("hann", n), (n - 1) // 2
    out = np.zeros((2 * beams, oversample * n), np.complex64)
    polar._beam_signals(out, z, dk, turn, np.float32(1600.0), w, m)
    want = beam_signals_numpy(z, dk, turn, 1600.0)
    np.testing.assert_allclose(out, padded(want, w, m, oversample * n), rtol=0, atol=1e-6 * np.abs(want).max())
    assert np.abs(want[beams:]).max() > 0 and np.abs(want[:beams] - want[beams:]).max() > 0.1
    plain = np.zeros((2 * beams, n), np.complex64)  # no window, no centring: the signals alone
    polar._beam_signals(plain, z, dk, turn, np.float32(1600.0), np.ones(n, np.float32), 0)
    profiles = range_compress(plain, 77e9, 1e7, window="hann", oversample=oversample, keep_samples=False)
    assert np.array_equal(fft_in_place(out), profiles.data)


class Unsampled(Trajectory):
    """A sampled trajectory the map does not see as one: its frames are placed by antenna_track, as before."""

    def __init__(self, inner: SampledTrajectory):
        self.inner = inner

    def sample(self, time_ns):
        return self.inner.sample(time_ns)

    def velocity(self, time_ns):
        return self.inner.velocity(time_ns)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    path = tmp_path_factory.mktemp("placement") / "pass.h5"
    simulate_recording(point_pass(0.4, duration_s=2.0), path)
    rec = Recording(path)
    yield rec, rec.radar(RADAR), rec.truth(), rec.tdm_tx_order(RADAR)
    rec.close()


def test_the_map_is_mains_to_rounding(drive, monkeypatch):
    """A point pass's map (frame by frame, and 4 frames a call) through the kernels, against the same frames
    placed by antenna_track and their beams' signals formed by numpy as before (the product as samples.T @
    weights): within -120 dB of the map's peak (float32 rounding; the kernels' maps differ by about -150 dB)."""
    rec, radar, truth, order = drive
    assert isinstance(truth, SampledTrajectory)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.0, range_max_m=3.0, presum=4)
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    frames = list(range(6, 30))

    def image(trajectory, batch):
        sm = StripMap(config)
        for a in range(0, len(frames), batch):
            ks = frames[a:a + batch]
            sm.add_frames(radar, order, [adc[k] for k in ks], [int(times[k]) for k in ks], trajectory)
        return sm

    new = {b: image(truth, b) for b in (1, 4)}

    def signals_as_before(out, z, dk, turn, k_c, w, m):
        # main's product was samples.T @ weights, z here its transpose: the same sums to float32 rounding
        out[...] = padded(beam_signals_numpy(z, dk, turn, float(k_c)), w, m, out.shape[1])

    monkeypatch.setattr(polar, "_beam_signals", signals_as_before)
    monkeypatch.setattr(stripmap_map, "place_profiles", None)  # must not be reached through Unsampled
    old = {b: image(Unsampled(truth), b) for b in (1, 4)}
    for b in (1, 4):
        assert new[b].tiles.keys() == old[b].tiles.keys() and new[b].profiles == old[b].profiles
        a, ref = new[b].mosaic()[0], old[b].mosaic()[0]
        peak = np.abs(ref).max()
        assert peak > 0
        assert 20 * np.log10(np.abs(a - ref).max() / peak) < -120
