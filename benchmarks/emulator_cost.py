"""The emulated radars' CPU per frame: replay's sender as it was against now, interleaved in one process.

    python benchmarks/emulator_cost.py [--seconds 4] [--rounds 4] [--laps 3]

In the four-radar soak the emulated hardware (a sender process per radar and the IMU, which the robot does
not run) shares this two-core machine with the daemon it feeds and took about half a core, so the soak
judged the emulator as much as the daemon. This measures a sender's CPU per frame on the soak's scene
(``soak_loop``, one radar at the reference waveform: 716,800 bytes, 498 SRF1 datagrams a frame), part by
part: reading the frame from the recording, encoding its datagrams, sending them.

- ``before``: replay as it was (ff18b4a): each frame read through HDF5 (``Recording.adc_iq``, Fletcher-32
  checked) on every lap, encoded a datagram at a time (tests/reference_srf1.py), one ``sendto`` each.
- ``now``: ``acquisition.replay``'s sending: the first lap read through HDF5, later laps as raw chunks
  checked by CRC32C against the first (``acquisition.replay_frames``); the datagrams packed by whole-array
  copies, their CRC32Cs computed one by one on the first lap and updated for the new header on later ones
  (``srf1.PackedEncoder``); sent up to 44 in one ``sendmsg`` with UDP segmentation
  (``drivers.radar.udp.UdpSender``).

Both send ``--laps`` laps of the frames to a receiver in another process that counts what arrives (the
datagrams are byte for byte the same: tests/test_replay_wire.py), paced at ``SPEED`` x the recorded frame
rate, in rounds that alternate which goes first, so the machine's load falls on both alike. CPU is this
process's (``time.process_time``, the kernel's loopback work in the send calls included where the kernel
charges it to the sender); the machine's softirq time over each pass is recorded beside it (work the
kernel may account there instead). The IMU emulator's CPU per sample (unchanged: its 400 wake-ups a second
keep its timing) is measured once for the whole emulator's share at 1x. The load average is recorded.

Writes docs/results/emulator_cost.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing as mp
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from acquisition.replay_frames import LapFrames  # noqa: E402
from drivers.emulators import XbusPty  # noqa: E402
from drivers.radar.srf1 import PackedEncoder  # noqa: E402
from drivers.radar.udp import UdpSender  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from reference_srf1 import encode_frame as encode_frame_before  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RADAR = "left_front"
RADARS_IN_SOAK = 4
SPEED = 4.0  # x the recorded frame rate: paced like the soak, a pass in a quarter of the time
IMU_SECONDS = 4.0


def simulate(seconds: float, work: Path) -> Path:
    path = work / f"soak_loop_{RADAR}_{seconds:g}s.h5"
    if not path.exists():
        scene = dataclasses.replace(load_scene("soak_loop"), radars=[RADAR], duration_s=seconds, imu=False)
        simulate_recording(scene, work / "partial.h5", overwrite=True)
        (work / "partial.h5").rename(path)
    return path


def receiver(ready, counts, stop) -> None:
    """Counts the datagrams that arrive, until ``stop``; ``counts`` gets the count at each pass's end marker."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 32 << 20)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.2)
    ready.put(sock.getsockname())
    n = 0
    while not stop.is_set():
        try:
            d = sock.recv(65536)
        except socket.timeout:
            continue
        if d == b"end of pass":
            counts.put(n)
            n = 0
        else:
            n += 1


