"""A fixed probe of the machine's speed, taken beside every speed figure (the VM's speed swings within an hour).

This machine is a Firecracker VM whose speed changes by up to 1.5x within an hour while idle
(docs/benchmark-notes.md, "The VM's speed"): a figure, and even a ratio taken in one run, needs to say which
hour it ran in. The probe measures, each as the best of a few short repeats on one thread (in rounds: kernel,
FMA, copy, kernel, ...):

``kernel``   sarbot's float32 backprojection (the public ``backproject``, linear mode, numba held to one thread)
             on a fixed case: 256 profiles onto 128 x 128 points, after a warm-up call. G backprojections/s, and
             cycles per backprojection at the nominal clock (``cpu MHz`` in /proc/cpuinfo). It is the kernel of
             the checkout: its figure compares hours at one commit, not commits (the other two do both).
``fma``      a float64 multiply-add loop kept in registers (16 independent chains, numba): the core's clock
             and FMA throughput, nothing else. GFLOP/s (2 a multiply-add) and FLOPs per nominal cycle.
``copy``     numpy copying 64 MiB into a buffer already touched: memory bandwidth, GB/s counting the bytes
             read and those written.

The speeds are from the calling thread's CPU time (best of the repeats), which a shared machine's load leaves
nearly alone; the same from wall time are under ``wall``. It costs about 0.2 s of CPU once numba has its
kernels (the first call in a process also loads them: ``setup_s``).
``probe()`` returns the figures as a dict; ``benchmarks/results_file.py`` records one before and one after
every speed benchmark (``provenance.machine_speed``).

    python benchmarks/machine_speed.py                       # one probe, one line
    python benchmarks/machine_speed.py --watch 300 [--every 5] [--name machine_speed]

``--watch`` prints a line per probe for that many seconds and writes docs/results/NAME.json (the probes as
rows) with a chart of each figure over time, relative to its best.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The kernel probe's fixed case: profiles x grid points.
KERNEL_PROFILES = 256
KERNEL_GRID_SIDE = 128
#: The FMA probe: independent chains (enough to cover the FMA units' latency) and multiply-adds per chain.
FMA_CHAINS = 16
FMA_STEPS = 2_000_000
#: The copy probe's buffer, bytes (well beyond the caches).
COPY_BYTES = 64 * 2**20
#: Repeats per probe; the best is reported (the load only ever slows a run down).
REPEATS = 5

_case: dict = {}


def nominal_hz() -> float | None:
    """The nominal clock the kernel reports (``cpu MHz`` in /proc/cpuinfo), Hz; None where it has none."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("cpu MHz"):
                return float(line.split(":")[1]) * 1e6
    except (OSError, ValueError):
        pass
    return None


def widest_vectors() -> str | None:
    """The widest x86 vector extension the VM's CPU offers (``avx512f``, ``avx2``, ``avx``, ``sse2``, from
    /proc/cpuinfo's flags): a host without AVX-512 runs sarbot's kernel without its permute gather, at a
    fraction of the speed, which no load explains. None where /proc/cpuinfo has no flags."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                return next((f for f in ("avx512f", "avx2", "avx", "sse2") if f in flags), "other")
    except OSError:
        pass
    return None


def steal_ticks() -> tuple[int, int] | None:
    """(steal, total) jiffies of all CPUs from /proc/stat: the time the host gave this VM's CPUs to others."""
    try:
        fields = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except (OSError, ValueError, IndexError):
        return None
    return (fields[7] if len(fields) > 7 else 0), sum(fields[:8])


