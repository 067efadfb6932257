"""The live map's lag in the daemon: the map-feedback live test's run, its timeline printed and recorded.

    python benchmarks/map_lag.py [--runs 1] [--speed 0.5] [-v]

The run is tests/test_map_feedback_live.py's (its scene, rig and map, imported from it): the daemon as
`sarbot run --map-refocus entropy --rio-map-feedback` makes it (drivers, recorder, odometry and strip-map
workers, each a process, ZeroMQ between them) on the replayed two-radar drive (about 10.5 s of data) at
``--speed`` (half, as the test). The hardware starts once every worker is warm; the run stops once it has
sent everything and the daemon has taken it.

Every health report (each 0.5 s) gives the map worker's counters (``StripMapWorker.counters``): frames
imaged and queued, its lag, its time imaging and refocusing, the longest refocus job, how long the latest
finished tiles waited for theirs; and the odometry's map updates. Printed as a timeline from the hardware's
start; ``-v`` also shows the workers' debug lines (each imaging call and each tile's refocus with its groups,
iterations and wait). Recorded: the lag when the replay ended and its largest, the time from the replay's
end to the daemon's return (the stop: the map's last imaging and refocus, its file), the map file's summary.
Wall-clock figures on a machine shared with others: the load average is recorded beside them.

Writes docs/results/map_lag.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from imaging.core import strict_json  # noqa: E402

RESULTS = ROOT / "docs" / "results"
MAP_KEYS = ("frames_imaged", "frames_queued", "frames_thinned", "frames_dropped_behind", "lag_ms", "busy_ms",
            "refocus_ms", "refocus_max_ms", "refocus_wait_ms", "tiles_refocused", "tiles_awaiting_refocus")


def _emulate(sim_path, targets, imu_link, held, speed):
    from acquisition.replay import replay

    replay(sim_path, targets, imu_link, speed, start_delay_s=1.0, held=held)


def run_once(work: Path, sim_path: Path, speed: float) -> dict:
    """One daemon run on the replayed drive; its timeline and summary."""
    from test_map_feedback_live import MAP, RADARS

    from acquisition.daemon import Setup, record
    from acquisition.replay import DevicesHeld
    from acquisition.workers.pipeline import add_pipeline_workers
    from drivers.radar.link import RadarLink
    from imaging.core.rig import default_rig
    from imaging.io.image_file import read_image

    work.mkdir(parents=True)
    ctx = mp.get_context("spawn")
    bound = {name: ctx.Value("i", 0) for name in RADARS}
    imu_link = work / "imu_tty"
    setup = Setup(default_rig(), [RadarLink(n, 0) for n in RADARS], str(imu_link), None, health_interval_s=0.5,
                  bound_ports=bound)
    _, map_path, _ = add_pipeline_workers(setup, work, "t", MAP, presum=MAP.presum, rio_map_feedback=True)
    held = DevicesHeld(ctx.Event(), ctx.Event(), ctx.Event())
    emulator = ctx.Process(target=_emulate, args=(str(sim_path), {n: ("127.0.0.1", p) for n, p in bound.items()},
                                                   str(imu_link), held, speed))
    emulator.start()
    deadline = time.monotonic() + 60
    while not imu_link.is_symlink() and time.monotonic() < deadline:
        time.sleep(0.05)
    done = threading.Event()
    marks = {}
    timeline = []

    def on_health(report):
        now = time.monotonic()
        if all(w.warm for w in report.workers.values()) and report.workers and not held.go.is_set():
            held.go.set()
            marks["go"] = now
        if held.sent.is_set() and "sent" not in marks:
            marks["sent"] = now
        m, rio = report.workers.get("stripmap"), report.workers.get("rio")
        if "go" in marks and m is not None:
            row = {"t_s": round(now - marks["go"], 2), **{k: m.counters.get(k, 0) for k in MAP_KEYS},
                   "map_velocity_updates": rio.counters.get("map_velocity_updates", 0) if rio else 0,
                   "rio_lag_ms": rio.counters.get("lag_ms", 0) if rio else 0}
            timeline.append(row)
        if held.sent.is_set() and not any(report.frames_per_s.values()) and report.imu_hz == 0:
            marks.setdefault("done", now)
            done.set()

    try:
        record(setup, work, 300.0, until=done, on_health=on_health, path=work / "recording.h5")
    finally:
        held.release.set()
        emulator.join(30)
    returned = time.monotonic()
    attrs = read_image(map_path).attrs if map_path.exists() else {}
    at_end = [r for r in timeline if "sent" in marks and r["t_s"] <= marks["sent"] - marks["go"]]
    return {
        "replay_s": round(marks["sent"] - marks["go"], 2) if "sent" in marks and "go" in marks else None,
        "lag_s_at_replay_end": at_end[-1]["lag_ms"] / 1e3 if at_end else None,
        "queued_frames_at_replay_end": at_end[-1]["frames_queued"] if at_end else None,
        "stop_s": round(returned - marks["done"], 2) if "done" in marks else None,
        "map_file_written": bool(attrs),
        "map_summary": {k: attrs[k].item() if hasattr(attrs[k], "item") else attrs[k] for k in ("frames_imaged", "frames_thinned", "frames_dropped_behind", "max_lag_s",
                                              "busy_s", "refocus_s", "refocus_max_s", "max_refocus_wait_s",
                                              "tiles_refocused", "tiles_awaiting_refocus") if k in attrs},
        "timeline": timeline,
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--speed", type=float, default=0.5, help="replay speed (the test's: 0.5)")
    parser.add_argument("-v", "--verbose", action="store_true", help="the workers' debug lines too")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--quick", action="store_true", help="one run, printed only (dev.py bench --quick)")
    args = parser.parse_args(argv)
    if args.quick:
        args.runs, args.no_write = 1, True
    from test_map_feedback_live import feedback_scene, simulated_rig

    from acquisition.processes import configure_logging
    from imaging.sim.simulator import simulate_recording

    configure_logging(1 if args.verbose else 0)
    load_before = os.getloadavg()
    runs = []
    with tempfile.TemporaryDirectory(prefix="sarbot-map-lag-") as tmp:
        sim = Path(tmp) / "drive.h5"
        simulate_recording(dataclasses.replace(feedback_scene(), rig=simulated_rig()), sim, overwrite=True)
        for i in range(args.runs):
            run = run_once(Path(tmp) / f"run{i}", sim, args.speed)
            run["load_average_after"] = list(os.getloadavg())
            runs.append(run)
            print(f"run {i}: " + " ".join(f"{k}={v}" for k, v in run.items() if k != "timeline"))
            keys = list(run["timeline"][0]) if run["timeline"] else []
            print(" ".join(f"{k:>10.10}" for k in keys))
            for row in run["timeline"]:
                print(" ".join(f"{row[k]:>10}" for k in keys))
    out = {"what": "tests/test_map_feedback_live.py's daemon run (two radars, entropy refocus, map feedback), the map "
                   "worker's counters every 0.5 s from the hardware's start",
           "speed": args.speed, "runs": runs, "load_average_before": list(load_before),
           "load_average_after": list(os.getloadavg())}
    if not args.no_write:
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "map_lag.json").write_text(strict_json.dumps(out, indent=1) + "\n")
        print(f"wrote {RESULTS / 'map_lag.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
