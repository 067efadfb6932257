"""The supervisor's recorder on the four-radar soak's mix: CPU per frame, a baseline commit's code against the
checkout's, interleaved in one process; and the recorder's RSS over a long run of each.

    python benchmarks/recorder_cpu_per_frame.py [--baseline COMMIT] [--rounds 6] [--ticks 200] [--rss-ticks 6000]

The mix is what the recorder takes in ``sarbot run`` with four radars (the default rig, the reference
waveform): every 52 ms one 716,800-byte int16 frame of each radar, IMU batches of 20 samples at 400 Hz (one per
50 ms), an event every 2 s; the frames' receive times are their frame end plus 10 ms and a few ms of jitter,
so the receive-delay check does its usual work. Each message is stored as ``Recorder.step`` stores it
(``_store`` then ``_report_gaps``), ``Message`` objects built once outside the timing; a flush every 10
ticks (0.52 s, the recorder's 0.5 s), its fsync thread included; closing included.

- ``cpu``: CPU per radar frame (``time.process_time``: the recorder and its fsync thread) of ``--ticks`` ticks,
  the two versions alternating which goes first in each round. The two files are compared dataset by dataset
  (values), attribute by attribute (``created_utc`` aside), and every ADC chunk as stored (data and checksum).
- ``rss``: each version alone in a fresh process (so neither's heap is the other's), ``--rss-ticks`` ticks as
  fast as it stores them, a new part every 1154 ticks (``--split-time 60`` at 1x) with each finished part
  deleted (as the soak's checker does), RSS read after the first tick (nothing written yet) and every 50
  ticks; the rise from the first part's end to the end (a leak), and the level (HDF5's chunk caches, numba).

The baseline's ``acquisition/recorder.py``, ``imaging/io/recording.py`` (its ``RecordingWriter``) and
``acquisition/ptp.py`` (its ``ReceiveDelay``) are loaded from git (``benchmarks/git_baseline.py``) beside the
checkout's. The machine is shared: the load average is recorded, and the ratios of the same rounds are the
figures, not the milliseconds.

Writes docs/results/recorder_cpu_per_frame.json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import acquisition.recorder as recorder_now  # noqa: E402
from acquisition.bus import Message  # noqa: E402
from acquisition.messages import Event, ImuBatch, RadarFrameMessage  # noqa: E402
from drivers.radar.stream import RadarFrame  # noqa: E402
from git_baseline import baseline_module  # noqa: E402
from imaging.core.rig import default_rig  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

#: main before wave 3m.
BASELINE = "aa20a74"
TICK_NS = 52_000_000
FLUSH_EVERY_TICKS = 10
SPLIT_EVERY_TICKS = 1154  # 60 s at 52 ms


def baseline_recorder(commit: str):
    """The recorder module of ``commit`` with that commit's RecordingWriter and ReceiveDelay."""
    recording = baseline_module(commit, "imaging/io/recording.py", "_baseline_recording")
    ptp = baseline_module(commit, "acquisition/ptp.py", "_baseline_ptp")
    recorder = baseline_module(commit, "acquisition/recorder.py", "_baseline_recorder")
    recorder.RecordingWriter = recording.RecordingWriter
    recorder.ReceiveDelay = ptp.ReceiveDelay
    return recorder


def soak_mix(n_ticks: int, seed: int = 0) -> tuple[object, list[Message]]:
    """The default rig and ``n_ticks`` ticks of its messages as they come off the bus."""
    rig = default_rig()
    wf = rig.radars[0].waveform
    shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)
    rng = np.random.default_rng(seed)
    iqs = [rng.integers(-2048, 2048, shape, dtype=np.int16) for _ in range(6)]
    frame_ns = wf.frame_duration_ns
    messages, seq = [], {}

    def add(parts, host_ns):
        k = seq.get(parts.topic, 0)
        seq[parts.topic] = k + 1
        messages.append(Message(parts.topic, k, parts.sensor_time_ns, host_ns, {"seq": k, "pub": "bench", **parts.fields},
                                parts.arrays))

    t0 = 1_700_000_000_000_000_000
    for k in range(n_ticks):
        t = t0 + k * TICK_NS
        for j, radar in enumerate(rig.radars):
            receive = t + frame_ns + 10_000_000 + int(rng.integers(0, 3_000_000))
            frame = RadarFrame(k, t, receive, True, 0, iqs[(k + j) % len(iqs)], True, 0)
            add(RadarFrameMessage(radar.name, frame).to_parts(), receive)
        n = 21 if k % 25 == 0 else 20  # 400 Hz in 52 ms ticks: a 21st sample now and then
        times = t + np.arange(n, dtype=np.int64) * 2_500_000
        add(ImuBatch(times, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), np.arange(n, dtype=np.uint32) + 21 * k,
                     times + 800_000, 1.5).to_parts(), int(times[-1]))
        if k % 38 == 37:
            add(Event(t, "radar.left_front", "warning", f"frame {k}: 1 datagram(s) lost").to_parts(), t)
    return rig, messages


