"""How close can any new process get to the backprojection kernel? (issue 34, item 4: "the whole command at
>= 85 % of the kernel as a whole new process"). The floor under ``sarbot image``, measured.

On image_command's cases (benchmarks/command_versions.py's ``CASES``; the recordings made as
``image_command.make_recording`` makes them) and, at the benchmark case's profiles (16 frames), on grids
between 256 x 256 and 512 x 512, one round is (interleaved, ``--rounds`` of them):

- the kernel alone in this process on the same profiles (as image_command times it), wall and CPU time;
- new processes (``image_command.COMMAND_ENV``, sarbot's byte code cached) that each do strictly less than
  ``sarbot image`` and no backprojection: (a) ``python -c pass``; (b) ``python -c "import numpy"``;
  (c) ``FLOOR`` step c: numpy, h5py, sarbot's recording module, the recording opened, its truth and every
  frame the command reads, in the command's blocks (numba is not imported: the JSON records
  ``numba_imported`` per step); (d) step d: (c) and range compression as ``form_image`` does it, block by
  block (``imaging.image_formation._BlockReader`` with the grid's box: the windowed chirp-z path of
  ``imaging.range_window``, 2 FFT threads, the profile buffers handed on, ``RowBuffers``; no numba either);
  (e) step e: (d) with numba's import and the direct kernel's load from numba's cache on a thread of its
  own started where the command starts it (``imaging.kernel_import``), then the kernel on 4 pixels;
  (f) the whole command (``python -m acquisition.cli -q image``) -- (a)-(e) only on the cases with their
  own recording; the grids at the benchmark case's profiles share its (a)-(e), which do not depend on the
  grid's spacing (the same 1 x 1 m box, the same range window).

From each round: the upper bound of the command's fraction of the kernel for ANY backprojector that must do
(d) in its own process (``bound_formula`` in the JSON):

    bound = K / (K + S + max(0, R - (2 K - K_cpu)) / 2)

K, K_cpu: the kernel's wall and CPU seconds alone (two threads); S: step (d)'s wall time from its launch to
its first block's profiles (interpreter, imports, open, the first block read and compressed: nothing can be
backprojected before it); R: step (d)'s CPU seconds after that (the other blocks read and compressed), which
can run beside the kernel only on core time the kernel leaves idle (2 K - K_cpu), the rest taking both
cores' time from it (/ 2). It leaves out the output files, the process's end and numba, so a real command
cannot beat it. The break-even kernel time (``bound`` = 85 %) is K* = (0.85 / 0.15) (S + max(0, R - idle) / 2).

    python benchmarks/image_floor.py [--rounds N] [--quick]

Writes docs/results/image_floor.json and docs/results/image_floor.png.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks"), str(ROOT / "tests")]

from command_versions import CASES, QUICK_CASES, timed_process, uptime  # noqa: E402
from image_command import COMMAND_ENV, make_recording  # noqa: E402
from results_file import RESULTS, load_average, probe_machine, write_results  # noqa: E402

#: The issue's target: the whole command at this fraction of the kernel.
TARGET = 0.85

#: A floor step in a new process: argv[1] the step ("c", "d" or "e"), argv[2] the recording, argv[3] the grid,
#: argv[4] (optional) an .npz to write (d)'s profiles to (for the tests). Prints one JSON line: marks
#: [name, perf_counter, process_time] (perf_counter is CLOCK_MONOTONIC, the parent's clock too) and whether numba
#: was imported. The collector is paused, as the command's start-up pauses it.
FLOOR = r"""
import gc, json, sys, time
gc.disable()
marks = [["start", time.perf_counter(), time.process_time()]]
def mark(name):
    marks.append([name, time.perf_counter(), time.process_time()])
step, path, grid_text = sys.argv[1], sys.argv[2], sys.argv[3]
import numpy as np; mark("numpy")
import h5py; mark("h5py")
from imaging.io.recording import Recording
if step in "de":
    from imaging.core.grid import Grid
    from imaging.image_formation import ImagingOptions, _BlockReader
    from imaging.row_buffers import RowBuffers
mark("sarbot's modules")
if step == "e":  # where `sarbot image` starts it: after its imports, before the recording is opened
    from imaging import kernel_import
    kernels = kernel_import.start_in_background()
