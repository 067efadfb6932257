"""Fast factorized backprojection against the direct kernel: speed-up against error, and against aperture.

The case: the left-front radar (all 16 channels, 1024 profiles a frame) driving at 0.4 m/s past five point
targets at about 2 m; the image 1 m x 0.6 m at 2 mm pixels (the cross-range resolution of a 2 m aperture
at 2 m is about 2 mm). The direct kernel (``imaging.backprojection.backproject``, linear, 8x oversampled
profiles) is the baseline, run in the same process on the same profiles; the error is FFBP's image
against it (energy of the difference over the image's, dB), beside the plan's bound and estimate. On the
longest aperture:

* ``frontier``: speed against error over FFBP's settings (leaf size, the leaves' and the merged grids'
  oversampling and taps), each run alternated with the default's in the same rounds (``speed_over_default``,
  the median of the rounds' ratios: a load that comes and goes hits both alike), and as the CPU time of a
  run on one thread (``cpu_speed_over_default``: on a loaded machine the steadier figure);
* ``threads``: FFBP's run on 1 and on 2 threads, with the machine as it is (interleaved with the direct
  kernel) and with another process keeping one core busy;
* ``reach``: the default's error where the plan works harder: the scene further out (3.5 and 5 m, pixels
  scaled with range; the profiles reach 6.6 m) and a 4 m aperture, on a smaller image (150 x 100 pixels).

The plan (``plan_factorized``) is timed too: ``plan_s`` (best of the repeats), ``plan_s_first_call`` (on the
first aperture the process's first plan, loading its numba passes from the cache, as ``sarbot image`` pays it), and in
``threads`` per round beside the direct kernel, for ``speedup_with_plan_over_direct_2_threads_interleaved``
(FFBP counting its plan, as a user imaging once pays it).

With ``--plan`` only the longest aperture's plan and run: the plan against the node-at-a-time builder it
replaced (tests/reference_ffbp_plan.py), alternated in one process, and FFBP with its plan against the direct
kernel in each round, both on 2 threads (a run of a minute or two, for a loaded machine; the load is recorded).
Each plan's page faults are counted, and the plan is also timed as a user meets it, in new processes
(``fresh_process``: the first plan, with numba's start and cache loads, and four more), beside the rounds'
(each after an 11 s direct image in a process that has freed large arrays, whose allocator state a user's
``sarbot image`` does not share). Why a plan in the rounds may cost more than in a fresh process
(``plan_conditions``): in each round the plan right after the direct kernel (the rounds' ``plan_s``), again,
after a 1 s pause and on a new thread; each with its parts' CPU time, the other threads' CPU time while it ran
(OpenMP's workers spinning), its wait for a core, the machine's steal time and the main heap's free chunks.

    python benchmarks/ffbp.py [--quick | --plan]

Writes docs/results/ffbp.json and docs/results/ffbp.png (``ffbp_quick.*`` with --quick, ``ffbp_plan.json``
with --plan).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks"), str(ROOT / "tests")]

from backprojection import make_case  # noqa: E402

from imaging.backprojection import backproject  # noqa: E402
from imaging.factorized_backprojection import FactorizedOptions, plan_factorized, run_factorized  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402
from process_stats import free_heap_chunks, machine_cpu_s, other_threads_cpu_s, this_thread_wait_s  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
SPEED_MPS = 0.4


def timed(fn, repeats: int):
    best, out = float("inf"), None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def error_db(image, reference) -> float:
    return float(20 * np.log10(np.linalg.norm(image - reference) / np.linalg.norm(reference)))


def load_text() -> str:
    """``uptime``'s line (the load averages), for the record: the machine is shared."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return " ".join(f"{x:.2f}" for x in os.getloadavg())


def machine(uptime_before: str) -> dict:
    return {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(), "numba": numba.__version__,
            "python": platform.python_version(), "load_average": os.getloadavg(),
            "uptime_before": uptime_before, "uptime_after": load_text()}


