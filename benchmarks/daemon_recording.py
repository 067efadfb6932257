"""Acquisition: the rate four radars can stream with zero loss through the drivers, the bus and the HDF5
recorder on loopback, CPU per process, and latency from a frame's last datagram to the bus.

    python benchmarks/daemon_recording.py [--quick]

`sarbot record` runs as it would on the robot (four SRF1 driver processes, recorder in the supervisor) on
the default rig (reference waveform: 716,800 bytes per frame every 52 ms per radar, 55 MB/s and about
38k datagrams/s for four). This process plays the four radars: phases at rising multiples of real time,
each frame a burst of MTU-sized datagrams. A phase is lossless when every frame it sent is in the file,
complete and valid, and no loss event was written. The baseline is the 1x phase of the same run.

Writes docs/results/acquisition.json and docs/results/acquisition.png.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.bus import BusSubscriber  # noqa: E402
from acquisition.messages import Health, RadarFrameMessage  # noqa: E402
from acquisition.processes import free_ports, free_tcp_endpoint  # noqa: E402
from drivers.radar.srf1 import encode_frame, restamp  # noqa: E402
from imaging.core.rig import default_rig  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from process_stats import child_pids, cpu_s  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def process_roles(pid: int) -> dict[int, str]:
    """The daemon and its children, by role."""
    return {pid: "supervisor + recorder", **dict.fromkeys(child_pids(pid) or [], "driver")}


class RadarPlayer:
    """Four radars on loopback: pre-encoded frames, header patched per frame (counter, PTP time)."""

    def __init__(self, ports: dict[str, int], shape, n_distinct: int = 3, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
        self.targets = {name: ("127.0.0.1", port) for name, port in ports.items()}
        self.frames = [[bytearray(d) for d in encode_frame(0, 0, 0, rng.integers(-2000, 2000, shape, dtype=np.int16))]
                       for _ in range(n_distinct)]
        self.datagrams_per_frame = len(self.frames[0])
        self.counter = 0

    def send_frame(self, t_ns: int) -> None:
        datagrams = self.frames[self.counter % len(self.frames)]
        for d in datagrams:
            restamp(d, self.counter, t_ns)  # with SRF1 v2's CRC made again: else every datagram is dropped
        for address in self.targets.values():
            for d in datagrams:
                self.sock.sendto(d, address)
        self.counter += 1

    def play(self, multiple: float, seconds: float, frame_interval_s: float) -> dict:
        period = frame_interval_s / multiple
        n = int(seconds / period)
        first = self.counter
        t0 = time.monotonic()
        for k in range(n):
            wait = t0 + k * period - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            self.send_frame(time.time_ns() + 37_000_000_000)
        elapsed = time.monotonic() - t0
        return {"multiple": multiple, "first_counter": first, "frames_per_radar": n, "send_s": elapsed,
                "achieved_multiple": n * frame_interval_s / elapsed}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer, shorter phases")
    args = ap.parse_args(argv)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    multiples = [1.0, 2.0, 3.0] if args.quick else [1.0, 1.5, 2.0, 2.5, 3.0, 4.0]
    phase_s = 3.0 if args.quick else 5.0
    rig = default_rig()
    wf = rig.radars[0].waveform
    shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)
    frame_bytes = int(np.prod(shape)) * 2
    ports = dict(zip(rig.radar_names, free_ports(len(rig.radars))))
    health_endpoint = free_tcp_endpoint()
    work = Path(tempfile.mkdtemp(prefix="sarbot-bench-acq-"))
    cmd = [sys.executable, "-m", "acquisition.cli", "record", "--config", str(ROOT / "imaging/rigs/default.toml"),
           "-o", str(work), "--health-endpoint", health_endpoint, "--min-free", "2G",
           *[a for name, port in ports.items() for a in ("--radar", f"{name}={port}")]]
    daemon = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    health: list[tuple[float, Health]] = []  # (monotonic time of arrival, report)
    latencies: list[tuple[float, float]] = []  # (monotonic time, datagram-to-bus latency ms) of one radar
    sub = BusSubscriber(health_endpoint, topics=[Health.TOPIC])
    listening = threading.Event()
    listening.set()

    def listen():
        tap = None
        while listening.is_set():
            m = sub.receive(timeout_ms=10)
            if m is not None:
                report = Health.from_message(m)
                health.append((time.monotonic(), report))
                if tap is None:  # the health report says where the drivers publish: tap one radar's stream
                    tap = BusSubscriber(report.endpoints[f"radar.{rig.radars[0].name}"], topics=[RadarFrameMessage.TOPIC])
            while tap is not None and (f := tap.receive(timeout_ms=0)) is not None:
                frame = RadarFrameMessage.from_message(f).frame
                latencies.append((time.monotonic(), (time.time_ns() - frame.receive_ns) * 1e-6))
        if tap is not None:
            tap.close()

    listener = threading.Thread(target=listen, daemon=True)
    listener.start()
    time.sleep(5.0)  # the daemon spawns its drivers and reports health once
    player = RadarPlayer(ports, shape)
    phases = []
    for m in multiples:
        tree = process_roles(daemon.pid)
        cpu0 = {pid: cpu_s(pid) for pid in tree}
        mine0 = time.process_time()
        t0 = time.monotonic()
        phase = player.play(m, phase_s, wf.frame_interval_s)
        time.sleep(1.0)  # let the pipeline drain before the CPU reading
        dt = time.monotonic() - t0
        cpu = {}
        for pid, role in tree.items():
            now = cpu_s(pid)
            if now is not None and cpu0[pid] is not None:  # None: the process has ended
                cpu.setdefault(role, []).append((now - cpu0[pid]) / dt)
        phase["cpu_fraction"] = {"supervisor + recorder": cpu.get("supervisor + recorder", [0])[0],
                                 "driver (mean of 4)": float(np.mean(cpu.get("driver", [0]))),
                                 "sender (this process)": (time.process_time() - mine0) / dt}
        phase["t_end"] = time.monotonic()
        phases.append(phase)
        print(f"{m:4.1f}x sent ({phase['achieved_multiple']:.2f}x achieved)", flush=True)
        time.sleep(1.0)
    time.sleep(1.0)
    daemon.send_signal(signal.SIGINT)  # stop as an operator would, after the last phase has drained
    out, err = daemon.communicate(timeout=120)
    listening.clear()
    listener.join()
    sub.close()
    if daemon.returncode != 0:
        print(err, file=sys.stderr)
        return 1
    path = Path(out.split("wrote ")[-1].strip())
    with Recording(path) as rec:
        counters = {n: rec.file[f"radar/{n}/frame_counter"][()] for n in rec.radar_names}
        valid = {n: rec.valid(n) for n in rec.radar_names}
        events = rec.events()
    for p in phases:
        lo, hi = p["first_counter"], p["first_counter"] + p["frames_per_radar"]
        got = {n: int(((c >= lo) & (c < hi) & (valid[n] == 1)).sum()) for n, c in counters.items()}
        p["frames_received_valid"] = got
        p["lossless"] = all(v == p["frames_per_radar"] for v in got.values())
        lat = np.array([v for t, v in latencies if p["t_end"] - phase_s - 1.0 <= t <= p["t_end"]])
        p["latency_ms_p50"] = float(np.percentile(lat, 50)) if lat.size else None
        p["latency_ms_p99"] = float(np.percentile(lat, 99)) if lat.size else None
        during = [h for t, h in health if p["t_end"] - phase_s - 1.0 <= t <= p["t_end"] and h.latency_ms]
        p["recorder_latency_ms_p50"] = float(np.median([h.latency_ms.p50 for h in during])) if during else None
        rate = p["achieved_multiple"] * 4 * frame_bytes / wf.frame_interval_s
        p["mbytes_per_s"] = rate / 1e6
        p["datagrams_per_s"] = p["achieved_multiple"] * 4 * player.datagrams_per_frame / wf.frame_interval_s
        print(f"{p['multiple']:4.1f}x: {p['mbytes_per_s']:6.1f} MB/s, {p['datagrams_per_s'] / 1e3:5.1f}k datagrams/s, "
              f"{'lossless' if p['lossless'] else 'LOSS ' + str(got)}, latency p50 {p['latency_ms_p50']:.1f} ms "
              f"p99 {p['latency_ms_p99']:.1f} ms, "
              f"CPU {', '.join(f'{k} {v:.2f}' for k, v in p['cpu_fraction'].items())}", flush=True)
    lossless = [p for p in phases if p["lossless"]]
    best = max((p["achieved_multiple"] for p in lossless), default=0.0)
    base = phases[0]
    summary = {
        "machine": f"{os.cpu_count()} cores",
        "waveform": {"frame_bytes": frame_bytes, "frame_interval_s": wf.frame_interval_s, "radars": 4,
                     "datagrams_per_frame": player.datagrams_per_frame,
                     "real_time_mbytes_per_s": 4 * frame_bytes / wf.frame_interval_s / 1e6},
        "phases": phases,
        "events_in_file": [list(e) for e in events],
        "max_lossless_multiple_of_real_time": best,
        "max_lossless_mbytes_per_s": best * 4 * frame_bytes / wf.frame_interval_s / 1e6,
        "baseline": "the 1x phase of the same run; ratios are achieved multiples against it",
        "ratio_to_baseline": {f"{p['multiple']}x": p["achieved_multiple"] / base["achieved_multiple"] for p in phases},
    }
    stem = "acquisition_quick" if args.quick else "acquisition"  # a smoke run keeps the real figures
    write_results(stem, summary, started_load=started_load)
    plot(phases, RESULTS / f"{stem}.png")
    path.unlink()
    print(f"four radars sustained {best:.2f}x real time with zero loss ({summary['max_lossless_mbytes_per_s']:.0f} MB/s); "
          f"wrote {RESULTS / (stem + '.json')}")
    return 0


def plot(phases, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    x = [p["mbytes_per_s"] for p in phases]
    for role in phases[0]["cpu_fraction"]:
        a.plot(x, [p["cpu_fraction"][role] for p in phases], "o-", label=role)
    for p in phases:
        if not p["lossless"]:
            a.axvspan(p["mbytes_per_s"] - 3, p["mbytes_per_s"] + 3, color="red", alpha=0.15)
    a.set_xlabel("offered rate, MB/s (four radars)")
    a.set_ylabel("CPU (fraction of one core)")
    a.set_title("CPU per process (red: loss)")
    a.legend(fontsize=8)
    b.plot(x, [p["latency_ms_p50"] or np.nan for p in phases], "o-", label="p50")
    b.plot(x, [p["latency_ms_p99"] or np.nan for p in phases], "s-", label="p99")
    b.set_xlabel("offered rate, MB/s")
    b.set_ylabel("last datagram of a frame to the bus, ms")
    b.set_title("latency")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
