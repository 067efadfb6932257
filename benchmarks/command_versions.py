"""`sarbot image` as a new process against its own kernel, at this checkout and at an earlier commit
(issue 34's, by default), timed alternately in one run, on the cases the issue's figure could have come from.

Issue 34 said "sarbot image as a whole process reaches 62-72 % of the kernel" at 9dd63ca, the last commit
before its work, without naming the case. Each version here is a tree of its own (the earlier one from
``git archive COMMIT``, with a numba cache of its own) that simulates its own recordings of the same
scenes, runs its own command (``python -m acquisition.cli -q image ...`` in that tree, a new process, with
its byte code cached as after an install) and times its own kernel on the same profiles in a worker
process that stays up (``backproject`` on all the case's frames at once, both cores, as the command runs
it). A round is: earlier command, earlier kernel, this command, this kernel; the fraction of the kernel
(kernel seconds / command seconds) is taken per round and the median over rounds reported, in wall time
and in CPU time (the command's process and its threads; the kernel's threads): on a machine others load,
the CPU-time fraction moves less, but it is not the wall-time figure the issue means (the kernel's CPU
time is spread over both cores, the start's is not).

The cases:

- ``benchmark_case``: the backprojection benchmark's (16 frames of the left-front radar, all 16 channels,
  256 x 256 pixels over 1 x 1 m);
- ``larger_case``: 32 frames on 512 x 512 pixels (8 times the work);
- ``readme_case``: the README's command: ``sarbot simulate paper_pass_0.4`` then ``sarbot image --radar
  left_front --frames 30:60 --grid -0.5:0.5:0.002,1.8:2.2:0.004`` (30 frames on 501 x 101 pixels).

    python benchmarks/command_versions.py [--baseline COMMIT] [--rounds N] [--quick] [--cases NAME,...]

Updates ``baseline_comparison`` in docs/results/image_command.json (image_command.py runs it too); with
``--cases`` (some of the cases alone) it is written as ``baseline_comparison_<commit>_<cases>`` beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from results_file import load_average, probe_machine, write_results

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
#: The last commit before issue 34's work: the state the issue measured.
BASELINE = "9dd63ca"
#: The command's environment: without PYTHONDONTWRITEBYTECODE, so that sarbot's byte code is cached as after
#: an install (else every run compiles the sources again).
COMMAND_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}

#: name -> (frames simulated or None for the README's scene, frames imaged "a:b" or None, grid).
CASES = {
    "benchmark_case": (16, None, "-0.5:0.5:0.00390625,1.5:2.5:0.00390625,0.3"),
    "larger_case": (32, None, "-0.5:0.5:0.001953125,1.5:2.5:0.001953125,0.3"),
    "readme_case": (None, "30:60", "-0.5:0.5:0.002,1.8:2.2:0.004"),
}
QUICK_CASES = {
    "benchmark_case": (4, None, "-0.5:0.5:0.0078125,1.5:2.5:0.0078125,0.3"),
    "readme_case": (None, "30:34", "-0.5:0.5:0.004,1.8:2.2:0.008"),
}

#: The worker in a tree: makes the recordings (that tree's simulator), the profiles of each case (that
#: tree's range compression), compiles, says "ready", then backprojects the case named on each stdin line.
WORKER = r"""
import json, subprocess, sys, time
sys.path.insert(0, ".")
import numpy as np
from imaging.backprojection import backproject
from imaging.core.grid import Grid
from imaging.core.rig import default_rig
from imaging.core.trajectory import StraightLine
from imaging.image_formation import ImagingOptions, frame_profiles
from imaging.io.recording import Recording
from imaging.sim.scene import DEFAULT_START_TIME_NS, Scene
from imaging.sim.simulator import simulate_recording
from imaging.sim.targets import PointTarget
cases, folder = json.loads(sys.argv[1]), sys.argv[2]
options, loaded = ImagingOptions(), {}
for name, (n_frames, frames, grid_text) in cases.items():
    path = f"{folder}/{name}.h5"
    if n_frames is None:
        subprocess.run([sys.executable, "-m", "acquisition.cli", "-q", "simulate", "paper_pass_0.4", "-o", path],
                       check=True, stdout=subprocess.DEVNULL)
    else:
        rig = default_rig()
        duration = n_frames * rig.radar("left_front").waveform.frame_interval_s
        traj = StraightLine(start_m=(-0.15 - 0.4 * duration / 2, -0.2, 0.0), speed_mps=0.4, t0_ns=DEFAULT_START_TIME_NS)
        targets = [PointTarget((dx, 2.0 + dy, 0.3)) for dx, dy in [(0, 0), (-0.2, 0.1), (0.25, -0.2), (0.1, 0.3), (-0.3, -0.3)]]
        simulate_recording(Scene(name="bench", rig=rig, trajectory=traj, targets=targets, duration_s=duration - 1e-3,
                                 radars=["left_front"], snr_db=0.0, seed=0, adc_counts_per_unit=2000.0), path)
    sel = slice(*map(int, frames.split(":"))) if frames else slice(None)
    with Recording(path) as rec:
        radar, truth = rec.radar("left_front"), rec.truth()
        z0 = float(np.mean(truth.position_m[:, 2])) + float(radar.mount.translation_m[2])
        grid = Grid.parse(grid_text, default_z_m=z0)
        prof, tx, rx, _, _ = frame_profiles(rec.adc("left_front", sel), rec.frame_time_ns("left_front", sel), radar,
                                            truth, rec.tdm_tx_order("left_front"), options)
    points = grid.points()
    backproject(prof, tx, rx, points[:2, :2], mode=options.mode)
    loaded[name] = (prof, tx, rx, points)
    print(json.dumps({"case": name, "profiles": int(prof.data.shape[0]), "grid_points": int(points.size // 3)}),
          flush=True)
print(json.dumps({"ready": True}), flush=True)
for line in sys.stdin:
    prof, tx, rx, points = loaded[line.strip()]
    t, c = time.perf_counter(), time.process_time()
    backproject(prof, tx, rx, points, mode=options.mode)
    print(json.dumps({"kernel_s": time.perf_counter() - t, "kernel_cpu_s": time.process_time() - c}), flush=True)
"""


class Version:
    """One tree: its kernel worker, and its command as a new process."""

    def __init__(self, label: str, tree: Path, folder: Path, cases: dict, env: dict):
        self.label, self.tree, self.folder, self.cases, self.env = label, tree, folder, cases, env
        folder.mkdir(parents=True, exist_ok=True)
        self.worker = subprocess.Popen([sys.executable, "-c", WORKER, json.dumps(cases), str(folder)],
                                       cwd=tree, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.sizes = {}
        while True:
            msg = json.loads(self.worker.stdout.readline())
            if msg.get("ready"):
                break
            self.sizes[msg["case"]] = {"profiles": msg["profiles"], "grid_points": msg["grid_points"]}

    def kernel(self, case: str) -> tuple[float, float]:
        """Wall and CPU seconds of the kernel on the case's profiles."""
        self.worker.stdin.write(case + "\n")
        self.worker.stdin.flush()
        msg = json.loads(self.worker.stdout.readline())
        return msg["kernel_s"], msg["kernel_cpu_s"]

    def command(self, case: str) -> tuple[float, float]:
        """Wall and CPU seconds (all its threads) of the command as a new process."""
        _, frames, grid = self.cases[case]
        line = [sys.executable, "-m", "acquisition.cli", "-q", "image", str(self.folder / f"{case}.h5"), "-o",
                str(self.folder / f"{case}_img.h5"), "--grid", grid, "--radar", "left_front", "--overwrite"]
        if frames:
            line += ["--frames", frames]
        wall, cpu, _ = timed_process(line, self.tree, self.env)
        return wall, cpu

    def close(self) -> None:
        self.worker.stdin.close()
        self.worker.wait()


def uptime() -> str:
    """``uptime``'s line: the machine is shared, and its load moves these figures."""
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def commit_of(tree: Path, rev: str = "HEAD") -> str:
    return subprocess.run(["git", "rev-parse", "--short", rev], cwd=tree, capture_output=True, text=True,
                          check=True).stdout.strip()


def compare(baseline: str, cases: dict, rounds: int, tmp: Path) -> dict:
    """The fraction of its kernel each version's command reaches on each case, alternating (see the module)."""
    old_tree = tmp / "baseline_tree"
    old_tree.mkdir()
    archive = subprocess.run(["git", "archive", baseline], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(old_tree)], input=archive, check=True)
    old_env = {**COMMAND_ENV, "NUMBA_CACHE_DIR": str(tmp / "baseline_numba_cache")}
    versions = [Version("baseline", old_tree, tmp / "baseline_data", cases, old_env),
                Version("now", ROOT, tmp / "now_data", cases, COMMAND_ENV)]
    dirty = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "acquisition", "imaging"], cwd=ROOT).returncode
    result = {"baseline_commit": commit_of(ROOT, baseline), "now_commit": commit_of(ROOT) + ("+changes" if dirty else ""),
              "rounds": rounds, "uptime_before": uptime(), "cases": {}}
    try:
        for case in cases:
            for v in versions:
                v.command(case)  # warm: the kernels compiled into numba's cache, byte code, the page cache
            times = {v.label: [] for v in versions}
            for _ in range(rounds):
                for v in versions:
                    times[v.label].append((v.command(case), v.kernel(case)))
            entry = {}
            for v in versions:
                rounds_ = times[v.label]
                fractions = [k[0] / c[0] for c, k in rounds_]
                cpu_fractions = [k[1] / c[1] for c, k in rounds_]
                entry[v.label] = {
                    **v.sizes[case],
                    "command_fraction_of_kernel": {"median": statistics.median(fractions), "min": min(fractions),
                                                   "max": max(fractions)},
                    "command_fraction_of_kernel_cpu_time": statistics.median(cpu_fractions),
                    "command_s": [c[0] for c, _ in rounds_], "kernel_s": [k[0] for _, k in rounds_],
                    "command_cpu_s": [c[1] for c, _ in rounds_], "kernel_cpu_s": [k[1] for _, k in rounds_],
                }
            result["cases"][case] = entry
            print(f"{case}: " + "; ".join(
                f"{label} {100 * e['command_fraction_of_kernel']['median']:.0f} % of its kernel "
                f"({100 * e['command_fraction_of_kernel']['min']:.0f}-{100 * e['command_fraction_of_kernel']['max']:.0f} %, "
                f"command {statistics.median(e['command_s']):.2f} s, kernel {statistics.median(e['kernel_s']):.2f} s; "
                f"CPU time {100 * e['command_fraction_of_kernel_cpu_time']:.0f} %)"
                for label, e in entry.items()), flush=True)
    finally:
        for v in versions:
            v.close()
    result["uptime_after"] = uptime()
    return result