def busy_core():
    """Another process keeping one core busy (as the robot's drivers, recorder and odometry do)."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def threads_study(plan, prof, tx, rx, t_direct_2: float, repeats: int, direct=None, make_plan=None) -> dict:
    """FFBP's run on 1 and 2 threads, with the machine as it is and with another process keeping one core
    busy; runs alternate between the thread counts. The direct kernel's 2-thread time is the baseline of
    the speed-ups (measured with the machine as it is); with ``direct`` (the direct kernel's call) it is
    also run in every round as it is, before the FFBP runs, for a speed-up per round (a load that comes and
    goes hits both alike): ``speedup_over_direct_2_threads_interleaved``, the median over rounds. With
    ``make_plan`` (the plan's call) the plan is made in every such round too, for
    ``speedup_with_plan_over_direct_2_threads_interleaved``: FFBP counting its plan and its run on 2 threads."""
    out = {}
    for label, busy in (("as_is", False), ("one_core_busy", True)):
        spinner = busy_core() if busy else None
        try:
            times = {1: [], 2: []}
            direct_times, plan_times = [], []
            for _ in range(repeats):
                if direct is not None and not busy:
                    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
                    direct_times.append(timed(direct, 1)[0])
                    if make_plan is not None:
                        plan_times.append(timed(make_plan, 1)[0])
                for threads in (1, 2):
                    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
                    times[threads].append(timed(lambda: run_factorized(plan, prof, tx, rx), 1)[0])
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
            if spinner is not None:
                spinner.kill()
                spinner.wait()
        best = {t: min(v) for t, v in times.items()}
        out[label] = {"run_s_1_thread": best[1], "run_s_2_threads": best[2], "two_over_one_thread_speed": best[1] / best[2],
                      "speedup_over_direct_2_threads": {t: t_direct_2 / v for t, v in best.items()}}
        if direct_times:
            per_round = sorted(d / f for d, f in zip(direct_times, times[2]))
            out[label]["direct_s_2_threads_per_round"] = direct_times
            out[label]["speedup_over_direct_2_threads_interleaved"] = float(np.median(per_round))
            print(f"  interleaved with the direct kernel: {np.median(per_round):.1f}x on 2 threads "
                  f"(rounds {', '.join(f'{r:.1f}' for r in per_round)})", flush=True)
        if plan_times:
            with_plan = sorted(d / (p + f) for d, p, f in zip(direct_times, plan_times, times[2]))
            out[label]["plan_s_per_round"] = plan_times
            out[label]["speedup_with_plan_over_direct_2_threads_interleaved"] = float(np.median(with_plan))
            print(f"  with its plan ({', '.join(f'{p:.3f}' for p in plan_times)} s): {np.median(with_plan):.1f}x the "
                  f"direct kernel on 2 threads (rounds {', '.join(f'{r:.1f}' for r in with_plan)})", flush=True)
        print(f"  {label.replace('_', ' ')}: FFBP run {best[1]:.2f} s on 1 thread, {best[2]:.2f} s on 2 "
              f"({best[1] / best[2]:.2f}x); {t_direct_2 / best[2]:.1f}x the direct kernel on 2 threads", flush=True)
    return out


#: The settings charted on the longest aperture (FactorizedOptions' fields; the first is the default).
FRONTIER = [{}, {"leaf_oversample": None, "leaf_taps": None},
            {"leaf_oversample": 1.3, "leaf_taps": 10}, {"leaf_oversample": 1.3, "leaf_taps": 12},
            {"leaf_oversample": 1.4, "leaf_taps": 8}, {"leaf_oversample": 1.4, "leaf_taps": 10},
            {"leaf_oversample": 1.6, "leaf_taps": 8}, {"leaf_oversample": 1.75, "leaf_taps": 8},
            {"leaf_oversample": 1.5, "leaf_taps": 10}, {"leaf_profiles": 256}, {"leaf_profiles": 1024},
            {"taps": 4, "oversample_range": 3, "oversample_angle": 3}, {"taps": 8},
            {"taps": 6, "oversample_range": 3, "oversample_angle": 3}, {"taps": 8, "oversample_range": 1.6, "oversample_angle": 1.6}]


def settings(options: FactorizedOptions) -> dict:
    return {f: getattr(options, f) for f in ("leaf_profiles", "taps", "oversample_range", "oversample_angle",
                                             "leaf_oversample", "leaf_taps")}


def cpu_1_thread(plan, prof, tx, rx) -> float:
    """CPU seconds of a run on one thread (all of it on the calling thread): the work, which time taken by
    other processes' turns on the core does not add to (their use of the caches still does)."""
    numba.set_num_threads(1)
    try:
        t = time.thread_time()
        run_factorized(plan, prof, tx, rx)
        return time.thread_time() - t
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


def frontier(prof, tx, rx, x, y, ref, t_direct: float, rounds: int) -> list:
    """Each of FRONTIER's settings: plan, run alternated with the default's run, error against ``ref``."""
    default = FactorizedOptions()
    plan_default = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, default)
    rows = []
    for fields in FRONTIER:
        options = dataclasses.replace(default, **fields)
        t_plan, plan = timed(lambda: plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, options), 1)
        img = run_factorized(plan, prof, tx, rx)  # (compiles what is new)
        ratios, runs, cpu_ratios = [], [], []
        for _ in range(rounds):
            t_default = timed(lambda: run_factorized(plan_default, prof, tx, rx), 1)[0]
            t_run = timed(lambda: run_factorized(plan, prof, tx, rx), 1)[0]
            ratios.append(t_default / t_run)
            runs.append(t_run)
            cpu_ratios.append(cpu_1_thread(plan_default, prof, tx, rx) / cpu_1_thread(plan, prof, tx, rx))
        cost = plan.cost()
        row = {**settings(options), "plan_s": t_plan, "run_s": min(runs), "speed_over_default": float(np.median(ratios)),
               "cpu_speed_over_default": float(np.median(cpu_ratios)),
               "speedup": t_direct / min(runs), "error_db": error_db(img, ref), "error_estimate_db": plan.error_estimate_db,
               "error_bound_db": plan.error_bound_db, "leaf_backprojections": cost["leaf_backprojections"],
               "multiply_adds": cost["multiply_adds"], "levels": plan.levels}
        rows.append(row)
        print(f"  {fields or 'default'}: {row['speed_over_default']:.2f}x the default's speed "
              f"({row['cpu_speed_over_default']:.2f}x in CPU time on one thread), error {row['error_db']:.1f} dB "
              f"(estimate {row['error_estimate_db']:.1f}), leaves {cost['leaf_backprojections'] / 1e6:.0f} M "
              f"backprojections, plan {t_plan:.2f} s", flush=True)
    return rows


