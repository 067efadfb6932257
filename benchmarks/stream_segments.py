"""The frame assembly's CPU per frame, fed one datagram at a time (``feed``) against batches of datagrams
received back to back (``feed_segments``, as UDP GRO hands them over), interleaved in one process on the same
datagrams.

    python benchmarks/stream_segments.py [--rounds 6] [--frames 12] [--batches 64,8]

- ``srf1``: ``Srf1Stream`` on the reference waveform's frames (716,800 bytes, 498 version 2 datagrams of 1,472
  bytes, the last shorter), distinct random frames packed as replay sends them (``PackedEncoder``). ``feed``
  gets each datagram as ``bytes`` (what ``UdpReceiver.receive`` returns; cutting them is not timed);
  ``feed_segments`` gets a frame's datagrams in batches of N (N - 1 full ones and the short last one end a
  frame's last batch, as GRO cuts at a shorter datagram), each as a ``memoryview`` of the packed buffer.
- ``dca1000``: ``Dca1000Assembler`` on a TI frame of 128 chirps x 4 RX x 256 samples, complex 1x (524,288
  bytes), in the card's 1,466-byte datagrams (1,456 bytes of samples), which do not line up with frames:
  batches of N datagrams of one stream.

Each mode is timed per frame (``time.process_time``, ``time.thread_time`` and wall clock around the calls
that give one frame), and the frames it gives are compared byte for byte with what was sent, outside the
timing, and dropped (a driver passes its frames on: kept, every new frame would be fresh memory to fault
in). Rounds alternate the order of the modes so the machine's load falls on all alike; the figures are the
medians over rounds and the ratio feed / feed_segments per round. The machine is shared: the load average and
the VM's speed probe are recorded.

Writes docs/results/stream_segments.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from drivers.radar.dca1000 import Dca1000Assembler, encode_data_packets  # noqa: E402
from driver_cpu_per_frame import frames_datagrams  # noqa: E402
from drivers.radar.srf1 import Srf1Stream  # noqa: E402
from imaging.core.waveform import Waveform  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

DCA_FRAME_BYTES = 128 * 4 * 256 * 4


def srf1_frames(n_frames: int, waveform: Waveform) -> tuple[list[bytes], list[tuple[np.ndarray, int]]]:
    """The wire bytes of ``n_frames`` distinct frames and each frame's datagrams packed: (buffer, size); the
    frames of ``driver_cpu_per_frame.frames_datagrams``."""
    iqs, packed = frames_datagrams(n_frames, waveform)
    return [iq.tobytes() for iq in iqs], [(p.data, p.size) for p in packed]


def srf1_batches(packed: tuple[np.ndarray, int], most: int) -> list[tuple[memoryview, int]]:
    """One frame's datagrams as GRO hands them over: ``most`` at a time, the short last one ending the last."""
    data, size = packed
    view = memoryview(data)
    step = most * size
    return [(view[o:o + step], size) for o in range(0, len(view), step)]


def timed(calls) -> tuple[list, float, float, float]:
    """Run ``calls`` (callables returning frames); the frames and the process, thread and wall seconds."""
    out = []
    c0, t0, w0 = time.process_time(), time.thread_time(), time.perf_counter()
    for call in calls:
        out += call()
    return out, time.process_time() - c0, time.thread_time() - t0, time.perf_counter() - w0


def run_srf1(mode: str, wire: list[bytes], packed: list, singles: list[list[bytes]], shape) -> dict:
    """One pass of ``mode`` ("feed" or "batch N") over every frame: CPU per frame and whether every frame came
    out whole, valid and byte for byte what was sent."""
    stream = Srf1Stream(shape, 1)
    cpu, thread, wall, same = [], [], [], True
    for k in range(len(wire)):
        if mode == "feed":
            calls = [lambda d=d: stream.feed(d, 1) for d in singles[k]]
        else:
            calls = [lambda b=b, s=s: stream.feed_segments(b, s, 1) for b, s in srf1_batches(packed[k], int(mode.split()[1]))]
        out, c, t, w = timed(calls)
        same &= len(out) == 1 and out[0].valid and out[0].iq.tobytes() == wire[k]
        cpu.append(c)
        thread.append(t)
        wall.append(w)
    return {"cpu_s": sum(cpu) / len(cpu), "thread_s": sum(thread) / len(thread), "wall_s": sum(wall) / len(wall),
            "frames_identical": bool(same), "datagrams": stream.counters.datagrams}


