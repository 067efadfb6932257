"""The live map's CPU per frame at the configured pre-summing: a baseline commit's map code against the
checkout's, interleaved in one process, fed the same messages; and how far the two maps differ.

    python benchmarks/stripmap_presum.py [--baseline COMMIT] [--rounds 4] [--seconds 12] [--work DIR]

Issue 34 item 5: in the quiet four-radar soak on the AMD VM the map pre-summed 28 % of its frames beyond the
configured factor, its frames needing 24 % of a core against the 30 % it got (docs/benchmark-notes.md). This
measures what one frame at the configured pre-summing (no catch-up) costs the daemon's own worker
(``acquisition.workers.stripmap.StripMapWorker``) on the soak's scene, as ``benchmarks/stripmap_capacity.py``
feeds it (its scene, events, bus messages and map settings, reused from there): four radars, the frames from
2.5 s on (driving), poses in batches of 10 ms held back 40 ms.

Two workers, one per version, take every message in turn (which goes first alternating by message, so the
machine's load and the caches fall on both alike). The baseline's worker holds a ``StripMap`` of the
baseline's ``imaging/stripmap/map.py``, ``polar.py`` and ``placement.py`` (where it has one) loaded from git
(``benchmarks/git_baseline.baseline_module``) beside the checkout's; everything else (the worker, pre-summing,
footprints, the kernels' other modules) is the checkout's in both. CPU per frame is the main thread's
(``time.thread_time``; ``time.process_time`` beside it) over ``handle`` and ``_image_ready`` of every
message, each version's warm-up left out. A round is a fresh pair of workers over the whole drive; the figure
is the median over rounds of the ratio baseline / now. The two maps are compared tile by tile after the last
round: the largest difference in dB below the baseline map's peak.

Writes docs/results/stripmap_presum.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import stripmap_capacity as capacity  # noqa: E402
from acquisition.messages import PoseBatch, decode  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from map_versions import baseline_map, make_worker, soak_map_settings  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

#: main before this round (wave 3l): the commit the soak's 28 % and the map's 3.1 ms a frame were measured at
BASELINE = "678e496"
#: the map's modules this round changed, loaded from the baseline where it has them
MODULES = ["imaging/stripmap/polar.py", "imaging/stripmap/placement.py", "imaging/stripmap/map.py"]


def messages(rec: Recording) -> list:
    """Every message of the drive in bus order: a frame's wire parts, or a PoseBatch."""
    evs, truth = capacity.events(rec, capacity.RADARS, capacity.DRIVING_FROM_S)
    times = {n: rec.frame_time_ns(n) for n in capacity.RADARS}
    iq = {n: rec.adc_iq(n, slice(None)) for n in capacity.RADARS}
    counters = dict.fromkeys(capacity.RADARS, 0)
    out = []
    for _, kind, payload in evs:
        if kind == 0:
            name, k = payload
            out.append(capacity.frame_message_bytes(name, counters[name], int(times[name][k]), iq[name][k]))
            counters[name] += 1
        else:
            s = capacity._sample(truth, payload)
            out.append(PoseBatch(payload, s.position_m, s.orientation_xyzw, s.velocity_mps))
    return out


def one_round(msgs: list, rig, map_config, classes: dict, first: int) -> dict:
    """A fresh worker per version over every message, in turn message by message; each one's thread and
    process CPU, frames imaged and final tiles."""
    workers, pubs = {}, {}
    for v, cls in classes.items():  # the version's class also in warm_up's scratch maps: its kernels compile there
        workers[v], pubs[v] = make_worker(rig, capacity.RADARS, map_config, cls, f"bench-presum-{v}")
    thread = dict.fromkeys(classes, 0.0)
    process = dict.fromkeys(classes, 0.0)
    order = list(classes)
    for i, m in enumerate(msgs):
        for v in (order if (i + first) % 2 == 0 else order[::-1]):
            w = workers[v]
            c, p = time.thread_time(), time.process_time()
            w.handle(decode(capacity.receive(m)) if isinstance(m, list) else m, live=True)
            w._image_ready(budget_s=10.0)
            thread[v] += time.thread_time() - c
            process[v] += time.process_time() - p
    for pub in pubs.values():
        pub.close()
    return {v: {"thread_cpu_s": thread[v], "process_cpu_s": process[v], "frames": workers[v].status.frames_imaged,
                "presummed_more": workers[v].status.frames_presummed_more, "tiles": workers[v].map.tiles}
            for v in classes}