def store(module, rig, messages: list[Message], path: Path, split_every_ticks: int | None = None, on_tick=None):
    """A version's Recorder storing ``messages`` as ``step`` does, flushing every ``FLUSH_EVERY_TICKS`` ticks."""
    recorder = module.Recorder(path, rig, ["tcp://127.0.0.1:9"], flush_interval_s=1e9,
                               split_s=1e9 if split_every_ticks else None)
    tick = 0
    for msg in messages:
        recorder._store(msg)
        recorder._report_gaps(msg.topic, msg.host_time_ns)
        if msg.topic == "imu":  # the tick's last message
            tick += 1
            if tick % FLUSH_EVERY_TICKS == 0:
                recorder.flush()
            if split_every_ticks and tick % split_every_ticks == 0:
                done = recorder.path
                recorder._next_part()
                done.unlink()
            if on_tick is not None:
                on_tick(tick)
    recorder.close()
    return recorder


def cpu_per_frame(module, rig, messages, path: Path) -> tuple[float, float]:
    """CPU and wall seconds per radar frame of storing ``messages`` into ``path``."""
    path.unlink(missing_ok=True)
    frames = sum(1 for m in messages if m.topic.startswith("radar/"))
    c0, w0 = time.process_time(), time.perf_counter()
    store(module, rig, messages, path)
    return (time.process_time() - c0) / frames, (time.perf_counter() - w0) / frames


def compare_files(a: Path, b: Path) -> dict:
    """Whether two recordings hold the same datasets, values, attributes and ADC chunks as stored."""
    import h5py

    different: list[str] = []
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        names_a, names_b = [], []
        fa.visit(names_a.append)
        fb.visit(names_b.append)
        if sorted(names_a) != sorted(names_b):
            different.append(f"objects: {sorted(set(names_a) ^ set(names_b))}")
        chunks = 0
        for name in [n for n in names_a if n in fb]:
            oa, ob = fa[name], fb[name]
            attrs_a = {k: v for k, v in oa.attrs.items() if k != "created_utc"}
            attrs_b = {k: v for k, v in ob.attrs.items() if k != "created_utc"}
            if sorted(attrs_a) != sorted(attrs_b) or any(not np.array_equal(attrs_a[k], attrs_b[k]) for k in attrs_a):
                different.append(f"{name} attributes")
            if isinstance(oa, h5py.Dataset):
                if oa.dtype != ob.dtype or oa.shape != ob.shape or oa.chunks != ob.chunks or oa.fletcher32 != ob.fletcher32:
                    different.append(f"{name} layout")
                elif not np.array_equal(oa[...], ob[...]):
                    different.append(f"{name} values")
                elif name.endswith("/adc"):
                    zeros = (0,) * (oa.ndim - 1)
                    for k in range(oa.shape[0]):
                        chunks += 1
                        if oa.id.read_direct_chunk((k, *zeros)) != ob.id.read_direct_chunk((k, *zeros)):
                            different.append(f"{name} chunk {k}")
                            break
        for root_attr in ("created_utc",):
            if root_attr not in fa.attrs or root_attr not in fb.attrs:
                different.append(f"/ {root_attr} missing")
    return {"identical": not different, "differences": different[:10], "adc_chunks_compared": chunks}


