"""The map corrects the odometry live: the real daemon (drivers, odometry and strip-map workers as processes,
ZeroMQ between them) fed by emulated hardware replaying a simulated drive, as `sarbot run --map-refocus
entropy --rio-map-feedback` runs it. The radars' Doppler reads 2 % low in the daemon (their chirp interval 2 %
shorter than its rig says: the radars' clock off), which is what the map's refocus sees."""

import re

import pytest

from acquisition.studies.map_feedback_live import TRUE_SCALE_PPM, run_daemon, simulate_drive


def run_with_feedback(tmp_path, sim_path) -> dict:
    """The daemon with the map's feedback on the replayed drive (acquisition.studies.map_feedback_live); the
    odometry's and the map's last health counters, the odometry's trajectory, each map update the odometry
    met (rio.map_feedback.MapUpdate, from the recording's /events) and whether the map file was written."""
    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import read_trajectory

    run = run_daemon(tmp_path / "with", sim_path, feedback=True)
    with Recording(run.recording_path) as rec:
        updates = [e[3] for e in rec.events() if e[1] == "rio" and e[3].startswith("map velocity error")]
    return {"counters": run.last_counters("rio"), "map_counters": run.last_counters("stripmap"),
            "trajectory": read_trajectory(run.trajectory_path), "map_updates": updates,
            "map_file": run.map_path.exists()}


SCALE = re.compile(r"Doppler scale [+-]\d+ -> ([+-]\d+) \+- (\d+) ppm$")


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    path = tmp_path_factory.mktemp("live") / "drive.h5"
    return simulate_drive(path), path


def test_the_live_map_s_velocity_errors_reach_the_odometry_s_filter(drive, tmp_path):
    """The map worker's ``map/velocity_error`` goes over the bus into the odometry worker, whose filter takes
    it (each update as the odometry wrote it to the recording's /events; none refused by the gate), and the
    map is written when the daemon stops.

    What this run does not show is the drift it saves: at CI length (3 m, three targets a side) the map reads
    one or two velocity errors, and a loaded machine thins the odometry's scans and the map's frames, so the
    drift with and without differs by chance. The drift is measured offline (benchmarks/map_feedback.py)."""
    scene, sim_path = drive
    run = run_with_feedback(tmp_path, sim_path)
    counters = run["counters"]
    if counters.get("scans_thinned_behind", 0) > 20:
        # The pipeline did not keep up with real time (a machine loaded by other jobs: 89-140 of the ~400 scans
        # thinned at load averages of 20-26 on 2 cores, 3 at 8): the map thinned its frames too, and tiles
        # refocused over part of their aperture read no velocity error. Not this test's subject.
        pytest.skip(f"the machine is too loaded to run the daemon in real time: {counters}")
    map_counters = run["map_counters"]
    if map_counters.get("frames_thinned", 0) > 0.2 * max(map_counters.get("frames_imaged", 0), 1):
        # The same from the map's side: at load 10-12 the map thinned 140 of 176 frames and its few tiles, read
        # late and over thinned apertures, all began in the filter's settling (none taken). A quiet run thins
        # 0-4 of about 290.
        pytest.skip(f"the machine is too loaded for the map to keep up in real time: {map_counters}")
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
