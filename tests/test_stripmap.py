"""The streaming strip map: equal to offline backprojection where it integrates everything, the aperture
limit sets the cross-range width, memory follows the area driven, and pre-summing within its bound keeps
the image."""

import dataclasses
import math

import numpy as np
import pytest
from conftest import R0, RADAR, point_pass, send_frame_and_poses
from reference_stripmap import block_reference

from imaging import metrics
from imaging.backprojection import backproject
from imaging.core.errors import ConfigError
from imaging.image_formation import ImagingOptions, frame_profiles
from imaging.io.image_file import read_image
from imaging.io.recording import Recording
from imaging.sim.simulator import simulate_recording
from imaging.stripmap import (
    StripMap,
    StripMapConfig,
    max_presum,
    presum_chirps,
    presum_phase_spread_rad,
)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """The left-front radar passing a point target at 2 m, 1.2 m of travel at 0.4 m/s."""
    path = tmp_path_factory.mktemp("stripmap") / "pass.h5"
    simulate_recording(point_pass(0.4, duration_s=3.0), path)
    rec = Recording(path)
    yield rec, rec.radar(RADAR), rec.truth(), rec.tdm_tx_order(RADAR)
    rec.close()


def build(rec, radar, truth, order, config, frames=None):
    sm = StripMap(config)
    adc = rec.adc(RADAR)
    times = rec.frame_time_ns(RADAR)
    for k in frames if frames is not None else range(adc.shape[0]):
        sm.add_frame(radar, order, adc[k], int(times[k]), truth)
    return sm


def test_where_it_integrates_every_frame_it_equals_offline_backprojection(drive):
    rec, radar, truth, order = drive
    config = StripMapConfig(aperture_m=4.0, beam_half_angle_deg=70.0, range_min_m=1.0, range_max_m=3.0, oversample=8,
                            algorithm="direct")  # the kernel's own map ("polar" is checked in test_stripmap_polar.py)
    frames = range(20, 40)
    sm = build(rec, radar, truth, order, config, frames)
    image, x, y = sm.mosaic()
    sel_x = np.flatnonzero(np.abs(x) < 0.1)
    sel_y = np.flatnonzero(np.abs(y - R0) < 0.1)
    gx, gy = np.meshgrid(x[sel_x], y[sel_y])
    points = np.stack([gx, gy, np.full(gx.shape, config.z_m)], axis=-1)
    offline = np.zeros(gx.shape, np.complex128)
    options = ImagingOptions(oversample=8)
    for k in frames:
        profiles, tx_m, rx_m, _, _ = frame_profiles(rec.adc(RADAR, slice(k, k + 1)), rec.frame_time_ns(RADAR, slice(k, k + 1)),
                                                    radar, truth, order, options)
        backproject(profiles, tx_m, rx_m, points, out=offline)
    ours = image[np.ix_(sel_y, sel_x)]
    assert np.abs(offline).max() > 0
    np.testing.assert_allclose(ours, offline, rtol=0, atol=1e-4 * np.abs(offline).max())


@pytest.mark.parametrize("aperture_m", [0.15, 0.3])
def test_the_aperture_limit_sets_the_cross_range_width(drive, aperture_m):
    rec, radar, truth, order = drive
    sm = build(rec, radar, truth, order, StripMapConfig(aperture_m=aperture_m, pixel_m=0.004, tile_px=64))
    image, x, y = sm.mosaic()
    got = metrics.analyze_target(image, x, y, (0.0, 1.0), near_m=(0.0, R0), half_length_m=0.15)
    theory = metrics.cross_range_resolution_theory_m(radar.waveform.wavelength_m, R0, aperture_m)
    assert np.hypot(got["peak_m"][0], got["peak_m"][1] - R0) < 0.01
    assert got["cross_range"]["half_power_width_m"] == pytest.approx(theory, rel=0.1)