def timed_process(command_line: list, cwd, env: dict, capture: bool = False) -> tuple[float, float, str]:
    """``command_line`` run to its end as a new process: its wall seconds, its CPU seconds (the process and its
    threads, from this one's children's usage) and, with ``capture``, its standard output."""
    before, t = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    run = subprocess.run(command_line, check=True, cwd=cwd, env=env, text=True,
                         stdout=subprocess.PIPE if capture else subprocess.DEVNULL,
                         stderr=subprocess.PIPE if capture else None)
    wall, after = time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, run.stdout or ""


def chosen_cases(ap: argparse.ArgumentParser, text: str, cases: dict) -> dict:
    """``--cases``' comma-separated names, each of ``cases``, in their order; else a usage error (exit 2)."""
    chosen = [c.strip() for c in text.split(",") if c.strip()]
    unknown = [c for c in chosen if c not in cases]
    if unknown or not chosen:
        ap.error(f"--cases: unknown case(s) {', '.join(unknown) or '(none given)'}; known: {', '.join(cases)}")
    return {name: cases[name] for name in chosen}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", default=BASELINE, help=f"the earlier commit (default {BASELINE}, issue 34's)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cases", help="only these cases, comma-separated")
    args = ap.parse_args()
    if args.rounds < 1:
        ap.error(f"--rounds must be at least 1, got {args.rounds}")
    cases = QUICK_CASES if args.quick else CASES
    if args.cases is not None:
        cases = chosen_cases(ap, args.cases, cases)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        result = compare(args.baseline, cases, args.rounds, Path(tmp))
    result["load_average"] = {"before": load_before, "after": os.getloadavg()}
    if args.quick:
        print(json.dumps(result, indent=2))
        return 0
    part = "baseline_comparison" if args.cases is None else \
        f"baseline_comparison_{result['baseline_commit']}_{'_'.join(cases)}"
    path = write_results("image_command", result, started_load=started_load, part=part)
    print(f"wrote {part} into {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