from imaging.frame_blocks import frame_blocks
step_frames = 8  # ImagingOptions().frames_per_block
def bounds(n):  # form_image's blocks
    return list(zip(*frame_blocks(n, step_frames)))
with Recording(path) as rec:
    if step == "c":
        truth = rec.truth()
        valid = rec.valid("left_front", slice(0, rec.n_frames("left_front")))
        frames = np.flatnonzero(valid)
        mark("open")
        total = 0
        for i, (a, b) in enumerate(bounds(frames.size)):
            block = slice(int(frames[a]), int(frames[b - 1]) + 1)
            total += rec.adc("left_front", block).size + rec.frame_time_ns("left_front", block).size
            if i == 0:
                mark("first block")
        mark("all blocks")
    else:
        options = ImagingOptions()
        assert options.frames_per_block == step_frames
        grid = Grid.parse(grid_text, default_z_m=0.3)
        buffers = RowBuffers()
        reader = _BlockReader(rec, "left_front", None, slice(None), options, None, None, None, buffers)
        reader.image_box_m = (np.array([grid.x_m.min(), grid.y_m.min(), grid.z_m.min()]),
                              np.array([grid.x_m.max(), grid.y_m.max(), grid.z_m.max()]))
        mark("open")
        kept = []
        for i, (a, b) in enumerate(bounds(reader.frame_indices.size)):
            profiles, tx_m, rx_m, _, _ = reader.block(a, b - a)
            if len(sys.argv) > 4:
                kept.append((profiles.data.copy(), profiles.range_start_m, tx_m, rx_m))
            if i == 0:
                mark("first block")
            if step == "d" or b < reader.frame_indices.size:
                buffers.give(profiles.rows)  # as form_image hands a backprojected block's buffer on
        mark("all blocks")
        if step == "e":
            kernels.join(); mark("kernels ready")
            from imaging.backprojection import backproject
            out = backproject(profiles, tx_m, rx_m, grid.points()[:2, :2]); mark("4 pixels")
        if len(sys.argv) > 4:
            np.savez(sys.argv[4], **{f"{k}{i}": v[j] for i, v in enumerate(kept)
                                      for j, k in enumerate(("data", "start", "tx", "rx"))})
print(json.dumps({"marks": marks, "numba_imported": "numba" in sys.modules}))
"""

#: The steps without a recording: the interpreter with its site, and with numpy.
BARE = {"a": "pass", "b": "import numpy"}


def run_step(step: str, rec_path: Path | None = None, grid_text: str = "", dump: Path | None = None) -> dict:
    """One floor step as a new process: its wall and CPU seconds (the process and its threads, from the parent)
    and, for c-e, the child's marks as seconds since the launch (wall) and CPU seconds since its start."""
    if step in BARE:
        cmd = [sys.executable, "-c", BARE[step]]
    elif step in "cde":
        cmd = [sys.executable, "-c", FLOOR, step, str(rec_path), grid_text, *([str(dump)] if dump else [])]
    else:
        raise ValueError(f"no floor step {step!r}")
    t0 = time.perf_counter()
    wall, cpu, out = timed_process(cmd, ROOT, COMMAND_ENV, capture=True)
    result = {"wall_s": wall, "cpu_s": cpu}
    if step in "cde":
        found = json.loads(out.splitlines()[-1])
        result["marks_wall_s"] = {name: t - t0 for name, t, _ in found["marks"]}
        result["marks_cpu_s"] = {name: c for name, _, c in found["marks"]}
        result["numba_imported"] = found["numba_imported"]
    return result


def bound(kernel_s: float, kernel_cpu_s: float, d: dict) -> dict:
    """The upper bound of the fraction (the module's formula) from a round's kernel and step (d)."""
    serial = d["marks_wall_s"]["first block"]
    rest_cpu = d["marks_cpu_s"]["all blocks"] - d["marks_cpu_s"]["first block"]
    idle = max(0.0, 2 * kernel_s - kernel_cpu_s)
    overhead = serial + max(0.0, rest_cpu - idle) / 2
    # The same with both cores free for this process (the load's share of them given back): the kernel's
    # CPU time spread over both, the serial part at its CPU time, the rest taking both cores' time from the kernel.
    k2 = kernel_cpu_s / 2
    overhead2 = d["marks_cpu_s"]["first block"] + rest_cpu / 2
    return {"serial_s": serial, "rest_cpu_s": rest_cpu, "kernel_idle_core_s": idle, "overhead_s": overhead,
            "fraction": kernel_s / (kernel_s + overhead), "break_even_kernel_s": TARGET / (1 - TARGET) * overhead,
            "both_cores_free": {"kernel_s": k2, "serial_cpu_s": d["marks_cpu_s"]["first block"],
                                "overhead_s": overhead2, "fraction": k2 / (k2 + overhead2),
                                "break_even_kernel_s": TARGET / (1 - TARGET) * overhead2}}


