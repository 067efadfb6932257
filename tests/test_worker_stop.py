"""A worker late at the stop writes what it has: the real daemon (drivers, recorder, odometry and strip-map
workers as processes, ZeroMQ between them) fed by emulated hardware replaying a short simulated drive, its
map made late by real work (a per-frame cost of about a second of CPU, eight frames a call, no catch-up) and
given a stop timeout shorter than one call. The daemon hurries it with SIGTERM; it leaves its queue, writes
the map with what its tiles hold, and exits before the second grace runs out: nothing is killed. The odometry
is late too (its last scans held until the hurry); its trajectory file says it was cut short."""

import dataclasses
import logging
import multiprocessing as mp
import threading
import time

import pytest
from conftest import send_frame_and_poses

from acquisition.workers.odometry import OdometryWorker
from imaging.core.rig import default_rig
from imaging.sim.scene import scene_from_dict
from imaging.stripmap import StripMapConfig

RADAR = "left_front"
#: About 0.8-1.4 s of CPU a frame on this VM (2 mm less than the default's 1 cm pixels, a 1 m aperture, the
#: direct kernel, no pre-summing): eight frames a call, so one call outlasts STOP_TIMEOUT_S in CPU alone.
MAP = StripMapConfig(pixel_m=0.0035, aperture_m=1.0, range_max_m=4.0, presum=1, algorithm="direct")
STOP_TIMEOUT_S = 6.0
#: The second grace: long enough for the call in progress on a loaded machine (the hurry waits for it).
HURRY_TIMEOUT_S = 90.0


class LateOdometryWorker(OdometryWorker):
    """The odometry with a filter whose last scans outlast the daemon's stop timeout: its ``finish`` holds them
    until the hurry (SIGTERM) comes, then goes on as the real one does, hurried: the scans left out."""

    def finish(self) -> None:
        until = time.monotonic() + STOP_TIMEOUT_S + HURRY_TIMEOUT_S  # the daemon kills it by then anyway
        while not self.hurried and time.monotonic() < until:
            time.sleep(0.01)
        super().finish()


def short_drive(path):
    """1.5 s standing (the odometry's start), then 1.2 m straight at 0.4 m/s past point targets and clutter."""
    from imaging.sim.simulator import simulate_recording

    scene = scene_from_dict({
        "name": "worker_stop", "duration_s": 1.5 + 1.2 / 0.4 + 0.5, "imu": True, "snr_db": 10.0, "seed": 3,
        "adc_counts_per_unit": 1000.0, "radars": [RADAR],
        "trajectory": {"kind": "path", "start_m": [0.0, 0.0, 0.0], "speed_mps": 0.4, "accel_mps2": 0.5,
                       "start_delay_s": 1.5, "segments": [["straight", 1.2]]},
        "target": [{"kind": "point", "position_m": [x, 1.6, 0.3], "amplitude": 1.0} for x in (0.3, 0.9)],
        "clutter": [{"count": 14, "box_m": [[-1.0, 3.0], [2.6, 4.5], [0.0, 0.8]], "amplitude": 0.6, "seed": 1}],
    })
    simulate_recording(scene, path, overwrite=True)


def _emulate(sim_path, targets, imu_link, held):
    from acquisition.replay import replay

    replay(sim_path, targets, imu_link, 1.0, start_delay_s=1.0, held=held)


