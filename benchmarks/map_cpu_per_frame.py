"""The live strip map's CPU per frame: the map's code at a baseline commit against the checkout's, interleaved
in one process on the soak's frames, one radar and the four-radar mix, and the two maps compared.

    python benchmarks/map_cpu_per_frame.py [--baseline d92f09a] [--rounds 4] [--seconds 12] [--work DIR]

The frames, poses and bus messages are ``stripmap_capacity.py``'s (the soak's scene ``soak_loop``, simulated
once into ``--work``; the frames from 2.5 s on, the robot driving; poses as the odometry sends them), fed to
the daemon's own worker (``acquisition.workers.stripmap.StripMapWorker``, ``sarbot run``'s map settings, one
kernel thread). Two workers, one with the baseline's strip-map modules (``imaging/stripmap/polar.py`` and
``map.py`` at ``--baseline``, by ``git_baseline.baseline_module``: the baseline map calls the baseline beams),
one with the checkout's, each take every message in turn, which goes first alternating, so the machine's load
falls on both alike. Per variant: process CPU (``time.process_time``) and thread CPU (``time.thread_time``)
beside wall time, of the worker's handling, imaging and publishing of each message with its bus decode.
A round is a fresh pair of workers over the lap; the figures are each round's ratio baseline / now and their
median. After each round the maps: bit for bit the same, or the checkout's SER against the baseline's.

Also the first candidate the task named, measured: the beams' range compression over only the bins their
pixels need (a chirp-z transform, ``imaging.range_window``) against the full FFT, on a frame's beam signals.

Writes docs/results/map_cpu_per_frame.json (``--name``: another stem).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import stripmap_capacity as capacity  # noqa: E402
from acquisition.messages import PoseBatch, decode  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from map_versions import baseline_map, make_worker, soak_map_settings  # noqa: E402
import imaging.stripmap  # noqa: E402
import imaging.stripmap.polar as polar_now  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

#: main when this benchmark was written (wave 3n's start)
BASELINE = "d92f09a"
#: the modules compared: the baseline map calls the baseline beams
MODULES = ["imaging/stripmap/polar.py", "imaging/stripmap/map.py"]


def one_round(rec, rig, radars, map_config, classes: dict, from_s: float) -> dict:
    """Every message of the lap through a fresh worker per variant, in turn; CPU and wall time per variant."""
    workers = {v: make_worker(rig, radars, map_config, c, f"bench-map-cpu-{v}") for v, c in classes.items()}
    spent = {v: np.zeros(3) for v in classes}  # process CPU, thread CPU, wall
    evs, truth = capacity.events(rec, radars, from_s)
    frame_times = {name: rec.frame_time_ns(name) for name in radars}
    counters = dict.fromkeys(radars, 0)
    iq_cache: dict = {}
    frames, next_publish = 0, None
    try:
        for t_avail, kind, payload in evs:
            if kind == 0:
                name, k = payload
                start, block = iq_cache.get(name, (-1, None))
                if block is None or not start <= k < start + block.shape[0]:
                    block = rec.adc_iq(name, slice(k, k + 32))
                    iq_cache[name] = start, block = k, block
                wire = capacity.frame_message_bytes(name, counters[name], int(frame_times[name][k]), block[k - start])
                counters[name] += 1
                frames += 1
            else:
                s = capacity._sample(truth, payload)
            next_publish = t_avail + int(capacity.PUBLISH_EVERY_S * 1e9) if next_publish is None else next_publish
            publish_now = t_avail >= next_publish
            if publish_now:
                next_publish += int(capacity.PUBLISH_EVERY_S * 1e9)
            order = list(classes) if frames % 2 else list(classes)[::-1]
            for v in order:
                worker = workers[v][0]
                c0, th0, w0 = time.process_time(), time.thread_time(), time.perf_counter()
                message = (decode(capacity.receive(wire)) if kind == 0 else
                           PoseBatch(payload, s.position_m, s.orientation_xyzw, s.velocity_mps))
                worker.handle(message, live=True)
                worker._image_ready(budget_s=10.0)  # what step() does, without its wall-clock publishing
                if publish_now:
                    worker._publish_tiles()
                spent[v] += (time.process_time() - c0, time.thread_time() - th0, time.perf_counter() - w0)
    finally:
        for _, pub in workers.values():
            pub.close()
    maps = {v: w.map for v, (w, _) in workers.items()}
    return {"frames": frames, "spent": spent, "maps": maps,
            "frames_imaged": {v: w.status.frames_imaged for v, (w, _) in workers.items()},
            "presummed_more": {v: w.status.frames_presummed_more for v, (w, _) in workers.items()}}


def compare_maps(base, now) -> dict:
    """Whether the checkout's map is the baseline's bit for bit, and its SER against it (dB)."""
    same_tiles = base.tiles.keys() == now.tiles.keys()
    identical = same_tiles and all(np.array_equal(base.tiles[k], now.tiles[k]) for k in base.tiles)
    a, _, _ = base.mosaic()
    b, _, _ = now.mosaic()
    if a.shape != b.shape:
        return {"same_tiles": same_tiles, "bit_for_bit": False, "ser_db": None}
    err = float(np.sum(np.abs(b.astype(np.complex128) - a) ** 2))
    ser = None if err == 0 else float(10 * np.log10(np.sum(np.abs(a.astype(np.complex128)) ** 2) / err))
    return {"same_tiles": same_tiles, "bit_for_bit": identical, "ser_db": ser}


def range_window_of_beams(rec, rig, map_config, reps: int = 200) -> dict:
    """A live frame's beams (left_front's, 4 s into the lap): how many of their bins the pixels need, and their
    range compression over only those (a chirp-z transform) against every bin (the zero-padded FFT, as
    ``frame_beams_over`` does it), CPU per frame; the windowed beam signals taken as the FFT gets them."""
    from imaging.pocketfft import fft_in_place
    from imaging.range_compression import range_bin_spacing_m
    from imaging.range_window import needed_bins, worth_it, zoom_spectrum
    from imaging.stripmap import StripMap

    captured = {}
    original = polar_now.fft_in_place

    def spy(rows, *args, **kwargs):
        captured.setdefault("rows", rows.copy())
        return original(rows, *args, **kwargs)

    radar = rig.radar("left_front")
    truth = rec.truth()
    sm = StripMap(map_config)
    polar_now.fft_in_place = spy
    try:
        k = int(np.searchsorted(rec.frame_time_ns("left_front"), truth.time_ns[0] + int(4e9)))
        sm.add_frames(radar, radar.waveform.tdm_tx_order(), [rec.adc_iq("left_front", slice(k, k + 1))[0]],
                      [int(rec.frame_time_ns("left_front")[k])], truth)
    finally:
        polar_now.fft_in_place = original
    rows = captured["rows"]
    wf = radar.waveform
    n = wf.samples_per_chirp
    n_fft = rows.shape[1]
    m = (n - 1) // 2
    pos = (np.arange(n) - m) % n_fft
    windowed = np.ascontiguousarray(rows[:, pos])  # sample i sits at i - m modulo n_fft
    step = range_bin_spacing_m(n_fft, wf.frequency_step_hz)
    # the footprint's two-way ranges: 2 x (range_min .. range_max with the aperture's half-width across)
    k0, k1 = needed_bins(2 * map_config.range_min_m, 2 * np.hypot(map_config.range_max_m, map_config.aperture_m / 2),
                         step, n_fft)
    ones = np.ones(n, np.float32)  # the window is in the samples already
    out = np.empty((rows.shape[0], k1 - k0), np.complex64)

    def full():
        padded = np.zeros_like(rows)
        padded[:, pos] = windowed
        return fft_in_place(padded)

    def window():
        return zoom_spectrum(windowed, ones, m, n_fft, k0, out)

    cpu = {"full FFT": [], "chirp-z window": []}
    for _ in range(3):
        for name, f in (("full FFT", full), ("chirp-z window", window)):
            f()
            t0 = time.process_time()
            for _ in range(reps):
                f()
            cpu[name].append((time.process_time() - t0) / reps * 1e3)
    ref = full()[:, k0:k1]
    got = window()
    ser = float(10 * np.log10(np.sum(np.abs(ref) ** 2) / np.sum(np.abs(got - ref) ** 2)))
    return {"beam_rows": int(rows.shape[0]), "samples": int(n), "n_fft": int(n_fft), "bins_needed": [int(k0), int(k1)],
            "fraction_of_bins": (k1 - k0) / n_fft, "worth_it": bool(worth_it(n, n_fft, k1 - k0)),
            "cpu_ms_per_frame": {k: float(np.median(v)) for k, v in cpu.items()},
            "cpu_ms_per_frame_each": cpu, "window_ser_db_against_full": ser}


def main(argv: list[str]) -> int:
    import numba

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help=f"the commit to compare with (default {BASELINE})")
    ap.add_argument("--rounds", type=int, default=4, help="rounds per case (default 4, at least 1)")
    ap.add_argument("--seconds", type=float, default=12.0, help="of the soak's lap simulated (default 12)")
    ap.add_argument("--work", help="folder for the simulated scene, kept for later runs (default: a new temporary one)")
    ap.add_argument("--name", default="map_cpu_per_frame", help="the results file's stem")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error(f"--rounds {args.rounds}: at least 1")
    started_load = load_average()
    probe_machine()
    numba.set_num_threads(1)  # the worker's kernel threads (--map-threads 1)
    rig, map_config = soak_map_settings()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="sarbot-bench-map-cpu-"))
    work.mkdir(parents=True, exist_ok=True)
    path = capacity.simulate(args.seconds, work)
    classes = {"baseline": baseline_map(args.baseline, MODULES)[0], "now": imaging.stripmap.StripMap}
    out = {"scene": "soak_loop", "seconds": args.seconds, "driving_from_s": capacity.DRIVING_FROM_S,
           "baseline": args.baseline, "presum": map_config.presum, "algorithm": map_config.algorithm,
           "changed_files": subprocess.run(["git", "diff", "--name-only", args.baseline, "--", "imaging/stripmap",
                                            "acquisition/workers/stripmap.py"], cwd=ROOT, capture_output=True,
                                           text=True).stdout.split(),
           "cases": {}}
    with Recording(path) as rec:
        out["range_window_of_beams"] = range_window_of_beams(rec, rig, map_config)
        print("range window of the beams:", out["range_window_of_beams"], flush=True)
        for case, radars in (("one radar", ["left_front"]), ("four radars", capacity.RADARS)):
            rows = []
            for r in range(args.rounds):
                load = os.getloadavg()[0]
                got = one_round(rec, rig, radars, map_config, classes, capacity.DRIVING_FROM_S)
                per = {v: 1e3 * s / got["frames"] for v, s in got["spent"].items()}
                row = {"load_1min": load, "frames": got["frames"], "frames_imaged": got["frames_imaged"],
                       "frames_presummed_more": got["presummed_more"],
                       **{f"{v}_ms_per_frame": {"process_cpu": p[0], "thread_cpu": p[1], "wall": p[2]}
                          for v, p in per.items()},
                       "baseline_over_now": {"process_cpu": float(per["baseline"][0] / per["now"][0]),
                                             "thread_cpu": float(per["baseline"][1] / per["now"][1]),
                                             "wall": float(per["baseline"][2] / per["now"][2])},
                       "maps": compare_maps(got["maps"]["baseline"], got["maps"]["now"])}
                rows.append(row)
                print(f"{case}, round {r} (load {load:.1f}): baseline {per['baseline'][0]:.3f}, now {per['now'][0]:.3f} "
                      f"ms CPU a frame ({row['baseline_over_now']['process_cpu']:.3f}x); maps {row['maps']}", flush=True)
            ratios = [row["baseline_over_now"]["process_cpu"] for row in rows]
            frames_per_s = sum(1.0 / rig.radar(n).waveform.frame_interval_s for n in radars)
            now_ms = float(np.median([row["now_ms_per_frame"]["process_cpu"] for row in rows]))
            base_ms = float(np.median([row["baseline_ms_per_frame"]["process_cpu"] for row in rows]))
            out["cases"][case] = {
                "radars": radars, "rounds": rows,
                "baseline_over_now_process_cpu_median": float(np.median(ratios)),
                "baseline_over_now_process_cpu_range": [float(min(ratios)), float(max(ratios))],
                "baseline_over_now_thread_cpu_median": float(np.median([row["baseline_over_now"]["thread_cpu"]
                                                                        for row in rows])),
                "now_ms_per_frame_median": now_ms, "baseline_ms_per_frame_median": base_ms,
                "core_fraction_at_1x": {"baseline": base_ms * 1e-3 * frames_per_s, "now": now_ms * 1e-3 * frames_per_s},
                "maps_bit_for_bit": all(row["maps"]["bit_for_bit"] for row in rows),
                "maps_worst_ser_db": min((row["maps"]["ser_db"] for row in rows if row["maps"]["ser_db"] is not None),
                                         default=None)}
    out["commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                   text=True).stdout.strip()
    out.update(cpu_count=os.cpu_count(), numba_threads=1)
    write_results(args.name, out, started_load=started_load, indent=1)
    print(f"wrote docs/results/{args.name}.json")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
