"""Where the backprojection kernel's cycles go: the kernel timed beside copies of itself that each leave one
part out, alternating in one process, the part's cost the difference.

The copies are made from imaging/backprojection.py's source with one part switched off (their images are
wrong; only their time counts):

``table``       the per-(block, profile) table (imaging/block_profiles.py): computed for the first group of
                the first block only, reused by all;
``place``       each pixel's range offset, bin and phase (the first pass): run for a group's first profile only;
``gather``      the two neighbouring bins of each pixel, copied side by side, or on AVX-512 permuted into
                planar arrays (the second pass): not run;
``sincos``      the phase's sine and cosine in the third pass: replaced by two loads;
``accumulate``  the whole third pass (sine, cosine, interpolation and accumulation): not run.

What is left over (the full kernel less all five) is the loops over profiles and blocks, the per-block set-up
and the memory traffic the parts share. On the kernel_versions benchmark's two cases (the benchmark case and
the one-antenna pass, 256 x 256 pixels), one thread, CPU time of the calling process times the CPU clock
(/proc/cpuinfo) per backprojection; the best of the rounds.

    python benchmarks/kernel_parts.py [--quick] [--rounds N] [--name NAME]

Writes docs/results/kernel_parts.json (NAME.json with ``--name``: the split on another CPU, beside the AVX-512
machine's), with the load average: the machine is shared.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
PARTS = ("table", "place", "gather", "sincos", "accumulate")

# (text in the kernel's source, what replaces it): each guarded by PART, a constant numba compiles away.
EDITS = (
    ("""    if linear:
        for i in range(nb):
            j = idx[i]
            pairs[i, 0] = row[j]
            pairs[i, 1] = row[j + np.uint32(1)]
        for i in range(nb):
            c, s = _cos_sin_turns(turns[i])""",
     """    if linear:
        if PART != "gather":
            for i in range(nb):
                j = idx[i]
                pairs[i, 0] = row[j]
                pairs[i, 1] = row[j + np.uint32(1)]
        for i in range(nb if PART != "accumulate" else 0):
            c, s = _cos_sin_turns(turns[i]) if PART != "sincos" else (turns[i], frac[i])"""),
    # ... and the same in the permute gather's pass (imaging/bin_gather.py), which the kernel takes on AVX-512.
    ("""    gather_planar(row, idx, planar)
    for i in range(idx.size):
        c, s = _cos_sin_turns(turns[i])""",
     """    if PART != "gather":
        gather_planar(row, idx, planar)
    for i in range(idx.size if PART != "accumulate" else 0):
        c, s = _cos_sin_turns(turns[i]) if PART != "sincos" else (turns[i], frac[i])"""),
    ("""            block_profile_table(cx, cy, cz, radius,""",
     """            if PART != "table" or blk == 0 and g == 0:
                block_profile_table(cx, cy, cz, radius,"""),
    # (the placement is called once per mode, ``linear`` a constant in each: the benchmark's mode is linear)
    ("""                if linear:
                    _place_block_profile(table, j,""",
     """                if PART == "place" and j > 0:
                    pass
                elif linear:
                    _place_block_profile(table, j,"""),
    # Defined contents where a part that fills them is left out (no stray bins or NaNs).
    ("""        table = np.empty(TABLE_SIZE, np.float32)""",
     """        table = np.zeros(TABLE_SIZE, np.float32)
        pairs[:] = 0
        planar[:] = 0
        idx[:] = 1"""),
)


def variant_source(source: str, part: str) -> str:
    """The kernel module's source with ``part`` left out ("none": all parts run)."""
    for old, new in EDITS:
        if old not in source:
            raise SystemExit(f"kernel_parts: the kernel's source has changed; this benchmark no longer finds {old.strip()[:60]!r}")
        source = source.replace(old, new)
    if "\nMODES = " not in source:
        raise SystemExit("kernel_parts: the kernel's source has changed; this benchmark no longer finds 'MODES = '")
    return source.replace("\nMODES = ", f"\nPART = {part!r}\nMODES = ", 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("--name", default=None, help="the JSON's name (default kernel_parts[_quick])")
    args = ap.parse_args()
    frames, px, one = (4, 128, 1024) if args.quick else (16, 256, 4096)
    rounds = args.rounds or (2 if args.quick else 3)
    tmp = tempfile.TemporaryDirectory()
    # The copies' compiled kernels in a cache of their own, not among the project's.
    os.environ["NUMBA_CACHE_DIR"] = str(Path(tmp.name) / "cache")
    sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
    import numba

    from backprojection import make_case
    from kernel_versions import cpu_hz, current_commit, uptime
    from peers import one_antenna_case
    from results_file import load_average, probe_machine, write_results

    from imaging.range_compression import range_compress

    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    uptime_before = uptime()
    source = (ROOT / "imaging" / "backprojection.py").read_text()
    kernels = {}
    for part in ("none",) + PARTS:
        path = Path(tmp.name) / f"kernel_without_{part}.py"
        path.write_text(variant_source(source, part))
        spec = importlib.util.spec_from_file_location(f"kernel_without_{part}", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        kernels[part] = module.backproject
    hz = cpu_hz() or float("nan")
    numba.set_num_threads(1)
    makers = {"benchmark": lambda: make_case(frames, px, px), "one_antenna": lambda: one_antenna_case(one, px, px)}
    result = {"commit": current_commit(), "rounds": rounds, "threads": 1, "quick": args.quick, "cpu_hz": hz}
    for name, make in makers.items():
        samples, wf, tx, rx, grid = make()
        prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, guarded=True)
        work = tx.shape[0] * px * px
        for run in kernels.values():
            run(prof, tx, rx, grid)  # compile / warm
        cpu_s = {part: [] for part in kernels}
        for _ in range(rounds):
            for part, run in kernels.items():
                c = time.process_time()
                run(prof, tx, rx, grid)
                cpu_s[part].append(time.process_time() - c)
        cycles = {part: min(t) * hz / work for part, t in cpu_s.items()}
        parts = {part: cycles["none"] - cycles[part] for part in PARTS}
        # "accumulate" includes "sincos": the rest is the full kernel less table, place, gather and accumulate.
        rest = cycles["none"] - sum(parts[p] for p in ("table", "place", "gather", "accumulate"))
        result[name] = {"backprojections": work, "cycles_per_backprojection": cycles["none"],
                        "cycles_of_part": {**parts, "interpolate_and_accumulate": parts["accumulate"] - parts["sincos"],
                                           "rest": rest},
                        "cycles_without_part": {p: cycles[p] for p in PARTS}}
        print(f"{name}: {cycles['none']:.2f} cycles per backprojection; "
              + ", ".join(f"{p} {v:.2f}" for p, v in result[name]["cycles_of_part"].items()), flush=True)
    result["machine"] = {"cores": os.cpu_count(), "load_average": os.getloadavg(), "uptime_before": uptime_before,
                         "uptime_after": uptime()}
    name = args.name or ("kernel_parts_quick" if args.quick else "kernel_parts")
    write_results(name, result, started_load=started_load)
    print(f"load average {result['machine']['load_average'][0]:.2f}; wrote {RESULTS / (name + '.json')}")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