def test_a_map_worker_late_at_the_stop_is_hurried_and_writes_its_map_with_every_frame_counted(tmp_path, caplog):
    from acquisition.daemon import Setup, record
    from acquisition.replay import DevicesHeld
    from acquisition.workers import WorkerSpec
    from acquisition.workers.odometry import OdometryWorkerConfig
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from drivers.radar.link import RadarLink
    from imaging.io.image_file import read_image
    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import read_trajectory

    sim_path = tmp_path / "drive.h5"
    short_drive(sim_path)
    rig = default_rig()
    ctx = mp.get_context("spawn")
    bound = {RADAR: ctx.Value("i", 0)}
    imu_link = tmp_path / "imu_tty"
    trajectory_path = tmp_path / "trajectory.h5"
    rio = WorkerSpec("rio", LateOdometryWorker, OdometryWorkerConfig(rig, [RADAR], str(trajectory_path)), upstream=True)
    map_path = tmp_path / "stripmap.h5"
    # No catch-up (no more pre-summing, no RX sums, no thinning): every frame costs what the map's config says.
    stripmap = WorkerSpec("stripmap", StripMapWorker, StripMapWorkerConfig(
        rig, [RADAR], MAP, rio.endpoint, str(map_path), catch_up_start_s=1e9, max_thinning=1, max_batch_frames=8))
    setup = Setup(rig, [RadarLink(RADAR, 0)], str(imu_link), None, health_interval_s=0.5, bound_ports=bound,
                  workers=[rio, stripmap], worker_stop_timeout_s=STOP_TIMEOUT_S, worker_hurry_timeout_s=HURRY_TIMEOUT_S)
    held = DevicesHeld(ctx.Event(), ctx.Event(), ctx.Event())
    emulator = ctx.Process(target=_emulate, args=(str(sim_path), {RADAR: ("127.0.0.1", bound[RADAR])}, str(imu_link), held))
    emulator.start()
    deadline = time.monotonic() + 60
    while not imu_link.is_symlink() and time.monotonic() < deadline:
        time.sleep(0.05)
    done = threading.Event()
    imaging = []

    def on_health(report):
        state = report.workers.get("stripmap")
        if report.workers and all(w.warm for w in report.workers.values()):
            held.go.set()
        if state is not None and state.counters.get("frames_imaged", 0):
            imaging.append(state.counters)
        # Stopped once the drive is sent and recorded, the map well behind it (at work on its backlog).
        if held.sent.is_set() and not any(report.frames_per_s.values()) and imaging:
            done.set()

    recording_path = tmp_path / "recording.h5"
    caplog.set_level(logging.WARNING, logger="sarbot")
    try:
        t0 = time.monotonic()
        record(setup, tmp_path, 300, until=done, on_health=on_health, path=recording_path)
        stop_s = time.monotonic() - t0
    finally:
        held.release.set()
        emulator.join(30)
    log = caplog.text
    assert done.is_set(), f"the map imaged nothing live, or the drive never ended: {imaging[-1:]}\n{log}"
    # The daemon said what happened, in its log and in the recording's /events: hurried, stopped, not killed.
    assert "stripmap still running" in log and "SIGTERM: it writes what it has" in log, log
    assert "stripmap stopped" in log and "killed" not in log, log
    assert "rio still running" in log and "rio stopped" in log, log
    assert "stripmap: its stop takes up to 45 s" in log  # its budgets cut to fit the 6 s
    with Recording(recording_path) as rec:
        events = [(source, level, message) for _, source, level, message in rec.events()]
        n_recorded = rec.n_frames(RADAR)
    with Recording(sim_path) as sim:
        n_sent = sim.n_frames(RADAR)
    assert ("stripmap", "warning") in {(s, lv) for s, lv, m in events if "SIGTERM: it writes what it has" in m}
    assert any(s == "stripmap" and "stopped" in m and "exit code 0" in m for s, _, m in events), events
    # The recording is complete: every frame the emulated radar sent.
    assert n_recorded == n_sent
    # The map is there, readable, says it was cut short, and accounts for every frame it was sent.
    img = read_image(map_path)
    a = img.attrs
    assert a["stop_cut_short"] == 1 and img.image.size and map_path.with_suffix(".png").exists()
    assert a["frames_imaged"] > 0 and a["frames_dropped_behind"] > 0, dict(a)
    counted = sum(int(a[k]) for k in ("frames_imaged", "frames_standing_still", "frames_skipped_invalid",
                                      "frames_dropped_behind", "frames_lost_on_bus", "frames_beyond_odometry",
                                      "frames_off_map", "frames_thinned"))
    assert counted == n_recorded, dict(a)
    # The odometry's trajectory is there, with the poses it had, and says it was cut short.
    traj = read_trajectory(trajectory_path)
    assert traj.stop_cut_short == 1 and traj.time_ns.size > 50, traj.time_ns.size
    print(f"stop and write {stop_s:.1f} s after the start; map {dict(a)}; {traj.time_ns.size} poses")


