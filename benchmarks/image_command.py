"""`sarbot image` as a whole command against its backprojection kernel alone: on the backprojection
benchmark's case (16 frames of the left-front radar, all 16 channels, a 256 x 256 grid) and on a larger
one (32 frames, a 512 x 512 grid: 8 times the work, 0.67 m of track imaged at 2 mm).

The command is timed as a new process (``python -m acquisition.cli image ...``: its imports, numba's cache
load and all), as a user runs it: with sarbot's modules byte-compiled, as they are after an install (this
environment's PYTHONDONTWRITEBYTECODE is left out of the command's, else every run compiles sarbot's
sources again); the kernel in this process, on the same profiles, alternating with it.

The command imports numba and its kernels, and loads the direct kernel from numba's cache, on a thread of
its own while it opens the recording and reads and range-compresses blocks ahead (imaging.kernel_import),
range-compresses the next block while the kernel backprojects this one (into the buffer of a block already
backprojected: imaging.image_formation.RowBuffers), places the antennas, backprojects, writes the image and its PNG (the pixels; ``--png-figure``'s
matplotlib figure is timed apart). ``form_image`` is the same without the files. Its throughput (grid
points x profiles per second of wall time) is printed as a fraction of the kernel's on the same profiles
in the same process, with the time of each stage, and what the process start costs, step by step, in a
new process of its own (``fixed_costs``: with the cyclic garbage collector paused during the start-up, as
the command runs it, and running, alternating), and scipy's range FFT against numpy's (``range_fft``).
``baseline_comparison`` is the command against its kernel at issue 34's commit and now, alternating, on the
cases the issue's figure could have come from (benchmarks/command_versions.py, which also runs alone).

``command_stages_s`` is the command's own account of where its wall time goes (``sarbot -v image``'s
"stage seconds" line, in runs of their own after the timed ones), and ``batch_of_benchmark_case_images``
the same question per image of a batch: 8 benchmark-case images formed one after another in one new
process, as a resident ``sarbot batch`` worker forms them (acquisition.batch.run_job), against the kernel.

The figure is the fraction per interleaved round (the command as a new process, then at once the kernel in
this process with numba's threads as many as the command's and the same threading layer: command, kernel,
command, kernel ...; ``command_fraction_of_kernel``: the median over rounds, ``..._per_round``: median, min,
max, ``rounds``: both seconds of every round, wall and CPU). ``command_fraction_of_kernel_best_times`` is the
earlier figure, the best command over the best kernel, timed at different moments of a VM whose speed moves.

    python benchmarks/image_command.py [--quick] [--baseline COMMIT | --no-baseline] [--cases NAME,...] [--rounds N]

Writes docs/results/image_command.json; with ``--cases`` only those cases, each into its own key of the
file (the other keys kept as they were), and nothing else (no batch, start-up steps or baseline).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from backprojection import best_time  # noqa: E402

from imaging.backprojection import backproject  # noqa: E402
from imaging.core.grid import Grid  # noqa: E402
from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import StraightLine  # noqa: E402
from imaging.image_formation import ImagingOptions, form_image, frame_profiles  # noqa: E402
from imaging.io.image_file import write_image  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import DEFAULT_START_TIME_NS, Scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.sim.targets import PointTarget  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402
from command_versions import BASELINE, CASES, QUICK_CASES, chosen_cases, compare, timed_process, uptime  # noqa: E402

#: The command's environment: this one without PYTHONDONTWRITEBYTECODE (see the module's docstring).
COMMAND_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}

#: What the start of ``sarbot image`` costs, step by step, in a new process, in the command's order: each
#: import on top of the ones before it; sarbot's own modules (scipy's FFT without scipy.fft's import:
#: imaging/pocketfft.py; numba's cache loads set to start numba's runtime alone, without its typing and
#: lowering registries and scipy.linalg: imaging.numba_target.load_cached_kernels_lightly); then a first
#: image of one frame on four pixels (the runtime's start, the kernel's load from numba's cache, its
#: threads' start), then the same image again (what it costs once all that is done). With argv[2] "paused" the start-up runs as the command runs
#: it (the cyclic garbage collector paused, then frozen: acquisition/cli/start_up.py); with "running" the
#: collector runs as usual. The last line also gives the collections' count and time (gc.callbacks).
FIXED_COSTS = r"""
import gc, json, sys, time
t = [time.perf_counter()]
steps, collections, began = [], {"full": 0, "all": 0, "seconds": 0.0}, [0.0]
def on_gc(phase, info):
    if phase == "start":
        began[0] = time.perf_counter()
        return
    collections["seconds"] += time.perf_counter() - began[0]
    collections["all"] += 1
    collections["full"] += info["generation"] == 2