class Case:
    """A grid over one recording's profiles: the kernel here, the command as a new process."""

    def __init__(self, rec_path: Path, grid_text: str, out: Path, warm_command: bool = True):
        from imaging.backprojection import backproject
        from imaging.core.grid import Grid
        from imaging.image_formation import ImagingOptions, frame_profiles
        from imaging.io.recording import Recording

        self.rec_path, self.grid_text, self._bp = rec_path, grid_text, backproject
        self.points = Grid.parse(grid_text, default_z_m=0.3).points()
        with Recording(rec_path) as rec:
            self.profiles = frame_profiles(rec.adc("left_front"), rec.frame_time_ns("left_front"),
                                           rec.radar("left_front"), rec.truth(), rec.tdm_tx_order("left_front"),
                                           ImagingOptions())[:3]
        self.command_line = [sys.executable, "-m", "acquisition.cli", "-q", "image", str(rec_path), "-o", str(out),
                             "--grid", grid_text, "--overwrite"]
        self.size = {"profiles": int(self.profiles[0].data.shape[0]), "grid_points": int(self.points.size // 3),
                     "grid": grid_text}
        self._bp(*self.profiles, self.points[:2, :2])  # compiled or loaded
        if warm_command:  # numba's cache, sarbot's byte code, the page cache (once per recording)
            self.command()

    def kernel(self) -> dict:
        t, c = time.perf_counter(), time.process_time()
        self._bp(*self.profiles, self.points)
        return {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}

    def command(self) -> dict:
        wall, cpu, _ = timed_process(self.command_line, ROOT, COMMAND_ENV)
        return {"wall_s": wall, "cpu_s": cpu}


def grid_of(n_px: int) -> str:
    """image_command's grid of n_px x n_px pixels over 1 x 1 m."""
    return f"-0.5:0.5:{1.0 / n_px},1.5:2.5:{1.0 / n_px},0.3"


def median_of(rounds: list, *keys) -> float:
    def get(r):
        for k in keys:
            r = r[k]
        return r
    return statistics.median(get(r) for r in rounds)


def chart(result: dict, path: Path) -> None:
    """Left: the floor steps' wall time against the kernel's (benchmark case); right: the command's fraction and
    the bound against the kernel's time, the 85 % line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    bench = result["cases"]["benchmark_case"]["median_s"]
    names = ["a", "b", "c", "d", "e", "f"]
    labels = ["(a) python", "(b) +numpy", "(c) +h5py,\nread", "(d) +range\ncompress", "(e) +numba,\nkernel load",
              "(f) sarbot\nimage"]
    ax1.bar(labels, [bench[n] for n in names], color="tab:blue")
    ax1.axhline(bench["kernel"], color="tab:red", label=f"kernel alone {bench['kernel']:.2f} s")
    ax1.axhline(bench["kernel"] / TARGET, color="tab:red", ls="--", label="85 %: kernel / 0.85")
    ax1.set_ylabel("wall time, s (median of rounds)")
    ax1.set_title("benchmark case: new processes doing less")
    ax1.tick_params(axis="x", labelsize=7)
    ax1.legend(fontsize=8)
    ks, cmd, bnd = [], [], []
    for c in result["cases"].values():
        ks.append(c["median_s"]["kernel"])
        cmd.append(c["command_fraction"]["median"])
        bnd.append(c["bound"]["fraction_median"])
    order = sorted(range(len(ks)), key=ks.__getitem__)
    ax2.plot([ks[i] for i in order], [cmd[i] for i in order], "o-", label="sarbot image (f)")
    ax2.plot([ks[i] for i in order], [bnd[i] for i in order], "s--", label="bound: any backprojector doing (d)")
    free = sorted((c["bound"]["both_cores_free_median"]["kernel_s"], c["bound"]["both_cores_free_median"]["fraction"])
                  for c in result["cases"].values())
    ax2.plot(*zip(*free), "^:", label="bound, both cores free (kernel CPU s / 2)")
    ax2.axhline(TARGET, color="tab:red", ls=":", label="85 %")
    ax2.set_xlabel("kernel alone, s")
    ax2.set_ylabel("fraction of the kernel (median of rounds)")
    ax2.set_title(f"load {result['load_average']['before'][0]:.1f}-{result['load_average']['after'][0]:.1f}")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="4 frames, small grids, 2 rounds (a smoke run, not written)")
    args = ap.parse_args()
    rounds = 2 if args.quick else args.rounds
    if args.quick:
        own = {"benchmark_case": (4, QUICK_CASES["benchmark_case"][2])}
        extra = {"benchmark_profiles_181px": ("benchmark_case", grid_of(181))}
    else:  # image_command's cases: (frames, grid); and grids at the benchmark case's profiles
        own = {name: (CASES[name][0], CASES[name][2]) for name in ("benchmark_case", "larger_case")}
        extra = {"benchmark_profiles_362px": ("benchmark_case", grid_of(362)),
                 "benchmark_profiles_443px": ("benchmark_case", grid_of(443))}
    started_load = load_average()
    probe_machine()
    load_before, uptime_before = os.getloadavg(), uptime()
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases, recs = {}, {}
        for name, (n_frames, grid_text) in own.items():
            recs[name] = tmp / f"{name}.h5"
            make_recording(recs[name], n_frames)
            cases[name] = Case(recs[name], grid_text, tmp / f"{name}_img.h5")
        for name, (rec_name, grid_text) in extra.items():
            cases[name] = Case(recs[rec_name], grid_text, tmp / f"{name}_img.h5", warm_command=False)
        for name in own:  # warm the page cache and byte code for the steps
            for step in "abcde":
                run_step(step, recs[name], cases[name].grid_text)
        found = {name: [] for name in cases}
        for r in range(rounds):
            for name, case in cases.items():
                entry = {}
                if name in own:
                    for step in "abcde":
                        entry[step] = run_step(step, recs[name], case.grid_text)
                entry["f"] = case.command()
                entry["kernel"] = case.kernel()
                found[name].append(entry)
            print(f"round {r + 1}/{rounds} done at {time.perf_counter() - t_start:.0f} s, load {os.getloadavg()[0]:.1f}",
                  flush=True)
    result_cases = {}
    for name, rs in found.items():
        steps_from = found[extra[name][0]] if name in extra else rs
        per_round = []
        for entry, steps in zip(rs, steps_from):
            k = entry["kernel"]
            per_round.append({"kernel": k, "command": entry["f"], "command_fraction": k["wall_s"] / entry["f"]["wall_s"],
                              "command_fraction_cpu": k["cpu_s"] / entry["f"]["cpu_s"],
                              "bound": bound(k["wall_s"], k["cpu_s"], steps["d"])})
        fr = [p["command_fraction"] for p in per_round]
        bf = [p["bound"]["fraction"] for p in per_round]
        med = {"kernel": median_of(rs, "kernel", "wall_s"), "kernel_cpu": median_of(rs, "kernel", "cpu_s"),
               "f": median_of(rs, "f", "wall_s"), "f_cpu": median_of(rs, "f", "cpu_s")}
        entry = {**cases[name].size, "frames": own[name][0] if name in own else own[extra[name][0]][0],
                 "floor_steps_from": extra[name][0] if name in extra else name,
                 "median_s": med,
                 "command_fraction": {"median": statistics.median(fr), "min": min(fr), "max": max(fr)},
                 "command_fraction_cpu_median": statistics.median(p["command_fraction_cpu"] for p in per_round),
                 "bound": {"fraction_median": statistics.median(bf), "min": min(bf), "max": max(bf),
                           **{key: statistics.median(p["bound"][key] for p in per_round)
                              for key in ("serial_s", "rest_cpu_s", "kernel_idle_core_s", "overhead_s",
                                          "break_even_kernel_s")},
                           "both_cores_free_median": {key: statistics.median(p["bound"]["both_cores_free"][key]
                                                                             for p in per_round)
                                                      for key in per_round[0]["bound"]["both_cores_free"]}},
                 "rounds": per_round}
        if name in own:
            for step in "abcde":
                med[step] = median_of(rs, step, "wall_s")
                med[step + "_cpu"] = median_of(rs, step, "cpu_s")
            entry["steps"] = {step: {"marks_wall_s_median": {m: statistics.median(e[step]["marks_wall_s"][m] for e in rs)
                                                             for m in rs[0][step]["marks_wall_s"]},
                                     "marks_cpu_s_median": {m: statistics.median(e[step]["marks_cpu_s"][m] for e in rs)
                                                            for m in rs[0][step]["marks_cpu_s"]},
                                     "numba_imported": rs[0][step]["numba_imported"]} for step in "cde"}
            entry["steps_raw"] = [{s: e[s] for s in "abcde"} for e in rs]
        result_cases[name] = entry
        free = entry["bound"]["both_cores_free_median"]
        print(f"{name}: both cores free: kernel {free['kernel_s']:.2f} s, overhead {free['overhead_s']:.3f} s, bound "
              f"{100 * free['fraction']:.0f} %, break-even kernel {free['break_even_kernel_s']:.2f} s", flush=True)
        print(f"{name}: kernel {med['kernel']:.2f} s, command {med['f']:.2f} s ({100 * entry['command_fraction']['median']:.0f} %,"
              f" rounds {100 * min(fr):.0f}-{100 * max(fr):.0f} %), bound {100 * entry['bound']['fraction_median']:.0f} % "
              f"(overhead {entry['bound']['overhead_s']:.3f} s, break-even kernel {entry['bound']['break_even_kernel_s']:.2f} s)"
              + ("; steps " + ", ".join(f"{s} {med[s]:.3f}" for s in "abcde") if name in own else ""), flush=True)
    reached = sorted((c["median_s"]["kernel"], name, c["command_fraction"]["median"]) for name, c in result_cases.items())
    result = {
        "cases": result_cases,
        "rounds": rounds,
        "quick": args.quick,
        "target_fraction": TARGET,
        "steps_are": {
            "a": "python -c pass (the interpreter and its site)",
            "b": "python -c 'import numpy'",
            "c": "FLOOR c: numpy, h5py, imaging.io.recording; open, truth, valid frames; every frame read in form_image's "
                 "blocks (2, then 8 at a time); no numba",
            "d": "FLOOR d: c with range compression as form_image does it (imaging.image_formation._BlockReader with the "
                 "grid's box: the chirp-z window of imaging.range_window, 2 FFT threads, RowBuffers); no numba",
            "e": "FLOOR e: d with imaging.kernel_import.start_in_background (numba's import, the direct kernel from its "
                 "cache) started after the imports, joined after the blocks, then the kernel on 4 pixels",
            "f": "python -m acquisition.cli -q image REC -o OUT --grid GRID --overwrite",
            "kernel": "imaging.backprojection.backproject on all the case's profiles (frame_profiles, every bin) in this process",
        },
        "bound_formula": "K / (K + S + max(0, R - (2 K - K_cpu)) / 2); K, K_cpu: the kernel's wall and CPU s alone; S: step d's "
                         "wall s from launch to its first block's profiles (marks_wall_s['first block']); R: step d's CPU s "
                         "after it (marks_cpu_s['all blocks'] - marks_cpu_s['first block']); per round, median reported. "
                         "Leaves out the files, the process's end and numba: no command can beat it. "
                         "break_even_kernel_s = 0.85 / 0.15 * (S + max(0, R - idle) / 2). On a loaded machine the "
                         "kernel gets less than both cores, and the core time it leaves is counted as idle though "
                         "others use it: bound.both_cores_free is the same with both cores this process's: "
                         "K2 = K_cpu / 2, overhead = S_cpu + R / 2 (S_cpu: step d's CPU s at its first block), "
                         "fraction K2 / (K2 + overhead), break-even 0.85 / 0.15 * overhead",
        "by_kernel_time": [{"case": n, "kernel_s": k, "command_fraction": f} for k, n, f in reached],
        "command_reaches_target_on": [n for k, n, f in reached if f >= TARGET],
        "load_average": {"before": load_before, "after": os.getloadavg()},
        "uptime": {"before": uptime_before, "after": uptime()},
        "run_s": time.perf_counter() - t_start,
    }
    if args.quick:
        print(json.dumps({k: v for k, v in result.items() if k != "cases"}, indent=1))
        return 0
    path = write_results("image_floor", result, started_load=started_load)
    chart(result, RESULTS / "image_floor.png")
    print(f"wrote {path} and image_floor.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