def test_memory_follows_the_area_driven(drive):
    rec, radar, truth, order = drive
    config = StripMapConfig()
    n = rec.n_frames(RADAR)
    half = build(rec, radar, truth, order, config, range(n // 2))
    full = build(rec, radar, truth, order, config)
    tile_m = config.tile_m
    # Tiles only where the beam went: between range_min and range_max ahead of the left-looking radar (at y = 0).
    rows = {k[1] for k in full.tiles}
    assert rows == set(range(int(config.range_min_m // tile_m), int(config.range_max_m // tile_m) + 1))
    # Twice the drive, about twice the tiles (plus the footprint's own extent).
    extent_x = lambda sm: (max(k[0] for k in sm.tiles) - min(k[0] for k in sm.tiles) + 1) * tile_m  # noqa: E731
    assert len(full.tiles) > len(half.tiles)
    assert extent_x(full) - extent_x(half) == pytest.approx(0.4 * (n - n // 2) * radar.waveform.frame_interval_s, abs=2 * tile_m)
    image, _, _ = full.mosaic()
    assert image.size <= len(full.tiles) * config.tile_px ** 2 * 1.5  # no big empty canvas around the tiles


def test_the_map_holds_at_most_max_tiles_and_counts_what_it_leaves_out(drive):
    """A long drive, or an odometry gone astray on a starved machine (the four-radar soak's map reached 4.5 GB,
    tiles kilometres apart), must not take the machine's memory: beyond max_tiles no tile is made, frames
    image into the tiles there are, and a frame with none is counted off the map."""
    rec, radar, truth, order = drive
    full = build(rec, radar, truth, order, StripMapConfig())
    limit = len(full.tiles) // 3
    capped = build(rec, radar, truth, order, StripMapConfig(max_tiles=limit))
    assert len(capped.tiles) == limit
    assert capped.tiles_refused > 0 and 0 < capped.frames_off_map < rec.n_frames(RADAR)
    assert capped.frames + capped.frames_off_map + capped.frames_standing == full.frames + full.frames_standing
    assert set(capped.tiles) < set(full.tiles)
    img = capped.to_image()
    assert img.attrs["frames_off_map"] == capped.frames_off_map and img.attrs["tiles_refused"] == capped.tiles_refused
    with pytest.raises(ConfigError, match="max_tiles"):
        StripMapConfig(max_tiles=0)


def test_a_mosaic_of_tiles_far_apart_stays_within_its_pixel_limit():
    """Tiles far apart (the soak's diverged odometry spread them over 17 x 387 km: a 487 TiB mosaic, and the
    map file was lost to MemoryError) give the window around their median, the others counted as left out."""
    config = StripMapConfig(tile_px=8)
    sm = StripMap(config)
    tile = np.ones((8, 8), np.complex128)
    for ix in range(10):  # a cluster of 10 x 3 tiles near the origin ...
        for iy in range(3):
            sm.tiles[(ix, iy)] = tile
    sm.tiles[(10**6, 5 * 10**5)] = tile  # ... and one astray
    image, x, y = sm.mosaic(max_pixels=64 * 64)  # 64 tiles of 8 x 8
    assert image.size <= 64 * 64
    assert sm.mosaic_tiles_left_out == 1
    assert np.count_nonzero(image) == 30 * 64  # every tile of the cluster is in the window
    assert x.size == image.shape[1] and y.size == image.shape[0] and x[0] < 0.08 * 10 and y[0] < 0.08 * 3
    del sm.tiles[(10**6, 5 * 10**5)]
    image, _, _ = sm.mosaic(max_pixels=64 * 64)  # the cluster alone fits: its bounding box, nothing left out
    assert sm.mosaic_tiles_left_out == 0 and image.shape == (3 * 8, 10 * 8)


def test_presum_within_its_bound_keeps_the_image_and_beyond_it_does_not(drive):
    rec, radar, truth, order = drive
    base = StripMapConfig(range_min_m=1.0, pixel_m=0.005)
    allowed = max_presum(base, radar, 0.4)
    assert allowed >= 2 and presum_phase_spread_rad(dataclasses.replace(base, presum=allowed), radar, 0.4) <= math.pi / 4
    frames = range(25, 50)
    ref, _, _ = build(rec, radar, truth, order, base, frames).mosaic()
    errors = {}
    for presum in (allowed, 16):
        img, _, _ = build(rec, radar, truth, order, dataclasses.replace(base, presum=presum), frames).mosaic()
        errors[presum] = 10 * np.log10(np.sum(np.abs(img - ref) ** 2) / np.sum(np.abs(ref) ** 2))
    assert errors[allowed] < -20
    assert errors[16] > errors[allowed] + 6


@pytest.mark.parametrize("order_kind", ["in turn", "shuffled"])
@pytest.mark.parametrize("presum", [1, 3, 4, 64])
def test_presum_chirps_sums_each_txs_consecutive_chirps(order_kind, presum):
    """Against a plain loop over groups: the same sums, from complex samples or straight from I/Q pairs
    (TXs in turn take a reshape instead of a gather; 64 is all of a TX's chirps, 3 leaves a remainder)."""
    from imaging.core.samples import iq_to_complex

    rng = np.random.default_rng(7)
    n_tx, per_tx = 4, 64
    order = np.tile(np.arange(n_tx), per_tx)
    if order_kind == "shuffled":
        order = np.concatenate([rng.permutation(n_tx) for _ in range(per_tx)])
    iq = rng.integers(-32768, 32767, (n_tx * per_tx, 3, 5, 2), dtype=np.int16)
    adc = iq_to_complex(iq)
    want, want_groups, want_tx = [], [], []
    for tx in range(n_tx):
        k = np.flatnonzero(order == tx)
        for g in range(per_tx // presum):
            chirps = k[g * presum:(g + 1) * presum]
            want.append(sum(adc[c].astype(np.complex128) for c in chirps))
            want_groups.append(chirps)
            want_tx.append(tx)
    for frame in (adc, iq):
        sums, groups, tx_index = presum_chirps(frame, order, n_tx, presum)
        assert sums.dtype == np.complex64 and sums.shape == (len(want), 3, 5)
        np.testing.assert_array_equal(groups, want_groups)
        np.testing.assert_array_equal(tx_index, want_tx)
        np.testing.assert_array_equal(sums, np.array(want))  # sums of int16 are exact in float32
    with pytest.raises(ValueError, match="presum 65"):
        presum_chirps(iq, order, n_tx, 65)
    with pytest.raises(ValueError, match="I/Q pairs"):
        presum_chirps(iq[..., 0], order, n_tx, 4)


def test_frames_taken_standing_still_are_left_out(drive):
    rec, radar, truth, order = drive
    from imaging.core.trajectory import StraightLine

    parked = StraightLine(start_m=(0.0, -0.2, 0.0), speed_mps=0.0, t0_ns=int(rec.frame_time_ns(RADAR)[0]))
    sm = StripMap(StripMapConfig())
    fp = sm.add_frame(radar, order, rec.adc(RADAR, slice(0, 1))[0], int(rec.frame_time_ns(RADAR)[0]), parked)
    assert fp.skipped == "standing still" and not sm.tiles and sm.frames_standing == 1


def _pausing(truth, times, first: int, last: int):
    """The drive's poses every 10 ms, but standing still (zero velocity) for frames first..last-1."""
    from imaging.core.trajectory import SampledTrajectory

    t = np.arange(int(times[0]) - 10 ** 8, int(times[-1]) + 10 ** 9, 10 ** 7, dtype=np.int64)
    s = truth.sample(t)
    velocity = s.velocity_mps.copy()
    velocity[(t >= times[first]) & (t < times[last])] = 0.0
    return SampledTrajectory(t, s.position_m, s.orientation_xyzw, velocity)


@pytest.mark.parametrize("batch", [2, 3, 4, 8])
def test_frames_imaged_together_make_the_map_they_make_one_by_one(drive, batch):
    """add_frames keeps every frame's own aperture window: the same tiles, values, counts and work as
    add_frame frame by frame, also with frames standing still inside a batch."""
    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    trajectory = _pausing(truth, times, 30, 33)  # frames 30, 31 and 32 taken standing still
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, presum=4)
    frames = list(range(10, 50))
    one, together = StripMap(config), StripMap(config)
    pairs_one = sum(one.add_frame(radar, order, adc[k], int(times[k]), trajectory).pixel_profile_pairs for k in frames)
    pairs, imaged, standing = 0, 0, 0
    for a in range(0, len(frames), batch):
        ks = frames[a:a + batch]
        fp = together.add_frames(radar, order, [adc[k] for k in ks], [int(times[k]) for k in ks], trajectory)
        pairs, imaged, standing = pairs + fp.pixel_profile_pairs, imaged + fp.frames_imaged, standing + fp.frames_standing
    assert standing == 3 and together.frames_standing == one.frames_standing == 3
    assert imaged == together.frames == one.frames == len(frames) - 3
    assert together.profiles == one.profiles and pairs == pairs_one
    assert together.tiles.keys() == one.tiles.keys()
    # To the float32 kernel's rounding (its blocks of pixels are not the same): -80 dB, as the kernel's budget.
    scale = max(np.abs(t).max() for t in one.tiles.values())
    for key, tile in one.tiles.items():
        np.testing.assert_allclose(together.tiles[key], tile, rtol=0, atol=1e-4 * scale)
    assert error_db(together.mosaic()[0], one.mosaic()[0]) < -80
    # Pre-summed as a live map catching up does it: the same again.
    one, together = StripMap(config), StripMap(config)
    for k in frames[:8]:
        one.add_frame(radar, order, adc[k], int(times[k]), trajectory, presum=64)
    together.add_frames(radar, order, [adc[k] for k in frames[:8]], [int(times[k]) for k in frames[:8]], trajectory, presum=64)
    assert together.tiles.keys() == one.tiles.keys() and error_db(together.mosaic()[0], one.mosaic()[0]) < -80


def test_pixels_take_exactly_the_frames_their_takers_name(drive):
    """Where a turn leaves a frame out between two that take a pixel (takers 0b101), the pixel gets the
    sum of exactly the frames named; and the footprint masks of several frames are each frame's own."""
    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    sm = StripMap(StripMapConfig(presum=8))
    ks = [20, 21, 22]
    profiles, tx_m, rx_m, look, _ = sm.frames_profiles(radar, order, [adc[k] for k in ks], [int(times[k]) for k in ks], truth)
    per = profiles.data.shape[0] // 3
    rng = np.random.default_rng(3)
    pts = np.stack([rng.uniform(-0.3, 0.3, 600), rng.uniform(1.5, 2.5, 600), np.full(600, 0.3)], axis=1)
    takers = rng.choice(np.array([0b001, 0b101, 0b111, 0b110, 0b010]), 600)
    got = sm._backproject_takers(profiles, tx_m, rx_m, pts, takers, per)
    each = [backproject(dataclasses.replace(profiles, data=profiles.data[f * per:(f + 1) * per], rows=None, samples=None),
                        tx_m[f * per:(f + 1) * per], rx_m[f * per:(f + 1) * per], pts) for f in range(3)]
    want = sum(np.where(takers >> f & 1, each[f], 0) for f in range(3))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * np.abs(want).max())  # float32 sums in the kernel
    centres = (0.5 * (tx_m + rx_m))[:, :2].reshape(3, per, 2).mean(axis=1)
    looks = look.reshape(3, per, 2).mean(axis=1)
    looks /= np.linalg.norm(looks, axis=1, keepdims=True)
    x, y = sm.tile_points((0, 3))
    masks = sm.footprint_mask(x[None, :], y[:, None], centres, looks)
    assert masks.shape == (3, 64, 64) and masks.any() and not masks.all(axis=0).all()
    for f in range(3):
        assert np.array_equal(masks[f], sm.footprint_mask(x[None, :], y[:, None], centres[f], looks[f]))


def test_add_frames_refuses_mismatched_or_too_many_frames(drive):
    from imaging.stripmap import MAX_BATCH_FRAMES

    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    sm = StripMap(StripMapConfig())
    with pytest.raises(ValueError, match="2 frames and 1 frame times"):
        sm.add_frames(radar, order, [adc[0], adc[1]], [int(times[0])], truth)
    with pytest.raises(ValueError, match=f"1 to {MAX_BATCH_FRAMES}"):
        sm.add_frames(radar, order, [adc[0]] * (MAX_BATCH_FRAMES + 1), [int(times[0])] * (MAX_BATCH_FRAMES + 1), truth)
    assert not sm.tiles and sm.frames == 0


def error_db(image, reference):
    return 10 * np.log10(np.sum(np.abs(image - reference) ** 2) / np.sum(np.abs(reference) ** 2))


def test_ffbp_blocks_equal_direct_backprojection_within_the_plans_error(drive):
    """A 1 m aperture at 4 mm pixels imaged in blocks of 4 frames by FFBP: within -40 dB of the same blocks
    imaged profile by profile, and the target as sharp and in the same place as the per-frame direct map."""
    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(aperture_m=1.0, pixel_m=0.004, beam_half_angle_deg=60.0, range_min_m=1.5, range_max_m=2.5,
                            presum=4, algorithm="ffbp", ffbp_block_frames=4)
    frames = range(6, 54)
    sm = StripMap(config)
    done = [sm.add_frame(radar, order, adc[k], int(times[k]), truth) for k in frames]
    # A block's tiles change when its fourth frame comes, and then by all four frames.
    assert [f.frames_imaged for f in done] == [0, 0, 0, 4] * 12
    assert all(not f.tiles for f in done[::4]) and all(f.tiles for f in done[3::4])
    assert sm.ffbp_blocks == 12 and sm.ffbp_blocks_direct == 0 and sm.ffbp_levels == 2 and sm.frames == 48
    ref = block_reference(config, radar, order, [(adc[k], int(times[k])) for k in frames], truth)
    image, x, y = sm.mosaic()
    expected, x_ref, _ = ref.mosaic()
    assert image.shape == expected.shape and x[0] == x_ref[0]
    measured = error_db(image, expected)
    assert measured < -40 and measured < sm.ffbp_error_bound_db
    direct = build(rec, radar, truth, order, dataclasses.replace(config, algorithm="direct"), frames).mosaic()[0]
    got = {name: metrics.analyze_target(im, x, y, (0.0, 1.0), near_m=(0.0, R0), half_length_m=0.15)
           for name, im in (("ffbp", image), ("direct", direct))}
    assert np.allclose(got["ffbp"]["peak_m"], got["direct"]["peak_m"], atol=0.002)
    assert got["ffbp"]["cross_range"]["half_power_width_m"] == pytest.approx(got["direct"]["cross_range"]["half_power_width_m"], rel=0.05)
    attrs = sm.to_image().attrs
    assert attrs["method"] == "stripmap-ffbp-linear" and attrs["ffbp_blocks"] == 12
    assert attrs["ffbp_error_bound_db"] == sm.ffbp_error_bound_db < -20


def test_ffbp_images_a_partial_block_on_flush_and_when_the_robot_stops(drive):
    rec, radar, truth, order = drive
    from imaging.core.trajectory import StraightLine

    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.01, range_min_m=1.5, range_max_m=2.5, presum=8, algorithm="ffbp", ffbp_block_frames=8)
    sm = StripMap(config)
    for k in range(20, 23):
        assert sm.add_frame(radar, order, adc[k], int(times[k]), truth).frames_imaged == 0
    assert not sm.tiles
    ended = sm.flush()
    assert ended.frames_imaged == 3 and ended.tiles and sm.frames == 3 and sm.ffbp_blocks == 1
    assert sm.flush().frames_imaged == 0  # nothing left
    for k in range(23, 25):
        sm.add_frame(radar, order, adc[k], int(times[k]), truth)
    parked = StraightLine(start_m=(0.0, -0.2, 0.0), speed_mps=0.0, t0_ns=int(times[0]))
    stopped = sm.add_frame(radar, order, adc[25], int(times[25]), parked)
    assert stopped.skipped == "standing still" and stopped.frames_imaged == 2 and stopped.tiles
    assert sm.frames == 5 and sm.frames_standing == 1 and sm.ffbp_blocks == 2


def test_an_ffbp_block_whose_track_runs_into_its_footprint_is_imaged_directly(drive):
    """Driving along the radar's boresight no polar grid has the footprint to one side: such a block goes
    through the direct kernel, counted, and equals the direct reference."""
    rec, radar, truth, order = drive
    from imaging.core.trajectory import SampledTrajectory

    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    t = truth.time_ns
    s = truth.sample(t)
    ahead = np.zeros_like(s.position_m)
    ahead[:, 1] = 0.4 * (t - t[0]) * 1e-9  # towards +y, where the left radar looks
    towards = SampledTrajectory(t, ahead, s.orientation_xyzw, np.tile([0.0, 0.4, 0.0], (t.size, 1)), source="test")
    config = StripMapConfig(pixel_m=0.01, range_min_m=1.0, range_max_m=2.5, presum=8, algorithm="ffbp", ffbp_block_frames=4)
    sm = StripMap(config)
    for k in range(20, 28):
        sm.add_frame(radar, order, adc[k], int(times[k]), towards)
    assert sm.ffbp_blocks == 2 and sm.ffbp_blocks_direct == 2
    ref = block_reference(config, radar, order, [(adc[k], int(times[k])) for k in range(20, 28)], towards)
    # The same kernel on the same points, grouped differently (its float32 geometry is relative to blocks of points).
    assert error_db(sm.mosaic()[0], ref.mosaic()[0]) < -80


def test_bad_settings_name_the_field():
    with pytest.raises(ConfigError, match="aperture_m"):
        StripMapConfig(aperture_m=0)
    with pytest.raises(ConfigError, match="mode"):
        StripMapConfig(mode="cubic")
    with pytest.raises(ConfigError, match="algorithm"):
        StripMapConfig(algorithm="fft")
    with pytest.raises(ConfigError, match="algorithm.*cannot refocus"):
        StripMapConfig(algorithm="ffbp", refocus="pga")
    with pytest.raises(ConfigError, match="range_min_m"):
        StripMapConfig(algorithm="ffbp", range_min_m=0.0)
    with pytest.raises(ConfigError, match="ffbp_block_frames"):
        StripMapConfig(algorithm="ffbp", ffbp_block_frames=0)
    with pytest.raises(ValueError, match="empty"):
        StripMap().mosaic()


def run_worker(drive, config, tmp_path, lost=()):
    """Frames 20-39 of ``drive`` and their poses through a strip-map worker process; returns the tiles it
    published last, its last status and the map file it wrote (checked equal to the tiles). Frames ``lost``
    are numbered but never sent, as if dropped on the bus. The IMU on the radar's mount, where the recording
    has one, goes out too, in 50 ms batches ahead of each frame, as its driver sends them."""
    import multiprocessing as mp
    import time

    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.messages import (
        MapStatus,
        ImuBatch,
        MapTile,
        PoseEnd,
        RadarFrameMessage,
        RadarImuBatch,
        WorkerState,
    )
    from acquisition.processes import free_tcp_endpoint
    from acquisition.workers import WorkerSpec, worker_process
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from imaging.core.rig import Rig
    from imaging.io.image_file import read_image

    rec, radar, truth, order = drive
    pixel = config.pixel_m
    driver_ep, pose_ep, out_ep = free_tcp_endpoint(), free_tcp_endpoint(), free_tcp_endpoint()
    frames_pub, poses_pub = BusPublisher(driver_ep), BusPublisher(pose_ep)
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    map_path = tmp_path / "map.h5"
    spec = WorkerSpec("stripmap", StripMapWorker,
                      StripMapWorkerConfig(Rig((radar,)), None, config, pose_ep, str(map_path)), out_ep)
    worker = ctx.Process(target=worker_process, args=(spec, [driver_ep], stop))
    worker.start()
    sub = BusSubscriber(out_ep, topics=["map/", WorkerState.TOPIC])
    # The worker subscribes, then warms up, then says it is warm: sent before that, frames could go before
    # its subscription reached the publisher (a fixed 3 s wait lost them all at load averages of 10-14).
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        m = sub.receive(timeout_ms=300)
        if m is not None and m.topic == WorkerState.TOPIC and WorkerState.from_message(m).warm:
            break
    times = rec.frame_time_ns(RADAR)
    iq = rec.file[f"radar/{RADAR}/adc"]
    imu, imu_sent = rec.radar_imu(RADAR), 0
    for k in range(20, 40):
        while imu is not None and imu_sent < imu["time_ns"].size and imu["time_ns"][imu_sent] < times[k] + 100_000_000:
            part = slice(imu_sent, imu_sent + 50)
            frames_pub.send(RadarImuBatch(RADAR, ImuBatch(imu["time_ns"][part], imu["gyro_radps"][part], imu["accel_mps2"][part],
                                                          imu["counter"][part], imu["host_time_ns"][part])))
            imu_sent += 50
        if k in lost:
            frames_pub._seq[RadarFrameMessage.topic_of(RADAR)] += 1
            continue
        send_frame_and_poses(frames_pub, poses_pub, RADAR, k, iq, times, truth)
        time.sleep(0.05)
    poses_pub.send(PoseEnd(time.time_ns()))
    time.sleep(1.0)
    stop.set()
    tiles, status = {}, None
    deadline = time.monotonic() + 30
    while worker.is_alive() or time.monotonic() < deadline:
        m = sub.receive(timeout_ms=300)
        if m is None:
            if not worker.is_alive():
                break
            continue
        if m.topic == MapTile.TOPIC:
            tile = MapTile.from_message(m)
            tiles[tile.key] = np.array(tile.image)
        elif m.topic == MapStatus.TOPIC:
            status = MapStatus.from_message(m)
    worker.join(30)
    frames_pub.close(), poses_pub.close(), sub.close()
    assert worker.exitcode == 0
    assert status is not None and status.frames_imaged == 20 - len(lost) and status.max_lag_s > 0
    assert status.frames_lost_on_bus == len(lost) and status.tiles == len(tiles)
    img = read_image(map_path)
    n = img.attrs["tile_px"]
    x0 = min(k[0] for k in tiles) * n * pixel
    y0 = min(k[1] for k in tiles) * n * pixel
    for (ix, iy), tile in tiles.items():
        c = int(round((ix * n * pixel - x0) / pixel))
        r = int(round((iy * n * pixel - y0) / pixel))
        np.testing.assert_allclose(img.image[r:r + n, c:c + n], tile, rtol=1e-6, atol=1e-6 * np.abs(tile).max())
    return tiles, status, img


def test_the_worker_publishes_tiles_and_its_lag_and_writes_the_map(drive, tmp_path):
    """The strip-map worker as the daemon runs it (its own process, real ZeroMQ): radar frames and poses in,
    ``map/tile`` and ``map/status`` out, the map file equal to the last tiles it published."""
    _, status, _ = run_worker(drive, StripMapConfig(presum=4), tmp_path, lost=(25, 26, 31))
    assert status.tiles_refocused == 0
    assert read_image(tmp_path / "map.h5").attrs["frames_lost_on_bus"] == 3  # the file says what it lacks


def test_the_worker_images_ffbp_blocks_and_the_last_one_at_the_end(drive, tmp_path):
    """17 frames in blocks of 8 through the worker process: two blocks live, the last frame's block when
    the run ends; every frame imaged, the tiles published and written, the lag measured."""
    config = StripMapConfig(presum=4, range_min_m=1.0, algorithm="ffbp", ffbp_block_frames=8)
    _, status, img = run_worker(drive, config, tmp_path, lost=(25, 26, 31))
    assert img.attrs["method"] == "stripmap-ffbp-linear" and img.attrs["ffbp_blocks"] == 3
    assert img.attrs["n_frames"] == 17 and img.attrs["ffbp_error_bound_db"] < -20


def test_the_worker_refocuses_tiles_and_publishes_them(tmp_path):
    """With --map-refocus the worker refocuses the tiles still open when the run ends, counts them in
    map/status and publishes them: the last tiles it sent are the map it wrote, side lobes down.
    With --map-imu-aided instead, the IMU on the radar's mount (its samples on the bus) does the same.
    """
    import dataclasses

    from imaging.core.geometry import Vibration
    from imaging.core.rig import ImuConfig, Rig

    path = tmp_path / "vibrating.h5"
    scene = point_pass(0.4, duration_s=3.0, origin=(0.32, 0.0), snr_db=10.0, vibration=Vibration(3.83, 0.319e-3, 0.7), seed=4)
    radars = tuple(dataclasses.replace(r, imu=ImuConfig(rate_hz=1000.0)) if r.name == RADAR else r for r in scene.rig.radars)
    simulate_recording(dataclasses.replace(scene, rig=Rig(radars, scene.rig.imu)), path)
    configs = {"none": StripMapConfig(presum=4), "entropy": StripMapConfig(presum=4, refocus="entropy"),
               "imu": StripMapConfig(presum=4, refocus_imu_aided=True)}
    with Recording(path) as rec:
        drive = (rec, rec.radar(RADAR), rec.truth(), rec.tdm_tx_order(RADAR))
        results = {r: run_worker(drive, config, tmp_path / r) for r, config in configs.items()}
    assert results["none"][1].tiles_refocused == 0
    assert results["entropy"][1].tiles_refocused >= 1
    assert results["imu"][1].tiles_refocused >= 1 and results["imu"][1].tiles_without_radar_imu == 0
    pslr = {}
    for r, (_, _, img) in results.items():
        a = metrics.analyze_target(img.image, img.x_m, img.y_m, (0.0, 1.0, 0.0), near_m=(0.32, R0), radius_m=0.05, half_length_m=0.15)
        pslr[r] = a["cross_range"]["pslr_db"]
    assert pslr["entropy"] < pslr["none"] - 3.0
    assert pslr["imu"] < pslr["none"] - 3.0




def test_a_worker_behind_sums_more_chirps_before_it_drops_a_frame(drive):
    """A backlog of the drive's frames (3 s of sensor time): the live worker images the oldest with more
    pre-summing (counted), drops none, and still focuses the target; without a backlog it does not."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    t = truth.time_ns[::10]
    poses = PoseBatch(t, truth.sample(t).position_m, truth.sample(t).orientation_xyzw, truth.sample(t).velocity_mps)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=2)

    def run(frames):
        worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5",
                                                     catch_up_start_s=1.0, catch_up_step_s=1.0), None)
        worker.handle(poses, live=True)
        for k in frames:
            frame = RadarFrame(k, int(times[k]), int(times[k]), True, 0, complex_to_iq(adc[k], 1000.0))
            worker.handle(RadarFrameMessage(RADAR, frame), live=True)
        worker._image_ready(budget_s=None)  # a live pass with no time limit: the whole backlog
        return worker

    behind = run(range(len(times)))  # every frame queued at once: 3 s behind
    status = behind.status
    assert status.frames_dropped_behind == 0 and status.frames_presummed_more > 10
    assert status.frames_imaged + status.frames_standing_still == len(times)
    caught_up = run([])
    for k in range(len(times)):  # one frame at a time: never behind
        frame = RadarFrame(k, int(times[k]), int(times[k]), True, 0, complex_to_iq(adc[k], 1000.0))
        caught_up.handle(RadarFrameMessage(RADAR, frame), live=True)
        caught_up._image_ready(budget_s=None)
    assert caught_up.status.frames_presummed_more == 0 and caught_up.status.presum_factor == 1
    assert behind.map.profiles < 0.6 * caught_up.map.profiles  # the catch-up costs fewer profiles
    # Both focus the target at r0 within a pixel (pre-summing more costs side-lobe level, not the peak).
    for worker in (behind, caught_up):
        img = worker.map.to_image()
        mag = np.abs(img.image)
        iy, ix = np.unravel_index(np.argmax(mag), mag.shape)
        assert abs(img.x_m[ix] - 0.0) < 0.02 and abs(img.y_m[iy] - R0) < 0.02


def test_a_worker_behind_images_queued_frames_of_a_radar_together(drive):
    """A backlog of two radars' frames (the drive's, under a second name too, interleaved as they arrive):
    the worker images up to max_batch_frames of a radar per call, counts them, and makes the map it makes
    frame by frame; frames not yet covered by poses wait."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    rec, radar, truth, order = drive
    twin = dataclasses.replace(radar, name="twin")
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    n = 24
    covered = t = truth.time_ns[truth.time_ns <= times[n - 4]]  # poses up to frame n-4's start: the last 4 wait
    s = truth.sample(t)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=4)

    def run(batch):
        worker = StripMapWorker(StripMapWorkerConfig(Rig((radar, twin)), None, config, "tcp://unused:1", "unused.h5",
                                                     catch_up_start_s=100.0, max_batch_frames=batch), None)
        worker.handle(PoseBatch(covered, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
        for k in range(n):
            for name in (RADAR, "twin"):
                frame = RadarFrame(k, int(times[k]), int(times[k]), True, 0, complex_to_iq(adc[k], 1000.0))
                worker.handle(RadarFrameMessage(name, frame), live=True)
        calls = []
        add_frames = worker.map.add_frames
        worker.map.add_frames = lambda radar, o, adcs, *a, **kw: calls.append((radar.name, len(adcs))) or add_frames(radar, o, adcs, *a, **kw)
        worker._image_ready(budget_s=None)
        return worker, calls

    one, one_calls = run(1)
    four, calls = run(4)
    waiting = [(f.radar, int(f.frame_time_ns)) for f in four.frames]
    assert waiting == [(f[0], int(f[2])) for f in one.frames] and len(waiting) == 2 * 4  # not covered yet
    assert [c[1] for c in one_calls] == [1] * 40 and one.status.frames_batched == 0
    assert max(c[1] for c in calls) == 4 and sum(c[1] for c in calls) == 40 and len(calls) == 10
    assert four.status.frames_batched == 40 and four.status.frames_imaged == one.status.frames_imaged == 40
    assert four.map.tiles.keys() == one.map.tiles.keys()
    assert error_db(four.map.mosaic()[0], one.map.mosaic()[0]) < -80


def test_a_frame_weighted_k_adds_k_times_its_contribution(drive):
    """``weight`` scales a frame's contribution and nothing else: the same tiles, the map times the weight."""
    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=4)
    maps = {}
    for weight in (1.0, 4.0):
        sm = maps[weight] = StripMap(config)
        for k in range(20, 26, 2):
            sm.add_frames(radar, order, [adc[k], adc[k + 1]], [int(times[k]), int(times[k + 1])], truth, weight=weight)
    assert maps[4.0].tiles.keys() == maps[1.0].tiles.keys() and maps[1.0].tiles
    np.testing.assert_allclose(maps[4.0].mosaic()[0], 4.0 * maps[1.0].mosaic()[0], rtol=1e-6)


def test_rx_channels_summed_make_nearly_the_same_map_from_a_quarter_of_the_profiles(drive):
    """Each TX's RX channels summed into one profile at their centroid: the point target where it was, as
    bright to within the array factor's loss at the aperture's edge, the map close to the one of every channel."""
    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=4)
    maps = {}
    for sum_rx in (False, True):
        sm = maps[sum_rx] = StripMap(config)
        for k in range(0, len(times), 2):
            sm.add_frames(radar, order, list(adc[k:k + 2]), [int(t) for t in times[k:k + 2]], truth, sum_rx=sum_rx)
    assert maps[True].profiles * radar.waveform.n_rx == maps[False].profiles
    assert maps[True].tiles.keys() == maps[False].tiles.keys()
    peaks = []
    for sm in maps.values():
        img = sm.to_image()
        mag = np.abs(img.image)
        iy, ix = np.unravel_index(np.argmax(mag), mag.shape)
        assert abs(img.x_m[ix] - 0.0) < 0.02 and abs(img.y_m[iy] - R0) < 0.02
        peaks.append(mag.max())
    assert 0.97 < peaks[1] / peaks[0] <= 1.0  # 0.99 here
    assert error_db(maps[True].mosaic()[0], maps[False].mosaic()[0]) < -25  # -35 dB here


def test_the_catch_up_ladder_sums_all_chirps_and_rx_before_it_thins_frames(drive):
    """The extra pre-summing doubles every catch_up_step_s of backlog past catch_up_start_s until a TX's chirps
    are all one sum; the next step sums the RX channels; only the steps after that thin frames (2, then 4,
    never past max_thinning)."""
    from acquisition.workers.stripmap import QueuedFrame, StripMapWorker, StripMapWorkerConfig
    from imaging.core.rig import Rig

    rec, radar, truth, order = drive
    wf = radar.waveform
    most = wf.chirps_per_frame // wf.n_tx // 4
    assert most == 16  # so the ladder below: 2, 4, 8, 16, then thinning
    config = StripMapConfig(presum=4)

    def ladder(backlog_s, **kw):
        worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5",
                                                     catch_up_start_s=0.5, catch_up_step_s=0.25, **kw), None)
        worker.frames.extend([QueuedFrame(RADAR, None, 0, 0), QueuedFrame(RADAR, None, round(backlog_s * 1e9), 0)])
        return worker.catch_up(RADAR)

    assert [ladder(b) for b in (0.0, 0.49, 0.5, 0.75, 1.0, 1.25, 1.49, 1.5, 1.75, 2.0, 10.0)] == [
        (1, False, 1), (1, False, 1), (2, False, 1), (4, False, 1), (8, False, 1), (16, False, 1), (16, False, 1),
        (16, True, 1), (16, True, 2), (16, True, 4), (16, True, 4)]
    assert ladder(10.0, max_thinning=1) == (16, True, 1) and ladder(10.0, max_thinning=2) == (16, True, 2)
    assert ladder(10.0, max_thinning=16) == (16, True, 16)
    # refocusing keeps every channel: no RX sums, so thinning comes a step sooner
    config = StripMapConfig(presum=4, refocus="entropy")
    assert [ladder(b) for b in (1.25, 1.5, 1.75)] == [(16, False, 1), (16, False, 2), (16, False, 4)]
    with pytest.raises(ConfigError, match="max_thinning"):
        StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5", max_thinning=3)


def test_a_worker_far_behind_thins_frames_and_keeps_the_map_s_scale(drive):
    """A backlog of the whole drive (3 s) with a catch-up that starts at once: past all-chirps pre-summing the
    worker images one frame in 2 or 4, counted, weighted so the target keeps its brightness; every frame is
    accounted for and none dropped."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    t = truth.time_ns[::10]
    poses = PoseBatch(t, truth.sample(t).position_m, truth.sample(t).orientation_xyzw, truth.sample(t).velocity_mps)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=4)

    def run(max_thinning):
        worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5",
                                                     catch_up_start_s=0.0, catch_up_step_s=0.25,
                                                     max_thinning=max_thinning), None)
        worker.handle(poses, live=True)
        for k in range(len(times)):
            frame = RadarFrame(k, int(times[k]), int(times[k]), True, 0, complex_to_iq(adc[k], 1000.0))
            worker.handle(RadarFrameMessage(RADAR, frame), live=True)
        worker._image_ready(budget_s=None)
        return worker

    thinned, summed = run(4), run(1)
    st = thinned.status
    assert summed.status.frames_thinned == 0 and summed.status.frames_imaged + summed.status.frames_standing_still == len(times)
    assert st.frames_thinned > len(times) // 4 and st.frames_dropped_behind == 0 and not thinned.frames
    assert st.frames_imaged + st.frames_standing_still + st.frames_thinned == len(times)
    assert st.frames_rx_summed > 0 and summed.status.frames_rx_summed > 0
    assert st.frames_imaged < 0.6 * summed.status.frames_imaged and thinned.map.profiles < summed.map.profiles
    peaks = []
    for worker in (thinned, summed):
        img = worker.map.to_image()
        mag = np.abs(img.image)
        iy, ix = np.unravel_index(np.argmax(mag), mag.shape)
        assert abs(img.x_m[ix] - 0.0) < 0.02 and abs(img.y_m[iy] - R0) < 0.02
        peaks.append(mag.max())
    assert 0.8 < peaks[0] / peaks[1] < 1.25  # weighted: the target as bright as with every frame imaged


def test_map_status_says_how_much_of_the_lag_is_waiting_for_the_odometry(drive):
    """3 s of frames queued but poses for only the first 0.2 s of them: the covered frames are imaged, the
    rest wait, and map/status gives how far the newest frame is ahead of the newest pose. Once the poses
    cover the queue, it is imaged and nothing waits."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.01, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=2)
    worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5"), None)

    def poses_until(t_end_ns):
        t = truth.time_ns[truth.time_ns <= t_end_ns]
        s = truth.sample(t)
        return PoseBatch(t, s.position_m, s.orientation_xyzw, s.velocity_mps)

    for k in range(len(times)):
        frame = RadarFrame(k, int(times[k]), int(times[k]), True, 0, complex_to_iq(adc[k], 1000.0))
        worker.handle(RadarFrameMessage(RADAR, frame), live=True)
    worker._image_ready(budget_s=None)  # no poses yet: everything queued waits
    assert worker.status.waiting_for_poses_s == pytest.approx((times[-1] - times[0]) * 1e-9)
    covered_ns = int(times[0]) + 200_000_000
    worker.handle(poses_until(covered_ns), live=True)
    queued = len(worker.frames)
    worker._image_ready(budget_s=None)
    status = worker.status
    assert 0 < queued - len(worker.frames) < queued // 4  # the covered frames went, the rest wait
    newest_pose = int(worker.poses[-1].time_ns[-1])
    assert status.waiting_for_poses_s == pytest.approx((times[-1] - newest_pose) * 1e-9)
    assert status.waiting_for_poses_s > 2.5

    worker.handle(poses_until(int(times[-1]) + 10 ** 9), live=True)  # the odometry catches up
    worker._image_ready(budget_s=None)
    assert not worker.frames and status.waiting_for_poses_s == 0.0
    assert status.frames_dropped_behind == 0


def test_the_worker_accounts_for_every_frame_when_the_odometry_stops_short(drive):
    """The run ends with the odometry's last pose short of the last frames: those are counted as beyond the
    odometry, so imaged + standing still + beyond + dropped + invalid is every frame received."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    covered = truth.time_ns[truth.time_ns <= times[-6]]  # the poses end inside frame -6
    s = truth.sample(covered)
    config = StripMapConfig(pixel_m=0.02, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=8)
    worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5"), None)
    worker.handle(PoseBatch(covered, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
    for k in range(len(times)):
        frame = RadarFrame(k, int(times[k]), int(times[k]), k != 3, 0, complex_to_iq(adc[k], 1000.0))
        worker.handle(RadarFrameMessage(RADAR, frame), live=True)
    worker._image_ready(final=True)
    st = worker.status
    assert st.frames_beyond_odometry == 6 and st.frames_skipped_invalid == 1 and st.frames_dropped_behind == 0
    assert st.frames_imaged + st.frames_standing_still + st.frames_beyond_odometry + st.frames_skipped_invalid == len(times)
    assert not worker.frames


def test_a_frame_covered_by_a_single_pose_waits_for_the_next(drive):
    """The odometry's first batch may hold one pose (a slow machine, the first scan): one pose is no
    trajectory, so the frames it covers wait in the queue instead of being taken off it and lost uncounted
    (what cost a CI run of the demo 5 frames)."""
    from acquisition.bus import BusPublisher
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.02, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=8)
    worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5"), None)
    for k in range(4):
        frame = RadarFrame(k, int(times[k]), int(times[k]), True, 0, complex_to_iq(adc[k], 1000.0))
        worker.handle(RadarFrameMessage(RADAR, frame), live=True)
    first = truth.time_ns[truth.time_ns > times[3] + radar.waveform.frame_duration_ns][:1]  # covers all four
    s = truth.sample(first)
    worker.handle(PoseBatch(first, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
    for _ in range(10):  # ten live steps with that one pose
        worker._image_ready(budget_s=None)
    assert len(worker.frames) == 4 and worker.status.frames_imaged + worker.status.frames_standing_still == 0
    rest = truth.time_ns[truth.time_ns > first[0]]
    s = truth.sample(rest)
    worker.handle(PoseBatch(rest, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
    worker._image_ready(budget_s=None)
    st = worker.status
    assert not worker.frames and st.frames_imaged + st.frames_standing_still == 4
    # Ended with a single pose ever: the frames are counted as beyond the odometry, not lost.
    pub = BusPublisher("tcp://127.0.0.1:*")
    try:
        lone = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5"), pub)
        frame = RadarFrame(0, int(times[0]), int(times[0]), True, 0, complex_to_iq(adc[0], 1000.0))
        lone.handle(RadarFrameMessage(RADAR, frame), live=True)
        s = truth.sample(first)
        lone.handle(PoseBatch(first, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
        lone.finish()
    finally:
        pub.close()
    assert lone.status.frames_beyond_odometry == 1 and not lone.frames



def test_frames_queued_behind_keep_the_poses_they_need(drive, monkeypatch):
    """A map behind the odometry by more than its pose window: the queued frames keep the poses that place
    them, so the live map is the map imaged on the full trajectory (frames placed at the first pose still
    held were smeared: a CI run of the demo saw a reflector 1.8x too wide)."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers import stripmap as worker_module
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    monkeypatch.setattr(worker_module, "POSE_WINDOW_NS", 500_000_000)  # the drive is 3 s; the window 0.5 s
    rec, radar, truth, order = drive
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.02, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=8)
    # No catch-up for the 3 s backlog: the map must equal the reference imaged at the same pre-summing.
    worker = StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, config, "tcp://unused:1", "unused.h5",
                                                 catch_up_start_s=10.0), None)
    for k in range(len(times)):  # every frame queued: the map is the whole drive behind
        iq = complex_to_iq(adc[k], 1000.0)
        worker.handle(RadarFrameMessage(RADAR, RadarFrame(k, int(times[k]), int(times[k]), True, 0, iq)), live=True)
    t = truth.time_ns
    for a in range(0, t.size, 10):  # the odometry's poses come in small batches, 3 s of them
        s = truth.sample(t[a:a + 10])
        worker.handle(PoseBatch(t[a:a + 10], s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
    assert worker.poses[0].time_ns[0] <= times[0]  # what the oldest frame needs is still held
    worker._image_ready(budget_s=None)
    assert not worker.frames and worker.status.frames_presummed_more == 0
    reference = build(rec, radar, truth, order, config, frames=range(len(times)))
    scale = 1000.0  # complex_to_iq's
    assert worker.map.tiles.keys() == reference.tiles.keys()
    for key, tile in reference.tiles.items():
        np.testing.assert_allclose(worker.map.tiles[key] / scale, tile, atol=1e-4 * np.abs(tile).max())
    # Nothing queued: poses older than the window are let go.
    s = truth.sample(t[-10:])
    worker.handle(PoseBatch(t[-10:] + 10 ** 9, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
    assert worker.poses[-1].time_ns[-1] - worker.poses[1].time_ns[0] <= 500_000_000


def test_poses_are_kept_for_the_earliest_queued_frame_not_the_first(drive, monkeypatch):
    """The radars' frames reach the queue interleaved, not in time order: a late radar's frame queued after a
    later one keeps the poses that place it (pose forgetting once looked only at the first frame queued)."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers import stripmap as worker_module
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq

    monkeypatch.setattr(worker_module, "POSE_WINDOW_NS", 500_000_000)  # the drive is 3 s; the window 0.5 s
    rec, radar, truth, order = drive
    twin = dataclasses.replace(radar, name="twin")
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    config = StripMapConfig(pixel_m=0.02, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=8)
    worker = StripMapWorker(StripMapWorkerConfig(Rig((radar, twin)), None, config, "tcp://unused:1", "unused.h5",
                                                 catch_up_start_s=10.0), None)
    last = len(times) - 1
    for name, k in ((RADAR, last), ("twin", 0)):  # the late radar's first frame is queued second
        iq = complex_to_iq(adc[k], 1000.0)
        worker.handle(RadarFrameMessage(name, RadarFrame(k, int(times[k]), int(times[k]), True, 0, iq)), live=True)
    t = truth.time_ns
    for a in range(0, t.size, 10):
        s = truth.sample(t[a:a + 10])
        worker.handle(PoseBatch(t[a:a + 10], s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
    assert times[last] - times[0] > 500_000_000  # the first queued frame alone would let the earliest one's poses go
    assert worker.poses[0].time_ns[0] <= times[0]
    assert worker._trajectory().time_ns[0] <= times[0]


@pytest.mark.parametrize("live", [True, False], ids=["live", "draining"])
def test_the_workers_trajectory_holds_only_the_poses_its_queued_frames_need(drive, live):
    """Three minutes of poses before the drive (standing at its start), then the drive's, 400 Hz in 10 ms
    batches: its frames, also under a second radar's name arriving a frame and a half late (the queue is not
    in time order), imaged as frames and poses arrive (poses 40 ms behind), or all at the end with every pose
    held (draining). The map is the one imaged on a trajectory of every pose, to float rounding, and no
    trajectory the worker builds reaches more than two batches back from the oldest frame queued."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import Rig
    from imaging.core.samples import complex_to_iq
    from imaging.core.trajectory import SampledTrajectory

    rec, radar, truth, order = drive
    twin = dataclasses.replace(radar, name="twin")
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    frame_ns, interval_ns = radar.waveform.frame_duration_ns, int(radar.waveform.frame_interval_s * 1e9)
    step, start = 2_500_000, int(truth.time_ns[0])
    standing = np.arange(start - 180 * 10 ** 9, start, step, dtype=np.int64)
    driving = np.arange(start, int(truth.time_ns[-1]), step, dtype=np.int64)
    s, first = truth.sample(driving), truth.sample(driving[:1])
    pose_t = np.concatenate([standing, driving])
    position = np.concatenate([np.repeat(first.position_m, standing.size, axis=0), s.position_m])
    attitude = np.concatenate([np.repeat(first.orientation_xyzw, standing.size, axis=0), s.orientation_xyzw])
    velocity = np.concatenate([np.zeros((standing.size, 3)), s.velocity_mps])
    every_pose = SampledTrajectory(pose_t, position, attitude, velocity)
    events = [(int(pose_t[a + 3]) + 40_000_000, 0, PoseBatch(pose_t[a:a + 4], position[a:a + 4], attitude[a:a + 4],
                                                             velocity[a:a + 4]))
              for a in range(0, pose_t.size - 3, 4)]
    for k in range(len(times)):
        iq = complex_to_iq(adc[k], 1000.0)
        end = int(times[k]) + frame_ns
        events.append((end, 1, RadarFrameMessage(RADAR, RadarFrame(k, int(times[k]), end, True, 0, iq))))
        events.append((end + 3 * interval_ns // 2, 1, RadarFrameMessage("twin", RadarFrame(k, int(times[k]), end, True,
                                                                                            0, iq))))
    events.sort(key=lambda e: (e[0], e[1]))
    config = StripMapConfig(pixel_m=0.02, aperture_m=0.3, range_min_m=1.5, range_max_m=2.5, z_m=0.3, presum=4)

    def run(full: bool):
        worker = StripMapWorker(StripMapWorkerConfig(Rig((radar, twin)), None, config, "tcp://unused:1", "unused.h5",
                                                     catch_up_start_s=100.0), None)
        built, windowed = [], worker._trajectory

        def trajectory():
            oldest = min(int(f.frame_time_ns) for f in worker.frames)
            traj = every_pose if full else windowed()
            built.append((int(traj.time_ns[0]), oldest, traj.time_ns.size, sum(b.time_ns.size for b in worker.poses)))
            return traj

        worker._trajectory = trajectory
        for _, _, message in events:
            worker.handle(message, live=live)
            if live:
                worker._image_ready(budget_s=None)
        worker._image_ready(final=True)
        return worker, built

    reference, _ = run(full=True)
    worker, built = run(full=False)
    assert worker.status.frames_imaged == reference.status.frames_imaged >= 2 * len(times) - 4
    assert worker.status.frames_standing_still == reference.status.frames_standing_still
    assert worker.map.tiles.keys() == reference.map.tiles.keys()
    # float rounding: the time origin's, through the beams' float32 signals (2e-9 of the peak seen, -176 dB)
    assert error_db(worker.map.mosaic()[0], reference.map.mosaic()[0]) < -150
    peak = max(np.abs(t).max() for t in reference.map.tiles.values())
    for key, tile in reference.map.tiles.items():
        np.testing.assert_allclose(worker.map.tiles[key], tile, rtol=0, atol=1e-8 * peak)
    # Each trajectory starts within two batches before the oldest frame queued: of minutes of poses held
    # (draining) or 5 s (live), it holds the drive's (every frame queued) or a few dozen.
    assert all(oldest - 2 * 4 * step <= t0 <= oldest for t0, oldest, _, _ in built)
    assert max(n for _, _, n, _ in built) <= (100 if live else driving.size + 2 * 4)
    assert max(held for _, _, _, held in built) > (2_000 if live else 70_000)
