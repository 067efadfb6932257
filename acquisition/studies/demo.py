"""``sarbot demo``: the whole pipeline on emulated hardware, fed by a built-in scene.

1. The scene ``demo_room`` is simulated into a recording (four radars' raw ADC, IMU, CAN, truth).
2. The recording is replayed through emulated hardware in real time: SRF1 datagrams on loopback UDP, Xbus
   bytes on a pseudo-terminal, CAN frames on python-can's UDP multicast bus.
3. The daemon runs as on the robot: a driver process per radar, the IMU and CAN drivers, the recorder, the
   odometry worker and the strip-map worker, over ZeroMQ.
4. The products (recording, trajectory, strip map HDF5 and PNG) are checked against the simulation's truth
   and summarised in ``report.md`` and ``report.json``.
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing as mp
import random
import threading
import time
from pathlib import Path

import numpy as np

from imaging import metrics
from imaging.core import strict_json
from imaging.core.errors import SarbotError
from imaging.io.image_file import read_image
from imaging.io.recording import Recording
from imaging.io.trajectory_file import read_trajectory
from imaging.plot import save_image_png
from imaging.sim.scene import load_scene
from imaging.sim.simulator import simulate_recording
from imaging.sim.targets import CornerReflector, Rod
from imaging.stripmap import StripMapConfig

from ..progress import Progress
from .common import label_of, target_xy

log = logging.getLogger(f"sarbot.{__name__}")

SCENE = "demo_room"
APERTURE_M = 0.3
#: The demo maps both sides: a second reflector, on the right at r0 = 2 m from the right radars' track, gives
#: the right pair something to focus (the studies that borrow ``demo_room`` keep its left-side targets only).
RIGHT_REFLECTOR = CornerReflector(position_m=(0.2, -2.4, 0.3), axis=(0.0, 1.0, 0.0), amplitude=2.0)
#: Everything the demo writes into its folder (and replaces on the next run).
DEMO_FILES = ("simulated.h5", "recording.h5", "trajectory_demo.h5", "stripmap_demo.h5", "stripmap_demo.png",
              "report.md", "report.json", "imu_tty")


def _targets_in_start_frame(scene) -> list[tuple[str, np.ndarray]]:
    """Where the rod face and the reflector are in the world frame of the run (origin at the start pose)."""
    start = scene.trajectory.sample(np.array([scene.start_time_ns]))
    rot = start.rotation.inv()
    out = []
    for t in scene.targets:
        if isinstance(t, (Rod, CornerReflector)):
            p = np.array([*target_xy(t), 0.3])  # the map plane, at the radars' height
            q = rot.apply(p - start.position_m[0])[0]
            out.append((f"{label_of(t)}, {'left' if q[1] > 0 else 'right'}", q))
    return out


def demo_scene():
    """``demo_room`` with a reflector on the right as well (``RIGHT_REFLECTOR``)."""
    scene = load_scene(SCENE)
    return dataclasses.replace(scene, targets=[*scene.targets, RIGHT_REFLECTOR])


def _emulate_hardware(sim_path: str, targets: dict, imu_link: str, speed: float, can, held) -> None:
    from ..replay import replay

    replay(Path(sim_path), targets, imu_link, speed, start_delay_s=4.0, can=can, held=held)


def _wait_for_link(link: Path, emulator, timeout_s: float = 60.0) -> None:
    """Until the emulator has made its IMU pty (``link`` points to it), or has died trying."""
    deadline = time.monotonic() + timeout_s
    while not link.is_symlink():
        if not emulator.is_alive() or time.monotonic() > deadline:
            emulator.join(5)
            raise SarbotError(f"the emulated hardware did not come up (exit code {emulator.exitcode}); see its message above")
        time.sleep(0.05)


def run_demo(out_dir: Path, speed: float = 0.5, view: tuple[str, int] | None = None,
             stop_settings: dict[str, float] | None = None) -> int:
    """``sarbot demo``. ``stop_settings``: the daemon's worker stop and hurry timeouts (``Setup`` fields,
    ``--worker-stop-timeout`` and ``--worker-hurry-timeout``) where not its defaults."""
    from drivers.can_driver import CanConfig
    from drivers.radar.link import RadarLink

    from ..daemon import Setup, record
    from ..replay import DevicesHeld
    from ..workers.pipeline import add_pipeline_workers

    t_start = time.monotonic()
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in DEMO_FILES:  # its own files of an earlier run, by name: nothing else in the folder is touched
        (out_dir / name).unlink(missing_ok=True)
    scene = demo_scene()
    sim_path = out_dir / "simulated.h5"
    print(f"sarbot demo: 1/3 simulating scene {scene.name!r}: {scene.duration_s:.0f} s, four radars, IMU, CAN")
    simulate_recording(scene, sim_path, progress=Progress("simulate"), overwrite=True)

    rig = scene.rig
    ctx = mp.get_context("spawn")
    # The drivers bind ports the system picks (0) and publish them; the emulated radars send there once
    # they go. Never a port picked as free and bound later: another program may take it in between.
    bound_ports = {name: ctx.Value("i", 0) for name in scene.radars}
    links = [RadarLink(name, 0) for name in scene.radars]
    # The emulated CAN bus is a multicast group its members share (SO_REUSEADDR): nothing to bind alone, so a
    # port of its own per run keeps two demos on one machine apart.
    can = CanConfig("udp_multicast", "239.74.163.2", options={"port": random.randint(49152, 65535)})
    imu_link = out_dir / "imu_tty"
    setup = Setup(rig, links, str(imu_link), can, health_interval_s=1.0, bound_ports=bound_ports, **(stop_settings or {}))
    config = StripMapConfig(aperture_m=APERTURE_M, range_min_m=1.0, range_max_m=4.0, z_m=0.3)
    # The map images all four radars, both sides of the drive, into one world-frame map; so does the odometry.
    traj_path, map_path, config = add_pipeline_workers(setup, out_dir, "demo", config, max_speed_mps=0.5, view=view)
    rec_path = out_dir / "recording.h5"
    print(f"sarbot demo: 2/3 replaying it through emulated hardware into the daemon (drivers, recorder, odometry, "
          f"strip map with pre-summing {config.presum}) at {speed:g}x real time")
    done = threading.Event()
    # The emulated hardware is a process of its own, as the real sensors are: sharing the daemon's
    # interpreter, its sending would steal the recorder's time.
    # The devices are plugged in before the daemon starts and stay until it has stopped, as on the robot: the
    # IMU driver finds its port at once, and is not told the device went away as the demo ends.
    held = DevicesHeld(ctx.Event(), ctx.Event(), ctx.Event())
    emulator = ctx.Process(target=_emulate_hardware, name="emulated-hardware",
                           args=(str(sim_path), {name: ("127.0.0.1", port) for name, port in bound_ports.items()}, str(imu_link),
                                 speed, can, held))
    emulator.start()
    _wait_for_link(imu_link, emulator)

    finished = threading.Event()

    warm = threading.Event()

    def play():
        # The hardware starts sending once the workers have compiled their kernels (a cold JIT cache takes tens
        # of seconds), as a robot starts driving once the daemon says it is ready.
        warm.wait(600)
        held.go.set()
        while not held.sent.wait(0.2) and emulator.is_alive():
            pass
        if not held.sent.is_set():  # it died sending: stop now (its exit code is checked below)
            done.set()
        finished.set()

    bar = Progress("pipeline")
    expected_s = 4.0 + scene.duration_s / speed + 1.0
    t_run = time.monotonic()
    player = threading.Thread(target=play, daemon=True)
    player.start()
    health = []

    def on_health(report):
        health.append(report)
        if report.warm:
            warm.set()
        bar(min(time.monotonic() - t_run, expected_s), expected_s)
        # Stop once the hardware has sent everything and the daemon has taken it all (a quiet second).
        if finished.is_set() and not any(report.frames_per_s.values()) and report.imu_hz == 0:
            done.set()

    try:
        record(setup, out_dir, until=done, on_health=on_health, path=rec_path)
    except BaseException:
        emulator.terminate()  # nothing left to send to
        raise
    finally:
        held.release.set()
        player.join(5)
        emulator.join(30)
    bar(expected_s, expected_s)
    if emulator.exitcode != 0:
        raise SarbotError(f"the emulated hardware failed (exit code {emulator.exitcode}); see its message above")

    print("sarbot demo: 3/3 checking the products against the simulation's truth")
    report = evaluate(scene, sim_path, rec_path, traj_path, map_path, health, config)
    report["elapsed_s"] = time.monotonic() - t_start
    report["replay_speed"] = speed
    (out_dir / "report.json").write_text(strict_json.dumps(report, indent=2))
    (out_dir / "report.md").write_text(markdown(report))
    print(markdown(report))
    print(f"sarbot demo: done in {report['elapsed_s']:.0f} s. Wrote to {out_dir.resolve()}/:")
    for path in (rec_path, traj_path, map_path, map_path.with_suffix(".png"), out_dir / "report.md", out_dir / "report.json"):
        print(f"  {path.name}")
    return 0 if report["ok"] else 1


def evaluate(scene, sim_path, rec_path, traj_path, map_path, health, config) -> dict:
    """What the demo shows, in numbers: nothing lost, the odometry's drift, the targets in the map."""
    from rio.evaluation import drift_report

    report: dict = {"scene": scene.name, "outputs": {"recording": str(rec_path), "trajectory": str(traj_path),
                                                     "strip_map": str(map_path), "strip_map_png": str(map_path.with_suffix(".png"))}}
    with Recording(sim_path) as sim, Recording(rec_path) as rec:
        frames = {n: [rec.n_frames(n), sim.n_frames(n)] for n in scene.radars}
        report["frames_recorded_of_sent"] = frames
        report["frames_invalid"] = {n: int((rec.valid(n) == 0).sum()) for n in scene.radars}
        report["imu_samples_recorded_of_sent"] = [int(rec.imu()["time_ns"].size), int(sim.imu()["time_ns"].size)]
        report["can_frames_recorded_of_sent"] = [int(rec.can()["time_ns"].size), int(sim.can()["time_ns"].size)]
        report["events"] = [e[1:] for e in rec.events()]
        truth = sim.truth()
    start = truth.sample(np.array([scene.start_time_ns]))
    traj = read_trajectory(traj_path)
    # The run's world frame starts at the start pose; the simulation's truth starts where the scene says.
    from imaging.core.trajectory import SampledTrajectory

    rot = start.rotation.inv()
    shifted = SampledTrajectory(truth.time_ns, rot.apply(truth.position_m - start.position_m[0]),
                                (rot * truth.sample(truth.time_ns).rotation).as_quat(), source="truth")
    report["odometry"] = drift_report(traj, shifted)
    img = read_image(map_path)
    report["strip_map"] = {"tiles": int(img.attrs["tiles"]), "frames_imaged": int(img.attrs["frames_imaged"]),
                           "max_lag_s": float(img.attrs["max_lag_s"]), "presum": int(img.attrs["presum"]),
                           **{k: int(img.attrs[k]) for k in ("frames_standing_still", "frames_beyond_odometry",
                                                             "frames_presummed_more", "frames_batched", "frames_rx_summed",
                                                             "frames_thinned",
                                                             "frames_dropped_behind",
                                                             "frames_lost_on_bus")},
                           "aperture_m": config.aperture_m, "extent_m": [float(np.ptp(img.x_m)), float(np.ptp(img.y_m))]}
    marks, targets = {}, []
    wavelength = scene.rig.radar("left_front").waveform.wavelength_m
    for label, p in _targets_in_start_frame(scene):
        marks[label] = (p[0], p[1])
        try:
            a = metrics.analyze_target(img.image, img.x_m, img.y_m, (0.0, 1.0), near_m=(p[0], p[1]), radius_m=0.1,
                                       half_length_m=0.15)
        except ValueError as e:  # the map does not reach the target: a finding for the report, not a crash
            targets.append({"target": label, "true_m": p[:2].tolist(), "missing": str(e)})
            continue
        r0 = float(abs(p[1]) - 0.2)  # the radars drive 0.2 m either side of the body origin
        theory = metrics.cross_range_resolution_theory_m(wavelength, r0, config.aperture_m)
        targets.append({"target": label, "true_m": p[:2].tolist(), "peak_m": a["peak_m"],
                        "error_m": float(np.hypot(a["peak_m"][0] - p[0], a["peak_m"][1] - p[1])),
                        "cross_range_width_m": a["cross_range"]["half_power_width_m"],
                        "cross_range_theory_m": theory, "range_width_m": a["range"]["half_power_width_m"],
                        "range_theory_m": metrics.range_resolution_theory_m(scene.rig.radar("left_front").waveform.sampled_bandwidth_hz),
                        "snr_db": a["snr_db"]})
    report["targets"] = targets
    save_image_png(map_path.with_suffix(".png"), img.image, img.x_m, img.y_m, marks=marks,
                   title=f"live strip map: {report['strip_map']['frames_imaged']} frames, aperture {config.aperture_m} m, "
                         f"on the odometry's trajectory")
    lost = sum(s - r for r, s in frames.values()) + sum(report["frames_invalid"].values())
    report["ok"] = bool(lost == 0 and all(t.get("error_m", np.inf) < 0.05 for t in targets)
                        and report["odometry"]["final_drift_m"] < 0.2)
    return report


