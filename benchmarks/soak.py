"""Soak: the whole daemon at 1x for half an hour, as on the robot, watched for loss, memory growth and lag.

    python benchmarks/soak.py [--minutes 30] [--quick]

The built-in scene ``soak_loop`` (a 26 s closed drive of the reference robot at the reference waveform,
14 MB/s per radar, and the IMU at 400 Hz) is simulated once and replayed lap after lap (``sarbot replay
--laps``, times and counters continuing) into ``sarbot run`` as the unit runs it (drivers at real-time
priority where allowed, workers niced): a driver process per radar, the IMU driver, the recorder, the
odometry worker and the live strip map. The recording is split every minute; each finished part is
checked (frames per radar, invalid frames, counter gaps, IMU samples, events) and deleted, so half an
hour fits on the disk.

By default the left pair of radars is replayed. All four (``--radars``) fill this two-core machine, whose
emulated hardware (a sender process per radar and the IMU, which the robot does not run) took about half a
core in the soak's accounting; replay's senders now read, encode and send a frame for about half the CPU
(0.13 of a core for four radars and the IMU at 1x against 0.30 before, measured interleaved on a loaded
machine: ``docs/results/emulator_cost.json``). Since 4671886 every frame is recorded and mapped, the map
pre-summing more to keep up (``docs/results/soak_4radars.json``).

Every 10 s it samples each process's resident memory (VmRSS) and CPU, the health report (bus loss,
invalid frames, restarts) and the workers' lag: the odometry's (last radar scan to its point cloud) and
the map's (last frame imaged), with the highest of every status message in between (a stall shorter than
10 s shows there too) and how much of the map's lag is waiting for the odometry's poses. At the end: frames sent against frames recorded, memory per process after
warm-up (its drift, goal within 20 MB, and its largest excursion), and the lag over the run (goal: flat).

CPU accounting (``cpu_accounting``): the daemon's processes, the emulated hardware, this script and the
rest of the machine (other users), against what the map's frames need at 1x as measured in one process
(docs/results/stripmap_capacity.json), with a ``verdict``: the daemon could not keep up, or the machine
was full (with the emulator, or with others' work). ``--emulator-nice 19`` runs the emulated hardware at
the lowest priority, so it takes only what the daemon leaves (``replay_behind_1x_s`` says whether it
still sent at 1x). ``--summary-of`` accounts an earlier run's samples again.

Writes docs/results/soak.json and docs/results/soak.png (docs/results/soak_quick.* with --quick); with other
radars than the left pair, soak_<N>radars.* (all four: ``--radars left_front,left_rear,right_front,right_rear``);
with other map settings (``--map-args``), soak_<--name>.*.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.bus import BusSubscriber  # noqa: E402
from acquisition.messages import Health, MapStatus, decode  # noqa: E402
from acquisition.processes import free_ports, free_tcp_endpoint  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.core import strict_json  # noqa: E402
from results_file import load_average, write_results  # noqa: E402
from process_stats import child_pids, cpu_s, machine_cpu_s, named_process_tree, rss_mb, run_queue_wait_s  # noqa: E402

RESULTS = ROOT / "docs" / "results"
SARBOT = [sys.executable, "-m", "acquisition.cli"]
SAMPLE_EVERY_S = 10.0
RSS_GOAL_MB = 20.0


class PartChecker:
    """Counts what the finished parts of the recording hold, then deletes them (the disk would fill)."""

    def __init__(self, folder: Path, radars: list[str]):
        self.folder = folder
        self.frames = dict.fromkeys(radars, 0)
        self.invalid = dict.fromkeys(radars, 0)
        self.counter_gaps = dict.fromkeys(radars, 0)
        self.imu_samples = 0
        self.events: list[str] = []
        self.parts = 0
        self._last_counter: dict[str, int] = {}

    def parts_on_disk(self) -> list[Path]:
        return sorted(self.folder.glob("recording_*.h5"))

    def check(self, path: Path) -> None:
        with Recording(path) as rec:
            for name in self.frames:
                counters = rec.frame_counter(name).astype(np.int64)
                self.frames[name] += counters.size
                self.invalid[name] += int(np.sum(rec.valid(name) == 0)) if counters.size else 0
                if counters.size:
                    previous = self._last_counter.get(name, counters[0] - 1)
                    steps = np.diff(np.concatenate([[previous], counters]))
                    self.counter_gaps[name] += int(np.sum(steps != 1))
                    self._last_counter[name] = int(counters[-1])
            imu = rec.imu()
            self.imu_samples += 0 if imu is None else int(imu["time_ns"].size)
            self.events += [f"{source} {level}: {message}" for _, source, level, message in rec.events()]
        self.parts += 1

    def check_finished(self) -> None:
        """Every part but the newest is closed (the recorder closes a part before it opens the next)."""
        for path in self.parts_on_disk()[:-1]:
            self.check(path)
            path.unlink()

    def imu_lag_s(self) -> float | None:
        """How far the newest IMU sample in the file being written is behind now (host receive time)."""
        parts = self.parts_on_disk()
        if not parts:
            return None
        try:
            with Recording(parts[-1]) as rec:
                imu = rec.imu()
                if imu is None or imu["host_time_ns"].size == 0:
                    return None
                return (time.time_ns() - int(imu["host_time_ns"][-1])) * 1e-9
        except Exception:  # noqa: BLE001 - the part is being created or its header not flushed yet
            return None


def simulate(work: Path) -> Path:
    path = work / "soak_loop.h5"
    subprocess.run([*SARBOT, "simulate", "soak_loop", "-o", str(path)], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    return path


def soak(minutes: float, work: Path, radars: list[str], map_args: list[str] = (), emulator_nice: int = 0) -> dict:
    """The soak; ``emulator_nice``: the emulated hardware (the replay: senders and IMU) niced that far."""
    with Recording(simulate(work)) as rec:
        frames_per_lap = rec.n_frames(radars[0])
        lap_s = frames_per_lap * float(np.median(np.diff(rec.frame_time_ns(radars[0])))) * 1e-9
    sim_path = work / "soak_loop.h5"
    laps = max(1, math.ceil(minutes * 60 / lap_s))
    out = work / "out"
    ports = dict(zip(radars, free_ports(len(radars))))
    health_endpoint = free_tcp_endpoint()
    imu_link = work / "imu_tty"
    run_cmd = [*SARBOT, "run", "--config", str(ROOT / "imaging" / "rigs" / "default.toml"), "-o", str(out),
               "--imu-port", str(imu_link), "--split-time", "60", "--health-endpoint", health_endpoint,
               "--min-free", "4G", "--map-radars", ",".join(radars), "--rio-radars", ",".join(radars), *[a for n, p in ports.items() for a in ("--radar", f"{n}={p}")],
               *map_args]
    log_file = open(work / "run.log", "w")
    # As the unit runs it: the drivers at real-time priority (where this user may), the workers niced.
    env = {**os.environ, "SARBOT_DRIVER_RT_PRIORITY": "40"}
    daemon = subprocess.Popen(run_cmd, cwd=ROOT, stdout=log_file, stderr=subprocess.STDOUT, text=True, env=env)
    sub = BusSubscriber(health_endpoint, topics=[Health.TOPIC])
    map_sub = None
    checker = PartChecker(out, radars)
    samples: list[dict] = []
    last_health: Health | None = None
    last_map: MapStatus | None = None
    # the highest lag of every message between two samples: a stall shorter than the sampling is seen too
    window_max = {"map_lag_window_max_s": 0.0, "odometry_lag_window_max_s": 0.0,
                  "map_waiting_for_poses_window_max_s": 0.0}
    t_warm = time.monotonic()
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:  # the workers compile their kernels before the pipeline is warm
        m = sub.receive(timeout_ms=500)
        if daemon.poll() is not None:
            raise SystemExit(f"sarbot run exited with {daemon.returncode}; see {work / 'run.log'}")
        if m is not None:
            last_health = Health.from_message(m)
            if last_health.warm:
                break
    warm_up_s = time.monotonic() - t_warm
    print(f"soak: pipeline warm after {warm_up_s:.0f} s; replaying {laps} laps of {lap_s:.1f} s "
          f"({laps * lap_s / 60:.1f} min)", flush=True)
    replay_started = time.monotonic()
    replay = subprocess.Popen([*SARBOT, "replay", str(sim_path), "--imu-link", str(imu_link), "--laps", str(laps),
                               "--start-delay", "1", *[a for n, p in ports.items() for a in ("--radar", f"{n}=127.0.0.1:{p}")]],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              preexec_fn=(lambda: os.nice(emulator_nice)) if emulator_nice else None)
    try:
        t0 = time.monotonic()
        cpu_before: dict[int, float] = {}
        wait_before: dict[int, float] = {}
        machine_before = machine_cpu_s()
        own_before = own_cpu_s()
        map_busy_before = 0.0
        next_sample = t0 + SAMPLE_EVERY_S
        while replay.poll() is None or time.monotonic() < next_sample - SAMPLE_EVERY_S + 5:
            m = sub.receive(timeout_ms=200)
            if m is not None:
                last_health = Health.from_message(m)
                odometry = last_health.workers.get("rio")
                if odometry is not None:
                    window_max["odometry_lag_window_max_s"] = max(window_max["odometry_lag_window_max_s"],
                                                                  odometry.counters.get("lag_ms", 0) / 1e3)
                if map_sub is None and "stripmap" in last_health.endpoints:
                    map_sub = BusSubscriber(last_health.endpoints["stripmap"], topics=[MapStatus.TOPIC])
            while map_sub is not None and (mm := map_sub.receive(timeout_ms=0)) is not None:
                last_map = decode(mm)
                window_max["map_lag_window_max_s"] = max(window_max["map_lag_window_max_s"], last_map.lag_s)
                window_max["map_waiting_for_poses_window_max_s"] = max(
                    window_max["map_waiting_for_poses_window_max_s"], last_map.waiting_for_poses_s)
            if time.monotonic() < next_sample:
                continue
            next_sample += SAMPLE_EVERY_S
            tree = named_process_tree(daemon.pid, "supervisor+recorder")
            sample = {"t_s": round(time.monotonic() - t0, 1), "rss_mb": {}, "cpu_pct": {}, "waiting_for_core_pct": {}}
            for pid, name in tree.items():
                rss, cpu, wait = rss_mb(pid), cpu_s(pid), run_queue_wait_s(pid)
                if rss is None or cpu is None:
                    continue
                sample["rss_mb"][name] = round(rss, 1)
                if pid in cpu_before:
                    sample["cpu_pct"][name] = round(100 * (cpu - cpu_before[pid]) / SAMPLE_EVERY_S, 1)
                if wait is not None and pid in wait_before:
                    sample["waiting_for_core_pct"][name] = round(100 * (wait - wait_before[pid]) / SAMPLE_EVERY_S, 1)
                cpu_before[pid] = cpu
                if wait is not None:
                    wait_before[pid] = wait
            # The emulated hardware shares the unit's two cores here (on the robot it does not): what it took,
            # and whether the machine as a whole had any left.
            for pid, name in {replay.pid: "replay", **{c: f"replay-{i}" for i, c in enumerate(
                    child_pids(replay.pid) or [])}}.items():
                cpu = cpu_s(pid)
                if cpu is not None and pid in cpu_before:
                    sample["replay_cpu_pct"] = sample.get("replay_cpu_pct", 0.0) + round(
                        100 * (cpu - cpu_before[pid]) / SAMPLE_EVERY_S, 1)
                if cpu is not None:
                    cpu_before[pid] = cpu
            own = own_cpu_s()
            sample["soak_cpu_pct"] = round(100 * (own - own_before) / SAMPLE_EVERY_S, 1)
            own_before = own
            machine = machine_cpu_s()
            sample["machine_cpu_pct"] = {k: round(100 * (machine[k] - machine_before[k]) / SAMPLE_EVERY_S, 1)
                                         for k in machine}
            machine_before = machine
            if last_health is not None:
                odometry = last_health.workers.get("rio")
                sample.update(bus_lost=last_health.bus_lost, restarts=last_health.restarts,
                              invalid=sum(last_health.invalid_frames.values()), frames_per_s=last_health.frames_per_s,
                              imu_hz=last_health.imu_hz,
                              odometry_lag_s=None if odometry is None else odometry.counters.get("lag_ms", 0) / 1e3,
                              odometry_counters=None if odometry is None else odometry.counters)
            if last_map is not None:
                sample.update(map_lag_s=round(last_map.lag_s, 3), map_dropped=last_map.frames_dropped_behind,
                              map_presummed_more=last_map.frames_presummed_more,
                              map_batched=last_map.frames_batched, map_thinned=last_map.frames_thinned,
                              map_rx_summed=last_map.frames_rx_summed,
                              map_imaged=last_map.frames_imaged, map_tiles=last_map.tiles,
                              map_waiting_for_poses_s=round(last_map.waiting_for_poses_s, 3),
                              map_imaging_cpu_pct=round(100 * (last_map.busy_s - map_busy_before) / SAMPLE_EVERY_S, 1))
                map_busy_before = last_map.busy_s
            sample.update({k: round(v, 3) for k, v in window_max.items()})
            window_max = dict.fromkeys(window_max, 0.0)
            sample["imu_in_file_lag_s"] = checker.imu_lag_s()
            checker.check_finished()
            samples.append(sample)
            print(f"soak: {sample['t_s']:6.0f} s  RSS {sum(sample['rss_mb'].values()):6.0f} MB  "
                  f"odometry lag {sample.get('odometry_lag_s')} (<= {sample.get('odometry_lag_window_max_s')})  "
                  f"map lag {sample.get('map_lag_s')} (<= {sample.get('map_lag_window_max_s')})  "
                  f"map dropped {sample.get('map_dropped')}  bus lost {sample.get('bus_lost')}", flush=True)
            if daemon.poll() is not None:
                break
    except BaseException:
        # The soak's own failure (or ^C) leaves no replay or daemon running on behind it.
        for proc in (replay, daemon):
            proc.kill()
        raise
    replay_out, replay_err = replay.communicate(timeout=120)
    replay_s = time.monotonic() - replay_started
    time.sleep(3.0)
    daemon.send_signal(signal.SIGINT)
    try:
        daemon.wait(timeout=180)
    except subprocess.TimeoutExpired:
        daemon.kill()
        daemon.wait()
    log_file.close()
    sub.close()
    if map_sub is not None:
        map_sub.close()
    for path in checker.parts_on_disk():
        checker.check(path)
        path.unlink()
    log_text = (work / "run.log").read_text()
    result = summarise(samples, checker, laps, frames_per_lap, lap_s, warm_up_s, replay.returncode, replay_err,
                       daemon.returncode, log_text.splitlines()[-20:])
    result["drivers_realtime"] = "not granted" not in log_text
    # The emulator keeps 1x if it finishes its laps on time (its start delay and 0.1 s start aside): a
    # replay starved of CPU sends late, and the daemon then sees less than 1x.
    result["emulator_nice"] = emulator_nice
    result["replay_s"] = replay_s
    result["replay_behind_1x_s"] = replay_s - laps * lap_s - 1.1
    result["cpu_accounting"] = cpu_accounting(samples, radars)
    return result


def own_cpu_s() -> float:
    """This script's CPU so far (its bus subscriptions and the checking of every recorded part), s."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def map_needs_core_fraction(radars: list[str]) -> dict | None:
    """What the map's frames need of one core at 1x, from docs/results/stripmap_capacity.json (measured in one
    process on the soak's scene, four radars), scaled to ``radars``; None without that file."""
    path = RESULTS / "stripmap_capacity.json"
    if not path.exists():
        return None
    capacity = json.loads(path.read_text())
    return {"core_fraction": capacity["polar"]["core_fraction_at_1x"] * len(radars) / len(capacity["radars"]),
            "commit": capacity.get("commit"), "cpu_ms_per_frame": capacity["polar"]["cpu_ms_per_frame"]}


