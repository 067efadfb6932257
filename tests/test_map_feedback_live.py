"""The map corrects the odometry live: the real daemon (drivers, odometry and strip-map workers as processes,
ZeroMQ between them) fed by emulated hardware replaying a simulated drive, as `sarbot run --map-refocus
entropy --rio-map-feedback` runs it. The radars' Doppler reads 2 % low in the daemon (their chirp interval 2 %
shorter than its rig says: the radars' clock off), which is what the map's refocus sees."""

import dataclasses
import multiprocessing as mp
import re
import threading
import time

import numpy as np
import pytest

from imaging.core.rig import default_rig
from imaging.sim.scene import scene_from_dict
from imaging.sim.simulator import simulate_recording
from imaging.stripmap import StripMapConfig

RADARS = ("left_front", "right_front")
DOPPLER_LOW = 0.02
TRUE_SCALE_PPM = round((1 / (1 - DOPPLER_LOW) - 1) * 1e6)  # the Doppler scale that corrects it: +20408
LENGTH_M = 3.0
#: The feedback drive's map (rio.feedback_drive.MAP_CONFIG) at the daemon's map height.
MAP = StripMapConfig(pixel_m=0.01, tile_px=32, aperture_m=0.6, beam_half_angle_deg=45.0, range_min_m=0.6,
                     range_max_m=2.5, presum=4, refocus="entropy", refocus_groups_per_frame=2)


def feedback_scene():
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


def simulated_rig():
    """The rig the drive is simulated with: each imaging radar's chirp interval 2 % shorter than the daemon's
    rig says (the default's 200 us fills the frame), so the daemon's Doppler reads 2 % low."""
    rig = default_rig()
    radars = [dataclasses.replace(r, waveform=dataclasses.replace(r.waveform, chirp_interval_s=r.waveform.chirp_interval_s * (1 - DOPPLER_LOW)))
              if r.name in RADARS else r for r in rig.radars]
    return dataclasses.replace(rig, radars=radars)


def _emulate(sim_path, targets, imu_link, held):
    from acquisition.replay import replay

    replay(sim_path, targets, imu_link, 0.5, start_delay_s=1.0, held=held)  # half speed, as the demo: a CI machine keeps up


def run_daemon(tmp_path, sim_path, feedback: bool) -> dict:
    """The daemon as `sarbot run` makes it (drivers, recorder, odometry and strip-map workers, each a process)
    on the replayed drive, until the hardware has sent everything and the daemon has taken it; returns the
    odometry worker's last health counters and its trajectory."""
    from acquisition.daemon import Setup, record
    from acquisition.replay import DevicesHeld
    from acquisition.workers.pipeline import add_pipeline_workers
    from drivers.radar.link import RadarLink
    from imaging.io.trajectory_file import read_trajectory

    out = tmp_path / ("with" if feedback else "without")
    out.mkdir()
    ctx = mp.get_context("spawn")
    bound = {name: ctx.Value("i", 0) for name in RADARS}
    imu_link = out / "imu_tty"
    setup = Setup(default_rig(), [RadarLink(n, 0) for n in RADARS], str(imu_link), None, health_interval_s=0.5,
                  bound_ports=bound)
    traj_path, _, _ = add_pipeline_workers(setup, out, "t", MAP, presum=MAP.presum, rio_map_feedback=feedback)
    held = DevicesHeld(ctx.Event(), ctx.Event(), ctx.Event())
    emulator = ctx.Process(target=_emulate, args=(str(sim_path), {n: ("127.0.0.1", p) for n, p in bound.items()},
                                                   str(imu_link), held))
    emulator.start()
    deadline = time.monotonic() + 60
    while not imu_link.is_symlink() and time.monotonic() < deadline:
        time.sleep(0.05)
    done, states, map_states = threading.Event(), [], []

    def on_health(report):
        if all(w.warm for w in report.workers.values()) and report.workers:
            held.go.set()  # the hardware starts once the workers have compiled, as the robot drives once ready
        rio = report.workers.get("rio")
        if rio is not None:
            states.append(rio.counters)
        stripmap = report.workers.get("stripmap")
        if stripmap is not None:
            map_states.append(stripmap.counters)
        if held.sent.is_set() and not any(report.frames_per_s.values()) and report.imu_hz == 0:
            done.set()

    try:
        # At most 300 s: a hardware emulator that never sends must not hang the test.
        record(setup, out, 300.0, until=done, on_health=on_health, path=out / "recording.h5")
    finally:
        held.release.set()
        emulator.join(30)
    traj = read_trajectory(traj_path)
    from imaging.io.recording import Recording

    with Recording(out / "recording.h5") as rec:  # each map update the odometry met (rio.map_feedback.MapUpdate)
        updates = [e[3] for e in rec.events() if e[1] == "rio" and e[3].startswith("map velocity error")]
    return {"counters": states[-1] if states else {}, "map_counters": map_states[-1] if map_states else {},
            "trajectory": traj, "map_updates": updates, "map_file": (out / "stripmap_t.h5").exists()}


