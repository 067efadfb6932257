"""The odometry worker behind the radar: it thins every radar's scans evenly, never leaves them all out, and
does not hold the filter for a radar gone silent. Frames go in through ``handle`` as the run loop gives them;
what the worker makes comes out on a real bus socket."""

from __future__ import annotations

import collections
import time

import numpy as np
import pytest

from acquisition.bus import BusPublisher, BusSubscriber
from acquisition.messages import Event, ImuBatch, PoseBatch, RadarFrameMessage, decode
from acquisition.workers.odometry import OdometryWorker, OdometryWorkerConfig
from drivers.radar.stream import RadarFrame
from imaging.core.rig import Rig, default_rig
from imaging.io.trajectory_file import read_trajectory

T0 = 1_700_000_000_000_000_000


@pytest.fixture
def worker_and_bus(tmp_path):
    rig = default_rig()
    pub = BusPublisher("tcp://127.0.0.1:*")
    sub = BusSubscriber(pub.endpoint, topics=["points/", "event"])
    time.sleep(0.3)  # the subscription reaches the publisher
    config = OdometryWorkerConfig(rig, None, str(tmp_path / "trajectory.h5"), publish_points=True, radar_silence_s=0.2)
    yield OdometryWorker(config, pub), sub, rig
    sub.close()
    pub.close()


def _received(sub: BusSubscriber) -> list:
    out = []
    while (msg := sub.receive(timeout_ms=200)) is not None:
        out.append(decode(msg))
    return out


def _frames(rig, n_per_radar: int, lag_s: float):
    """Frames of every radar in turn, as the bus interleaves them, each ``lag_s`` after its last datagram."""
    rng = np.random.default_rng(0)
    wf = rig.radars[0].waveform
    iq = rng.integers(-300, 300, (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2), dtype=np.int16)
    for k in range(n_per_radar):
        for r in rig.radars:
            t = T0 + k * int(round(wf.frame_interval_s * 1e9))
            received = time.time_ns() - int(lag_s * 1e9)
            yield RadarFrameMessage(r.name, RadarFrame(k, t, received, True, 0, iq))


def test_a_worker_behind_thins_every_radar_evenly_and_never_leaves_all_out(worker_and_bus):
    worker, sub, rig = worker_and_bus
    every = worker.every[rig.radars[0].name]
    n = 48 * every  # 48 scan candidates per radar
    for lag_s, thinning in ((0.0, 1), (1.0, 4), (120.0, 8)):  # on time; 1 s behind; minutes behind
        worker.seen.clear()
        thinned = worker.rio.stats["scans_thinned_behind"]
        for message in _frames(rig, n, lag_s):
            worker.handle(message, live=True)
        scans = collections.Counter(m.radar for m in _received(sub) if not isinstance(m, Event))
        assert scans == {r.name: 48 // thinning for r in rig.radars}, (lag_s, scans)
        assert worker.rio.stats["scans_thinned_behind"] - thinned == 4 * (48 - 48 // thinning)
    # Each frame moved the radar's watermark, taken or not: the filter need not wait for the ones left out.
    last = T0 + (n - 1) * int(round(rig.radars[0].waveform.frame_interval_s * 1e9))
    assert worker.rio.radar_watermark_ns == last + rig.radars[0].waveform.frame_duration_ns // 2


def test_a_radar_gone_silent_does_not_hold_the_odometry(worker_and_bus):
    worker, sub, rig = worker_and_bus
    for message in _frames(rig, 2, 0.0):
        worker.handle(message, live=True)
    imu = ImuBatch(np.array([T0], np.int64), np.zeros((1, 3)), np.array([[0.0, 0.0, 9.81]]), np.zeros(1, np.uint32),
                   np.array([T0], np.int64))
    worker.handle(imu, live=True)
    assert worker.rio.radar_watermark_ns is not None  # frames came just now: the filter waits for the radars
    first, *others = rig.radars
    time.sleep(0.3)  # longer than radar_silence_s
    for message in _frames(Rig(tuple(others)), 3, 0.0):  # all but one radar still send
        worker.handle(message, live=True)
    worker.handle(imu, live=True)
    events = [m.message for m in _received(sub) if isinstance(m, Event)]
    assert len(events) == 1 and events[0].startswith(f"no frame of radar {first.name} for ")
    assert events[0].endswith("odometry no longer waits for it")
    newest = T0 + 2 * int(round(first.waveform.frame_interval_s * 1e9)) + first.waveform.frame_duration_ns // 2
    assert worker.rio.radar_watermark_ns == newest  # the silent radar no longer holds the filter back
    time.sleep(0.3)
    worker.handle(imu, live=True)  # now none sends: the filter waits for none
    assert worker.rio.radar_watermark_ns is None
    assert len([m for m in _received(sub) if isinstance(m, Event)]) == len(others)
    for message in _frames(rig, 1, 0.0):  # the radars back: the filter waits for them again
        worker.handle(message, live=True)
    assert worker.rio.radar_watermark_ns == T0 + first.waveform.frame_duration_ns // 2


def test_no_radar_at_all_releases_the_odometry_after_the_silence(worker_and_bus):
    worker, sub, rig = worker_and_bus
    imu = ImuBatch(np.array([T0], np.int64), np.zeros((1, 3)), np.array([[0.0, 0.0, 9.81]]), np.zeros(1, np.uint32),
                   np.array([T0], np.int64))
    worker.handle(imu, live=True)
    assert worker.rio.radar_watermark_ns is not None  # waits for the first radar data
    time.sleep(0.3)
    worker.handle(imu, live=True)
    assert worker.rio.radar_watermark_ns is None
    events = [m.message for m in _received(sub) if isinstance(m, Event)]
    assert len(events) == 1 and "IMU alone" in events[0]


@pytest.mark.parametrize("hurried, expected", [("never", 0), ("before finish", 1), ("after finish", 0),
                                               ("instead of finish", 1)])
def test_the_trajectory_file_says_whether_the_hurry_left_scans_out(worker_and_bus, hurried, expected):
    """Hurried before ``finish`` (the daemon's SIGTERM after its stop timeout), the filter's last scans are left
    out and the file's ``stop_cut_short`` is 1; so it is when finish never ran (hurried while warming up, then
    an error). Hurried once finish is done (while writing), nothing was left out: 0, as without a hurry."""
    worker, sub, rig = worker_and_bus
    n = 30
    t = T0 + np.arange(n, dtype=np.int64) * 10_000_000
    worker._publish(PoseBatch(t, np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3))))
    worker.hurried = hurried == "before finish"
    if hurried != "instead of finish":
        worker.finish()
    worker.hurried = hurried != "never"
    worker.write_products()
    back = read_trajectory(worker.config.trajectory_path)
    assert back.stop_cut_short == expected and back.time_ns.size == n