def cpu_accounting(samples: list[dict], radars: list[str]) -> dict:
    """Where the machine's CPU went over the run (means of the 10 s samples, % of one core): the daemon's
    processes, the emulated hardware (the replay: a sender per radar and the IMU; on the robot these are
    devices), this script, and everything else on the machine (``other``: other users), with what was left
    idle; and whether the map got what its frames need (``map_needs_core_fraction``). ``verdict`` says which
    it was: the daemon could not keep up, or the machine was full (with the emulator, or with others' work)."""
    rows = [s for s in samples if s.get("cpu_pct") and "machine_cpu_pct" in s]
    if not rows:
        return {}

    def mean(values) -> float:
        values = [v for v in values if v is not None]
        return round(float(np.mean(values)), 1) if values else 0.0

    names = sorted({n for s in rows for n in s["cpu_pct"]})
    per_process = {n: mean([s["cpu_pct"].get(n) for s in rows]) for n in names}
    daemon = round(sum(per_process.values()), 1)
    emulator = mean([s.get("replay_cpu_pct") for s in rows])
    own = mean([s.get("soak_cpu_pct") for s in rows])
    busy = mean([s["machine_cpu_pct"]["busy"] for s in rows])
    idle = mean([s["machine_cpu_pct"]["idle"] for s in rows])
    other = round(max(busy - daemon - emulator - own, 0.0), 1)
    map_got = per_process.get("sarbot-stripmap", 0.0)
    map_waited = mean([s.get("waiting_for_core_pct", {}).get("sarbot-stripmap") for s in rows])
    needs = map_needs_core_fraction(radars)
    out = {"cores": os.cpu_count(), "daemon_pct": daemon, "daemon_per_process_pct": per_process,
           "emulator_pct": emulator, "soak_script_pct": own, "other_pct": other, "idle_pct": idle,
           "machine_busy_pct": busy, "map_pct": map_got, "map_waiting_for_core_pct": map_waited,
           "map_needs_pct": None if needs is None else round(100 * needs["core_fraction"], 1), "map_needs_from": needs}
    # Per frame the daemon received (all radars; fewer than 1x when the emulator sent late): what each process
    # and the emulated hardware cost a frame, comparable between loaded and quiet runs.
    received = mean([sum((s.get("frames_per_s") or {}).values()) for s in rows])
    out["frames_per_s_received"] = received
    if received > 0:
        out["cpu_ms_per_frame"] = {"daemon": round(10 * daemon / received, 3), "emulator": round(10 * emulator / received, 3),
                                   "daemon_per_process": {n: round(10 * v / received, 3) for n, v in per_process.items()}}
    if needs is None:
        out["verdict"] = "unknown: no docs/results/stripmap_capacity.json to say what the map needs"
        return out
    short = 100 * needs["core_fraction"] - map_got
    # Idle time the map could have had: a machine with a core's tenth or more idle was not full.
    full = idle < 10.0
    if short <= 0 or not full:
        out["verdict"] = (f"the daemon: the map got {map_got:.0f} % of a core (it needs {out['map_needs_pct']:.0f} %) "
                          f"with {idle:.0f} % of the machine idle")
    elif other > short:
        out["verdict"] = (f"the machine was full with others' work: the map got {map_got:.0f} % of a core against the "
                          f"{out['map_needs_pct']:.0f} % its frames need, {other:.0f} % went to other processes on the "
                          f"machine, {emulator:.0f} % to the emulated hardware, {idle:.0f} % idle")
    else:
        out["verdict"] = (f"the machine was full with the emulator: the map got {map_got:.0f} % of a core against the "
                          f"{out['map_needs_pct']:.0f} % its frames need, the emulated hardware took {emulator:.0f} % "
                          f"(on the robot, devices), other processes {other:.0f} %, {idle:.0f} % idle")
    return out


