"""The live map's lag in the daemon: the map-feedback live test's run, its timeline printed and recorded.

    python benchmarks/map_lag.py [--runs 1] [--speed 0.5] [-v]

The run is tests/test_map_feedback_live.py's (acquisition.studies.map_feedback_live, which both use): the daemon as
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
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from results_file import load_average, write_results  # noqa: E402

MAP_KEYS = ("frames_imaged", "frames_queued", "frames_thinned", "frames_dropped_behind", "lag_ms", "busy_ms",
            "refocus_ms", "refocus_max_ms", "refocus_wait_ms", "tiles_refocused", "tiles_awaiting_refocus")


def run_once(work: Path, sim_path: Path, speed: float) -> dict:
    """One daemon run on the replayed drive; its timeline and summary."""
    from acquisition.studies.map_feedback_live import run_daemon
    from imaging.io.image_file import read_image

    run = run_daemon(work, sim_path, feedback=True, speed=speed)
    timeline = []
    for now, report in run.reports:
        m, rio = report.workers.get("stripmap"), report.workers.get("rio")
        if run.go_s is not None and now >= run.go_s and m is not None:
            timeline.append({"t_s": round(now - run.go_s, 2), **{k: m.counters.get(k, 0) for k in MAP_KEYS},
                             "map_velocity_updates": rio.counters.get("map_velocity_updates", 0) if rio else 0,
                             "rio_lag_ms": rio.counters.get("lag_ms", 0) if rio else 0})
    attrs = read_image(run.map_path).attrs if run.map_path.exists() else {}
    replayed = run.sent_s is not None and run.go_s is not None
    at_end = [r for r in timeline if replayed and r["t_s"] <= run.sent_s - run.go_s]
    return {
        "replay_s": round(run.sent_s - run.go_s, 2) if replayed else None,
        "lag_s_at_replay_end": at_end[-1]["lag_ms"] / 1e3 if at_end else None,
        "queued_frames_at_replay_end": at_end[-1]["frames_queued"] if at_end else None,
        "stop_s": round(run.returned_s - run.done_s, 2) if run.done_s is not None else None,
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
    from acquisition.processes import configure_logging
    from acquisition.studies.map_feedback_live import simulate_drive

    configure_logging(1 if args.verbose else 0)
    started_load = load_average()
    load_before = os.getloadavg()
    runs = []
    with tempfile.TemporaryDirectory(prefix="sarbot-map-lag-") as tmp:
        sim = Path(tmp) / "drive.h5"
        simulate_drive(sim)
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
        print(f"wrote {write_results('map_lag', out, started_load=started_load, indent=1)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