SCALE = re.compile(r"Doppler scale [+-]\d+ -> ([+-]\d+) \+- (\d+) ppm$")


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    path = tmp_path_factory.mktemp("live") / "drive.h5"
    scene = dataclasses.replace(feedback_scene(), rig=simulated_rig())
    simulate_recording(scene, path, overwrite=True)
    return scene, path


def test_the_live_map_s_velocity_errors_reach_the_odometry_s_filter(drive, tmp_path):
    """The map worker's ``map/velocity_error`` goes over the bus into the odometry worker, whose filter takes
    it (each update as the odometry wrote it to the recording's /events; none refused by the gate), and the
    map is written when the daemon stops.

    What this run does not show is the drift it saves: at CI length (3 m, three targets a side) the map reads
    one or two velocity errors, and a loaded machine thins the odometry's scans and the map's frames, so the
    drift with and without differs by chance. The drift is measured offline (benchmarks/map_feedback.py)."""
    scene, sim_path = drive
    run = run_daemon(tmp_path, sim_path, True)
    counters = run["counters"]
    if counters.get("scans_thinned_behind", 0) > 20:
        # The pipeline did not keep up with real time (a machine loaded by other jobs: 89-140 of the ~400 scans
        # thinned at load averages of 20-26 on 2 cores, 3 at 8): the map thinned its frames too, and tiles
        # refocused over part of their aperture read no velocity error. Not this test's subject.
        pytest.skip(f"the machine is too loaded to run the daemon in real time: {counters}")
    # What the filter made of each map measurement (its residual, sigma, the scale around it), for a failure.
    # The recording's /events hold every one the odometry met (rio.map_feedback.MapUpdate); the health counters
    # are the last report's, which an update arriving in the run's last half second is not in yet.
    lines = run["map_updates"]
    updates = "\n".join(lines)
    print(f"{counters}\nmap: {run['map_counters']}\n{updates}")  # -s: the run's updates also when it passes
    assert run["map_file"], "the strip map was not written at stop"
    taken = [line for line in lines if line.endswith("ppm") and ": accepted;" in line]
    assert taken, f"{counters}\nmap: {run['map_counters']}\n{updates}"
    assert len(taken) >= counters.get("map_velocity_updates", 0), updates
    # The gate may refuse one: a tile that found no real track error (a live run's first read +510 +- 46 mm/s;
    # chi2 114). Most are taken.
    assert len(taken) > sum(": refused by the gate;" in line for line in lines), updates
    # The Doppler scale learnt from it is the truth (the radars read 2 % low: 1 / 0.98 - 1 = +20408 ppm) within
    # 3 of its own sigmas: the map's sigmas are honest (rio.map_feedback: one tile cannot tell an along-track
    # velocity error from the odometry's position error curving across the track, and a tile of thinned frames
    # reads its bend poorly), so the scale averages the measurements instead of following the last. The CI run
    # that chased them ended at +40332 ppm, its measurements claiming 2-5 mm/s where they scattered by 18.
    last = SCALE.search(lines[-1])
    assert last, lines[-1]
    scale_ppm, sigma_ppm = int(last.group(1)), int(last.group(2))
    print(f"Doppler scale learnt {scale_ppm:+d} +- {sigma_ppm} ppm, truth {TRUE_SCALE_PPM:+d}")
    assert abs(scale_ppm - TRUE_SCALE_PPM) < 3 * sigma_ppm, updates
    assert sigma_ppm < 50_000, updates  # it learnt from the map: its prior is 5 %
    traj = run["trajectory"]
    truth = scene.trajectory.sample(traj.time_ns[-1:]).position_m[0]
    assert traj.position_m[-1, 0] - traj.position_m[0, 0] > 0.5 * (truth[0] - scene.trajectory.sample(traj.time_ns[:1]).position_m[0][0])
