"""The live map's refocus on one BLAS thread against OpenBLAS's own (a thread per core), tile by tile.

    python benchmarks/refocus_threads.py [--repeats 1]

Why: in tests/test_map_feedback_live.py (two radars, ``refocus="entropy"``) the map ended 10-21 s behind.
The map worker refocuses a finished tile from its group images (``imaging.stripmap.refocus``); the entropy
method's gradient (``imaging.autofocus.subapertures.entropy_and_gradient``) is a product of small matrices
for every 256 pixels, which numpy hands to OpenBLAS; above a size OpenBLAS splits each product over its
threads, one per core, and on a machine whose cores are busy with other processes those threads wait for
each other at every call. The worker now limits BLAS to its ``threads`` (one by default,
``acquisition.workers.stripmap``).

Data: the live test's drive (``rio.feedback_drive``: 2 s standing, 3 m straight at 0.4 m/s past point
targets on both sides; the two front radars; its map: 1 cm pixels, 32 px tiles, 0.6 m aperture, pre-summing
4, two groups a frame), simulated once and imaged on the true trajectory with the map refocusing later
(``StripMap(refocus_later=True)``), so every finished tile keeps its group images. Then every tile with
groups enough is refocused twice from the same group images, once with BLAS on one thread and once on
OpenBLAS's default, the order alternating tile by tile (and repeat by repeat), in this one process: the
machine's load falls on both alike; it is recorded. CPU time (``time.process_time``, all threads) and wall
time per tile; the two estimates must agree (the same arithmetic, summed in another order).

Writes docs/results/refocus_threads.json.
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from threadpoolctl import threadpool_info, threadpool_limits  # noqa: E402

from imaging.core import strict_json  # noqa: E402
from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import SampledTrajectory  # noqa: E402
from imaging.stripmap import StripMap  # noqa: E402
from rio.feedback_drive import IMAGING_RADARS, MAP_CONFIG, simulate_feedback_drive  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
LENGTH_M = 3.0  # the live test's drive


def image_drive(length_m: float):
    """The drive's frames imaged on the truth with refocus left for later: (map, CPU s per frame)."""
    drive = simulate_feedback_drive(length_m=length_m)
    rig = default_rig()
    first = min(int(drive.frames[n][0][0]) for n in IMAGING_RADARS)
    t = first - 1_000_000_000 + np.arange(0, int((drive.duration_s + 2) * 1e9), 5_000_000, dtype=np.int64)
    truth = SampledTrajectory.from_trajectory(drive.truth, t)
    frames = sorted(((int(tf), n, f) for n in IMAGING_RADARS for tf, f in zip(*drive.frames[n])), key=lambda e: e[0])
    strip = StripMap(MAP_CONFIG, refocus_later=True)
    cpu = []
    for tf, name, frame in frames:
        radar = rig.radar(name)
        c = time.process_time()
        strip.add_frame(radar, np.asarray(radar.waveform.tdm_tx_order()), frame, tf, truth)
        cpu.append(time.process_time() - c)
    return strip, np.array(cpu)


def refocus_once(strip: StripMap, key, threads: int | None):
    """Refocus tile ``key`` on a copy of the map's refocus state: (CPU s, wall s, result)."""
    state = copy.copy(strip._refocus)
    state.groups = {key: list(strip._refocus.groups[key])}
    state.awaiting, state.results, state.geometry = set(), {}, {}
    tiles = {key: strip.tiles[key].copy()}
    with threadpool_limits(threads, user_api="blas"):
        c, w = time.process_time(), time.monotonic()
        state.refocus_tile(key, tiles, strip.tile_points)
        return time.process_time() - c, time.monotonic() - w, state.results.get(key)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="one repeat, the target tiles only")
    args = parser.parse_args(argv)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    load_before = os.getloadavg()
    strip, frame_cpu = image_drive(LENGTH_M)
    keys = [k for k, g in strip._refocus.groups.items() if len(g) >= 8]
    default_threads = max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
    rows = {1: {}, None: {}}
    for rep in range(1 if args.quick else args.repeats):
        for i, key in enumerate(keys):
            for threads in ((1, None) if (i + rep) % 2 == 0 else (None, 1)):
                cpu, wall, result = refocus_once(strip, key, threads)
                row = rows[threads].setdefault(key, {"cpu_s": [], "wall_s": [], "result": result})
                row["cpu_s"].append(cpu)
                row["wall_s"].append(wall)
    applied = [k for k in keys if rows[1][k]["result"] is not None and rows[1][k]["result"].applied]
    agree = max((float(np.max(np.abs(rows[1][k]["result"].track_error.displacement_m
                                     - rows[None][k]["result"].track_error.displacement_m))) for k in applied), default=0.0)

    def total(threads, which, only=None):
        return float(sum(np.mean(rows[threads][k][which]) for k in (only or keys)))

    tiles_out = [{"tile": list(k), "groups": len(strip._refocus.groups[k]),
                  "iterations": int(rows[1][k]["result"].iterations),
                  "cpu_s_one_thread": float(np.mean(rows[1][k]["cpu_s"])),
                  "cpu_s_default_threads": float(np.mean(rows[None][k]["cpu_s"])),
                  "wall_s_one_thread": float(np.mean(rows[1][k]["wall_s"])),
                  "wall_s_default_threads": float(np.mean(rows[None][k]["wall_s"]))} for k in applied]
    out = {
        "what": "the live test's map (two radars, entropy refocus): each finished tile refocused from the same group "
                "images with BLAS on one thread and on OpenBLAS's default, alternating, in one process",
        "frames": int(frame_cpu.size), "imaging_cpu_ms_per_frame_median": 1e3 * float(np.median(frame_cpu)),
        "tiles_refocused": len(keys), "tiles_applied": len(applied), "blas_default_threads": int(default_threads),
        "refocus_cpu_s_all_tiles_one_thread": total(1, "cpu_s"),
        "refocus_cpu_s_all_tiles_default_threads": total(None, "cpu_s"),
        "refocus_wall_s_all_tiles_one_thread": total(1, "wall_s"),
        "refocus_wall_s_all_tiles_default_threads": total(None, "wall_s"),
        "refocus_cpu_ratio_default_over_one": total(None, "cpu_s") / max(total(1, "cpu_s"), 1e-9),
        "refocus_wall_ratio_default_over_one": total(None, "wall_s") / max(total(1, "wall_s"), 1e-9),
        "applied_tiles": tiles_out,
        "estimates_max_difference_m": agree,
        "drive_s": float(frame_cpu.size / len(IMAGING_RADARS) * default_rig().radar(IMAGING_RADARS[0]).waveform.frame_interval_s),
        "repeats": 1 if args.quick else args.repeats,
        "load_average_before": list(load_before), "load_average_after": list(os.getloadavg()),
    }
    print(strict_json.dumps({k: v for k, v in out.items() if k != "applied_tiles"}, indent=1))
    for t in tiles_out:
        print(t)
    if not args.quick:
        write_results("refocus_threads", out, started_load=started_load, indent=1)
        print(f"wrote {RESULTS / 'refocus_threads.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
