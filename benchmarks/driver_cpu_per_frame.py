"""A radar driver's and the recorder's CPU per frame: the code of a baseline commit against the checkout's, interleaved
in one process, fed the same datagrams.

    python benchmarks/driver_cpu_per_frame.py [--baseline COMMIT] [--rounds 6] [--frames 20] [--speed 1]

The reference waveform's frame is 716,800 bytes in 498 SRF1 (version 2) datagrams; four radars send one each
every 52 ms. Two measurements, each in rounds that alternate which code goes first (so the machine's load
falls on both alike):

- ``assembly``: ``Srf1Stream.feed`` alone (parsing, CRC32C, putting each chunk in its frame), every datagram
  of ``--frames`` frames fed from memory; CPU from ``time.process_time``. The frames that come out are
  compared byte for byte between the two.
- ``receive_per_frame``: the receiver alone on 3 frames' datagrams waiting in the socket (sent segmented, as
  replay sends), CPU per frame (``time.thread_time``): the baseline's ``UdpReceiver.receive`` (one
  ``recvmsg`` and its kernel stamp a datagram) against what the checkout's driver loop calls,
  ``receive_segments`` (with UDP GRO a batch of up to 64 datagrams a call); the checkout's ``receive`` (the
  batch handed out a datagram at a time, for its other callers) is recorded beside them
  (``now_receive_one_by_one``).
- ``recorder``: ``Recorder`` storing ``--recorder-frames`` frames of one radar as they come off the bus
  (decoded, checked, appended to the HDF5 file) with a flush every 10 frames (its 0.5 s), closing included;
  CPU from ``time.process_time`` (its background fsync thread included). The two files are compared column
  by column.
- ``driver_loop``: ``radar_driver_loop`` as the driver process runs it (``UdpReceiver`` on loopback with its
  kernel stamps, the stream, ``BusPublisher`` sending each frame to a subscriber), in a thread of its own,
  fed by this process's main thread with the datagrams of ``--frames`` frames at ``--speed`` x the radar's
  frame rate (``UdpSender``, as replay sends them); CPU is the driver thread's (``time.thread_time``), so the
  sender's and the subscriber's are left out; ZeroMQ's own I/O thread is left out too (it moves the
  frame's bytes, the same in both). The subscriber checks every frame arrived, whole and valid.

The baseline's ``drivers/radar/srf1.py``, ``drivers/radar/udp.py``, ``acquisition/driver_loops.py`` and
``acquisition/recorder.py`` are
loaded from git (``git show COMMIT:PATH``) as modules of their own beside the checkout's; everything they
import is the checkout's. Figures are medians over rounds of the CPU per frame, and the ratio baseline /
now per round. The machine is shared: the load average and the VM's speed probe are recorded.

Writes docs/results/driver_cpu_per_frame.json (``--name``: another stem).
"""

from __future__ import annotations

import argparse
import statistics
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import acquisition.driver_loops as driver_loops_now  # noqa: E402
import acquisition.recorder as recorder_now  # noqa: E402
import drivers.radar.srf1 as srf1_now  # noqa: E402
import drivers.radar.udp as udp_now  # noqa: E402
from acquisition.bus import BusPublisher, BusSubscriber  # noqa: E402
from acquisition.messages import RadarFrameMessage  # noqa: E402
from imaging.core.waveform import Waveform  # noqa: E402
from git_baseline import baseline_module  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

#: The commit before the driver's CPU was cut (main at the start of wave 3j). UDP GRO's run (wave 3m) took
#: ``--baseline aa20a74 --name driver_cpu_per_frame_gro``.
BASELINE = "4da3eec"


def frames_datagrams(n_frames: int, waveform: Waveform, seed: int = 0) -> tuple[list, list]:
    """The iq of ``n_frames`` distinct frames and their SRF1 datagrams (packed, as replay sends them)."""
    shape = (waveform.chirps_per_frame, waveform.n_rx, waveform.samples_per_chirp, 2)
    rng = np.random.default_rng(seed)
    iqs = [rng.integers(-2048, 2048, shape, dtype=np.int16) for _ in range(n_frames)]
    encoder = srf1_now.PackedEncoder(1)
    packed = []
    for k, iq in enumerate(iqs):  # the encoder's buffer holds until its next call: copied at once
        p = encoder(k, 1_700_000_000_000_000_000 + k * 52_000_000, iq)
        packed.append(srf1_now.PackedDatagrams(p.data.copy(), p.size))
    return iqs, packed


