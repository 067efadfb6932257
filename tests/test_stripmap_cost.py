"""The map's cheaper paths per frame give the numbers of the paths they replace: the footprint masks of many
tiles in one kernel are numpy's pixel for pixel, the tiles' pixel centres made once a frame are
``tile_points``', and a frame's beams read at its masked pixels are its beams read at their list
(benchmarks/stripmap_capacity.py measures what each saves; the worker's trajectory window is tested with
the worker, in test_stripmap.py)."""

import dataclasses
import math

import numpy as np
import pytest

from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns, SampledTrajectory
from imaging.stripmap import StripMap, StripMapConfig
from imaging.stripmap.footprint import footprint_mask, footprint_masks


@pytest.mark.parametrize("frames", [1, 3])
def test_the_footprint_masks_of_many_tiles_are_numpys_pixel_for_pixel(frames):
    config = StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=4.0, beam_half_angle_deg=45.0)
    sm = StripMap(config)
    rng = np.random.default_rng(5)
    centres = rng.uniform(-0.5, 0.5, (frames, 2))
    angle = 0.7 + 0.02 * np.arange(frames)  # diagonal: a box of tiles the footprint crosses
    looks = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    keys = sm.footprint_tiles(centres, looks)
    assert len(keys) > 15  # a footprint's box of tiles, some taken in part, some not at all
    x = np.array([sm.tile_points(k)[0] for k in keys])
    y = np.array([sm.tile_points(k)[1] for k in keys])
    got = footprint_masks(config, x, y, centres, looks)
    assert got.shape == (len(keys), frames, 64, 64)
    partial = 0
    for t in range(len(keys)):
        want = footprint_mask(config, x[t][None, :], y[t][:, None], centres, looks)
        assert np.array_equal(got[t], want)
        partial += bool(want.any() and not want.all())
    assert partial >= 5 and got.any(axis=(1, 2, 3)).sum() < len(keys)


@pytest.mark.parametrize("frames", [1, 3])
def test_the_tiles_a_frame_takes_carry_their_tile_points_and_masks(frames):
    """``_footprints`` makes every tile's pixel centres at once: ``tile_points``' numbers bit for bit, also
    at negative keys, with each tile's masks as numpy makes them; the tiles of the box no frame takes are
    left out, and a full map refuses new tiles, counted."""
    config = StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=4.0, beam_half_angle_deg=45.0)
    sm = StripMap(config)
    rng = np.random.default_rng(6)
    centres = rng.uniform(-0.5, 0.5, (frames, 2))
    angle = 2.3 + 0.02 * np.arange(frames)  # towards -x, +y: negative and positive keys
    looks = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    box = sm.footprint_tiles(centres, looks)
    taken = sm._footprints(centres, looks)
    assert len(box) > len(taken.keys) > 5 and min(k[0] for k in taken.keys) < 0 < max(k[1] for k in taken.keys)
    assert taken.masks.shape == (len(taken.keys), frames, 64, 64) and taken.refused == 0
    for key, mask, x, y in zip(taken.keys, taken.masks, taken.x_m, taken.y_m):
        want_x, want_y = sm.tile_points(key)
        assert np.array_equal(x, want_x) and np.array_equal(y, want_y)
        assert np.array_equal(mask, footprint_mask(config, want_x[None, :], want_y[:, None], centres, looks))
    assert all(not footprint_mask(config, sm.tile_points(k)[0][None, :], sm.tile_points(k)[1][:, None], centres,
                                  looks).any() for k in set(box) - set(taken.keys))
    full = StripMap(dataclasses.replace(config, max_tiles=3))
    some = full._footprints(centres, looks)
    assert some.keys == taken.keys[:3] and some.refused == len(taken.keys) - 3 == full.tiles_refused
    assert np.array_equal(some.x_m, taken.x_m[:3]) and np.array_equal(some.masks, taken.masks[:3])


