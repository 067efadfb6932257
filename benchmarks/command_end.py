"""How a new ``sarbot image`` process ends: at once after its files are closed (``acquisition.cli.end_process``:
the exit handlers, the streams flushed, ``os._exit``) against the usual end (``sys.exit(main())``: the
interpreter's teardown, which frees one by one the objects numpy, h5py and numba made at the start).

Both are the same tree's command on the backprojection benchmark's case (16 frames, 256 x 256 pixels; the
recording of benchmarks/image_command.py), each a new process run with ``-v``, alternating, one after the
other in every round. Per run: the wall time seen from here, the CPU time of the process and its threads, and
``outside_command``: the wall time less the command's own "stage seconds" ``command`` (from sarbot's command
line being imported to the end of ``cmd_image``), i.e. the interpreter's start, which both share, and the
process's end, which is what differs. The images of both are compared bit for bit.

    python benchmarks/command_end.py [--rounds N]

Writes docs/results/command_end.json.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from image_command import COMMAND_ENV, make_recording  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

GRID = "-0.5:0.5:0.00390625,1.5:2.5:0.00390625,0.3"
#: The two ends: the entry point as it is, and sarbot's command line ended the usual way.
ENDS = {
    "at_once": ["-m", "acquisition.cli"],
    "usual": ["-c", "import sys; from acquisition.cli import main; sys.exit(main())"],
}


def run(end: str, rec: Path, out: Path) -> dict:
    """One command as a new process: wall, CPU and the command's own stage seconds."""
    line = [sys.executable, *ENDS[end], "-v", "image", str(rec), "-o", str(out), f"--grid={GRID}", "--overwrite"]
    before, t = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    err = subprocess.run(line, check=True, cwd=ROOT, env=COMMAND_ENV, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True).stderr
    wall, after = time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN)
    stages = json.loads(next(x for x in err.splitlines() if "stage seconds: " in x).split("stage seconds: ", 1)[1])
    return {"wall_s": wall, "cpu_s": after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime,
            "command_s": stages["command"], "outside_command_s": wall - stages["command"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=8)
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rec = tmp / "benchmark_case.h5"
        make_recording(rec, 16)
        outs = {end: tmp / f"{end}.h5" for end in ENDS}
        for end in ENDS:  # warm: numba's cache, the byte code, the page cache
            run(end, rec, outs[end])
        runs: dict[str, list] = {end: [] for end in ENDS}
        for _ in range(args.rounds):
            for end in ENDS:
                runs[end].append(run(end, rec, outs[end]))
        import h5py
        import numpy as np

        with h5py.File(outs["at_once"]) as a, h5py.File(outs["usual"]) as b:
            same = bool(np.array_equal(a["image"][...], b["image"][...]))
        same_png = outs["at_once"].with_suffix(".png").read_bytes() == outs["usual"].with_suffix(".png").read_bytes()
    median = {end: {key: statistics.median(r[key] for r in found) for key in found[0]} for end, found in runs.items()}
    saved = [u["outside_command_s"] - a["outside_command_s"] for a, u in zip(runs["at_once"], runs["usual"])]
    result = {
        "case": {"frames": 16, "grid": GRID},
        "rounds": args.rounds,
        "median_s": median,
        "end_saved_s_per_round": {"median": statistics.median(saved), "min": min(saved), "max": max(saved)},
        "runs": runs,
        "same_image": same,
        "same_png": same_png,
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
    for end, m in median.items():
        print(f"{end}: " + ", ".join(f"{k} {v:.3f}" for k, v in m.items()))
    print(f"the end at once saves {statistics.median(saved):.3f} s a process (rounds {min(saved):.3f} to "
          f"{max(saved):.3f}); the same image: {same}, the same PNG: {same_png}")
    write_results("command_end", result, started_load=started_load)
    print(f"wrote {ROOT / 'docs' / 'results' / 'command_end.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