def reach(quick: bool) -> list:
    """The default's error against the direct kernel where the plan works harder: further out, longer."""
    # The profiles reach 6.6 m (13.2 m of two-way range): 5 m is as far out as the image fits in them.
    cases = [(0.5, 2.0)] if quick else [(2.0, 2.0), (2.0, 3.5), (2.0, 5.0), (4.0, 2.0)]
    rows = []
    for aperture_m, range_m in cases:
        samples, wf, tx, rx, _ = make_case(int(round(aperture_m / (SPEED_MPS * 0.052))), 2, 2)
        prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
        del samples
        pixel_m = 0.004 * range_m / 2.0
        x = np.arange(-75, 75) * pixel_m
        y = range_m + np.arange(-50, 50) * pixel_m
        xx, yy = np.meshgrid(x, y)
        ref = backproject(prof, tx, rx, np.stack([xx, yy, np.full_like(xx, 0.3)], axis=-1))
        plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, FactorizedOptions())
        row = {"aperture_m": aperture_m, "range_m": range_m, "pixel_m": pixel_m, "levels": plan.levels,
               "error_db": error_db(run_factorized(plan, prof, tx, rx), ref), "error_estimate_db": plan.error_estimate_db,
               "error_bound_db": plan.error_bound_db}
        rows.append(row)
        del prof
        print(f"  reach: {aperture_m:g} m aperture, scene at {range_m:g} m: error {row['error_db']:.1f} dB "
              f"(estimate {row['error_estimate_db']:.1f}), {plan.levels} levels", flush=True)
    return rows