@pytest.mark.parametrize("dtype", [np.complex128, np.complex64])
def test_values_added_to_tiles_are_numpys_masked_additions_bit_for_bit(dtype):
    """``_add_to_tiles`` (a kernel per tile) sums what numpy's ``tile[pixels] += v`` sums, in the same order:
    into tiles already holding values and new ones, two value lists (refocusing's groups) one after the
    other, complex64 values taken to complex128 as numpy takes them."""
    rng = np.random.default_rng(7)
    sm = StripMap(StripMapConfig())
    n = sm.config.tile_px
    touched = [(0, 0), (1, 0), (-2, 5), (3, 3)]
    pixels = [rng.random((n, n)) < p for p in (0.1, 0.5, 1.0, 0.0)]
    where = [(m, int(np.count_nonzero(m))) for m in pixels]
    total = sum(c for _, c in where)
    values = [(rng.standard_normal(total) + 1j * rng.standard_normal(total)).astype(dtype) for _ in range(2)]
    for key in touched[:2]:
        sm._tile(key)[:] = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    want = {key: tile.copy() for key, tile in sm.tiles.items()}
    for v in values:
        start = 0
        for key, (m, c) in zip(touched, where):
            want.setdefault(key, np.zeros((n, n), np.complex128))[m] += v[start:start + c]
            start += c
    sm._add_to_tiles(touched, where, values)
    assert sm.tiles.keys() == want.keys()
    for key, tile in want.items():
        assert sm.tiles[key].dtype == np.complex128 and np.array_equal(sm.tiles[key], tile)
    assert np.count_nonzero(sm.tiles[(3, 3)]) == 0 and np.count_nonzero(sm.tiles[(-2, 5)]) == n * n


def test_one_frame_read_at_its_masked_pixels_is_the_frame_read_at_its_pixel_list():
    """A frame as the live map takes it one at a time ("polar"): its beams read straight at the pixels its
    tile masks take give the numbers of its beams read at the list of those pixels (``_polar_takers``)."""
    from imaging.core.trajectory import StraightLine

    rig = default_rig()
    radar = rig.radars[0]
    wf = radar.waveform
    sm = StripMap(StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=4.0, presum=4))
    t0 = 10 ** 9
    drive = StraightLine(speed_mps=0.4, t0_ns=t0)
    noise = np.random.default_rng(2).integers(-512, 512, (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2),
                                              dtype=np.int16)
    samples, tx_m, rx_m, look, _ = sm.frames_profiles(radar, radar.waveform.tdm_tx_order(), [noise], [t0 + 10 ** 8],
                                                      drive, compress=False)
    centres = (0.5 * (tx_m + rx_m))[:, :2].mean(axis=0, keepdims=True)
    looks = look.mean(axis=0, keepdims=True)
    looks /= np.linalg.norm(looks, axis=1, keepdims=True)
    taken = sm._footprints(centres, looks)
    assert len(taken.keys) > 5
    pts = []
    for key, mask in zip(taken.keys, taken.masks):
        x, y = sm.tile_points(key)
        iy, ix = np.nonzero(mask[0])
        pts.append(np.stack([x[ix], y[iy], np.full(iy.size, sm.config.z_m)], axis=1))
    pts = np.concatenate(pts)
    want = sm._polar_takers(radar, samples, tx_m, rx_m, looks, pts, None, samples.shape[0])
    got = sm._polar_masked(radar, samples, tx_m, rx_m, looks[0], taken)
    assert got.shape == want.shape and np.count_nonzero(want) > 0.9 * want.size
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())


def test_a_sampled_trajectorys_velocity_alone_is_its_samples():
    """The map's moving check asks only the velocity: the same numbers as a whole sample's, clipped the same
    way before the first pose and after the last."""
    drive = PathWithTurns(segments=(("straight", 0.3), ("arc", 0.5, 120.0)), speed_mps=0.4, accel_mps2=0.5,
                          start_delay_s=0.5, t0_ns=10 ** 9)
    t = 10 ** 9 + np.arange(0, 4_000_000_000, 2_500_000, dtype=np.int64)
    s = drive.sample(t)
    traj = SampledTrajectory(t, s.position_m, s.orientation_xyzw, s.velocity_mps)
    asked = np.concatenate([[t[0] - 10 ** 8], np.random.default_rng(4).integers(t[0], t[-1], 500), [t[-1] + 10 ** 8]])
    assert np.array_equal(traj.velocity(asked), traj.sample(asked).velocity_mps)
    assert np.array_equal(drive.velocity(asked), drive.sample(asked).velocity_mps)
    assert np.ptp(traj.velocity(asked)[:, 1]) > 0.3  # the turn: the velocity's direction changes