@numba.njit(cache=True, fastmath=True)
def fma_chains(x0: np.ndarray, multiplier: float, addend: float, steps: int) -> np.ndarray:
    """``steps`` multiply-adds ``x = x * multiplier + addend`` on each of ``x0``'s values, which are independent
    chains held in registers (so the loop waits on the FMA units alone).

    Parameters
    ----------
    x0 : ndarray, float64, shape (FMA_CHAINS,)
    multiplier, addend : float
    steps : int

    Returns
    -------
    ndarray, float64, shape (FMA_CHAINS,)
    """
    # Sixteen named scalars, not an array: LLVM keeps them in registers, where an array would be stored and
    # reloaded every step and the loop would wait on the store port instead.
    a0, a1, a2, a3, a4, a5, a6, a7 = x0[0], x0[1], x0[2], x0[3], x0[4], x0[5], x0[6], x0[7]
    a8, a9, a10, a11, a12, a13, a14, a15 = x0[8], x0[9], x0[10], x0[11], x0[12], x0[13], x0[14], x0[15]
    m, c = multiplier, addend
    for _ in range(steps):
        a0 = a0 * m + c
        a1 = a1 * m + c
        a2 = a2 * m + c
        a3 = a3 * m + c
        a4 = a4 * m + c
        a5 = a5 * m + c
        a6 = a6 * m + c
        a7 = a7 * m + c
        a8 = a8 * m + c
        a9 = a9 * m + c
        a10 = a10 * m + c
        a11 = a11 * m + c
        a12 = a12 * m + c
        a13 = a13 * m + c
        a14 = a14 * m + c
        a15 = a15 * m + c
    return np.array([a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11, a12, a13, a14, a15])


def fma_reference(x0: np.ndarray, multiplier: float, addend: float, steps: int) -> np.ndarray:
    """:func:`fma_chains` in plain numpy (for the tests), the closed form of the recurrence."""
    m = float(multiplier)
    geometric = steps if m == 1.0 else (1.0 - m**steps) / (1.0 - m)
    return np.asarray(x0, np.float64) * m**steps + addend * geometric


def kernel_case():
    """The kernel probe's fixed profiles, antenna positions and grid (made once a process): a straight 0.25 m
    pass at y = 0 of one TX-RX pair, random profiles of the left-front radar's waveform (the kernel's speed does
    not depend on what the profiles hold), a 1 m x 1 m grid 2 m away."""
    if not _case:
        from imaging.core.rig import default_rig
        from imaging.range_compression import range_compress

        wf = default_rig().radar("left_front").waveform
        rng = np.random.default_rng(0)
        samples = (rng.standard_normal((KERNEL_PROFILES, wf.samples_per_chirp))
                   + 1j * rng.standard_normal((KERNEL_PROFILES, wf.samples_per_chirp))).astype(np.complex64)
        profiles = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, keep_samples=False,
                                  guarded=True)
        x_m = np.linspace(-0.125, 0.125, KERNEL_PROFILES)
        tx_m = np.stack([x_m, np.zeros_like(x_m), np.zeros_like(x_m)], axis=1)
        rx_m = tx_m + np.array([0.004, 0.0, 0.0])
        side = np.linspace(-0.5, 0.5, KERNEL_GRID_SIDE)
        xx, yy = np.meshgrid(side, 2.0 + side)
        grid_m = np.stack([xx, yy, np.full_like(xx, 0.3)], axis=-1)
        _case.update(profiles=profiles, tx_m=tx_m, rx_m=rx_m, grid_m=grid_m,
                     out=np.zeros(grid_m.shape[:-1], np.complex128))
    return _case


def _best(fns: dict, repeats: int) -> dict:
    """Run each of ``fns`` (name -> callable) ``repeats`` times, in rounds (each once, in turn), so that a
    moment when another process shares the core hits all of them alike and each has the probe's whole length
    to catch a quiet moment. Per name: the best wall time and the best CPU time of the calling thread (which
    runs the kernel held to one thread), s, and the worst wall time over the best."""
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            c, t = time.thread_time(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - t)
            cpu[name].append(time.thread_time() - c)
    return {name: {"wall_s": min(wall[name]), "cpu_s": min(cpu[name]),
                   "worst_over_best": max(wall[name]) / min(wall[name])} for name in fns}