def run_case(n_frames: int, x, y, configs, repeats: int, study_threads: bool = False) -> dict:
    samples, wf, tx, rx, _ = make_case(n_frames, 2, 2)
    prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
    del samples
    xx, yy = np.meshgrid(x, y)
    grid = np.stack([xx, yy, np.full_like(xx, 0.3)], axis=-1)
    t_direct, ref = timed(lambda: backproject(prof, tx, rx, grid), 1)
    n_bp = tx.shape[0] * x.size * y.size
    case = {"frames": n_frames, "aperture_m": float(np.ptp(0.5 * (tx[:, 0] + rx[:, 0]))), "profiles": int(tx.shape[0]),
            "pixels": int(x.size * y.size), "direct_s": t_direct, "direct_gbps": n_bp / t_direct / 1e9, "ffbp": []}
    print(f"{n_frames} frames ({case['aperture_m']:.2f} m), {case['pixels']} pixels: direct {t_direct:.2f} s "
          f"({case['direct_gbps']:.2f} G backprojections/s)", flush=True)
    for options in configs:
        def make_plan(options=options):
            return plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, options)

        t_first = timed(make_plan, 1)[0]  # the first case's: the process's first plan
        t_plan, plan = timed(make_plan, repeats)
        run_factorized(plan, prof, tx, rx)  # compile
        t_run, img = timed(lambda: run_factorized(plan, prof, tx, rx), repeats)
        row = {**settings(options), "plan_s": t_plan, "plan_s_first_call": t_first, "run_s": t_run, "speedup": t_direct / (t_plan + t_run), "error_db": error_db(img, ref),
               "error_bound_db": plan.error_bound_db, "error_estimate_db": plan.error_estimate_db, "cost": plan.cost()}
        case["ffbp"].append(row)
        print(f"  taps {options.taps} oversample {options.oversample_range:g}/{options.oversample_angle:g}, leaves "
              f"{options.leaf_taps} taps oversampled {options.leaf_oversample:g}: "
              f"plan {t_plan:.2f} s + run {t_run:.2f} s -> {row['speedup']:.1f}x the direct kernel, error "
              f"{row['error_db']:.1f} dB (estimate {row['error_estimate_db']:.1f}, bound {row['error_bound_db']:.1f}), "
              f"{plan.levels} levels, {len(plan.roots)} roots", flush=True)
        if study_threads and options == configs[0]:
            row["threads"] = threads_study(plan, prof, tx, rx, t_direct, max(2, repeats),
                                           direct=lambda: backproject(prof, tx, rx, grid), make_plan=make_plan)
    if study_threads:
        case["frontier"] = frontier(prof, tx, rx, x, y, ref, t_direct, max(2, repeats))
    return case


def thread_usage() -> tuple:
    """This thread's page faults served without I/O (a new page: zeroed, mapped) and its system CPU seconds so
    far: a plan dearer in system time than in a fresh process waits on the OS (new pages, their mapping), one
    dearer in user time computes slower (the caches, the core's speed)."""
    usage = resource.getrusage(resource.RUSAGE_THREAD)
    return usage.ru_minflt, usage.ru_stime


#: The plan's parts whose CPU time ``plan_study`` splits out (imaging.factorized_backprojection's names): the
#: phase centres' frames (numba passes and a batched eigh), the grids' placement (a numba pass), their edges
#: (numpy); the rest of a plan is its Python.
PLAN_PARTS = ("node_frames", "place_grids", "grid_edges", "track_axis")