def assembly_cpu_per_frame(srf1, shape, datagrams: list[list[bytes]]) -> tuple[float, list]:
    """CPU seconds per frame of feeding every datagram to a fresh ``Srf1Stream``; the frames out."""
    stream = srf1.Srf1Stream(shape, 1)
    out = []
    t0 = time.process_time()
    for frame in datagrams:
        for d in frame:
            out += stream.feed(d, 1)
    cpu = time.process_time() - t0
    return cpu / len(datagrams), out


def receive_cpu_per_frame(udp, packed: list, call: str = "receive") -> tuple[float, int]:
    """CPU seconds per frame of a version's ``UdpReceiver`` (``udp``: its module) taking ``packed``'s datagrams,
    all waiting in the socket (so no wait is timed), by ``call`` ("receive": a datagram a call;
    "receive_segments": a batch a call), and how many datagrams it took."""
    receiver = udp.UdpReceiver("127.0.0.1", 0, coalesce_s=0, timeout_s=0)
    sender = udp_now.UdpSender()
    for datagrams in packed:
        sender.send(datagrams, receiver.address)
    time.sleep(0.05)  # loopback delivers
    n = 0
    receive = getattr(receiver, call)
    t0 = time.thread_time()
    if call == "receive_segments":
        while (got := receive()) is not None:
            n += -(-len(got[0]) // got[1])
    else:
        while receive() is not None:
            n += 1
    cpu = time.thread_time() - t0
    sender.close()
    receiver.close()
    return cpu / len(packed), n


def recorder_cpu_per_frame(recorder_module, folder: Path, iqs: list, n_frames: int, flush_every: int = 10) -> tuple[float, Path]:
    """CPU seconds per frame of a version's ``Recorder`` storing ``n_frames`` radar frames as they come off
    the bus (``Message``s built once, outside the timing) and flushing every ``flush_every`` frames (its
    0.5 s at one radar's 19.2 frames a second), closing included; and the file it wrote."""
    from acquisition.bus import Message
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import rig_from_dict

    rig = rig_from_dict({"radar": {"left": {}}})
    messages = []
    for k in range(n_frames):
        frame = RadarFrame(k, 1_700_000_000_000_000_000 + k * 52_000_000, 1_700_000_000_010_000_000 + k * 52_000_000,
                           k % 7 != 3, 0, iqs[k % len(iqs)], k % 11 != 5, 0)
        p = RadarFrameMessage("left", frame).to_parts()
        messages.append(Message(p.topic, k, p.sensor_time_ns, 0, {"seq": k, "pub": "bench", **p.fields}, p.arrays))
    path = folder / f"{recorder_module.__name__.rsplit('.', 1)[-1]}.h5"
    path.unlink(missing_ok=True)
    recorder = recorder_module.Recorder(path, rig, ["tcp://127.0.0.1:9"], flush_interval_s=1e9)
    t0 = time.process_time()
    for k, msg in enumerate(messages):
        recorder._store(msg)
        if k % flush_every == flush_every - 1:
            recorder.flush()
    recorder.close()
    return (time.process_time() - t0) / n_frames, path


def same_recordings(a: Path, b: Path) -> bool:
    """Whether two recordings hold the same radar frames, columns and clock marks."""
    import h5py

    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        ga, gb = fa["radar/left"], fb["radar/left"]
        names = [n for n in ga if isinstance(ga[n], h5py.Dataset)]
        return sorted(names) == sorted(n for n in gb if isinstance(gb[n], h5py.Dataset)) and all(
            np.array_equal(ga[n][...], gb[n][...]) for n in names)


class CountingPublisher:
    """The driver's publisher, counting the frames it sends; ``done`` once ``expected`` have gone."""

    def __init__(self, pub: BusPublisher, expected: int):
        self.pub, self.expected, self.sent = pub, expected, 0
        self.done = threading.Event()

    def send(self, message) -> int:
        seq = self.pub.send(message)
        if isinstance(message, RadarFrameMessage):
            self.sent += 1
            if self.sent >= self.expected:
                self.done.set()
        return seq


def driver_loop_cpu_per_frame(loops, udp, srf1, shape, packed: list, interval_s: float, iqs: list) -> dict:
    """One pass of the driver loop (``loops``/``udp``/``srf1``: a version's modules) over ``packed``."""
    receiver = udp.UdpReceiver("127.0.0.1", 0)
    pub = BusPublisher("tcp://127.0.0.1:0", high_water_mark=1000, watch_subscriptions=True)
    sub = BusSubscriber(pub.endpoint, topics=[RadarFrameMessage.TOPIC], high_water_mark=1000)
    # Until the subscription reaches the publisher, ZeroMQ drops what it sends (the first frame, loaded).
    if not pub.wait_for_subscriber(RadarFrameMessage.TOPIC, 10.0):
        raise RuntimeError("the subscriber did not subscribe within 10 s")
    counting = CountingPublisher(pub, len(packed))
    stop = threading.Event()
    cpu = {}

    def drive():
        t0 = time.thread_time()
        loops.radar_driver_loop(receiver, "left", srf1.Srf1Stream(shape, 1), counting, stop)
        cpu["s"] = time.thread_time() - t0

    got = []

    def drain():
        while len(got) < len(packed):
            msg = sub.receive(timeout_ms=2000)
            if msg is None:
                break
            m = RadarFrameMessage.from_message(msg)
            got.append((m.frame.frame_counter, m.frame.valid, bool(np.array_equal(m.frame.iq, iqs[m.frame.frame_counter]))))

    driver, drainer = threading.Thread(target=drive), threading.Thread(target=drain)
    driver.start()
    drainer.start()
    sender = udp_now.UdpSender()
    start = time.monotonic()
    wall0 = time.perf_counter()
    for k, datagrams in enumerate(packed):
        time.sleep(max(0.0, start + k * interval_s - time.monotonic()))
        sender.send(datagrams, receiver.address)
    counting.done.wait(10)
    wall = time.perf_counter() - wall0
    stop.set()
    driver.join(5)
    drainer.join(5)
    sender.close()
    receiver.close()
    pub.close()
    sub.close()
    whole = sum(1 for _, valid, same in got if valid and same)
    return {"cpu_s_per_frame": cpu["s"] / len(packed), "frames_sent": len(packed), "frames_published": counting.sent,
            "frames_received_whole": whole, "kernel_drops": receiver.kernel_drops, "wall_s": wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", default=BASELINE, help="the commit whose driver code is compared")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--frames", type=int, default=20, help="frames per pass")
    parser.add_argument("--recorder-frames", type=int, default=60, help="frames the recorder stores per pass")
    parser.add_argument("--speed", type=float, default=1.0, help="x the radar's frame rate (19.2 Hz)")
    parser.add_argument("--name", default="driver_cpu_per_frame", help="the results file's stem")
    args = parser.parse_args()
    probe = udp_now.UdpReceiver("127.0.0.1", 0)
    gro = probe.gro  # whether this kernel gave the checkout's receiver UDP GRO
    probe.close()

    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    baseline = {"srf1": baseline_module(args.baseline, "drivers/radar/srf1.py", "_baseline_srf1"),
                "udp": baseline_module(args.baseline, "drivers/radar/udp.py", "_baseline_udp"),
                "loops": baseline_module(args.baseline, "acquisition/driver_loops.py", "_baseline_driver_loops")}
    now = {"srf1": srf1_now, "udp": udp_now, "loops": driver_loops_now}
    waveform = Waveform()
    shape = (waveform.chirps_per_frame, waveform.n_rx, waveform.samples_per_chirp)
    iqs, packed = frames_datagrams(args.frames, waveform)
    datagrams = [p.split() for p in packed]
    interval_s = waveform.frame_interval_s / args.speed

    baseline["recorder"] = baseline_module(args.baseline, "acquisition/recorder.py", "_baseline_recorder")
    now["recorder"] = recorder_now
    folder = Path(tempfile.mkdtemp(prefix="driver_cpu_per_frame."))
    versions = {"baseline": baseline, "now": now}
    recorder = {v: [] for v in versions}
    same_files = True
    assembly = {v: [] for v in versions}
    receive = {v: [] for v in versions}
    received = {v: [] for v in versions}
    loop = {v: [] for v in versions}
    same_frames = True
    for r in range(args.rounds):
        order = list(versions) if r % 2 == 0 else list(versions)[::-1]
        out = {}
        for v in order:
            cpu, out[v] = assembly_cpu_per_frame(versions[v]["srf1"], shape, datagrams)
            assembly[v].append(cpu)
        for v in order + ["now_receive_one_by_one"]:  # 3 frames: what the socket's buffer (4 MB here) holds
            udp, call = (udp_now, "receive") if v == "now_receive_one_by_one" else \
                (versions[v]["udp"], "receive_segments" if v == "now" else "receive")
            cpu, n = receive_cpu_per_frame(udp, packed[:3], call)
            receive.setdefault(v, []).append(cpu)
            received.setdefault(v, []).append(n)
        same_frames &= all(a.frame_counter == b.frame_counter and a.valid and b.valid and a.iq.tobytes() == b.iq.tobytes()
                           for a, b in zip(out["baseline"], out["now"], strict=True))
        files = {}
        for v in order:
            cpu, files[v] = recorder_cpu_per_frame(versions[v]["recorder"], folder, iqs, args.recorder_frames)
            recorder[v].append(cpu)
        same_files &= same_recordings(files["baseline"], files["now"])
        for v in order:
            loop[v].append(driver_loop_cpu_per_frame(versions[v]["loops"], versions[v]["udp"], versions[v]["srf1"],
                                                     shape, packed, interval_s, iqs))
        print(f"round {r + 1}: assembly ms/frame baseline {assembly['baseline'][-1] * 1e3:.3f} now "
              f"{assembly['now'][-1] * 1e3:.3f}; receive ms/frame baseline {receive['baseline'][-1] * 1e3:.3f} now "
              f"{receive['now'][-1] * 1e3:.3f}; driver loop baseline {loop['baseline'][-1]['cpu_s_per_frame'] * 1e3:.3f} "
              f"now {loop['now'][-1]['cpu_s_per_frame'] * 1e3:.3f}; recorder baseline {recorder['baseline'][-1] * 1e3:.3f} "
              f"now {recorder['now'][-1] * 1e3:.3f}", flush=True)

    def summary(per_round: dict) -> dict:
        ratios = [b / n for b, n in zip(per_round["baseline"], per_round["now"])]
        return {"cpu_ms_per_frame": {v: [x * 1e3 for x in xs] for v, xs in per_round.items()},
                "median_cpu_ms_per_frame": {v: statistics.median(xs) * 1e3 for v, xs in per_round.items()},
                "ratio_baseline_over_now_per_round": ratios, "median_ratio": statistics.median(ratios)}

    loop_cpu = {v: [p["cpu_s_per_frame"] for p in passes] for v, passes in loop.items()}
    result = {
        "baseline_commit": args.baseline, "rounds": args.rounds, "frames_per_pass": args.frames, "speed": args.speed,
        "frame_bytes": int(np.prod(shape)) * 4, "datagrams_per_frame": len(datagrams[0]),
        "assembly": {**summary(assembly), "frames_identical": same_frames},
        "receive_per_frame": {**summary({v: receive[v] for v in versions}),
                              "baseline_call": "receive", "now_call": "receive_segments",
                              "now_receive_one_by_one_cpu_ms_per_frame": [x * 1e3 for x in receive["now_receive_one_by_one"]],
                              "now_receive_one_by_one_median_ratio": statistics.median(
                                  b / n for b, n in zip(receive["baseline"], receive["now_receive_one_by_one"])),
                              "datagrams_taken_per_pass": received, "datagrams_sent_per_pass": 3 * len(datagrams[0])},
        "driver_loop": {**summary(loop_cpu),
                        "passes": loop,
                        "every_frame_whole": all(p["frames_received_whole"] == p["frames_sent"] for ps in loop.values()
                                                 for p in ps)},
        "recorder": {**summary(recorder), "frames_per_pass": args.recorder_frames, "flush_every_frames": 10,
                     "files_identical": same_files},
        "load_average_end": load_average(),
        "udp_gro": gro,
    }
    shutil.rmtree(folder, ignore_errors=True)
    path = write_results(args.name, result, started_load=started_load)
    print(f"assembly: {result['assembly']['median_ratio']:.2f}x, receive: {result['receive_per_frame']['median_ratio']:.2f}x, "
          f"driver loop: {result['driver_loop']['median_ratio']:.2f}x "
          f"(baseline / now, median of {args.rounds} rounds) -> {path}")


if __name__ == "__main__":
    main()