gc.callbacks.append(on_gc)
def step(name):
    t.append(time.perf_counter()); steps.append((name, t[-1] - t[-2]))
from acquisition.cli.start_up import collector_paused
import contextlib
with collector_paused() if sys.argv[2] == "paused" else contextlib.nullcontext():
    import numpy; step("numpy")
    import h5py; step("h5py")
    import numba; step("numba")
    import acquisition.cli.imaging
    from imaging.image_formation import ImagingOptions, image_recording
    from imaging.io.recording import Recording
    from imaging.plot import save_image_pixels_png
    from imaging.io.image_file import write_image
    from imaging.numba_target import load_cached_kernels_lightly
    load_cached_kernels_lightly(); step("sarbot's modules")
def one():
    with Recording(sys.argv[1]) as rec:
        return image_recording(rec, "left_front", "0:0.002:0.002,2:2.002:0.002", "truth", slice(0, 1), ImagingOptions())
one(); step("first image of one frame (numba's runtime, the kernel from its cache, its threads)")
one(); step("the same image again")
gc.collect(); step("a full collection at the end (as at exit)")
print(json.dumps({"steps": steps, "collections": collections}))
"""

#: The range FFT: scipy's (what range compression uses) against numpy's on the benchmark case's rows
#: (1,024 profiles of one frame, 16x zero-padding), complex64 both: same numbers? time of each, best of 5.
RANGE_FFT = r"""
import json, sys, time
import numpy as np, scipy.fft
from imaging.core.rig import default_rig
wf = default_rig().radar("left_front").waveform
n, n_fft = wf.samples_per_chirp, 16 * wf.samples_per_chirp
rows = np.zeros((1024, n_fft), np.complex64)
rng = np.random.default_rng(0)
rows[:, :n] = rng.standard_normal((1024, n)) + 1j * rng.standard_normal((1024, n))
def best(f):
    times = []
    for _ in range(5):
        x = rows.copy(); t = time.process_time(); f(x); times.append(time.process_time() - t)
    return min(times)
a, b = scipy.fft.fft(rows.copy(), axis=-1, overwrite_x=True), np.fft.fft(rows, axis=-1)
print(json.dumps({"samples": n, "n_fft": n_fft, "rows": 1024, "numpy_dtype": str(b.dtype), "bit_identical": bool(np.array_equal(a, b)),
                  "largest_difference_of_peak": float(np.abs(a - b).max() / np.abs(a).max()),
                  "scipy_cpu_s": best(lambda x: scipy.fft.fft(x, axis=-1, overwrite_x=True)),
                  "numpy_cpu_s": best(lambda x: np.fft.fft(x, axis=-1, out=x))}))
"""

RESULTS = ROOT / "docs" / "results"
#: Images of the benchmark case formed in one process (``batch_per_image``).
BATCH_IMAGES = 8


def make_recording(path: Path, n_frames: int) -> None:
    rig = default_rig()
    wf = rig.radar("left_front").waveform
    duration = n_frames * wf.frame_interval_s
    traj = StraightLine(start_m=(-0.15 - 0.4 * duration / 2, -0.2, 0.0), speed_mps=0.4, t0_ns=DEFAULT_START_TIME_NS)
    targets = [PointTarget((dx, 2.0 + dy, 0.3)) for dx, dy in [(0, 0), (-0.2, 0.1), (0.25, -0.2), (0.1, 0.3), (-0.3, -0.3)]]
    scene = Scene(name="bench", rig=rig, trajectory=traj, targets=targets, duration_s=duration - 1e-3,
                  radars=["left_front"], snr_db=0.0, seed=0, adc_counts_per_unit=2000.0)  # int16, as a radar sends
    simulate_recording(scene, path)


def import_times(cmd: list) -> dict:
    """What the command's imports cost (``python -X importtime``): the total of the top-level imports and
    the largest of them, seconds (cumulative, each with what it imports)."""
    err = subprocess.run(cmd, check=True, cwd=ROOT, env=COMMAND_ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True).stderr
    top = {}
    for line in err.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cumulative, name = line[len("import time:"):].split("|")
        if not name.startswith("  "):  # top level: one space after the bar, nested ones indented further
            top[name.strip()] = top.get(name.strip(), 0.0) + int(cumulative) * 1e-6
    largest = dict(sorted(top.items(), key=lambda kv: -kv[1])[:10])
    return {"total_s": sum(top.values()), "largest_s": largest}


def fixed_costs(rec_path: Path, rounds: int = 3) -> dict:
    """``FIXED_COSTS`` in new processes, the collector paused (as the command) and running, alternating, after
    one run that warms the page cache: seconds per step (the median over rounds), the start-up's total, and
    the garbage collections' count and time."""
    runs = {"paused": [], "running": []}
    for i in range(rounds + 1):
        for gc_mode, found in runs.items():
            out = subprocess.run([sys.executable, "-c", FIXED_COSTS, str(rec_path), gc_mode], check=True, cwd=ROOT,
                                 env=COMMAND_ENV, capture_output=True, text=True).stdout
            if i:
                found.append(json.loads(out.splitlines()[-1]))
    result = {}
    for gc_mode, found in runs.items():
        names = [name for name, _ in found[0]["steps"]]
        steps = {name: statistics.median(dict(r["steps"])[name] for r in found) for name in names}
        result[f"collector_{gc_mode}"] = {
            "steps_s": steps, "total_s": statistics.median(sum(dict(r["steps"]).values()) for r in found),
            "collections": {key: statistics.median(r["collections"][key] for r in found)
                            for key in ("all", "full", "seconds")}}
    return result