def _ticks_end(messages: list[Message], ticks: int) -> int:
    """How many of ``messages`` make their first ``ticks`` ticks (each ends with its IMU batch)."""
    ends = [k + 1 for k, m in enumerate(messages) if m.topic == "imu"]
    return ends[ticks - 1]


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def rss_run(version: str, commit: str, n_ticks: int) -> dict:
    """In this (fresh) process: one version storing ``n_ticks`` ticks with parts split and deleted, RSS sampled."""
    from acquisition.processes import release_free_heap

    module = recorder_now if version == "now" else baseline_recorder(commit)
    folder = Path(tempfile.mkdtemp(prefix="recorder_rss."))
    rig, lap = soak_mix(min(n_ticks, 200))
    lap_ticks = min(n_ticks, 200)
    samples = []
    started = time.monotonic()
    last_trim = [started]

    def on_tick(tick):
        now = time.monotonic()
        if now - last_trim[0] >= 1.0:  # as the daemon's loop does
            release_free_heap()
            last_trim[0] = now
        if tick % 50 == 0 or tick == 1:  # tick 1: before the first flush (nothing written yet)
            samples.append((tick, round(rss_mb(), 1)))

    def laps():
        """The same ticks again and again, the times continuing (the recorder stores what it is given; the
        sequence numbers it checks are the subscriber's, not used here)."""
        for k in range((n_ticks + lap_ticks - 1) // lap_ticks):
            shift = k * lap_ticks * TICK_NS
            for m in lap[:None if (k + 1) * lap_ticks <= n_ticks else _ticks_end(lap, n_ticks - k * lap_ticks)]:
                yield Message(m.topic, m.seq, m.sensor_time_ns + shift, m.host_time_ns + shift,
                              {**m.header, **({"frame_time_ns": m.header["frame_time_ns"] + shift,
                                               "receive_ns": m.header["receive_ns"] + shift}
                                              if m.topic.startswith("radar/") else {})},
                              m.arrays if not m.topic == "imu" else [m.arrays[0] + shift, *m.arrays[1:4], m.arrays[4] + shift])

    store(module, rig, laps(), folder / "rss.h5", SPLIT_EVERY_TICKS, on_tick)
    shutil.rmtree(folder, ignore_errors=True)
    after_first_part = [r for t, r in samples if t >= SPLIT_EVERY_TICKS]
    return {"version": version, "ticks": n_ticks, "frames": 4 * n_ticks, "wall_s": time.monotonic() - started,
            "rss_mb_every_50_ticks": samples,
            "rss_rise_after_first_part_mb": (after_first_part[-1] - after_first_part[0]) if after_first_part else None,
            "rss_first_tick_mb": samples[0][1], "rss_max_mb": max(r for _, r in samples)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", default=BASELINE)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--ticks", type=int, default=200, help="ticks (4 frames each) per timed pass")
    parser.add_argument("--rss-ticks", type=int, default=6000, help="ticks of each version's RSS run (0: none)")
    parser.add_argument("--rss-only", choices=["now", "baseline"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.rss_only:
        print(json.dumps(rss_run(args.rss_only, args.baseline, args.rss_ticks)))
        return

    started_load = load_average()
    probe_machine()
    versions = {"baseline": baseline_recorder(args.baseline), "now": recorder_now}
    rig, messages = soak_mix(args.ticks)
    folder = Path(tempfile.mkdtemp(prefix="recorder_cpu_per_frame."))
    cpu = {v: [] for v in versions}
    wall = {v: [] for v in versions}
    comparisons = []
    store(recorder_now, rig, messages[:60], folder / "warm.h5")  # numba's kernel loaded before timing
    for r in range(args.rounds):
        order = list(versions) if r % 2 == 0 else list(versions)[::-1]
        for v in order:
            c, w = cpu_per_frame(versions[v], rig, messages, folder / f"{v}.h5")
            cpu[v].append(c)
            wall[v].append(w)
        if r == 0 or r == args.rounds - 1:
            comparisons.append(compare_files(folder / "baseline.h5", folder / "now.h5"))
        print(f"round {r + 1}: CPU ms/frame baseline {cpu['baseline'][-1] * 1e3:.3f} now {cpu['now'][-1] * 1e3:.3f} "
              f"(load {load_average()[0]})", flush=True)
    shutil.rmtree(folder, ignore_errors=True)
    ratios = [b / n for b, n in zip(cpu["baseline"], cpu["now"])]
    result = {
        "baseline_commit": args.baseline, "rounds": args.rounds, "ticks_per_pass": args.ticks,
        "frames_per_pass": 4 * args.ticks, "flush_every_ticks": FLUSH_EVERY_TICKS,
        "cpu": {"cpu_ms_per_frame": {v: [x * 1e3 for x in xs] for v, xs in cpu.items()},
                "wall_ms_per_frame": {v: [x * 1e3 for x in xs] for v, xs in wall.items()},
                "median_cpu_ms_per_frame": {v: statistics.median(xs) * 1e3 for v, xs in cpu.items()},
                "ratio_baseline_over_now_per_round": ratios, "median_ratio": statistics.median(ratios)},
        "files_compared": comparisons,
        "files_identical": all(c["identical"] for c in comparisons),
    }
    if args.rss_ticks:
        result["rss"] = {}
        for v in versions:
            out = subprocess.run([sys.executable, __file__, "--rss-only", v, "--baseline", args.baseline,
                                  "--rss-ticks", str(args.rss_ticks)], check=True, capture_output=True, text=True)
            result["rss"][v] = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"rss {v}: rise after the first part {result['rss'][v]['rss_rise_after_first_part_mb']} MB, "
                  f"max {result['rss'][v]['rss_max_mb']} MB", flush=True)
    result["load_average_end"] = load_average()
    path = write_results("recorder_cpu_per_frame", result, started_load=started_load)
    print(f"recorder: {result['cpu']['median_ratio']:.2f}x less CPU per frame (baseline / now, median of {args.rounds} "
          f"rounds), files identical: {result['files_identical']} -> {path}")


if __name__ == "__main__":
    main()