def split_plan_parts() -> dict:
    """Wrap PLAN_PARTS in imaging.factorized_backprojection with a CPU timer (this thread's); returns the dict
    the wrappers add to (cleared by the caller before a plan)."""
    import imaging.factorized_backprojection as fb

    spent: dict = {}

    def timed_part(name, fn):
        def part(*args, **kwargs):
            t = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] = spent.get(name, 0.0) + time.thread_time() - t
        return part

    for name in PLAN_PARTS:
        setattr(fb, name, timed_part(name, getattr(fb, name)))
    return spent


#: The plan as ``sarbot image --algorithm ffbp`` meets it: a new process that imports sarbot, loads its cached
#: kernels as that command does, and plans.
FRESH_PLAN = """
import json, resource, sys, time
import numpy as np
from imaging.factorized_backprojection import plan_factorized
from imaging.numba_target import load_cached_kernels_lightly
load_cached_kernels_lightly()  # as sarbot image starts (acquisition/cli/imaging.py)
case = np.load(sys.argv[1])
args = (case["tx"], case["rx"], case["x"], case["y"], 0.3, float(case["carrier_hz"]), float(case["bandwidth_hz"]))
rows = []
for _ in range(int(sys.argv[2])):
    before, wall, cpu = resource.getrusage(resource.RUSAGE_THREAD), time.perf_counter(), time.thread_time()
    plan_factorized(*args)
    wall, cpu, after = time.perf_counter() - wall, time.thread_time() - cpu, resource.getrusage(resource.RUSAGE_THREAD)
    rows.append([wall, cpu, after.ru_minflt - before.ru_minflt, after.ru_stime - before.ru_stime])
print(json.dumps(rows))
"""


def fresh_process_plans(tx, rx, x, y, carrier_hz: float, bandwidth_hz: float, processes: int) -> dict:
    """The plan in new processes (each its first plan, numba started and the plan's kernels loaded from its
    cache, then four more): what a user imaging once pays, whatever an in-process benchmark's earlier work
    left behind (the allocator's state above all: a fresh process maps large temporaries afresh, a page fault
    a page)."""
    import json
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "case.npz"
        np.savez(path, tx=tx, rx=rx, x=x, y=y, carrier_hz=carrier_hz, bandwidth_hz=bandwidth_hz)

        def plans() -> list:
            return json.loads(subprocess.run([sys.executable, "-c", FRESH_PLAN, str(path), "5"], cwd=ROOT, check=True,
                                             capture_output=True, text=True).stdout)

        plans()  # numba's cache holds the plan's kernels from here on (a first run ever compiles them)
        runs = [plans() for _ in range(max(1, processes))]
    first, later = np.array([run[0] for run in runs]), np.array([row for run in runs for row in run[1:]])
    return {"processes": len(runs), "plans": runs, "first_plan_s": float(np.median(first[:, 0])),
            "first_plan_cpu_s": float(np.median(first[:, 1])), "first_plan_faults": int(np.median(first[:, 2])),
            "plan_s": float(np.median(later[:, 0])), "plan_cpu_s": float(np.median(later[:, 1])),
            "first_plan_system_s": float(np.median(first[:, 3])), "plan_faults": int(np.median(later[:, 2])),
            "plan_system_s": float(np.median(later[:, 3]))}