def range_fft() -> dict:
    """``RANGE_FFT`` in a new process: scipy's FFT against numpy's on the range rows."""
    out = subprocess.run([sys.executable, "-c", RANGE_FFT], check=True, cwd=ROOT, env=COMMAND_ENV, capture_output=True,
                         text=True).stdout
    return json.loads(out.splitlines()[-1])


#: What the command's numba runs its kernels with: its threading layer and thread count, read in a new
#: process with the command's environment (the benchmark's kernel must run with the same).
NUMBA_THREADS = r"""
import json, numba
import numpy as np
@numba.njit(parallel=True)
def touch(a):
    for i in numba.prange(a.size):
        a[i] += 1
touch(np.zeros(4))
print(json.dumps({"threading_layer": numba.threading_layer(), "threads": numba.get_num_threads()}))
"""


def numba_threads_of_the_command() -> dict:
    """``NUMBA_THREADS`` in a new process with the command's environment."""
    out = subprocess.run([sys.executable, "-c", NUMBA_THREADS], check=True, cwd=ROOT, env=COMMAND_ENV,
                         capture_output=True, text=True).stdout
    return json.loads(out.splitlines()[-1])


def kernel_threads_here() -> dict:
    """The threading layer and thread count the kernel runs with in this process (after its first call)."""
    import numba

    return {"threading_layer": numba.threading_layer(), "threads": numba.get_num_threads()}


