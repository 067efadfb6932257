"""The live map refocuses finished tiles after its imaging, not within it: a map that refocuses later makes the
same map; the worker's imaging calls never run a refocus, each step refocuses one tile at least and more only
within its budget; its BLAS runs on its own threads; and its stop is bounded, the map written with what it
left undone counted."""

import dataclasses

import numpy as np
import pytest
from conftest import RADAR, point_pass

from imaging.core.geometry import Vibration
from imaging.io.recording import Recording
from imaging.sim.simulator import simulate_recording
from imaging.stripmap import StripMap, StripMapConfig

#: The map of tests/test_stripmap.py's refocus test: entropy refocus on a vibrating pass, a target whose tile
#: refocus changes.
CONFIG = StripMapConfig(presum=4, refocus="entropy")


@pytest.fixture(autouse=True)
def blas_on_one_thread():
    """BLAS on one thread, as in the map worker: OpenBLAS's own threads make the refocus 27x dearer in CPU on a
    loaded machine (benchmarks/refocus_threads.py)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        yield


@pytest.fixture(scope="module")
def vibrating(tmp_path_factory):
    """The left-front radar passing a point target 2 m off, 1.2 m at 0.4 m/s, its mount vibrating."""
    path = tmp_path_factory.mktemp("refocus_later") / "vibrating.h5"
    scene = point_pass(0.4, duration_s=3.0, origin=(0.32, 0.0), snr_db=10.0, vibration=Vibration(3.83, 0.319e-3, 0.7), seed=4)
    simulate_recording(scene, path)
    rec = Recording(path)
    yield rec, rec.radar(RADAR), rec.truth(), rec.tdm_tx_order(RADAR)
    rec.close()


def test_a_map_refocusing_later_names_each_finished_tile_once_and_makes_the_same_map(vibrating):
    """Frame by frame, the map that refocuses inside ``add_frame`` and the one that names the finished tiles
    (``refocus_later``) and has them refocused after the call make the same tiles and estimates; the later
    map refocuses nothing within a call, and a tile is named once until it is refocused."""
    rec, radar, truth, order = vibrating
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    inline, later = StripMap(CONFIG), StripMap(CONFIG, refocus_later=True)
    refocused_inline, refocused_later, named = [], [], []
    for k in range(adc.shape[0]):
        refocused_inline += inline.add_frame(radar, order, adc[k], int(times[k]), truth).refocused
        footprint = later.add_frame(radar, order, adc[k], int(times[k]), truth)
        assert footprint.refocused == []
        named += footprint.finished
        refocused_later += later.refocus_tiles(footprint.finished)
    assert len(named) == len(set(named)) > 0
    assert refocused_later == refocused_inline and len(refocused_inline) >= 1
    assert later.tiles.keys() == inline.tiles.keys()
    for key, tile in inline.tiles.items():
        np.testing.assert_array_equal(later.tiles[key], tile)
    for key in refocused_inline:
        np.testing.assert_array_equal(later.refocus_results[key].track_error.displacement_m,
                                      inline.refocus_results[key].track_error.displacement_m)


def test_a_tile_awaiting_its_refocus_is_named_once_however_many_frames_miss_it(vibrating):
    """All frames in before any refocus: every tile named at most once, and the tiles named and those still
    being imaged at the end are every tile holding group images."""
    rec, radar, truth, order = vibrating
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    later = StripMap(CONFIG, refocus_later=True)
    named = []
    for k in range(adc.shape[0]):
        named += later.add_frame(radar, order, adc[k], int(times[k]), truth).finished
    assert len(named) == len(set(named)) > 0
    held = later.tiles_to_refocus
    assert held >= len(named)
    later.refocus_tiles(named)
    assert later.tiles_to_refocus == held - len(named)  # the rest are still being imaged


def make_worker(vibrating, tmp_path=None):
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from imaging.core.rig import Rig

    _, radar, _, _ = vibrating

    class Sent(list):
        send = list.append

    path = str(tmp_path / "map.h5") if tmp_path is not None else "unused.h5"
    return StripMapWorker(StripMapWorkerConfig(Rig((radar,)), None, CONFIG, "tcp://unused:1", path), Sent())


def feed(worker, vibrating, frames):
    """Frames ``frames`` of the pass into the worker as bus messages, with the true poses covering them."""
    from acquisition.messages import PoseBatch, RadarFrameMessage
    from drivers.radar.stream import RadarFrame
    from imaging.core.samples import complex_to_iq

    rec, _, truth, _ = vibrating
    adc, times = rec.adc(RADAR), rec.frame_time_ns(RADAR)
    for k in frames:
        t = truth.time_ns[(truth.time_ns > (worker.poses[-1].time_ns[-1] if worker.poses else 0))
                          & (truth.time_ns <= times[k] + 200_000_000)]
        if t.size:
            s = truth.sample(t)
            worker.handle(PoseBatch(t, s.position_m, s.orientation_xyzw, s.velocity_mps), live=True)
        worker.handle(RadarFrameMessage(RADAR, RadarFrame(k, int(times[k]), int(times[k]), True, 0,
                                                          complex_to_iq(adc[k], 1000.0))), live=True)


def test_the_worker_refocuses_after_its_imaging_one_job_a_step_within_its_budget(vibrating, monkeypatch):
    """The worker's imaging calls never run a tile's refocus (the map names the tiles; the worker refocuses them
    after the step's imaging), and with no time left in the budget a step refocuses exactly one tile. The
    tiles passed are refocused while the run goes on, the time counted (map/status, health counters)."""
    from acquisition.workers import stripmap as worker_module
    from imaging.stripmap import refocus as refocus_module

    monkeypatch.setattr(worker_module, "REFOCUS_STEP_BUDGET_S", 0.0)
    worker = make_worker(vibrating)
    inside, refocused_inside = [False], []
    add_frames, refocus_tile = worker.map.add_frames, refocus_module.TileRefocus.refocus_tile

    def imaging(*args, **kwargs):
        inside[0] = True
        try:
            return add_frames(*args, **kwargs)
        finally:
            inside[0] = False

    def refocusing(self, *args, **kwargs):
        refocused_inside.append(inside[0])
        return refocus_tile(self, *args, **kwargs)

    monkeypatch.setattr(worker.map, "add_frames", imaging)
    monkeypatch.setattr(refocus_module.TileRefocus, "refocus_tile", refocusing)
    rec = vibrating[0]
    tiles_run = []
    for k in range(rec.adc(RADAR).shape[0]):
        feed(worker, vibrating, [k])
        worker._image_ready(budget_s=None)
        awaiting = worker.status.tiles_awaiting_refocus
        worker._refocus_ready(budget_s=worker_module.REFOCUS_STEP_BUDGET_S)
        tiles_run.append(awaiting - worker.status.tiles_awaiting_refocus)
    status = worker.status
    assert refocused_inside and not any(refocused_inside)  # every refocus ran after an imaging call, none within
    assert max(tiles_run) == 1  # one tile a step with no budget left
    assert status.tiles_refocused >= 1 and status.refocus_s > 0 and status.refocus_max_s > 0
    assert status.tiles_awaiting_refocus == sum(len(job.keys) for job in worker.refocus_jobs)
    counters = worker.counters()
    assert counters["tiles_refocused"] == status.tiles_refocused and counters["refocus_ms"] == round(status.refocus_s * 1e3)


def test_the_worker_s_blas_runs_on_its_own_threads(vibrating):
    """After warming up, numpy's and scipy's BLAS run on the worker's ``threads`` (one), not a thread per core:
    on a loaded machine OpenBLAS's threads made the refocus 27x dearer in CPU (benchmarks/refocus_threads.py)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    worker = make_worker(vibrating)
    with threadpool_limits(2, user_api="blas"):  # a thread per core of this two-core machine; restored afterwards
        assert any(i["num_threads"] == 2 for i in threadpool_info() if i["user_api"] == "blas")
        worker.warm_up()
        blas = [i for i in threadpool_info() if i["user_api"] == "blas"]
        assert len(blas) >= 2  # numpy's and scipy's (imported for the refocus before the limit)
        assert all(i["num_threads"] == worker.config.threads == 1 for i in blas)


def test_the_worker_s_stop_is_bounded_and_it_writes_the_map_saying_what_it_left(vibrating, tmp_path):
    """The stop's imaging and refocus run for at most ``finish_max_s`` (here none left): the frames still
    queued are counted as dropped, the tiles not refocused as awaiting, and the map is written with both."""
    from imaging.io.image_file import read_image

    rec = vibrating[0]
    n = rec.adc(RADAR).shape[0]
    worker = make_worker(vibrating, tmp_path)
    feed(worker, vibrating, range(n - 10))
    worker._image_ready(budget_s=None)  # imaged, the finished tiles' jobs queued and not run
    assert worker.refocus_jobs and worker.status.tiles_refocused == 0
    feed(worker, vibrating, range(n - 10, n))
    worker.finish_max_s = 0.0
    worker.finish()
    status = worker.status
    assert status.frames_dropped_behind == 10 and not worker.frames
    assert status.tiles_refocused == 0 and status.tiles_awaiting_refocus == worker.map.tiles_to_refocus > 0
    worker.write_products()
    attrs = read_image(tmp_path / "map.h5").attrs
    assert attrs["frames_dropped_behind"] == 10 and attrs["tiles_awaiting_refocus"] == status.tiles_awaiting_refocus
    assert attrs["stop_cut_short"] == 0  # its own budget ran out: not hurried by the daemon
    # a worker 2.4 s behind thins its frames (the catch-up ladder): every frame is accounted for
    assert attrs["frames_imaged"] + attrs["frames_standing_still"] + attrs["frames_thinned"] + 10 == n


def test_a_hurried_worker_drops_its_queue_skips_the_refocus_and_writes_the_map_saying_so(vibrating, tmp_path):
    """Hurried (the daemon's SIGTERM after its stop timeout), the worker's finish images nothing more however
    much budget it has: the queued frames are dropped, no tile is refocused, every frame is accounted for and
    the file says it was cut short."""
    from imaging.io.image_file import read_image

    rec = vibrating[0]
    n = rec.adc(RADAR).shape[0]
    worker = make_worker(vibrating, tmp_path)
    feed(worker, vibrating, range(n - 10))
    worker._image_ready(budget_s=None)
    imaged = worker.status.frames_imaged
    feed(worker, vibrating, range(n - 10, n))
    worker.hurried = True
    worker._image_ready(budget_s=None)  # live imaging takes nothing more either
    worker._refocus_ready(budget_s=None)
    assert worker.status.frames_imaged == imaged and len(worker.frames) == 10
    assert worker.finish_max_s == 30.0  # the budget was there: the hurry, not the budget, cut it short
    worker.finish()
    worker.write_products()
    attrs = read_image(tmp_path / "map.h5").attrs
    assert attrs["stop_cut_short"] == 1 and attrs["frames_dropped_behind"] == 10 and attrs["tiles_refocused"] == 0
    assert attrs["tiles_awaiting_refocus"] == worker.map.tiles_to_refocus > 0
    assert attrs["frames_imaged"] + attrs["frames_standing_still"] + attrs["frames_thinned"] + 10 == n


def test_the_stop_budgets_fit_the_daemon_s_timeout():
    """The map's own budgets (10 s draining, 30 s finishing, 5 s kept for writing) fit in the daemon's 60 s
    and stay; a shorter timeout scales draining and finishing alike to what is left after writing; none left: 0."""
    from acquisition.workers import Worker, stop_budgets, stop_needs_s
    from acquisition.workers.stripmap import StripMapWorker

    assert stop_needs_s(StripMapWorker) == 45.0
    assert stop_budgets(StripMapWorker, 60.0) == (10.0, 30.0)
    assert stop_budgets(StripMapWorker, 25.0) == pytest.approx((5.0, 15.0))
    assert stop_budgets(StripMapWorker, 5.0) == (0.0, 0.0)
    assert stop_budgets(Worker, 1.0) == (0.0, 0.0) and stop_budgets(Worker, 60.0) == (10.0, 0.0)