def map_difference(a: dict, b: dict) -> tuple[float, float]:
    """The largest |a - b| over the tiles and a's peak |a| (tiles in one only count whole)."""
    peak = max(float(np.abs(t).max()) for t in a.values())
    worst = 0.0
    for key in set(a) | set(b):
        ta, tb = a.get(key, 0), b.get(key, 0)
        worst = max(worst, float(np.abs(np.asarray(ta) - np.asarray(tb)).max()))
    return worst, peak


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help=f"commit to compare against (default {BASELINE})")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=12.0, help="of the soak's lap simulated (default 12)")
    ap.add_argument("--work", help="folder for the simulated scene, kept for later runs (stripmap_capacity's --work)")
    ap.add_argument("--name", default="stripmap_presum", help="results file's stem")
    args = ap.parse_args(argv)
    started_load = load_average()
    probe_machine()
    numba.set_num_threads(1)  # the worker's kernel threads (--map-threads 1)
    rig, map_config = soak_map_settings()
    from imaging.stripmap import StripMap

    old, loaded = baseline_map(args.baseline, MODULES)
    classes = {"baseline": old, "now": StripMap}
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="sarbot-bench-presum-"))
    work.mkdir(parents=True, exist_ok=True)
    with Recording(capacity.simulate(args.seconds, work)) as rec:
        msgs = messages(rec)
    rounds, loads = [], []
    for r in range(args.rounds):
        loads.append(load_average())
        res = one_round(msgs, rig, map_config, classes, first=r)
        rounds.append(res)
        print(f"round {r}: " + ", ".join(f"{v} {1e3 * x['thread_cpu_s'] / x['frames']:.3f} ms" for v, x in res.items())
              + f"; ratio {res['baseline']['thread_cpu_s'] / res['now']['thread_cpu_s']:.3f}; load {loads[-1]}",
              flush=True)
    last = rounds[-1]
    per = {v: [1e3 * x[v]["thread_cpu_s"] / x[v]["frames"] for x in rounds] for v in classes}
    per_process = {v: [1e3 * x[v]["process_cpu_s"] / x[v]["frames"] for x in rounds] for v in classes}
    ratios = [x["baseline"]["thread_cpu_s"] / x["now"]["thread_cpu_s"] for x in rounds]
    worst, peak = map_difference(last["baseline"]["tiles"], last["now"]["tiles"])
    frames_per_s = sum(1.0 / rig.radar(n).waveform.frame_interval_s for n in capacity.RADARS)
    out = {
        "scene": "soak_loop", "seconds": args.seconds, "radars": capacity.RADARS, "presum": map_config.presum,
        "algorithm": map_config.algorithm, "baseline": args.baseline, "baseline_modules": loaded,
        "rounds": args.rounds, "frames_per_round": last["now"]["frames"],
        "frames_presummed_more": {v: last[v]["presummed_more"] for v in classes},
        "thread_cpu_ms_per_frame": per, "process_cpu_ms_per_frame": per_process,
        "median_thread_cpu_ms_per_frame": {v: statistics.median(x) for v, x in per.items()},
        "baseline_over_now_each_round": ratios, "baseline_over_now_median": statistics.median(ratios),
        "core_fraction_at_1x_median": {v: statistics.median(x) * 1e-3 * frames_per_s for v, x in per.items()},
        "map_max_abs_difference": worst, "map_peak_abs": peak,
        # None: the two maps are the same to the last bit
        "map_difference_db_below_peak": 20 * np.log10(worst / peak) if worst > 0 else None,
        "tiles": {v: len(last[v]["tiles"]) for v in classes},
        "load_average_1min_at_each_round": loads,
    }
    print(f"median ratio {out['baseline_over_now_median']:.3f}; map difference {worst:.3g} against a peak of "
          f"{peak:.3g} ({out['map_difference_db_below_peak']} dB)")
    path = write_results(args.name, out, started_load=started_load, indent=1)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