def test_sigterm_without_a_stop_makes_a_worker_write_its_map_and_exit(tmp_path):
    """SIGTERM alone (the kernel's when the daemon dies, ``die_with_parent``; the stop event never set): the
    strip-map worker's process leaves its live loop, writes the map of what it imaged, says it was cut short,
    and exits 0, instead of dying with nothing written as it did."""
    from conftest import RADAR as PASS_RADAR
    from conftest import point_pass

    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.messages import MapStatus, WorkerState
    from acquisition.processes import free_tcp_endpoint
    from acquisition.workers import WorkerSpec, worker_process
    from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig
    from imaging.core.rig import Rig
    from imaging.io.image_file import read_image
    from imaging.io.recording import Recording
    from imaging.sim.simulator import simulate_recording

    sim = tmp_path / "pass.h5"
    simulate_recording(point_pass(0.4, duration_s=1.5), sim)
    with Recording(sim) as rec:
        radar, truth = rec.radar(PASS_RADAR), rec.truth()
        times, iq = rec.frame_time_ns(PASS_RADAR), rec.file[f"radar/{PASS_RADAR}/adc"][:]
    driver_ep, pose_ep, out_ep = free_tcp_endpoint(), free_tcp_endpoint(), free_tcp_endpoint()
    frames_pub, poses_pub = BusPublisher(driver_ep), BusPublisher(pose_ep)
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    map_path = tmp_path / "map.h5"
    spec = WorkerSpec("stripmap", StripMapWorker, StripMapWorkerConfig(
        Rig((radar,)), None, StripMapConfig(presum=4), pose_ep, str(map_path)), out_ep)
    worker = ctx.Process(target=worker_process, args=(spec, [driver_ep], stop, (), 60.0))
    worker.start()
    sub = BusSubscriber(out_ep, topics=["map/", WorkerState.TOPIC])
    imaged, deadline = 0, time.monotonic() + 300
    while time.monotonic() < deadline:  # warm before anything is sent (its subscription is up)
        m = sub.receive(timeout_ms=300)
        if m is not None and m.topic == WorkerState.TOPIC and WorkerState.from_message(m).warm:
            break
    n = len(times)
    for k in range(n):
        send_frame_and_poses(frames_pub, poses_pub, PASS_RADAR, k, iq, times, truth)
        time.sleep(0.02)
    while time.monotonic() < deadline and imaged == 0:  # some of it in the map
        m = sub.receive(timeout_ms=300)
        if m is not None and m.topic == MapStatus.TOPIC:
            imaged = MapStatus.from_message(m).frames_imaged
    worker.terminate()  # SIGTERM; the stop event is never set
    worker.join(120)
    frames_pub.close(), poses_pub.close(), sub.close()
    assert worker.exitcode == 0 and not stop.is_set()
    a = read_image(map_path).attrs
    assert a["stop_cut_short"] == 1 and a["frames_imaged"] >= imaged > 0
    counted = sum(int(a[k]) for k in ("frames_imaged", "frames_standing_still", "frames_skipped_invalid",
                                      "frames_dropped_behind", "frames_lost_on_bus", "frames_beyond_odometry",
                                      "frames_off_map", "frames_thinned"))
    assert counted == n, dict(a)


def _deaf_to_sigterm():
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    time.sleep(60)


def _hurries_on_sigterm():
    import signal
    import sys

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    time.sleep(60)


