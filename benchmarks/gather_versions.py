"""The permute gather alone against an earlier version of itself, timed alternately in one process.

The kernel's comparison (``kernel_versions.py``) times whole backprojections, in which the gather is about a
third of the cycles on a CPU without AVX-512; on a shared machine its rounds scatter by more than a change to
the gather alone is worth. This times only ``gather_planar`` (imaging/bin_gather.py): the current module and
COMMIT's (``git show COMMIT:imaging/bin_gather.py``, loaded under another name beside it), each inside a
numba loop over the same profiles, one call per (block, profile) as in the kernel (few blocks and profiles,
repeated, so that bins and rows stay in cache as in the kernel), on one thread, A B A B ..., with each call's thread CPU time beside its wall time. The pixels' bins are those of 16 x 16-pixel blocks
walked in 4 x 4 squares (``imaging.patches.patch_order``) with a range gradient drawn per (block, profile) so
that a 4 x 4 square's bins span up to 7, as on the benchmark grid (its 4 x 2 halves up to 4); both versions
must give the same planar rows bit for bit.

    python benchmarks/gather_versions.py [--baseline COMMIT] [--rounds N] [--name NAME]

Writes docs/results/gather_versions.json (NAME.json with ``--name``).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

import numba  # noqa: E402
import numpy as np  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

from imaging import bin_gather  # noqa: E402
from imaging.patches import patch_order  # noqa: E402

#: Few enough that the rows and bins stay in L2, as in the kernel (its bins are in L1, written just before the
#: gather, its rows a chunk's, read block after block); REPEATS times over.
BLOCKS, PROFILES, ROW_BINS, REPEATS = 8, 16, 2803, 128


def baseline_module(commit: str, folder: Path):
    """COMMIT's imaging/bin_gather.py, imported as a module of its own."""
    source = subprocess.run(["git", "show", f"{commit}:imaging/bin_gather.py"], cwd=ROOT, capture_output=True,
                            text=True, check=True).stdout
    path = folder / "bin_gather_baseline.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("bin_gather_baseline", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def timed_loop(gather_planar):
    """A numba loop calling ``gather_planar`` once per (block, profile); returns the groups the permutes took."""

    @numba.njit(nogil=True)
    def run(rows, idx, planar, repeats):
        done = 0
        for _ in range(repeats):
            for b in range(idx.shape[0]):
                for p in range(idx.shape[1]):
                    done += gather_planar(rows[p], idx[b, p], planar)
        return done

    return run


def case(seed: int = 3):
    """rows complex64 [PROFILES, ROW_BINS] and idx uint32 [BLOCKS, PROFILES, 256]: each block's pixels in the
    kernel's order, bins base + gx x + gy y with x, y the pixel's column and row in the 16 x 16 block."""
    rng = np.random.default_rng(seed)
    rows = (rng.standard_normal((PROFILES, ROW_BINS)) + 1j * rng.standard_normal((PROFILES, ROW_BINS))).astype(np.complex64)
    y, x = np.divmod(patch_order((32, 32), 16, 256, 4)[:256], 32)  # the first block of a larger grid
    # a 4 x 4 square spans 3 (|gx| + |gy|) bins: up to 7 where |gx| + |gy| <= 2.4
    angle = rng.uniform(0, 2 * np.pi, (BLOCKS, PROFILES, 1))
    size = rng.uniform(0.8, 2.4, (BLOCKS, PROFILES, 1)) / (np.abs(np.cos(angle)) + np.abs(np.sin(angle)))
    base = rng.uniform(40, ROW_BINS - 80, (BLOCKS, PROFILES, 1))
    pos = base + size * (np.cos(angle) * x + np.sin(angle) * y)
    return rows, np.floor(pos).astype(np.uint32)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", required=True, help="the earlier bin_gather's commit")
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--name", default="gather_versions")
    args = ap.parse_args()
    if not bin_gather.PERMUTE_GATHER:
        print("this CPU has neither AVX2 nor AVX-512: no permute gather to time")
        return 1
    started_load = load_average()
    probe_machine()
    rows, idx = case()
    with tempfile.TemporaryDirectory() as tmp:
        old_module = baseline_module(args.baseline, Path(tmp))
        old, new = timed_loop(old_module.gather_planar), timed_loop(bin_gather.gather_planar)
        planar_old, planar_new = np.full((4, 256), np.nan, np.float32), np.full((4, 256), np.nan, np.float32)
        taken = old(rows, idx[:1], planar_old, 1), new(rows, idx[:1], planar_new, 1)  # compile
        assert taken[0] == taken[1] and np.array_equal(planar_old.view(np.uint32), planar_new.view(np.uint32))
    groups = REPEATS * idx.size // bin_gather.LANES
    permuted = new(rows, idx, planar_new, REPEATS)
    rounds = []
    for _ in range(args.rounds):
        row = {}
        for label, fn in (("baseline", old), ("current", new)):
            c, t = time.thread_time(), time.perf_counter()
            fn(rows, idx, planar_new, REPEATS)
            row[label] = {"cpu_s": time.thread_time() - c, "wall_s": time.perf_counter() - t}
        rounds.append(row)
    cpu = [r["baseline"]["cpu_s"] / r["current"]["cpu_s"] for r in rounds]
    wall = [r["baseline"]["wall_s"] / r["current"]["wall_s"] for r in rounds]
    pixels = REPEATS * idx.size
    result = {
        "baseline_commit": args.baseline, "lanes": bin_gather.LANES, "rounds": args.rounds,
        "case": {"blocks": BLOCKS, "profiles": PROFILES, "repeats": REPEATS, "pixels_per_block": 256, "row_bins": ROW_BINS,
                 "groups": groups, "groups_permuted": int(permuted)},
        "speedup_cpu_time_median": statistics.median(cpu), "speedup_cpu_time_min": min(cpu),
        "speedup_cpu_time_max": max(cpu), "speedup_wall_median": statistics.median(wall),
        "ns_per_pixel_best_cpu": {k: 1e9 * min(r[k]["cpu_s"] for r in rounds) / pixels for k in ("baseline", "current")},
        "rounds_s": rounds,
    }
    best = result["ns_per_pixel_best_cpu"]
    print(f"gather alone, {bin_gather.LANES} lanes, {permuted} of {groups} groups permuted: current {statistics.median(cpu):.2f}x "
          f"the baseline's speed in CPU time ({min(cpu):.2f}-{max(cpu):.2f}; wall {statistics.median(wall):.2f}x), "
          f"best {best['current']:.3f} ns per pixel against {best['baseline']:.3f}; load {load_average()}")
    print(f"wrote {write_results(args.name, result, started_load=started_load)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
