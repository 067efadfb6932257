"""The map-feedback live run: the real daemon (drivers, recorder, odometry and strip-map workers, each a
process, ZeroMQ between them) as `sarbot run --map-refocus entropy --rio-map-feedback` makes it, fed by
emulated hardware replaying a simulated two-radar drive (see docs/architecture.md, processes). The radars'
Doppler reads 2 % low in the daemon (their chirp interval 2 % shorter than its rig says: the radars' clock
off), which is what the map's refocus sees.

One set-up for the two that run it: tests/test_map_feedback_live.py (the map's velocity errors reach the
odometry's filter) and benchmarks/map_lag.py (the map worker's lag over the run); and the same drive's inputs
for an offline run as the live workers make them (``live_drive_inputs``: benchmarks/map_feedback_live_drive.py,
map_feedback_settling.py, map_feedback_wild.py).
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import threading
import time
from pathlib import Path

import numpy as np

from imaging.core.rig import Rig, default_rig
from imaging.sim.scene import Scene, scene_from_dict
from imaging.stripmap import StripMapConfig

RADARS = ("left_front", "right_front")
DOPPLER_LOW = 0.02
TRUE_SCALE_PPM = round((1 / (1 - DOPPLER_LOW) - 1) * 1e6)  # the Doppler scale that corrects it: +20408
LENGTH_M = 3.0
#: The feedback drive's map (rio.feedback_drive.MAP_CONFIG) at the daemon's map height.
MAP = StripMapConfig(pixel_m=0.01, tile_px=32, aperture_m=0.6, beam_half_angle_deg=45.0, range_min_m=0.6,
                     range_max_m=2.5, presum=4, refocus="entropy", refocus_groups_per_frame=2)
#: Half speed, as the demo: a CI machine keeps up.
REPLAY_SPEED = 0.5
#: At most this long a run: a hardware emulator that never sends must not hang a test.
RUN_LIMIT_S = 300.0


def feedback_scene() -> Scene:
    """2 s standing, then 3 m straight at 0.4 m/s past point targets every 0.64 m on both sides at 1.44 and
    1.76 m (at the centres of the map's tiles, as in rio.feedback_drive), clutter beyond them for the odometry."""
    tile = MAP.tile_m
    xs = (np.arange(3, 9, 2) + 0.5) * tile
    targets = [{"kind": "point", "position_m": [float(x), float(side * (row + 0.5) * tile), MAP.z_m], "amplitude": 1.0}
               for side, row in ((1, 4), (-1, 5)) for x in xs]
    return scene_from_dict({
        "name": "map_feedback_live", "duration_s": 2.0 + LENGTH_M / 0.4 + 1.0, "imu": True, "snr_db": 10.0, "seed": 3,
        "adc_counts_per_unit": 1000.0, "radars": list(RADARS),
        "trajectory": {"kind": "path", "start_m": [0.0, 0.0, 0.0], "speed_mps": 0.4, "accel_mps2": 0.5,
                       "start_delay_s": 2.0, "segments": [["straight", LENGTH_M]]},
        "imu_errors": {"gyro_bias_radps": [0.002, -0.003, 0.001], "accel_bias_mps2": [0.05, -0.04, 0.03]},
        "target": targets,
        "clutter": [{"count": 14, "box_m": [[-1.0, 4.0], [2.6, 4.5], [0.0, 0.8]], "amplitude": 0.6, "seed": 1},
                    {"count": 14, "box_m": [[-1.0, 4.0], [-4.5, -2.6], [0.0, 0.8]], "amplitude": 0.6, "seed": 2}],
    })


def simulated_rig() -> Rig:
    """The rig the drive is simulated with: each imaging radar's chirp interval 2 % shorter than the daemon's
    rig says (the default's 200 us fills the frame), so the daemon's Doppler reads 2 % low."""
    rig = default_rig()
    radars = [dataclasses.replace(r, waveform=dataclasses.replace(r.waveform, chirp_interval_s=r.waveform.chirp_interval_s * (1 - DOPPLER_LOW)))
              if r.name in RADARS else r for r in rig.radars]
    return dataclasses.replace(rig, radars=radars)


def simulate_drive(path: Path) -> Scene:
    """Simulate the drive (:func:`feedback_scene` on :func:`simulated_rig`) into the recording ``path``;
    returns the scene."""
    from imaging.sim.simulator import simulate_recording

    scene = dataclasses.replace(feedback_scene(), rig=simulated_rig())
    simulate_recording(scene, path, overwrite=True)
    return scene


@dataclasses.dataclass
class LiveDriveInputs:
    """The live test's drive as the live workers take it: the truth, the IMU (time ns, specific force m/s^2,
    rate rad/s), the odometry's scans (``rio.odometry.RadarScan``, time-ordered) and, where asked, each imaging
    radar's raw frames (time ns [F], ADC samples)."""

    truth: object
    imu: tuple[np.ndarray, np.ndarray, np.ndarray]
    scans: list
    frames: dict[str, tuple[np.ndarray, np.ndarray]]

    @property
    def start_ns(self) -> int:
        """The first IMU sample's time."""
        return int(self.imu[0][0])

    @property
    def duration_s(self) -> float:
        """From the first IMU sample to the last."""
        return (int(self.imu[0][-1]) - self.start_ns) * 1e-9


def live_drive_inputs(seed: int, folder: Path, frames: bool = True) -> LiveDriveInputs:
    """The live test's drive (:func:`feedback_scene` on :func:`simulated_rig`) simulated with noise seed ``seed``
    into a recording in ``folder`` (removed after), read as the live workers read it: scans from the raw frames
    with the daemon's rig (its chirp interval 2 % longer than the radars', so the Doppler reads 2 % low), 10 a
    second a radar; with ``frames``, every imaging radar's raw frames for the map."""
    from imaging.io.recording import Recording
    from imaging.sim.simulator import simulate_recording
    from rio.odometry import _scans_from_adc

    rig = default_rig()
    path = Path(folder) / f"drive_{seed}.h5"
    simulate_recording(dataclasses.replace(feedback_scene(), rig=simulated_rig(), seed=seed), path, overwrite=True)
    try:
        with Recording(path) as rec:
            imu = rec.imu()
            scans, raw = [], {}
            for name in RADARS:
                every = max(1, int(round(1.0 / (rig.radar(name).waveform.frame_interval_s * 10.0))))
                scans += _scans_from_adc(rec, name, rig.radar(name), 0, None)[::every]
                if frames:
                    raw[name] = (np.asarray(rec.frame_time_ns(name)), rec.adc(name))
            truth = rec.truth()
    finally:
        path.unlink(missing_ok=True)
    scans.sort(key=lambda s: s.time_ns)
    return LiveDriveInputs(truth, (imu["time_ns"], imu["accel_mps2"], imu["gyro_radps"]), scans, raw)


@dataclasses.dataclass
class LiveRun:
    """What one daemon run left: every health report as it came, the moments that mark the run, its files.

    Times are ``time.monotonic()`` seconds; a mark is None where the run never got there.
    """

    reports: list  #: (time s, acquisition.daemon Health report), every one the daemon sent
    go_s: float | None  #: the hardware let go: every worker warm (compiled), as the robot drives once ready
    sent_s: float | None  #: the first report after the hardware had sent everything
    done_s: float | None  #: the first report after that with no frame and no IMU sample coming in
    returned_s: float  #: the daemon returned (stopped, its files written)
    recording_path: Path
    trajectory_path: Path
    map_path: Path

    def last_counters(self, worker: str) -> dict:
        """The named worker's counters in the last report that had it (``{}`` if none)."""
        found = [r.workers[worker].counters for _, r in self.reports if worker in r.workers]
        return found[-1] if found else {}


def _emulate(sim_path, targets, imu_link, held, speed):
    from acquisition.replay import replay

    replay(sim_path, targets, imu_link, speed, start_delay_s=1.0, held=held)


def run_daemon(work: Path, sim_path: Path, *, feedback: bool = True, speed: float = REPLAY_SPEED) -> LiveRun:
    """The daemon as `sarbot run` makes it on the replayed drive ``sim_path``, in the new folder ``work``,
    until the hardware has sent everything and the daemon has taken it.

    Parameters
    ----------
    work
        A folder to make: the recording, trajectory and map files and the emulated IMU's link go here.
    sim_path
        The drive (:func:`simulate_drive`).
    feedback
        Whether the map's velocity errors go to the odometry (``--rio-map-feedback``).
    speed
        Replay speed, a multiple of real time.
    """
    from acquisition.daemon import Setup, record
    from acquisition.replay import DevicesHeld
    from acquisition.workers.pipeline import add_pipeline_workers
    from drivers.radar.link import RadarLink

    work.mkdir(parents=True)
    ctx = mp.get_context("spawn")
    bound = {name: ctx.Value("i", 0) for name in RADARS}
    imu_link = work / "imu_tty"
    setup = Setup(default_rig(), [RadarLink(n, 0) for n in RADARS], str(imu_link), None, health_interval_s=0.5,
                  bound_ports=bound)
    trajectory_path, map_path, _ = add_pipeline_workers(setup, work, "t", MAP, presum=MAP.presum,
                                                        rio_map_feedback=feedback)
    held = DevicesHeld(ctx.Event(), ctx.Event(), ctx.Event())
    emulator = ctx.Process(target=_emulate, args=(str(sim_path), {n: ("127.0.0.1", p) for n, p in bound.items()},
                                                   str(imu_link), held, speed))
    emulator.start()
    deadline = time.monotonic() + 60
    while not imu_link.is_symlink() and time.monotonic() < deadline:
        time.sleep(0.05)
    done = threading.Event()
    reports: list = []
    marks: dict[str, float] = {}

    def on_health(report):
        now = time.monotonic()
        reports.append((now, report))
        if all(w.warm for w in report.workers.values()) and report.workers and not held.go.is_set():
            held.go.set()
            marks["go"] = now
        if held.sent.is_set():
            marks.setdefault("sent", now)
            if not any(report.frames_per_s.values()) and report.imu_hz == 0:
                marks.setdefault("done", now)
                done.set()

    recording_path = work / "recording.h5"
    try:
        record(setup, work, RUN_LIMIT_S, until=done, on_health=on_health, path=recording_path)
    finally:
        held.release.set()
        emulator.join(30)
    return LiveRun(reports, marks.get("go"), marks.get("sent"), marks.get("done"), time.monotonic(),
                   recording_path, trajectory_path, map_path)