def test_the_daemon_kills_a_worker_only_after_sigterm_and_its_grace_and_says_each_step():
    """``stop_processes`` with real processes: a worker that exits on SIGTERM is hurried and not killed, one deaf
    to it is killed once ``worker_hurry_timeout_s`` has passed after it; each step is an /events line; a negative
    timeout is refused, naming the field."""
    from acquisition.daemon import Setup, check_stop_timeouts, stop_processes
    from acquisition.processes import ProcessSpec
    from imaging.core.errors import SarbotError

    ctx = mp.get_context("fork")
    procs = {"quick": ctx.Process(target=_hurries_on_sigterm), "deaf": ctx.Process(target=_deaf_to_sigterm)}
    for p in procs.values():
        p.start()
    specs = {role: ProcessSpec(role, None, (), worker=True) for role in procs}
    setup = Setup(default_rig(), [], worker_stop_timeout_s=0.5, worker_hurry_timeout_s=1.0)
    events = []
    t0 = time.monotonic()
    stop_processes(procs, specs, setup, t0, lambda t, source, level, message: events.append((source, level, message)))
    took = time.monotonic() - t0
    assert not any(p.is_alive() for p in procs.values())
    assert procs["quick"].exitcode == 0 and procs["deaf"].exitcode == -9
    assert [(s, lv) for s, lv, _ in events].count(("quick", "warning")) == 2  # hurried, stopped
    assert ("deaf", "error") in [(s, lv) for s, lv, _ in events]
    assert any(s == "deaf" and "did not stop 1 s after SIGTERM either; killed" in m for s, _, m in events)
    assert took >= 1.5  # a lower bound (load only makes it later): no kill before the stop timeout and the grace
    with pytest.raises(SarbotError, match="worker_hurry_timeout_s"):
        check_stop_timeouts(dataclasses.replace(setup, worker_hurry_timeout_s=-1.0))


def test_a_stop_longer_than_the_units_timeout_stop_sec_is_warned_of_at_the_start(monkeypatch, caplog):
    """``check_stop_timeouts`` with the unit's TimeoutStopSec as the unit passes it on (SARBOT_TIMEOUT_STOP_S):
    the defaults (60 s + 15 s + 5 s for a kill) fit in the unit's 90 s; a longer stop is one warning naming both
    timeouts and the unit's; without the variable, or without workers, nothing is said of the unit; a value
    that is no number of seconds is said, and the rest of the check still runs."""
    from acquisition.daemon import Setup, check_stop_timeouts, stop_lasts_s
    from acquisition.workers import WorkerSpec
    from acquisition.workers.odometry import OdometryWorkerConfig

    rio = WorkerSpec("rio", OdometryWorker, OdometryWorkerConfig(default_rig(), None, "t.h5"), endpoint="ipc:///x")
    setup = Setup(default_rig(), [], workers=[rio])
    assert stop_lasts_s(setup) == 80.0

    def said(unit: str | None, **fields) -> list[str]:
        if unit is None:
            monkeypatch.delenv("SARBOT_TIMEOUT_STOP_S", raising=False)
        else:
            monkeypatch.setenv("SARBOT_TIMEOUT_STOP_S", unit)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="sarbot"):
            check_stop_timeouts(dataclasses.replace(setup, **fields))
        return [r.getMessage() for r in caplog.records]

    assert said("90") == [] and said("80") == [] and said("infinity", worker_stop_timeout_s=1e6) == []
    warned = said("90", worker_stop_timeout_s=75.0)
    assert len(warned) == 1 and warned[0].startswith("the stop may last 95 s (worker_stop_timeout_s 75 s + "
                                                     "worker_hurry_timeout_s 15 s + 5 s for a killed worker), more "
                                                     "than the unit's TimeoutStopSec (90 s)"), warned
    assert said("79") and said("90", worker_hurry_timeout_s=30.0)
    assert said(None, worker_stop_timeout_s=600.0) == [] and said("10", workers=[]) == []
    # A short stop timeout: the worker's budgets are cut (said as before), and the unit's limit is checked too.
    warned = said("10", worker_stop_timeout_s=20.0, worker_hurry_timeout_s=12.0)
    assert [w.split(":")[0] for w in warned] == ["rio", "the stop may last 37 s (worker_stop_timeout_s 20 s + "
                                                 "worker_hurry_timeout_s 12 s + 5 s for a killed worker), more than "
                                                 "the unit's TimeoutStopSec (10 s)"], warned
    warned = said("ninety")
    assert warned == ["SARBOT_TIMEOUT_STOP_S='ninety': not a number of seconds; the stop's fit in the unit's "
                      "TimeoutStopSec is not checked"], warned