def run_dca(mode: str, stream_bytes: bytes, datagrams: list[bytes], packed: np.ndarray, size: int) -> dict:
    """One pass of ``mode`` over the DCA1000 stream, per frame; the frames compared with the stream."""
    asm = Dca1000Assembler(DCA_FRAME_BYTES)
    if mode == "feed":
        calls = [lambda d=d: asm.feed(d, 1) for d in datagrams]
    else:
        step = int(mode.split()[1]) * size
        view = memoryview(packed)
        calls = [lambda o=o: asm.feed_segments(view[o:o + step], size, 1) for o in range(0, len(view), step)]
    cpu = thread = wall = 0.0
    same, frames = True, 0
    for chunk in range(0, len(calls), 16):  # a few frames' worth at a time, their frames checked and dropped
        out, c, t, w = timed(calls[chunk:chunk + 16])
        cpu, thread, wall = cpu + c, thread + t, wall + w
        for f in out:
            same &= f.valid and bytes(f.data) == stream_bytes[f.index * DCA_FRAME_BYTES:(f.index + 1) * DCA_FRAME_BYTES]
        frames += len(out)
    n = len(stream_bytes) // DCA_FRAME_BYTES
    return {"cpu_s": cpu / n, "thread_s": thread / n, "wall_s": wall / n, "frames_identical": bool(same and frames == n),
            "datagrams": asm.counters.datagrams}


def summary(per_round: dict[str, list[dict]]) -> dict:
    out = {"cpu_ms_per_frame": {m: [r["cpu_s"] * 1e3 for r in rs] for m, rs in per_round.items()},
           "median_cpu_ms_per_frame": {m: statistics.median(r["cpu_s"] for r in rs) * 1e3 for m, rs in per_round.items()},
           "median_thread_ms_per_frame": {m: statistics.median(r["thread_s"] for r in rs) * 1e3
                                          for m, rs in per_round.items()},
           "median_wall_ms_per_frame": {m: statistics.median(r["wall_s"] for r in rs) * 1e3 for m, rs in per_round.items()},
           "frames_identical": all(r["frames_identical"] for rs in per_round.values() for r in rs)}
    for m in per_round:
        if m != "feed":
            ratios = [f["cpu_s"] / b["cpu_s"] for f, b in zip(per_round["feed"], per_round[m])]
            out[f"ratio_feed_over_{m.replace(' ', '_')}_per_round"] = ratios
            out[f"median_ratio_feed_over_{m.replace(' ', '_')}"] = statistics.median(ratios)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--frames", type=int, default=12, help="SRF1 frames per pass")
    parser.add_argument("--dca-frames", type=int, default=12, help="DCA1000 frames per pass")
    parser.add_argument("--batches", default="64,8", help="batch sizes (datagrams) of feed_segments")
    args = parser.parse_args()

    started_load = load_average()
    probe_machine()
    modes = ["feed"] + [f"batch {int(n)}" for n in args.batches.split(",")]
    waveform = Waveform()
    shape = (waveform.chirps_per_frame, waveform.n_rx, waveform.samples_per_chirp)
    wire, packed = srf1_frames(args.frames, waveform)
    singles = [[data[o:o + size].tobytes() for o in range(0, data.size, size)] for data, size in packed]
    rng = np.random.default_rng(1)
    dca_bytes = rng.integers(-3000, 3000, args.dca_frames * DCA_FRAME_BYTES // 2, dtype=np.int16).tobytes()
    dca_datagrams = encode_data_packets(dca_bytes)
    dca_packed = np.frombuffer(b"".join(dca_datagrams), np.uint8)
    results = {"srf1": {m: [] for m in modes}, "dca1000": {m: [] for m in modes}}
    for r in range(args.rounds):
        order = modes if r % 2 == 0 else modes[::-1]
        for m in order:
            results["srf1"][m].append(run_srf1(m, wire, packed, singles, shape))
        for m in order:
            results["dca1000"][m].append(run_dca(m, dca_bytes, dca_datagrams, dca_packed, len(dca_datagrams[0])))
        print(f"round {r + 1}: " + "; ".join(
            f"{fmt} " + ", ".join(f"{m} {results[fmt][m][-1]['cpu_s'] * 1e3:.3f}" for m in modes) for fmt in results)
            + " ms CPU/frame", flush=True)

    result = {
        "rounds": args.rounds, "load_average_end": load_average(), "modes": modes,
        "srf1": {"frames_per_pass": args.frames, "frame_bytes": len(wire[0]), "datagrams_per_frame": len(singles[0]),
                 "datagram_bytes": packed[0][1], **summary(results["srf1"])},
        "dca1000": {"frames_per_pass": args.dca_frames, "frame_bytes": DCA_FRAME_BYTES,
                    "datagrams_per_pass": len(dca_datagrams), "datagram_bytes": len(dca_datagrams[0]),
                    **summary(results["dca1000"])},
    }
    path = write_results("stream_segments", result, started_load=started_load)
    print(" ".join(f"{fmt}: " + ", ".join(f"feed / {m} {result[fmt][f'median_ratio_feed_over_{m.replace(chr(32), chr(95))}']:.2f}x"
                                          for m in modes[1:]) for fmt in ("srf1", "dca1000")) + f" -> {path}")


if __name__ == "__main__":
    main()