def plan_study(rounds: int) -> dict:
    """The longest aperture's plan against the node-at-a-time builder it replaced, CPU and wall time
    alternated in each round, and FFBP with its plan against the direct kernel in each round (2 threads)."""
    from reference_ffbp_plan import plan_factorized_reference

    n_frames = int(round(2.0 / (SPEED_MPS * 0.052)))
    samples, wf, tx, rx, _ = make_case(n_frames, 2, 2)
    prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
    del samples
    x, y = np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002)
    xx, yy = np.meshgrid(x, y)
    grid = np.stack([xx, yy, np.full_like(xx, 0.3)], axis=-1)
    args = (tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz)
    t_first = timed(lambda: plan_factorized(*args), 1)[0]  # the process's first plan: its passes loaded
    plan_before = plan_factorized_reference(*args)
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    t_direct, ref = timed(lambda: backproject(prof, tx, rx, grid), 1)
    plan = plan_factorized(*args)
    errors = {name: error_db(run_factorized(p, prof, tx, rx), ref) for name, p in (("plan", plan), ("plan_before", plan_before))}
    rows = {k: [] for k in ("direct_s", "plan_s", "plan_before_s", "plan_cpu_s", "plan_before_cpu_s", "run_s")}

    rows.update(plan_faults=[], plan_before_faults=[], plan_system_s=[], plan_before_system_s=[])
    # Why a plan may cost more here than in a fresh process: each plan's surroundings (see plan_conditions).
    conditions: dict = {k: [] for k in ("right_after_direct", "again", "after_pause", "new_thread_after_pause")}
    parts = split_plan_parts()

    def clocked(fn):
        (faults, system), t, c = thread_usage(), time.perf_counter(), time.thread_time()
        fn()
        wall, cpu, (faults_after, system_after) = time.perf_counter() - t, time.thread_time() - c, thread_usage()
        return wall, cpu, faults_after - faults, system_after - system

    def observed(on_new_thread: bool = False) -> dict:
        """A plan, with what went on around it: this thread's CPU time by part, the other threads' CPU time,
        its wait for a core, the machine's steal time, and the main heap's free chunks before it."""
        heap_chunks = free_heap_chunks()
        parts.clear()
        row: dict = {}

        def go():
            others, wait, steal = other_threads_cpu_s(), this_thread_wait_s(), machine_cpu_s()["steal"]
            row["wall_s"], row["cpu_s"], row["faults"], row["system_s"] = clocked(lambda: plan_factorized(*args))
            row["other_threads_cpu_s"] = other_threads_cpu_s() - others
            row["wait_for_core_s"] = this_thread_wait_s() - wait
            row["machine_steal_s"] = machine_cpu_s()["steal"] - steal

        if on_new_thread:
            worker = threading.Thread(target=go)
            worker.start()
            worker.join()
        else:
            go()
        row["parts_cpu_s"] = dict(parts)
        row["free_heap_chunks_before"] = heap_chunks
        return row

    for _ in range(rounds):
        rows["direct_s"].append(timed(lambda: backproject(prof, tx, rx, grid), 1)[0])
        first = observed()  # the rounds' plan, as before: right after the direct kernel
        conditions["right_after_direct"].append(first)
        for key, value in (("system_s", "system_s"), ("s", "wall_s"), ("cpu_s", "cpu_s"), ("faults", "faults")):
            rows[f"plan_{key}"].append(first[value])
        wall, cpu, faults, system = clocked(lambda: plan_factorized_reference(*args))
        rows["plan_before_system_s"].append(system)
        rows["plan_before_s"].append(wall)
        rows["plan_before_cpu_s"].append(cpu)
        rows["plan_before_faults"].append(faults)
        conditions["again"].append(observed())  # the same process state, not right after the direct kernel
        rows["run_s"].append(timed(lambda: run_factorized(plan, prof, tx, rx), 1)[0])
        time.sleep(1.0)  # workers asleep, the cores idle a while
        conditions["after_pause"].append(observed())
        time.sleep(1.0)
        conditions["new_thread_after_pause"].append(observed(on_new_thread=True))  # another thread, another heap
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    fresh = fresh_process_plans(tx, rx, x, y, prof.carrier_hz, prof.bandwidth_hz, rounds)
    r = {k: np.array(v) for k, v in rows.items()}
    out = {"aperture_m": float(np.ptp(0.5 * (tx[:, 0] + rx[:, 0]))), "profiles": int(tx.shape[0]), "pixels": int(x.size * y.size),
           "nodes": sum(1 for _ in plan.nodes()), "rounds": rows, "first_plan_in_process_s": t_first,
           "plan_s": float(r["plan_s"].min()), "plan_before_s": float(r["plan_before_s"].min()),
           "plan_over_before_wall": float(np.median(r["plan_before_s"] / r["plan_s"])),
           "plan_over_before_cpu": float(np.median(r["plan_before_cpu_s"] / r["plan_cpu_s"])),
           "plan_over_run": float(np.median(r["plan_s"] / r["run_s"])),
           "speedup_over_direct_2_threads_interleaved": float(np.median(r["direct_s"] / r["run_s"])),
           "speedup_with_plan_over_direct_2_threads_interleaved": float(np.median(r["direct_s"] / (r["plan_s"] + r["run_s"]))),
           "speedup_with_plan_before_over_direct_2_threads_interleaved": float(np.median(r["direct_s"] / (r["plan_before_s"] + r["run_s"]))),
           "plan_faults": int(np.median(r["plan_faults"])), "plan_system_s": float(np.median(r["plan_system_s"])),
           "fresh_process": fresh,
           "speedup_with_fresh_process_plan_over_direct_2_threads_interleaved":
               float(np.median(r["direct_s"] / (fresh["plan_s"] + r["run_s"]))),
           "speedup_with_fresh_process_first_plan_over_direct_2_threads_interleaved":
               float(np.median(r["direct_s"] / (fresh["first_plan_s"] + r["run_s"]))),
           "error_db": errors["plan"], "error_db_plan_before": errors["plan_before"],
           "plan_conditions": conditions,
           "plan_cpu_s_by_condition": {name: float(np.median([c["cpu_s"] for c in rows_])) for name, rows_ in conditions.items()}}
    print(f"2 m: plan {out['plan_s']:.3f} s (first in the process {t_first:.3f} s) against {out['plan_before_s']:.3f} s before "
          f"({out['plan_over_before_wall']:.1f}x wall, {out['plan_over_before_cpu']:.1f}x CPU), {out['plan_over_run']:.2f} of the run; "
          f"FFBP {out['speedup_over_direct_2_threads_interleaved']:.1f}x the direct kernel, with its plan "
          f"{out['speedup_with_plan_over_direct_2_threads_interleaved']:.1f}x (with the plan before "
          f"{out['speedup_with_plan_before_over_direct_2_threads_interleaved']:.1f}x); error {errors['plan']:.2f} dB "
          f"({errors['plan_before']:.2f} dB with the plan before); {out['plan_faults']} page faults and "
          f"{out['plan_system_s']:.3f} s of system time a plan in the rounds; "
          f"in a fresh process the first plan {fresh['first_plan_s']:.3f} s ({fresh['first_plan_faults']} faults), then "
          f"{fresh['plan_s']:.3f} s ({fresh['plan_faults']} faults): FFBP {out['speedup_with_fresh_process_plan_over_direct_2_threads_interleaved']:.1f}x "
          f"the direct kernel with such a plan, {out['speedup_with_fresh_process_first_plan_over_direct_2_threads_interleaved']:.1f}x "
          f"with the first", flush=True)
    print("  a plan's CPU time (median of the rounds): " + ", ".join(
        f"{name.replace('_', ' ')} {v:.3f} s" for name, v in out["plan_cpu_s_by_condition"].items())
        + f"; in a fresh process {fresh['plan_cpu_s']:.3f} s", flush=True)
    return out


