"""Fast factorized backprojection against the direct kernel: speed-up against error, and against aperture.

The case: the left-front radar (all 16 channels, 1024 profiles a frame) driving at 0.4 m/s past five point
targets at about 2 m; the image 1 m x 0.6 m at 2 mm pixels (the cross-range resolution of a 2 m aperture
at 2 m is about 2 mm). The direct kernel (``imaging.backprojection.backproject``, linear, 8x oversampled
profiles) is the baseline, run in the same process on the same profiles; the error is FFBP's image
against it (energy of the difference over the image's, dB), beside the plan's bound and estimate. On the
longest aperture, FFBP's run on 1 and on 2 threads, with the machine as it is and with another process
keeping one core busy.

    python benchmarks/ffbp.py [--quick]

Writes docs/results/ffbp.json and docs/results/ffbp.png (``ffbp_quick.*`` with --quick).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

from backprojection import make_case  # noqa: E402

from imaging.backprojection import backproject  # noqa: E402
from imaging.factorized_backprojection import FactorizedOptions, plan_factorized, run_factorized  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402
from imaging.core import strict_json  # noqa: E402

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


def busy_core():
    """Another process keeping one core busy (as the robot's drivers, recorder and odometry do)."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def threads_study(plan, prof, tx, rx, t_direct_2: float, repeats: int, direct=None) -> dict:
    """FFBP's run on 1 and 2 threads, with the machine as it is and with another process keeping one core
    busy; runs alternate between the thread counts. The direct kernel's 2-thread time is the baseline of
    the speed-ups (measured with the machine as it is); with ``direct`` (the direct kernel's call) it is
    also run in every round as it is, before the FFBP runs, for a speed-up per round (a load that comes and
    goes hits both alike): ``speedup_over_direct_2_threads_interleaved``, the median over rounds."""
    out = {}
    for label, busy in (("as_is", False), ("one_core_busy", True)):
        spinner = busy_core() if busy else None
        try:
            times = {1: [], 2: []}
            direct_times = []
            for _ in range(repeats):
                if direct is not None and not busy:
                    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
                    direct_times.append(timed(direct, 1)[0])
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
        print(f"  {label.replace('_', ' ')}: FFBP run {best[1]:.2f} s on 1 thread, {best[2]:.2f} s on 2 "
              f"({best[1] / best[2]:.2f}x); {t_direct_2 / best[2]:.1f}x the direct kernel on 2 threads", flush=True)
    return out


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
        t_plan, plan = timed(lambda: plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz, options), 1)
        run_factorized(plan, prof, tx, rx)  # compile
        t_run, img = timed(lambda: run_factorized(plan, prof, tx, rx), repeats)
        row = {"taps": options.taps, "oversample_range": options.oversample_range,
               "oversample_angle": options.oversample_angle, "leaf_profiles": options.leaf_profiles,
               "plan_s": t_plan, "run_s": t_run, "speedup": t_direct / (t_plan + t_run), "error_db": error_db(img, ref),
               "error_bound_db": plan.error_bound_db, "error_estimate_db": plan.error_estimate_db, "cost": plan.cost()}
        case["ffbp"].append(row)
        print(f"  taps {options.taps} oversample {options.oversample_range:g}/{options.oversample_angle:g}: "
              f"plan {t_plan:.2f} s + run {t_run:.2f} s -> {row['speedup']:.1f}x the direct kernel, error "
              f"{row['error_db']:.1f} dB (estimate {row['error_estimate_db']:.1f}, bound {row['error_bound_db']:.1f}), "
              f"{plan.levels} levels, {len(plan.roots)} roots", flush=True)
        if study_threads and options == configs[0]:
            row["threads"] = threads_study(plan, prof, tx, rx, t_direct, max(2, repeats),
                                           direct=lambda: backproject(prof, tx, rx, grid))
    return case


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    main = result["cases"][-1]
    for row in main["ffbp"]:
        ax1.plot(row["error_db"], row["speedup"], "o", color="C0")
        ax1.plot(row["error_estimate_db"], row["speedup"], "x", color="C1")
        ax1.annotate(f"{row['taps']} taps, x{row['oversample_range']:g}", (row["error_db"], row["speedup"]),
                     textcoords="offset points", xytext=(5, 4), fontsize=8)
    ax1.axvline(-40, color="0.6", ls="--", lw=0.8)
    ax1.axhline(10, color="0.6", ls="--", lw=0.8)
    ax1.plot([], [], "o", color="C0", label="measured error")
    ax1.plot([], [], "x", color="C1", label="plan's estimate")
    ax1.set(xlabel="error against the direct kernel, dB", ylabel="speed-up over the direct kernel",
            title=f"{main['aperture_m']:.1f} m aperture, {main['pixels'] / 1e3:.0f} k pixels")
    ax1.legend(fontsize=8)
    default = FactorizedOptions()
    ap, sp = [], []
    for case in result["cases"]:
        for row in case["ffbp"]:
            if (row["taps"], row["oversample_range"]) == (default.taps, default.oversample_range):
                ap.append(case["aperture_m"])
                sp.append(row["speedup"])
    ax2.plot(ap, sp, "o-")
    ax2.set(xlabel="aperture, m", ylabel="speed-up (default settings)", title="speed-up against aperture length")
    ax2.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a smaller case (for a smoke run)")
    args = ap.parse_args()
    frame_m = SPEED_MPS * 0.052
    if args.quick:
        apertures, x, y, repeats = [0.5], np.arange(-0.3, 0.3, 0.004), np.arange(1.8, 2.2, 0.004), 1
    else:
        apertures, x, y, repeats = [0.5, 1.0, 2.0], np.arange(-0.5, 0.5, 0.002), np.arange(1.7, 2.3, 0.002), 2
    uptime_before = load_text()
    default = FactorizedOptions()
    sweep = [default, FactorizedOptions(taps=4, oversample_range=3, oversample_angle=3), FactorizedOptions(taps=8),
             FactorizedOptions(taps=6, oversample_range=3, oversample_angle=3)]
    backproject(*[range_compress(np.ones((4, 175), complex), 76e9, 22.75e6, oversample=8, guarded=True)],
                np.zeros((4, 3)), np.zeros((4, 3)), np.ones((2, 2, 3)))  # compile the direct kernel outside the timing
    cases = []
    for aperture in apertures:
        configs = sweep if aperture == apertures[-1] else [default]
        cases.append(run_case(int(round(aperture / frame_m)), x, y, configs, repeats, study_threads=aperture == apertures[-1]))
    result = {"machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(), "numba": numba.__version__,
                          "python": platform.python_version(), "load_average": os.getloadavg(),
                          "uptime_before": uptime_before, "uptime_after": load_text()},
              "case": {"speed_mps": SPEED_MPS, "range_m": 2.0, "pixel_m": float(x[1] - x[0]), "image_m": [float(np.ptp(x)), float(np.ptp(y))],
                       "profile_oversample": 8, "direct_mode": "linear", "quick": args.quick},
              "cases": cases}
    RESULTS.mkdir(parents=True, exist_ok=True)
    name = "ffbp_quick" if args.quick else "ffbp"
    (RESULTS / f"{name}.json").write_text(strict_json.dumps(result, indent=2))
    chart(result, RESULTS / f"{name}.png")
    print(f"wrote {RESULTS / (name + '.json')} and {name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