def rss_summary(samples: list[dict], duration_s: float) -> dict:
    """Per process, after warm-up (from the third minute, or a tenth of a shorter run): ``drift_mb``, the
    median of the last tenth of the samples less that of the first tenth (the trend a leak shows), and
    ``excursion_mb``, the highest sample less the first (what a backlog borrows for a while)."""
    settle_s = min(180.0, 0.1 * duration_s) if duration_s > 300 else 0.3 * duration_s
    out = {}
    for name in sorted({n for s in samples for n in s["rss_mb"]}):
        values = np.array([s["rss_mb"][name] for s in samples if name in s["rss_mb"] and s["t_s"] >= settle_s])
        if values.size < 2:
            continue
        tenth = max(1, values.size // 10)
        out[name] = {"after_warm_up_mb": float(values[0]), "end_mb": float(values[-1]), "max_mb": float(values.max()),
                     "drift_mb": float(np.median(values[-tenth:]) - np.median(values[:tenth])),
                     "excursion_mb": float(values.max() - values[0])}
    return out


def summarise(samples, checker, laps, frames_per_lap, lap_s, warm_up_s, replay_code, replay_err, daemon_code,
              log_tail) -> dict:
    duration_s = samples[-1]["t_s"] if samples else 0.0
    growth = rss_summary(samples, duration_s)
    def lag_stats(key, window_key=None):
        values = np.array([s[key] for s in samples if s.get(key) is not None], float)
        if values.size == 0:
            return None
        half = values.size // 2
        stats = {"p50_s": float(np.median(values)), "max_s": float(values.max()),
                 "first_half_p50_s": float(np.median(values[:half])) if half else None,
                 "second_half_p50_s": float(np.median(values[half:]))}
        peaks = np.array([s[window_key] for s in samples if s.get(window_key) is not None], float)
        if peaks.size:  # max_s is of the samples (every 10 s); these are of every status message
            stats.update(max_any_s=float(peaks.max()), p99_any_s=float(np.quantile(peaks, 0.99)),
                         windows_over_2s=int(np.sum(peaks > 2.0)), windows=int(peaks.size))
        return stats

    sent = laps * frames_per_lap
    last = samples[-1] if samples else {}
    result = {
        "minutes": duration_s / 60, "laps": laps, "lap_s": lap_s, "warm_up_s": warm_up_s,
        "frames_sent_per_radar": sent, "frames_recorded": checker.frames, "invalid_frames": checker.invalid,
        "counter_gaps": checker.counter_gaps, "imu_samples": checker.imu_samples,
        "imu_samples_sent": int(round(laps * lap_s * 400)), "parts": checker.parts,
        "bus_lost": last.get("bus_lost"), "restarts": last.get("restarts"),
        "map_frames_dropped": last.get("map_dropped"), "map_frames_imaged": last.get("map_imaged"),
        "map_frames_presummed_more": last.get("map_presummed_more"), "map_frames_batched": last.get("map_batched"),
        "map_frames_rx_summed": last.get("map_rx_summed"), "map_frames_thinned": last.get("map_thinned"),
        "odometry_counters": last.get("odometry_counters"),
        "rss": growth, "rss_goal_mb": RSS_GOAL_MB,
        "rss_flat": all(g["drift_mb"] <= RSS_GOAL_MB for g in growth.values()),
        "odometry_lag": lag_stats("odometry_lag_s", "odometry_lag_window_max_s"),
        "map_lag": lag_stats("map_lag_s", "map_lag_window_max_s"),
        "map_waiting_for_poses": lag_stats("map_waiting_for_poses_s", "map_waiting_for_poses_window_max_s"),
        "imu_in_file_lag": lag_stats("imu_in_file_lag_s"),
        "no_loss": all(checker.frames[n] == sent and checker.invalid[n] == 0 for n in checker.frames)
        and last.get("bus_lost") == 0,
        "warnings_and_errors": sorted({e for e in checker.events if " info:" not in e})[:50],
        "replay_exit": replay_code, "replay_stderr_tail": replay_err.splitlines()[-5:],
        "daemon_exit": daemon_code, "daemon_log_tail": log_tail, "samples": samples,
        # the machine's load at the end (1, 5, 15 min): other work on it shows here
        "load_average_end": list(os.getloadavg()), "cpu_count": os.cpu_count(),
    }
    return result


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = result["samples"]
    t = np.array([s["t_s"] for s in samples]) / 60
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for name in sorted({n for s in samples for n in s["rss_mb"]}):
        ax1.plot([s["t_s"] / 60 for s in samples if name in s["rss_mb"]],
                 [s["rss_mb"][name] for s in samples if name in s["rss_mb"]], label=name)
    ax1.set_ylabel("resident memory, MB")
    ax1.legend(fontsize=7, ncol=3)
    radars = result.get("radars", [])
    ax1.set_title(f"soak at 1x: {result['minutes']:.0f} min, {len(radars)} radars + IMU, recorder, odometry, live map")
    for key, label in (("odometry_lag_s", "odometry lag"), ("map_lag_s", "map lag"),
                       ("map_lag_window_max_s", "map lag, highest in each 10 s"),
                       ("imu_in_file_lag_s", "IMU in file lag")):
        ax2.plot(t, [s.get(key) if s.get(key) is not None else np.nan for s in samples], label=label)
    ax2.set_ylabel("lag, s")
    ax2.set_xlabel("time, min")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--quick", action="store_true", help="3 minutes (a check that the soak runs)")
    ap.add_argument("--summary-of", metavar="JSON",
                    help="no run: summarise and chart the samples of an earlier run's JSON again")
    ap.add_argument("--radars", default="left_front,left_rear",
                    help="radars replayed and mapped (default the left pair; four, with their emulation on the same "
                         "two cores, fill this machine: see the module notes)")
    ap.add_argument("--map-args", default="", help="more `sarbot run` options for the map, quoted (e.g. \"--map-algorithm "
                    "ffbp --map-aperture 2 --map-pixel 0.004\"); the results then go to soak_<--name>.*")
    ap.add_argument("--name", help="the results' name with --map-args or --emulator-nice (soak_NAME.json)")
    ap.add_argument("--emulator-nice", type=int, default=0,
                    help="run the emulated hardware (the replay's senders and IMU) niced this far (19: it takes what "
                         "the daemon leaves; whether it still kept 1x is in replay_behind_1x_s)")
    args = ap.parse_args()
    started_load = load_average()
    if (args.map_args or args.emulator_nice) and not args.name:
        ap.error("--map-args and --emulator-nice need --name (the results must not overwrite the default soak's)")
    if args.summary_of:
        path = Path(args.summary_of)
        result = json.loads(path.read_text())
        result["rss"] = rss_summary(result["samples"], result["samples"][-1]["t_s"])
        result["rss_flat"] = all(g["drift_mb"] <= RSS_GOAL_MB for g in result["rss"].values())
        result["cpu_accounting"] = cpu_accounting(result["samples"], result.get("radars") or list(result["frames_recorded"]))
        write_results(path.stem, result, started_load=started_load, folder=path.parent, indent=1)
        chart(result, path.with_suffix(".png"))
        print(strict_json.dumps({"rss": result["rss"], "cpu_accounting": result["cpu_accounting"]}, indent=1))
        return 0 if result["no_loss"] and result["rss_flat"] else 1
    minutes = 3.0 if args.quick else args.minutes
    radars = args.radars.split(",")
    with tempfile.TemporaryDirectory(prefix="sarbot-soak-") as tmp:
        result = soak(minutes, Path(tmp), radars, shlex.split(args.map_args), args.emulator_nice)
    result["radars"] = radars
    result["map_args"] = args.map_args
    result["commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                      text=True).stdout.strip()
    # The left pair (the default) writes soak.*; another set of radars a file of its own (soak_4radars.*).
    stem = "soak" if radars == ["left_front", "left_rear"] else f"soak_{len(radars)}radars"
    stem = f"soak_{args.name}" if args.name else stem
    stem += "_quick" if args.quick else ""
    write_results(stem, result, started_load=started_load, indent=1)
    chart(result, RESULTS / f"{stem}.png")
    print(strict_json.dumps({k: v for k, v in result.items() if k not in ("samples", "daemon_log_tail")}, indent=1))
    print(f"wrote {RESULTS / (stem + '.json')} and {stem}.png")
    return 0 if result["no_loss"] and result["rss_flat"] else 1


if __name__ == "__main__":
    sys.exit(main())