def measure_case(tmp: Path, name: str, n_frames: int, n_px: int, repeats: int, rounds_n: int) -> dict:
    """The kernel, form_image, the files (best of ``repeats`` each) and the command as a new process
    alternating with the kernel in ``rounds_n`` rounds."""
    grid_text = f"-0.5:0.5:{1.0 / n_px},1.5:2.5:{1.0 / n_px},0.3"
    rec_path = tmp / f"{name}.h5"
    make_recording(rec_path, n_frames)
    grid = Grid.parse(grid_text, default_z_m=0.3)
    points = grid.points()
    options = ImagingOptions()
    with Recording(rec_path) as rec:
        radar = rec.radar("left_front")
        truth = rec.truth()
        n = rec.n_frames("left_front")

        def compress():
            return frame_profiles(rec.adc("left_front"), rec.frame_time_ns("left_front"), radar, truth,
                                  rec.tdm_tx_order("left_front"), options)

        profiles, tx_m, rx_m, _, _ = compress()
        n_p = profiles.data.shape[0]
        backproject(profiles, tx_m, rx_m, points[:2, :2])  # compile
        threads = {"command": numba_threads_of_the_command(), "kernel": kernel_threads_here()}
        if threads["command"] != threads["kernel"]:
            raise SystemExit(f"the kernel would run with other threads than the command's: {threads}")
        t_kernel = best_time(lambda: backproject(profiles, tx_m, rx_m, points), repeats)
        t_compress = best_time(compress, repeats)
        image = backproject(profiles, tx_m, rx_m, points)
        # The library call behind the command: read, range-compress (overlapped), backproject.
        t_form = best_time(lambda: form_image(rec, "left_front", grid, truth, options=options), repeats)

    from imaging.io.image_file import SarImage
    from imaging.plot import ImagePicture, save_image_pixels_png

    img = SarImage(image, grid.x_m, grid.y_m, grid.z_m, {"wavelength_m": 0.0039})
    t_write = best_time(lambda: write_image(tmp / "w.h5", img), repeats)
    t_png = best_time(lambda: save_image_pixels_png(tmp / "w.png", image, grid.x_m, grid.y_m, title="bench"), repeats)
    # --png-figure: laying its figure out (axes, ticks, colour bar: all from the grid), then drawing the pixels.
    t_figure_layout = best_time(lambda: ImagePicture(grid.x_m, grid.y_m), repeats)
    picture = ImagePicture(grid.x_m, grid.y_m)
    t_figure = best_time(lambda: picture.save(tmp / "f.png", image, title="bench"), repeats)
    out = tmp / f"{name}_img.h5"
    command_line = [sys.executable, "-m", "acquisition.cli", "-q", "image", str(rec_path), "-o", str(out),
                    "--grid", grid_text, "--overwrite"]

    def command() -> tuple[float, float]:
        wall, cpu, _ = timed_process(command_line, ROOT, COMMAND_ENV)
        return wall, cpu

    command()  # warm: the kernels compiled into numba's cache, sarbot's byte code written, files in the page cache
    # Alternating: the whole command as a new process, then the kernel alone here; ratio per round, in wall
    # time and in CPU time (the command's process and its threads; the kernel's threads), which others' load
    # moves less.
    rounds, cpu_rounds = [], []
    for _ in range(rounds_n):
        t_cmd, cpu_cmd = command()
        t, c = time.perf_counter(), time.process_time()
        backproject(profiles, tx_m, rx_m, points)
        rounds.append((t_cmd, time.perf_counter() - t))
        cpu_rounds.append((cpu_cmd, time.process_time() - c))
    stages = command_stages(command_line, max(2, repeats // 2))
    t_command = min(r[0] for r in rounds)
    fractions = [k / c for c, k in rounds]
    cpu_fractions = [k / c for c, k in cpu_rounds]
    work = n_p * points.reshape(-1, 3).shape[0]
    result = {
        "case": {"frames": n, "profiles": n_p, "grid_points": int(points.size // 3), "grid": grid_text},
        "numba_threads": threads,
        "kernel_backprojections_per_s": work / t_kernel,
        "command_backprojections_per_s": work / t_command,
        "command_fraction_of_kernel": statistics.median(fractions),
        "command_fraction_of_kernel_best_times": t_kernel / t_command,
        "rounds": [{"command_s": c, "kernel_s": k, "fraction": k / c, "command_cpu_s": cc, "kernel_cpu_s": kc,
                    "cpu_fraction": kc / cc} for (c, k), (cc, kc) in zip(rounds, cpu_rounds)],
        "command_fraction_of_kernel_per_round": {"median": statistics.median(fractions), "min": min(fractions),
                                                 "max": max(fractions)},
        "command_fraction_of_kernel_cpu_time_per_round": {"median": statistics.median(cpu_fractions),
                                                          "min": min(cpu_fractions), "max": max(cpu_fractions)},
        "command_and_kernel_cpu_s_per_round": cpu_rounds,
        "form_image_fraction_of_kernel": t_kernel / t_form,
        "seconds": {"command": t_command, "form_image": t_form, "kernel": t_kernel, "read_and_range_compress": t_compress,
                    "write_image": t_write, "png": t_png,
                    "command_minus_form_image_write_png": t_command - t_form - t_write - t_png,
                    "png_figure_layout": t_figure_layout, "png_figure_draw": t_figure},
        "command_stages_s": stages,
    }
    sec = result["seconds"]
    print(f"{name}: sarbot image {100 * statistics.median(fractions):.1f} % of the kernel per round (median of "
          f"{len(fractions)}; min {100 * min(fractions):.1f} %, max {100 * max(fractions):.1f} %; CPU time "
          f"{100 * statistics.median(cpu_fractions):.1f} %); rounds (command s, kernel s): "
          + ", ".join(f"({c:.2f}, {k:.2f})" for c, k in rounds)
          + f"; kernel {work / t_kernel / 1e9:.3f} G/s, form_image {100 * t_kernel / t_form:.0f} %, best over best "
          f"{100 * t_kernel / t_command:.0f} %;"
          " seconds: " + ", ".join(f"{k} {v:.3f}" for k, v in sec.items()), flush=True)
    print(f"{name}: the command's stages (median of {stages['runs']} runs with -v): "
          + ", ".join(f"{k} {v:.3f}" for k, v in stages["median_s"].items()), flush=True)
    return result


def command_stages(command_line: list, runs: int) -> dict:
    """The command's own account of its wall time (``sarbot -v image``'s "stage seconds" line, read from its
    stderr: imaging.core.stage_clock), in runs of their own after the timed rounds, with what it cannot see:
    the interpreter's start before sarbot's command line is imported and the process's end after the line
    (``outside_command``: the process's wall time minus the line's ``command``). Median of each over the runs."""
    verbose = [command_line[0], "-m", "acquisition.cli", "-v", *command_line[4:]]  # -v in place of -q
    found = []
    for _ in range(runs):
        t = time.perf_counter()
        err = subprocess.run(verbose, check=True, cwd=ROOT, env=COMMAND_ENV, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True).stderr
        wall = time.perf_counter() - t
        line = next(x for x in err.splitlines() if "stage seconds: " in x)
        seconds = json.loads(line.split("stage seconds: ", 1)[1])
        found.append({**seconds, "outside_command": wall - seconds["command"], "process": wall})
    names = list(found[0])
    return {"runs": runs, "median_s": {k: statistics.median(f.get(k, 0.0) for f in found) for k in names},
            "note": "the main thread's stages add up to 'command' (before_command, start_up, open_recording, image_recording, "
                    "write_image, write_png); form_image's (open_frames, wait_for_block, kernel_import_wait, "
                    "backproject, antenna_summary, free_block, attributes) add up to image_recording less its grid "
                    "and trajectory set-up; compress_thread.* run on the other thread, beside them"}


#: A batch in one process, as a resident worker (a Dask worker of ``sarbot batch``) forms it:
#: acquisition.batch.run_job, as many times as asked (argv[3]), on the recording argv[1] and grid argv[2]; each
#: job's seconds as run_job counts them, the process's wall time from outside.
BATCH = r"""
import json, sys, time
t = time.perf_counter()
from acquisition.batch import ImageJob, run_job
seconds = []
for i in range(int(sys.argv[3])):
    r = run_job(ImageJob(sys.argv[1], "left_front", sys.argv[2], f"{sys.argv[4]}_{i}.h5"))
    assert r["error"] is None, r["error"]
    seconds.append(r["seconds"])
print(json.dumps({"job_seconds": seconds, "in_process_s": time.perf_counter() - t}))
"""


def batch_per_image(tmp: Path, n_frames: int, n_px: int, n_images: int, rounds: int) -> dict:
    """``n_images`` images of the case in one new process (``BATCH``: as ``sarbot batch``'s workers form them,
    without the PNG), alternating with the kernel alone in this process on the same profiles: each image's
    fraction of the kernel, the first (the process's start in it) and the later ones, and the whole process's
    wall time per image."""
    grid_text = f"-0.5:0.5:{1.0 / n_px},1.5:2.5:{1.0 / n_px},0.3"
    rec_path = tmp / "batch.h5"
    make_recording(rec_path, n_frames)
    grid = Grid.parse(grid_text, default_z_m=0.3)
    points = grid.points()
    with Recording(rec_path) as rec:
        profiles, tx_m, rx_m, _, _ = frame_profiles(rec.adc("left_front"), rec.frame_time_ns("left_front"),
                                                    rec.radar("left_front"), rec.truth(),
                                                    rec.tdm_tx_order("left_front"), ImagingOptions())
    backproject(profiles, tx_m, rx_m, points[:2, :2])  # compiled or loaded
    runs, kernels = [], []
    for i in range(rounds + 1):  # the first warms numba's cache and the page cache
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", BATCH, str(rec_path), grid_text, str(n_images), str(tmp / "batch")],
                             check=True, cwd=ROOT, env=COMMAND_ENV, capture_output=True, text=True).stdout
        wall = time.perf_counter() - t
        t = time.perf_counter()
        backproject(profiles, tx_m, rx_m, points)
        if i:
            runs.append({**json.loads(out.splitlines()[-1]), "process_s": wall})
            kernels.append(time.perf_counter() - t)
    fractions = [{"first": k / r["job_seconds"][0], "later_median": k / statistics.median(r["job_seconds"][1:]),
                  "process_per_image": k * n_images / r["process_s"]} for r, k in zip(runs, kernels)]
    result = {"case": {"frames": n_frames, "grid": grid_text, "images": n_images, "png": False},
              "rounds": [{**r, "kernel_s": k, "fraction_of_kernel": f} for r, k, f in zip(runs, kernels, fractions)],
              "fraction_of_kernel_median": {key: statistics.median(f[key] for f in fractions) for key in fractions[0]}}
    med = result["fraction_of_kernel_median"]
    print(f"batch of {n_images} in one process: an image after the first {100 * med['later_median']:.0f} % of the "
          f"kernel, the first {100 * med['first']:.0f} %, the whole process {100 * med['process_per_image']:.0f} % "
          "per image", flush=True)
    return result


def only_cases(cases: dict, quick: bool) -> int:
    """``--cases``: measure these cases alone and write each into its key of the JSON, the rest kept."""
    started_load = load_average()
    probe_machine()
    name = "image_command_quick" if quick else "image_command"
    with tempfile.TemporaryDirectory() as tmp:
        for case, spec in cases.items():
            load_before, uptime_before = os.getloadavg(), uptime()
            result = {**measure_case(Path(tmp), case, *spec), "load_average": {"before": load_before,
                                                                             "after": os.getloadavg()},
                      "uptime": {"before": uptime_before, "after": uptime()}}
            write_results(name, result, started_load=started_load, part=case)
            print(f"wrote {case} into {RESULTS / (name + '.json')}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--baseline", default=BASELINE, help=f"the earlier commit to compare with (default {BASELINE}, "
                    "issue 34's; see benchmarks/command_versions.py)")
    ap.add_argument("--no-baseline", action="store_true",
                    help="keep the JSON's baseline_comparison as it is (command_versions.py measures it alone)")
    ap.add_argument("--cases", help="only these cases, comma-separated (of benchmark_case, larger_case), each "
                    "written into its own key of the JSON; nothing else is measured")
    ap.add_argument("--rounds", type=int, help="interleaved rounds of command and kernel per case (default: 5 for "
                    "the benchmark case, 4 for the larger one; 1 with --quick)")
    args = ap.parse_args()
    # name -> (frames, pixels a side, best-of repeats for the kernel, form_image and the files, rounds)
    cases = {"benchmark_case": (4, 128, 1, 1), "larger_case": (8, 256, 1, 1)} if args.quick else \
        {"benchmark_case": (16, 256, 5, 5), "larger_case": (32, 512, 2, 4)}
    if args.rounds is not None:
        if args.rounds < 1:
            ap.error(f"--rounds must be at least 1, got {args.rounds}")
        cases = {name: (*case[:3], args.rounds) for name, case in cases.items()}
    if args.cases is not None:
        return only_cases(chosen_cases(ap, args.cases, cases), args.quick)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    load_before, uptime_before = os.getloadavg(), uptime()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        results = {name: measure_case(tmp, name, *case) for name, case in cases.items()}
        bench_frames, bench_px = cases["benchmark_case"][:2]
        batch = batch_per_image(tmp, bench_frames, bench_px, BATCH_IMAGES, 1 if args.quick else 3)
        bench = tmp / "benchmark_case.h5"
        imports = import_times([sys.executable, "-X", "importtime", "-m", "acquisition.cli", "-q", "image", str(bench),
                                "-o", str(tmp / "imp.h5"), "--grid", results["benchmark_case"]["case"]["grid"]])
        start = fixed_costs(bench)
        fft = range_fft()
        baseline = None if args.no_baseline else \
            compare(args.baseline, QUICK_CASES if args.quick else CASES, 1 if args.quick else 3, tmp)
    for gc_mode, found in start.items():
        print(f"process start, {gc_mode}: " + ", ".join(f"{k} {v:.3f}" for k, v in found["steps_s"].items())
              + f"; total {found['total_s']:.3f} s, collections {found['collections']}")
    print(f"range FFT: {fft}")
    result = {
        **results,
        "quick": args.quick,
        "command_is": "a new process: python -m acquisition.cli image (sarbot's byte code cached, as after an install)",
        "load_average": {"before": load_before, "after": os.getloadavg()},
        "uptime": {"before": uptime_before, "after": uptime()},
        "command_imports": imports,
        "process_start": start,
        "range_fft": fft,
        "batch_of_benchmark_case_images": batch,
        "baseline_comparison": baseline,
    }
    name = "image_command_quick" if args.quick else "image_command"
    if baseline is None:  # kept as command_versions.py last measured it
        previous = json.loads((RESULTS / f"{name}.json").read_text()) if (RESULTS / f"{name}.json").exists() else {}
        result["baseline_comparison"] = previous.get("baseline_comparison")
    write_results(name, result, started_load=started_load)
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