def softirq_s() -> float:
    """The machine's softirq time so far (all CPUs), s."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()
    return int(fields[7]) / os.sysconf("SC_CLK_TCK")


@dataclasses.dataclass
class Pass:
    frames: int = 0
    datagrams_sent: int = 0
    datagrams_received: int = 0
    cpu_s: dict = dataclasses.field(default_factory=lambda: {"read": 0.0, "encode": 0.0, "send": 0.0})
    later_laps_cpu_s: dict = dataclasses.field(default_factory=lambda: {"read": 0.0, "encode": 0.0, "send": 0.0})
    later_laps_frames: int = 0
    machine_softirq_s: float = 0.0
    wall_s: float = 0.0


def run_pass(rec: Recording, which: str, laps: int, address, counts) -> Pass:
    """One pass of ``laps`` laps, the frames paced at SPEED x their recorded rate, timed part by part."""
    times = rec.frame_time_ns(RADAR)
    lap_ns = int(times[-1] - times[0]) + int(np.median(np.diff(times)))
    p = Pass()
    frames = LapFrames(rec, RADAR, laps) if which == "now" else None
    sender = UdpSender() if which == "now" else None
    encoder = PackedEncoder(0)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
    clock = time.process_time
    softirq0, t0 = softirq_s(), time.monotonic()
    for lap in range(laps):
        for k in range(times.size):
            wait = t0 + (int(times[k]) - int(times[0]) + lap * lap_ns) * 1e-9 / SPEED - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            t_ns, counter = int(times[k]) + lap * lap_ns, lap * times.size + k
            a = clock()
            iq = frames.read(lap, k) if frames is not None else rec.adc_iq(RADAR, slice(k, k + 1))[0]
            b = clock()
            if sender is not None:
                packed = encoder(counter, t_ns, iq, frame_key=k)
                c = clock()
                p.datagrams_sent += sender.send(packed, address)
            else:
                datagrams = encode_frame_before(0, counter, t_ns, iq)
                c = clock()
                for d in datagrams:
                    sock.sendto(d, address)
                p.datagrams_sent += len(datagrams)
            e = clock()
            for parts in (p.cpu_s, p.later_laps_cpu_s) if lap else (p.cpu_s,):
                parts["read"] += b - a
                parts["encode"] += c - b
                parts["send"] += e - c
            p.frames += 1
            p.later_laps_frames += 1 if lap else 0
    p.wall_s = time.monotonic() - t0
    p.machine_softirq_s = softirq_s() - softirq0
    time.sleep(0.3)
    sock.sendto(b"end of pass", address)
    p.datagrams_received = counts.get(timeout=30)
    sock.close()
    if sender is not None:
        sender.close()
    return p


def imu_cost(seconds: float) -> dict:
    """The IMU emulator (``drivers.emulators.XbusPty``) at 400 Hz and 1x into a reader process: CPU per sample."""
    n = int(400 * seconds)
    emu = XbusPty(np.full((n, 3), 0.01), np.tile([0.0, 0.0, 9.81], (n, 1)), rate_hz=400.0, speed=1.0)
    reader = subprocess.Popen([sys.executable, "-c", f"import os\nfd = os.open({emu.port!r}, os.O_RDONLY)\n"
                               "while os.read(fd, 4096): pass"])
    time.sleep(0.5)
    cpu0, t0 = time.process_time(), time.monotonic()
    emu.start()
    emu.done.wait()
    cpu, wall = time.process_time() - cpu0, time.monotonic() - t0
    reader.kill()
    reader.wait()
    emu.close()
    return {"samples": n, "cpu_us_per_sample": 1e6 * cpu / n, "core_fraction_at_1x": cpu / wall}


def per_frame_ms(p: Pass, later: bool = False) -> dict:
    parts, frames = (p.later_laps_cpu_s, p.later_laps_frames) if later else (p.cpu_s, p.frames)
    out = {k: 1e3 * v / frames for k, v in parts.items()}
    out["total"] = sum(out.values())
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="of the soak's lap simulated (frames per lap)")
    ap.add_argument("--rounds", type=int, default=4, help="rounds of both variants, which goes first alternating")
    ap.add_argument("--laps", type=int, default=3, help="laps a pass sends (the first reads through HDF5)")
    ap.add_argument("--work", help="folder for the simulated scene, kept for later runs")
    args = ap.parse_args(argv)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="sarbot-bench-emulator-"))
    work.mkdir(parents=True, exist_ok=True)
    path = simulate(args.seconds, work)
    ctx = mp.get_context("spawn")
    ready, counts, stop = ctx.Queue(), ctx.Queue(), ctx.Event()
    rx = ctx.Process(target=receiver, args=(ready, counts, stop), daemon=True)
    rx.start()
    address = ready.get(timeout=60)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    passes: dict[str, list[Pass]] = {"before": [], "now": []}
    loads = []
    with Recording(path) as rec:
        frames_per_s = 1e9 / float(np.median(np.diff(rec.frame_time_ns(RADAR))))
        run_pass(rec, "now", 1, address, counts)  # warm: imports, the page cache, first sends
        for r in range(args.rounds):
            loads.append(os.getloadavg()[0])
            for which in (("before", "now") if r % 2 == 0 else ("now", "before")):
                p = run_pass(rec, which, args.laps, address, counts)
                passes[which].append(p)
                ms = per_frame_ms(p)
                print(f"round {r}, {which}: {ms['total']:.3f} ms CPU a frame (read {ms['read']:.3f}, encode "
                      f"{ms['encode']:.3f}, send {ms['send']:.3f}); {p.datagrams_received}/{p.datagrams_sent} "
                      f"datagrams arrived; softirq {1e3 * p.machine_softirq_s / p.frames:.3f} ms a frame", flush=True)
    stop.set()
    rx.join(timeout=5)
    imu = imu_cost(IMU_SECONDS)
    ratios = [sum(b.cpu_s.values()) / sum(n.cpu_s.values()) for b, n in zip(passes["before"], passes["now"])]
    best = {w: min(ps, key=lambda p: sum(p.cpu_s.values())) for w, ps in passes.items()}
    out = {
        "scene": "soak_loop", "radar": RADAR, "seconds": args.seconds, "laps_per_pass": args.laps,
        "rounds": args.rounds, "pace_x_recorded": SPEED, "frames_per_pass": best["now"].frames,
        "datagrams_per_frame": best["now"].datagrams_sent // best["now"].frames,
        "radar_frames_per_s_at_1x": frames_per_s,
        "before": {"code": "ff18b4a: HDF5 read every lap, a datagram at a time, one sendto each",
                   "cpu_ms_per_frame": per_frame_ms(best["before"]),
                   "later_laps_cpu_ms_per_frame": per_frame_ms(best["before"], later=True)},
        "now": {"code": "raw chunk reads after the first lap, packed datagrams, segmented sends",
                "cpu_ms_per_frame": per_frame_ms(best["now"]),
                "later_laps_cpu_ms_per_frame": per_frame_ms(best["now"], later=True)},
        "before_over_now_each_round": ratios,
        "before_over_now_later_laps_each_round": [
            sum(b.later_laps_cpu_s.values()) / sum(n.later_laps_cpu_s.values())
            for b, n in zip(passes["before"], passes["now"])],
        "datagrams_received_over_sent": {w: [p.datagrams_received / p.datagrams_sent for p in ps]
                                         for w, ps in passes.items()},
        "machine_softirq_ms_per_frame": {w: [1e3 * p.machine_softirq_s / p.frames for p in ps] for w, ps in passes.items()},
        # The machine's softirq time (10 ms ticks, everyone's) charged to each frame, as an upper bound on kernel
        # work done for the sends outside this process's CPU time: the ratio with it added to both.
        "before_over_now_with_machine_softirq_each_round": [
            (sum(b.cpu_s.values()) + b.machine_softirq_s) / (sum(n.cpu_s.values()) + n.machine_softirq_s)
            for b, n in zip(passes["before"], passes["now"])],
        "imu_emulator": imu,
        "load_average_1min_at_each_round": loads, "cpu_count": os.cpu_count(),
        "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                 text=True).stdout.strip(),
    }
    # The whole emulator at 1x in the four-radar soak: four senders (a lap of 500 frames, then later laps;
    # the soak's 5 minutes are 12 laps) and the IMU.
    soak_laps = 12
    for which in ("before", "now"):
        p = best[which]
        first_ms = 1e3 * (sum(p.cpu_s.values()) - sum(p.later_laps_cpu_s.values())) / (p.frames - p.later_laps_frames)
        later_ms = per_frame_ms(p, later=True)["total"]
        mean_ms = (first_ms + (soak_laps - 1) * later_ms) / soak_laps
        out[which]["first_lap_cpu_ms_per_frame"] = first_ms
        out[which]["five_minute_soak_mean_cpu_ms_per_frame"] = mean_ms
        out[which]["four_radars_and_imu_core_fraction_at_1x"] = (
            RADARS_IN_SOAK * frames_per_s * mean_ms * 1e-3 + imu["core_fraction_at_1x"])
    write_results("emulator_cost", out, started_load=started_load, indent=1)
    print(json.dumps({k: v for k, v in out.items() if k in ("before", "now", "before_over_now_each_round", "imu_emulator")},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
