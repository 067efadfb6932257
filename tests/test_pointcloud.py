"""Point clouds from raw simulated frames: positions, Doppler and the ego velocity they give."""

import functools

import numpy as np
import pytest

from imaging.core.rig import default_rig
from imaging.core.trajectory import StraightLine
from imaging.sim.simulator import simulate_frames
from imaging.sim.targets import PointTarget
from rio.ego_velocity import EgoStatus, sensor_velocity
from rio.pointcloud import PointCloudConfig, cfar_2d, detect
from reference_pointcloud import reference_cube

RADAR = default_rig().radar("left_front")  # looks along +y of the body; the robot drives along +x
TARGETS = [(-1.0, 2.0, 0.3), (0.5, 3.0, 0.3), (1.5, 1.5, 0.3), (-2.0, 4.0, 0.3), (0.0, 5.0, 0.3), (2.5, 3.5, 0.3)]


def frame_of(speed, snr_db=0.0, seed=0):
    traj = StraightLine(start_m=(-0.15, -0.2, 0.0), speed_mps=speed)
    adc = simulate_frames(RADAR, traj, [PointTarget(t) for t in TARGETS], np.array([0]), snr_db=snr_db,
                          rng=np.random.default_rng(seed))
    return adc[0], traj


def expected_in_sensor_frame(traj, t_ns):
    s = traj.sample(np.array([t_ns]))
    origin = s.position_m[0] + s.rotation.as_matrix()[0] @ RADAR.mount.translation_m
    r_s = s.rotation.as_matrix()[0] @ RADAR.mount.rotation.as_matrix()
    rel = (np.asarray(TARGETS) - origin) @ r_s
    v_s = r_s.T @ s.velocity_mps[0]
    u = rel / np.linalg.norm(rel, axis=1, keepdims=True)
    return rel, -u @ v_s, v_s


def test_detects_every_target_where_it_is():
    frame, traj = frame_of(speed=0.5)
    pc = detect(frame, RADAR, RADAR.waveform.tdm_tx_order())
    mid = int(RADAR.waveform.chirps_per_frame * RADAR.waveform.chirp_interval_s * 1e9 / 2)
    rel, doppler, _ = expected_in_sensor_frame(traj, mid)
    for p, d in zip(rel, doppler):
        dist = np.linalg.norm(pc.xyz_m[:, :2] - p[:2], axis=1)
        k = int(np.argmin(dist))
        rng = np.linalg.norm(p)
        assert pc.range_m[k] == pytest.approx(rng, abs=0.02)  # under a range bin (2.6 cm)
        assert np.degrees(pc.azimuth_rad[k]) == pytest.approx(np.degrees(np.arctan2(p[1], p[0])), abs=1.5)
        assert pc.doppler_mps[k] == pytest.approx(d, abs=0.01)  # under a third of a Doppler bin (3.7 cm/s)
    assert pc.xyz_m.shape[0] <= len(TARGETS) + 2  # no forest of false alarms


def test_ego_velocity_from_raw_frames():
    for speed in (0.3, 0.8):
        frame, traj = frame_of(speed=speed, snr_db=-5.0, seed=3)
        pc = detect(frame, RADAR, RADAR.waveform.tdm_tx_order())
        est = sensor_velocity(pc.xyz_m, pc.doppler_mps)
        _, _, v_s = expected_in_sensor_frame(traj, 0)
        assert est.status is EgoStatus.OK
        # The array has no elevation: only the horizontal velocity is measured.
        assert np.abs(est.velocity_mps[:2] - v_s[:2]).max() < 0.02


def test_tdm_phase_correction_matters():
    # Without removing the TDM motion phase a fast target lands at the wrong angle.
    frame, traj = frame_of(speed=1.0)
    good = detect(frame, RADAR, RADAR.waveform.tdm_tx_order())
    import rio.pointcloud as pcm

    original = pcm.np.exp
    try:
        pcm.np.exp = lambda x: np.ones_like(x)  # disable the correction only
        bad = detect(frame, RADAR, RADAR.waveform.tdm_tx_order())
    finally:
        pcm.np.exp = original
    mid = int(RADAR.waveform.chirps_per_frame * RADAR.waveform.chirp_interval_s * 1e9 / 2)
    rel, _, _ = expected_in_sensor_frame(traj, mid)
    az_true = np.arctan2(rel[:, 1], rel[:, 0])

    def worst(pc):
        return max(np.min(np.abs(pc.azimuth_rad - a)) for a in az_true)

    assert worst(good) < np.radians(1.5) < worst(bad)