def markdown(report: dict) -> str:
    o = report["odometry"]
    sm = report["strip_map"]
    lines = [f"# sarbot demo: {report['scene']}", "",
             "| radar | frames recorded / sent | invalid |", "| --- | --- | --- |"]
    for n, (r, s) in report["frames_recorded_of_sent"].items():
        lines.append(f"| {n} | {r} / {s} | {report['frames_invalid'][n]} |")
    lines += ["", f"IMU samples {report['imu_samples_recorded_of_sent'][0]} / {report['imu_samples_recorded_of_sent'][1]}, "
              f"CAN frames {report['can_frames_recorded_of_sent'][0]} / {report['can_frames_recorded_of_sent'][1]}, "
              f"events in the recording: {len(report['events'])}.", "",
              f"Odometry: {o['distance_m']:.2f} m driven, final drift {100 * o['final_drift_m']:.1f} cm "
              f"({o['final_drift_percent']:.2f} %), ATE {100 * o['ate_rmse_m']:.1f} cm.", "",
              f"Strip map: {sm['frames_imaged']} frames imaged into {sm['tiles']} tiles "
              f"({sm['extent_m'][0]:.1f} m x {sm['extent_m'][1]:.1f} m), aperture {sm['aperture_m']} m, pre-summing "
              f"{sm['presum']}, largest lag behind the sensors {sm['max_lag_s']:.2f} s.", "",
              "| target | true (m) | in the map (m) | error (cm) | cross-range width (cm) | theory (cm) |",
              "| --- | --- | --- | --- | --- | --- |"]
    for t in report["targets"]:
        if "missing" in t:
            lines.append(f"| {t['target']} | ({t['true_m'][0]:.3f}, {t['true_m'][1]:.3f}) | not in the map: {t['missing']} | | | |")
            continue
        lines.append(f"| {t['target']} | ({t['true_m'][0]:.3f}, {t['true_m'][1]:.3f}) | ({t['peak_m'][0]:.3f}, "
                     f"{t['peak_m'][1]:.3f}) | {100 * t['error_m']:.1f} | {100 * t['cross_range_width_m']:.2f} | "
                     f"{100 * t['cross_range_theory_m']:.2f} |")
    lines += ["", "Everything sent arrived and the targets are where the scene put them." if report["ok"] else
              "**Something is off: see the numbers above.**"]
    return "\n".join(lines) + "\n"
