"""Live strip map: frames per second against the sensor rate, and map error against an offline full
backprojection of the same data, for the settings that trade one for the other.

    python benchmarks/stripmap.py [--quick]

Data: the demo scene (four reference radars, 0.4 m/s past a rod, a reflector and clutter), simulated once.
Speed: every setting images the same frames of all four radars, interleaved as they arrive live, on this
machine's two cores (the worker alone; the daemon's other processes are measured by daemon_recording.py).
The sensor rate is 4 x 19.2 = 77 frames/s. The live worker runs its kernel on one thread
(``StripMapWorkerConfig.threads``): the CPU time per frame of the default setting on one and on two
threads says what a second thread costs a machine the map shares with the drivers. Error: the left-front radar's map over the rod and reflector
against the exact matched filter (mode "exact", no pre-summing, same aperture limit), as error energy
relative to the reference image, dB. The baseline is the default setting, run in the same process.
Batching (what the live worker does with frames queued behind): the CPU per frame when each radar's
frames go into the map 1, 2, 4 or 8 at a time (``StripMap.add_frames``), at the default pre-summing and at
the catch-up's most (all of a TX's chirps), as a ratio to one at a time, and the batched map's difference
from the frame-by-frame one (the same map: the float32 kernel's rounding).

Writes docs/results/stripmap.json and docs/results/stripmap.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.stripmap import StripMap, StripMapConfig, max_presum  # noqa: E402
from results_file import finite_or_none, load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
DEFAULT = StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=4.0, z_m=0.3)


def frames_of(rec: Recording, names, first: int, count: int):
    out = []
    for k in range(first, first + count):
        for name in names:
            out.append((name, rec.adc(name, slice(k, k + 1))[0], int(rec.frame_time_ns(name)[k])))
    return out


def run(config: StripMapConfig, rec: Recording, frames, truth, cpu: list | None = None) -> tuple[StripMap, float]:
    """The map of ``frames`` and the wall time it took; its process CPU time appended to ``cpu`` if given."""
    sm = StripMap(config)
    radars = {n: rec.radar(n) for n in rec.radar_names}
    orders = {n: rec.tdm_tx_order(n) for n in rec.radar_names}
    name, adc, t = frames[0]
    StripMap(config).add_frame(radars[name], orders[name], adc, t, truth)  # compile / warm caches
    t0, c0 = time.perf_counter(), time.process_time()
    for name, adc, t in frames:
        sm.add_frame(radars[name], orders[name], adc, t, truth)
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    return sm, time.perf_counter() - t0


def cpu_by_threads(config: StripMapConfig, rec: Recording, frames, truth, repeats: int = 3) -> dict:
    """CPU and wall time per frame of ``config`` with the kernel on 1 and on 2 threads (best of ``repeats``)."""
    import numba

    out = {}
    for threads in (1, 2):
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        cpu, wall = [], []
        for _ in range(repeats):
            wall.append(run(config, rec, frames, truth, cpu)[1])
        out[str(threads)] = {"cpu_ms_per_frame": 1e3 * min(cpu) / len(frames), "wall_ms_per_frame": 1e3 * min(wall) / len(frames)}
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    return out


def batching(config: StripMapConfig, rec: Recording, frames, truth, presums, batches=(1, 2, 4, 8), repeats: int = 3) -> list:
    """CPU per frame imaging ``frames`` (every radar's, interleaved) ``batch`` frames of a radar at a time,
    best of ``repeats``; and the map's difference from the frame-by-frame one, dB."""
    radars = {n: rec.radar(n) for n in rec.radar_names}
    orders = {n: rec.tdm_tx_order(n) for n in rec.radar_names}
    by_radar = {n: [f for f in frames if f[0] == n] for n in radars}
    rows = []
    for presum in presums:
        one = None
        for batch in batches:
            cpu = []
            for _ in range(repeats):
                sm = StripMap(config)
                c0 = time.process_time()
                for a in range(0, max(len(v) for v in by_radar.values()), batch):
                    for name, mine in by_radar.items():
                        if mine[a:a + batch]:
                            sm.add_frames(radars[name], orders[name], [f[1] for f in mine[a:a + batch]],
                                          [f[2] for f in mine[a:a + batch]], truth, presum=presum)
                cpu.append(time.process_time() - c0)
            one = one or (sm, min(cpu))
            rows.append({"presum": presum, "batch_frames": batch, "cpu_ms_per_frame": 1e3 * min(cpu) / len(frames),
                         "ratio_to_one_at_a_time": one[1] / min(cpu),
                         "difference_from_one_at_a_time_db": None if sm is one[0] else finite_or_none(map_error_db(sm, one[0]))})
            print(f"presum {presum:3d}, {batch} frame(s) at a time: {rows[-1]['cpu_ms_per_frame']:.2f} ms of CPU a frame "
                  f"({rows[-1]['ratio_to_one_at_a_time']:.2f}x)", flush=True)
    return rows


def map_error_db(sm: StripMap, ref: StripMap) -> float:
    img, x, y = sm.mosaic()
    r, xr, yr = ref.mosaic()
    assert img.shape == r.shape and np.allclose(x, xr) and np.allclose(y, yr)
    return float(10 * np.log10(np.sum(np.abs(img - r) ** 2) / np.sum(np.abs(r) ** 2)))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames and settings")
    args = ap.parse_args(argv)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    scene = load_scene("demo_room")
    work = Path(tempfile.mkdtemp(prefix="sarbot-bench-stripmap-"))
    path = work / "demo_room.h5"
    print("simulating the demo scene ...", flush=True)
    simulate_recording(scene, path)
    rec = Recording(path)
    truth = rec.truth()
    n_speed = 20 if args.quick else 50
    n_error = 20 if args.quick else 40
    first = int(3.2 / 0.052)  # driving at full speed, the rod and reflector in the beam of the left radars
    speed_frames = frames_of(rec, rec.radar_names, first, n_speed)
    error_frames = frames_of(rec, ["left_front"], first, n_error)
    radar = rec.radar("left_front")
    auto = max_presum(DEFAULT, radar, 0.5)
    sensor_fps = 4 / radar.waveform.frame_interval_s
    settings = [("default: linear x8, presum auto", dataclasses.replace(DEFAULT, presum=auto))]
    modes = [("nearest", 8), ("linear", 4), ("linear", 8), ("linear", 16)]
    presums = [1, 2, 4, 8] if not args.quick else [1, 4]
    for mode, over in modes:
        for p in presums:
            cfg = dataclasses.replace(DEFAULT, mode=mode, oversample=over, presum=p)
            if cfg != settings[0][1]:
                settings.append((f"{mode} x{over}, presum {p}", cfg))
    print("reference: exact matched filter, no pre-summing ...", flush=True)
    ref, ref_s = run(dataclasses.replace(DEFAULT, mode="exact", presum=1), rec, error_frames, truth)
    threads = cpu_by_threads(settings[0][1], rec, speed_frames, truth)
    print("default setting, CPU per frame: " + ", ".join(f"{n} thread(s) {v['cpu_ms_per_frame']:.1f} ms"
                                                         for n, v in threads.items()), flush=True)
    import numba

    numba.set_num_threads(1)  # as the live worker runs it
    wf = radar.waveform
    from imaging.core.samples import complex_to_iq

    as_received = [(n, complex_to_iq(a, 1000.0), t) for n, a, t in speed_frames]  # int16 I/Q, as off the bus
    batched = batching(dataclasses.replace(DEFAULT, presum=auto), rec, as_received, truth,
                       presums=[auto, wf.chirps_per_frame // wf.n_tx])
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    rows = []
    base_fps = None
    for label, cfg in settings:
        sm, secs = run(cfg, rec, speed_frames, truth)
        fps = len(speed_frames) / secs
        err_map, _ = run(cfg, rec, error_frames, truth)
        err = map_error_db(err_map, ref)
        base_fps = base_fps or fps
        from imaging.stripmap import presum_phase_spread_rad

        row = {"setting": label, "mode": cfg.mode, "oversample": cfg.oversample, "presum": cfg.presum,
               "frames_per_s": fps, "real_time_multiple": fps / sensor_fps, "ratio_to_baseline": fps / base_fps,
               "error_db": finite_or_none(err), "presum_phase_spread_rad_at_0.5_mps": presum_phase_spread_rad(cfg, radar, 0.5),
               "tiles": len(sm.tiles)}
        rows.append(row)
        print(f"{label:34s} {fps:7.1f} frames/s = {fps / sensor_fps:5.2f}x the four radars "
              f"({fps / base_fps:4.2f}x baseline), error {err:6.1f} dB", flush=True)
    summary = {
        "scene": "demo_room", "radars": 4, "sensor_frames_per_s": sensor_fps, "frames_timed": len(speed_frames),
        "error_reference": "mode exact, presum 1, same aperture limit (0.3 m), left_front radar, "
                           f"{len(error_frames)} frames; reference took {ref_s:.1f} s",
        "default": dataclasses.asdict(settings[0][1]), "rows": rows, "default_by_kernel_threads": threads,
        "batching": batched, "batching_note": "CPU per frame on one kernel thread, the frames of each radar imaged "
                                              "batch_frames at a time (StripMap.add_frames), every radar's in turn",
        "baseline": "the default setting in the same process",
    }
    stem = "stripmap_quick" if args.quick else "stripmap"  # a smoke run keeps the real figures
    write_results(stem, summary, started_load=started_load)
    plot(rows, sensor_fps, RESULTS / f"{stem}.png")
    rec.close()
    path.unlink()
    print(f"wrote {RESULTS / (stem + '.json')}")
    return 0


def plot(rows, sensor_fps: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    markers = {"nearest": "v", "linear": "o"}
    for r in rows:
        ax.scatter(r["frames_per_s"], r["error_db"], marker=markers.get(r["mode"], "s"), s=20 + 15 * r["presum"],
                   color="C3" if r["setting"].startswith("default") else "C0")
        ax.annotate(f"{r['mode'][0]}x{r['oversample']} p{r['presum']}", (r["frames_per_s"], r["error_db"]), fontsize=7,
                    xytext=(4, 2), textcoords="offset points")
    ax.axvline(sensor_fps, color="k", ls="--", lw=1)
    ax.text(sensor_fps, ax.get_ylim()[1], " four radars, real time", va="top", fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("strip-map frames per second (2 cores)")
    ax.set_ylabel("error against exact full backprojection, dB")
    ax.set_title("live strip map: speed against accuracy (red: default)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