@pytest.mark.parametrize("kind", ["ca", "os"])
def test_cfar_finds_a_point_in_noise(kind):
    rng = np.random.default_rng(1)
    power = rng.exponential(1.0, (64, 128))
    power[20, 40] = 200.0
    hits, noise = cfar_2d(power, PointCloudConfig(cfar=kind))
    assert hits[20, 40]
    assert hits.sum() < 5  # false alarms stay rare at 13 dB
    assert noise[20, 40] == pytest.approx(1.0, rel=0.5)


def test_odometry_from_raw_adc_recording(tmp_path):
    """IMU plus raw ADC frames (no point clouds in the file): rio.pointcloud feeds the EKF."""
    import json
    import subprocess
    import sys

    rig = tmp_path / "rig.toml"
    rig.write_text('[imu]\nrate_hz = 400.0\n[radar.left]\nmount_translation_m = [0.15, 0.2, 0.3]\nmount_yaw_deg = 90.0\n'
                   'waveform = { chirps_per_frame = 64, frame_interval_s = 0.052 }\n'
                   '[radar.right]\nmount_translation_m = [0.15, -0.2, 0.3]\nmount_yaw_deg = -90.0\n'
                   'waveform = { f0_hz = 76.2e9, chirps_per_frame = 64, frame_interval_s = 0.052 }\n')
    rng = np.random.default_rng(4)
    points = "".join(f'[[target]]\nkind = "point"\nposition_m = [{x:.2f}, {y:.2f}, {z:.2f}]\n'
                     for x, y, z in zip(rng.uniform(-4, 8, 40), np.r_[rng.uniform(1.0, 4.5, 20), rng.uniform(-4.5, -1.0, 20)],
                                        rng.uniform(0.0, 0.8, 40)))
    scene = tmp_path / "adc_drive.toml"
    scene.write_text('duration_s = 10.0\nimu = true\nsnr_db = 0.0\nrig = "rig.toml"\n'
                     '[trajectory]\nkind = "path"\nstart_m = [-2.0, 0.0, 0.0]\nspeed_mps = 0.5\naccel_mps2 = 0.4\n'
                     'start_delay_s = 2.0\nsegments = [["straight", 3.0]]\n' + points)
    rec = tmp_path / "adc.h5"
    cmd = [sys.executable, "-m", "acquisition.cli"]
    assert subprocess.run([*cmd, "simulate", str(scene), "-o", str(rec)], capture_output=True).returncode == 0
    res = subprocess.run([*cmd, "rio", str(rec), "-o", str(tmp_path / "traj.h5")], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["radar_updates"] > 100
    assert report["against_truth"]["distance_m"] == pytest.approx(3.0, abs=0.05)
    assert report["against_truth"]["final_drift_m"] < 0.05


def test_sar_image_on_the_odometry_trajectory(tmp_path):
    """Raw frames + IMU -> point clouds -> EKF trajectory -> backprojection: the target focuses as on truth."""
    import json
    import subprocess
    import sys

    import h5py

    rig = tmp_path / "rig.toml"
    rig.write_text('[imu]\nrate_hz = 400.0\n[radar.left]\nmount_translation_m = [0.15, 0.2, 0.3]\nmount_yaw_deg = 90.0\n'
                   'waveform = { chirps_per_frame = 64, frame_interval_s = 0.052 }\n')
    rng = np.random.default_rng(5)
    clutter = "".join(f'[[target]]\nkind = "point"\nposition_m = [{x:.2f}, {y:.2f}, {z:.2f}]\n'
                      for x, y, z in zip(rng.uniform(-3, 5, 25), rng.uniform(1.0, 4.5, 25), rng.uniform(0.0, 0.8, 25)))
    scene = tmp_path / "pass.toml"
    scene.write_text('duration_s = 8.0\nimu = true\nsnr_db = 0.0\nrig = "rig.toml"\n'
                     '[trajectory]\nkind = "path"\nstart_m = [-1.5, -0.2, 0.0]\nspeed_mps = 0.4\naccel_mps2 = 0.4\n'
                     'start_delay_s = 2.0\nsegments = [["straight", 2.0]]\n'
                     '[[target]]\nkind = "corner"\nposition_m = [0.0, 2.0, 0.3]\namplitude = 5.0\n' + clutter)
    cmd = [sys.executable, "-m", "acquisition.cli"]
    rec, traj = tmp_path / "pass.h5", tmp_path / "traj.h5"
    assert subprocess.run([*cmd, "simulate", str(scene), "-o", str(rec)], capture_output=True).returncode == 0
    res = subprocess.run([*cmd, "rio", str(rec), "-o", str(traj), "--start-from-truth"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    widths = {}
    for source in ("truth", str(traj)):
        img = tmp_path / f"img_{len(widths)}.h5"
        # Frames 80-95: the radar passes the reflector (x = 0) with a 0.3 m aperture.
        res = subprocess.run([*cmd, "image", str(rec), "-o", str(img), "--frames", "80:95", "--trajectory", source,
                              "--grid", "-0.15:0.15:0.002,1.85:2.15:0.004"], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        res = subprocess.run([*cmd, "analyze", str(img), "--at", "0,2"], capture_output=True, text=True)
        widths[source] = json.loads(res.stdout)
        with h5py.File(img) as f:
            assert f.attrs["trajectory_source"] == ("truth" if source == "truth" else "rio")
    ours, truth = widths[str(traj)], widths["truth"]
    assert np.hypot(ours["peak_m"][0] - truth["peak_m"][0], ours["peak_m"][1] - truth["peak_m"][1]) < 0.01
    print("RIO/truth: cross-range width", ours["cross_range"]["half_power_width_m"] / truth["cross_range"]["half_power_width_m"],
          "peak", ours["peak_amplitude"] / truth["peak_amplitude"])
    # Millimetre trajectory errors across the aperture (a wavelength is 3.8 mm) defocus the image: the
    # limit issue 5 charts. Measured here on a 0.3 m aperture at 0.4 m/s: 17 % wider, peak at 0.54.
    assert ours["cross_range"]["half_power_width_m"] < 1.3 * truth["cross_range"]["half_power_width_m"]
    assert ours["peak_amplitude"] > 0.4 * truth["peak_amplitude"]


@pytest.mark.parametrize("case", ["in turn", "shuffled", "odd slow time"])
def test_range_doppler_cube_matches_a_plain_per_tx_reference(case):
    """The in-place cube (one padded buffer, the fftshift folded into the Doppler window) is the textbook one."""
    import dataclasses

    from rio.pointcloud import range_doppler_cube

    radar = RADAR
    if case == "odd slow time":  # 15 chirps per TX: the fftshift cannot ride on the window's sign
        radar = dataclasses.replace(RADAR, waveform=dataclasses.replace(RADAR.waveform, chirps_per_frame=60))
    rng = np.random.default_rng(7)
    wf = radar.waveform
    frame = (rng.standard_normal((wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp))
             + 1j * rng.standard_normal((wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp))).astype(np.complex64)
    order = np.asarray(wf.tdm_tx_order())
    if case == "shuffled":
        order = rng.permutation(order)
    cube, positions, tx_of_channel, n_range = range_doppler_cube(frame, radar, order, PointCloudConfig())
    want, want_positions = reference_cube(frame, radar, order, PointCloudConfig())
    assert cube.shape == want.shape == (wf.chirps_per_frame // wf.n_tx, wf.n_tx * wf.n_rx, n_range)
    assert np.abs(cube - want).max() < 1e-5 * np.abs(want).max()  # single precision
    np.testing.assert_array_equal(positions, want_positions)
    assert np.all(np.diff(positions) >= 0)
    np.testing.assert_array_equal(np.bincount(tx_of_channel), [wf.n_rx] * wf.n_tx)


def test_a_tx_order_that_fires_the_txs_unequally_is_refused():
    from rio.pointcloud import range_doppler_cube

    wf = RADAR.waveform
    frame = np.zeros((wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp), np.complex64)
    order = np.asarray(wf.tdm_tx_order())
    order[0] = 1
    with pytest.raises(ValueError, match="equally often"):
        range_doppler_cube(frame, RADAR, order, PointCloudConfig())
    with pytest.raises(ValueError, match="entries for a frame of"):
        range_doppler_cube(frame, RADAR, order[:-1], PointCloudConfig())


def test_iq_to_complex_is_i_plus_j_q():
    from imaging.core.samples import iq_to_complex

    iq = np.random.default_rng(2).integers(-32768, 32767, (8, 3, 5, 2), endpoint=True).astype(np.int16)
    for pairs in (iq, iq[:, :, ::2]):  # also from a strided view
        got = iq_to_complex(pairs)
        assert got.dtype == np.complex64 and got.shape == pairs.shape[:-1]
        np.testing.assert_array_equal(got, pairs[..., 0].astype(np.float64) + 1j * pairs[..., 1].astype(np.float64))
    with pytest.raises(ValueError, match="last axis of 2"):
        iq_to_complex(iq[..., :1])


def _frames_iq(n, seed=3):
    """``n`` frames of the default radar as the wire carries them (int16 I/Q): targets moving, in noise."""
    from imaging.core.samples import complex_to_iq

    return [complex_to_iq(frame_of(0.3 * k, snr_db=10.0, seed=seed + k)[0], 50.0) for k in range(n)]


def test_the_detector_on_int16_iq_gives_detect_on_complex_frames_bit_for_bit_scan_after_scan():
    """The live odometry's PointCloudDetector (windows made once, one cube buffer reused, filled straight from
    the I/Q) makes the point cloud the plain ``detect`` makes of the complex frame, scan after scan: the
    buffer carries nothing from one scan into the next."""
    from imaging.core.samples import iq_to_complex
    from rio.pointcloud import PointCloudDetector

    frames = _frames_iq(3)
    order = RADAR.waveform.tdm_tx_order()
    detector = PointCloudDetector(RADAR, order)
    for iq in [*frames, frames[0]]:
        want = detect(iq_to_complex(iq), RADAR, order)
        got = detector.detect(iq)
        assert want.xyz_m.shape[0] >= len(TARGETS)
        for field in ("xyz_m", "doppler_mps", "snr_db", "range_m", "azimuth_rad"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
        np.testing.assert_array_equal(detector.detect(iq_to_complex(iq)).xyz_m, want.xyz_m)  # complex in too


@pytest.mark.parametrize("kind", ["ca", "os"])
def test_cfar_keeps_only_the_largest_cell_of_each_3x3_neighbourhood_as_a_maximum_filter_does(kind):
    """The local-maximum test at the cells over the threshold is the whole map's maximum filter (Doppler
    wrapping, the range's edges repeated), ties and edges included."""
    import scipy.ndimage

    rng = np.random.default_rng(4)
    power = rng.exponential(1.0, (64, 128)).astype(np.float32)
    for d, r in ((0, 40), (63, 41), (30, 0), (31, 127), (10, 60), (10, 61), (50, 90), (51, 91)):
        power[d, r] = 300.0  # on the Doppler wrap, at the range edges, ties side by side and diagonal
    power[20:23, 100:103] = 250.0  # a plateau
    hits, noise = cfar_2d(power, PointCloudConfig(cfar=kind))
    threshold = noise * 10 ** (PointCloudConfig().threshold_db / 10)
    local_max = power == scipy.ndimage.maximum_filter(power, size=3, mode=("wrap", "nearest"))
    want = (power > threshold) & local_max
    np.testing.assert_array_equal(hits, want)
    assert want[0, 40] and want[63, 41] and want[30, 0] and want[31, 127] and want[10, 60] and want[21, 101]


def test_the_detector_refuses_a_frame_of_the_wrong_form():
    from rio.pointcloud import PointCloudDetector

    detector = PointCloudDetector(RADAR, RADAR.waveform.tdm_tx_order())
    wf = RADAR.waveform
    with pytest.raises(ValueError, match="last axis of 2"):
        detector.detect(np.zeros((wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 3), np.int16))
    with pytest.raises(ValueError, match=r"\[chirps, rx, samples\]"):
        detector.detect(np.zeros((wf.n_rx, wf.samples_per_chirp), np.complex64))


@functools.lru_cache(maxsize=1)  # one simulated frame for the twelve cases
def _cfar_maps():
    """Power maps for the numba CFAR: noise with targets on the Doppler wrap, at the range edges, ties side
    by side and a plateau; a simulated frame's (the detector's own map); and shapes other than the radar's."""
    from rio.pointcloud import PointCloudDetector

    rng = np.random.default_rng(7)
    edges = rng.exponential(1.0, (64, 128)).astype(np.float32)
    for d, r in ((0, 40), (63, 41), (30, 0), (31, 127), (10, 60), (10, 61), (50, 90), (51, 91)):
        edges[d, r] = 300.0
    edges[20:23, 100:103] = 250.0
    detector = PointCloudDetector(RADAR, RADAR.waveform.tdm_tx_order())
    cube, _ = detector.cube(_frames_iq(1)[0])
    radar_map = np.sum(np.abs(cube) ** 2, axis=1)
    small = (rng.exponential(1.0, (8, 16)) * 1e6).astype(np.float32)  # windows longer than the map's sides
    small[3, 5] = 1e9
    odd = rng.exponential(1.0, (63, 101)).astype(np.float32)
    odd[::9, ::7] *= 100.0  # many detections, close together
    return {"edges": edges, "radar": radar_map, "small": small, "odd": odd}


@pytest.mark.parametrize("name", ["edges", "radar", "small", "odd"])
@pytest.mark.parametrize("cells", [((2, 2), (4, 8)), ((1, 0), (3, 5)), ((0, 3), (1, 2))])
def test_the_numba_ca_cfar_gives_cfar_2ds_detections_and_noise_to_the_bit(name, cells):
    """rio.pointcloud_kernels.ca_cfar_peaks against the numpy and scipy reference ``cfar_2d``: the same
    detections in the same (row-major) order and the same noise map, every bit, for guard and training
    boxes of several sizes."""
    from rio.pointcloud import PointCloudDetector

    power = _cfar_maps()[name]
    config = PointCloudConfig(guard_cells=cells[0], training_cells=cells[1])
    hits, noise = cfar_2d(power, config)
    d, r, got_noise = PointCloudDetector(RADAR, RADAR.waveform.tdm_tx_order(), config)._cfar(power)
    want_d, want_r = np.nonzero(hits)
    assert want_d.size > 0
    np.testing.assert_array_equal(d, want_d)
    np.testing.assert_array_equal(r, want_r)
    assert got_noise.dtype == noise.dtype
    np.testing.assert_array_equal(got_noise.view(np.uint64), noise.view(np.uint64))


@pytest.mark.parametrize("cfar", ["ca", "os"])
def test_the_detector_gives_the_plain_reference_point_clouds_to_the_bit(cfar):
    """The detector's point clouds (numba CFAR, the TDM phase per TX, dB at the angle peak only) are those
    of the plain reference (tests/reference_pointcloud.reference_points: cfar_2d, the phase per channel, dB
    over the whole angle spectrum), every field to the bit, scan after scan; with an ordered-statistic CFAR
    as well; and with few detections allowed (their ranking by power)."""
    from reference_pointcloud import reference_points
    from rio.pointcloud import PointCloudDetector

    order = RADAR.waveform.tdm_tx_order()
    for config in (PointCloudConfig(cfar=cfar), PointCloudConfig(cfar=cfar, max_detections=4, min_range_m=1.0)):
        detector = PointCloudDetector(RADAR, order, config)
        for iq in _frames_iq(3, seed=11):
            got = detector.detect(iq)
            cube, layout = detector.cube(iq)
            want = reference_points(cube, layout, RADAR, config, np.sum(np.abs(cube) ** 2, axis=1))
            assert want.xyz_m.shape[0] >= (4 if config.max_detections == 4 else len(TARGETS))
            for field in ("xyz_m", "doppler_mps", "snr_db", "range_m", "azimuth_rad"):
                np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