def probe(repeats: int = REPEATS) -> dict:
    """Measure the machine's speed now: sarbot's kernel, an FMA loop and a memory copy, each the best of
    ``repeats`` on one thread.

    Returns
    -------
    dict
        ``utc``; ``kernel_gbp_per_s`` (G backprojections/s) and ``kernel_cycles_per_backprojection`` (at
        ``nominal_hz``); ``fma_gflops`` and ``fma_flops_per_cycle``; ``copy_gb_per_s`` (read + written): all
        from the best CPU time of the repeats; ``wall``: the three speeds from the best wall time;
        ``worst_over_best`` (each figure's slowest repeat over its best, wall time: the scatter within this
        probe); ``repeats``; ``widest_vectors`` (the CPU's widest vector extension); ``probe_s`` (wall time of
        the measurement), ``setup_s`` (making the case and loading the kernels, the first time in a process),
        ``steal_fraction`` (the CPU time the host took from this VM during the probe, /proc/stat; None where
        unknown), ``load_average``.
    """
    from imaging.backprojection import backproject

    started = time.perf_counter()
    case = kernel_case()
    x0 = np.linspace(1.0, 2.0, FMA_CHAINS)

    def kernel():
        case["out"][:] = 0
        backproject(case["profiles"], case["tx_m"], case["rx_m"], case["grid_m"], out=case["out"])

    # The kernel as the benchmarks run it (its parallel form), on one thread: the probe's figure must not
    # depend on how many threads the benchmark that calls it chose; theirs is restored after.
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        kernel()  # warm-up: the kernel loaded (or compiled), the profiles in cache
        fma_chains(x0, 0.999999, 1e-6, 1000)
        src = np.ones(COPY_BYTES // 8)
        dst = np.empty_like(src)
        np.copyto(dst, src)  # every page of both touched before the timing
        setup_s = time.perf_counter() - started

        steal_before = steal_ticks()
        measured = time.perf_counter()
        timed = _best({"kernel": kernel, "fma": lambda: fma_chains(x0, 0.999999, 1e-6, FMA_STEPS),
                       "copy": lambda: np.copyto(dst, src)}, repeats)
        probe_s = time.perf_counter() - measured
        steal_after = steal_ticks()
    finally:
        numba.set_num_threads(threads)
    del src, dst

    hz = nominal_hz()
    backprojections = KERNEL_PROFILES * KERNEL_GRID_SIDE**2
    flops = 2.0 * FMA_CHAINS * FMA_STEPS
    steal = None
    if steal_before and steal_after and steal_after[1] > steal_before[1]:
        steal = (steal_after[0] - steal_before[0]) / (steal_after[1] - steal_before[1])
    # The speeds from CPU time: on this shared machine a short repeat's wall time is mostly how long the
    # scheduler gave the core to others (under a load of 8 on 2 cores the kernel got 43 % of its wall time);
    # the CPU time is what the VM's core did with the time it had. The wall-time figures are kept beside them.
    kernel_s, fma_s, copy_s = (timed[k]["cpu_s"] for k in ("kernel", "fma", "copy"))
    return {
        "utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "kernel_gbp_per_s": backprojections / kernel_s / 1e9,
        "kernel_cycles_per_backprojection": None if hz is None else kernel_s * hz / backprojections,
        "fma_gflops": flops / fma_s / 1e9,
        "fma_flops_per_cycle": None if hz is None else flops / (fma_s * hz),
        "copy_gb_per_s": 2 * COPY_BYTES / copy_s / 1e9,
        "wall": {"kernel_gbp_per_s": backprojections / timed["kernel"]["wall_s"] / 1e9,
                 "fma_gflops": flops / timed["fma"]["wall_s"] / 1e9,
                 "copy_gb_per_s": 2 * COPY_BYTES / timed["copy"]["wall_s"] / 1e9},
        "worst_over_best": {k: v["worst_over_best"] for k, v in timed.items()},
        "repeats": repeats,
        "nominal_hz": hz,
        "widest_vectors": widest_vectors(),
        "probe_s": probe_s,
        "setup_s": setup_s,
        "steal_fraction": steal,
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }


def line(p: dict) -> str:
    """One probe as a line of text."""
    cycles = p["kernel_cycles_per_backprojection"]
    return (f"{p['utc']}  kernel {p['kernel_gbp_per_s']:.3f} G bp/s"
            + (f" ({cycles:.2f} cycles)" if cycles is not None else "")
            + f"  fma {p['fma_gflops']:.2f} GFLOP/s  copy {p['copy_gb_per_s']:.1f} GB/s"
            + f"  {p['widest_vectors']}  probe {p['probe_s']:.2f} s  load {p['load_average'][0]:.2f}"
            + (f"  steal {100 * p['steal_fraction']:.1f} %" if p["steal_fraction"] is not None else ""))


def spread(rows: list[dict]) -> dict:
    """Each figure's worst over best across ``rows`` (probes), and its best and median."""
    out = {}
    for key in ("kernel_gbp_per_s", "fma_gflops", "copy_gb_per_s"):
        values = [r[key] for r in rows]
        out[key] = {"best": max(values), "median": float(np.median(values)), "worst": min(values),
                    "best_over_worst": max(values) / min(values)}
    return out


def chart(rows: list[dict], path: Path, title: str) -> None:
    """Each figure over the watch, relative to its best probe."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = datetime.datetime.fromisoformat(rows[0]["utc"])
    minutes = [(datetime.datetime.fromisoformat(r["utc"]) - t0).total_seconds() / 60 for r in rows]
    fig, ax = plt.subplots(figsize=(8, 4))
    for key, label in (("kernel_gbp_per_s", "sarbot kernel (1 thread)"), ("fma_gflops", "float64 FMA loop"),
                       ("copy_gb_per_s", "64 MiB copy")):
        values = np.array([r[key] for r in rows])
        ax.plot(minutes, values / values.max(), marker=".", label=f"{label}, best {values.max():.3g}")
    ax.set_xlabel(f"minutes after {rows[0]['utc']}")
    ax.set_ylabel("speed / best probe")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--watch", type=float, default=None, metavar="SECONDS",
                    help="probe for this long, a line per probe, and write docs/results/NAME.json with a chart")
    ap.add_argument("--every", type=float, default=5.0, metavar="SECONDS",
                    help="start a probe this often while watching (0: back to back; default 5)")
    ap.add_argument("--name", default="machine_speed", help="the watch's JSON and chart name (default machine_speed)")
    ap.add_argument("--repeats", type=int, default=REPEATS,
                    help=f"repeats per probe, the best kept (default {REPEATS})")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats must be at least 1, got {args.repeats}")
    if args.watch is None:
        print(line(probe(args.repeats)), flush=True)
        return 0
    if args.watch <= 0 or args.every < 0:
        ap.error("--watch must be positive and --every not negative")
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from results_file import RESULTS, load_average, write_results

    started_load = load_average()
    rows = []
    end = time.monotonic() + args.watch
    while time.monotonic() < end:
        start = time.monotonic()
        rows.append(probe(args.repeats))
        print(line(rows[-1]), flush=True)
        time.sleep(max(0.0, args.every - (time.monotonic() - start)))
    result = {"watch_s": args.watch, "every_s": args.every, "probes": len(rows), "spread": spread(rows),
              "case": {"kernel_profiles": KERNEL_PROFILES, "kernel_grid_points": KERNEL_GRID_SIDE**2,
                       "fma_chains": FMA_CHAINS, "fma_steps": FMA_STEPS, "copy_bytes": COPY_BYTES},
              "rows": rows}
    path = write_results(args.name, result, started_load=started_load)
    chart(rows, RESULTS / f"{args.name}.png", f"Probe speed over {args.watch / 60:.0f} min (load avg "
          f"{started_load[0]:.1f}-{load_average()[0]:.1f})")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