def label(row: dict) -> str:
    """The settings that differ from the default's, briefly."""
    default = FactorizedOptions()
    names = {"leaf_profiles": "leaf", "taps": "taps", "oversample_range": "os_r", "oversample_angle": "os_a",
             "leaf_oversample": "leaf os", "leaf_taps": "leaf taps"}
    if row["leaf_oversample"] is None and row["leaf_taps"] is None:
        return "leaves as merged grids (before)"
    parts = [f"{short} {row[f]}" for f, short in names.items() if row[f] != getattr(default, f)]
    return ", ".join(parts) or "default"


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax3, ax2) = plt.subplots(1, 3, figsize=(16, 4.8))
    main = result["cases"][-1]
    for row in main.get("frontier", []):
        speed = row["cpu_speed_over_default"]
        ax1.plot(row["error_db"], speed, "o", color="C3" if label(row) == "default" else "C0")
        ax1.plot(row["error_estimate_db"], speed, "x", color="C1")
        ax1.annotate(label(row), (row["error_db"], speed), textcoords="offset points", xytext=(4, 3), fontsize=6.5)
    ax1.axvline(-40, color="0.6", ls="--", lw=0.8)
    ax1.axvline(-41, color="0.8", ls=":", lw=0.8)
    ax1.plot([], [], "o", color="C0", label="measured error")
    ax1.plot([], [], "x", color="C1", label="plan's estimate (flat spectrum)")
    ax1.set(xlabel="error against the direct kernel, dB", ylabel="speed over the default's (CPU time, 1 thread)",
            title=f"settings, {main['aperture_m']:.1f} m aperture, {main['pixels'] / 1e3:.0f} k pixels")
    ax1.legend(fontsize=7)
    names = [f"{r['aperture_m']:g} m at {r['range_m']:g} m" for r in result["reach"]]
    ax3.plot(names, [r["error_db"] for r in result["reach"]], "o", label="measured")
    ax3.plot(names, [r["error_estimate_db"] for r in result["reach"]], "x", label="plan's estimate")
    ax3.axhline(-40, color="0.6", ls="--", lw=0.8)
    ax3.set(ylabel="error, dB", title="default settings: aperture at scene range")
    ax3.legend(fontsize=7)
    ap = [case["aperture_m"] for case in result["cases"]]
    sp = [case["ffbp"][0]["speedup"] for case in result["cases"]]
    ax2.plot(ap, sp, "o-")
    ax2.set(xlabel="aperture, m", ylabel="speed-up with its plan (default settings)", title="speed-up against aperture length")
    ax2.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="a smaller case (for a smoke run)")
    mode.add_argument("--plan", action="store_true", help="only the 2 m aperture's plan and run (docs/results/ffbp_plan.json)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of --plan (default 3)")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    if args.plan:
        uptime_before = load_text()
        backproject(*[range_compress(np.ones((4, 175), complex), 76e9, 22.75e6, oversample=8, guarded=True)],
                    np.zeros((4, 3)), np.zeros((4, 3)), np.ones((2, 2, 3)))  # compile the direct kernel outside the timing
        study = plan_study(args.rounds)
        result = {"machine": machine(uptime_before), "case": {"speed_mps": SPEED_MPS, "range_m": 2.0, "pixel_m": 0.002,
                                                              "profile_oversample": 8, "direct_mode": "linear"},
                  "default": settings(FactorizedOptions()), "plan": study}
        print(f"wrote {write_results('ffbp_plan', result, started_load=started_load)}")
        return 0
    frame_m = SPEED_MPS * 0.052
    if args.quick:
        apertures, x, y, repeats = [0.5], np.arange(-0.3, 0.3, 0.004), np.arange(1.8, 2.2, 0.004), 1
    else:
        apertures, x, y, repeats = [0.5, 1.0, 2.0], np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002), 2
    uptime_before = load_text()
    default = FactorizedOptions()
    backproject(*[range_compress(np.ones((4, 175), complex), 76e9, 22.75e6, oversample=8, guarded=True)],
                np.zeros((4, 3)), np.zeros((4, 3)), np.ones((2, 2, 3)))  # compile the direct kernel outside the timing
    cases = []
    for aperture in apertures:
        configs = [default]
        cases.append(run_case(int(round(aperture / frame_m)), x, y, configs, repeats, study_threads=aperture == apertures[-1]))
    result = {"machine": machine(uptime_before),
              "case": {"speed_mps": SPEED_MPS, "range_m": 2.0, "pixel_m": float(x[1] - x[0]), "image_m": [float(np.ptp(x)), float(np.ptp(y))],
                       "profile_oversample": 8, "direct_mode": "linear", "quick": args.quick},
              "cases": cases, "default": settings(default), "reach": reach(args.quick)}
    name = "ffbp_quick" if args.quick else "ffbp"
    write_results(name, result, started_load=started_load)
    chart(result, RESULTS / f"{name}.png")
    print(f"wrote {RESULTS / (name + '.json')} and {name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
