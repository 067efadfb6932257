"""Range compression of only the bins an image needs (imaging.range_window: a chirp-z transform) against
every bin (the zero-padded FFT), on ``sarbot image``'s blocks, alternated in one process.

For each case (image_command.py's: the benchmark case, 16 frames onto 257 x 257 pixels, and the larger one,
32 frames onto 513 x 513 over the same square metre) it records the window (bins made / n_fft, per block),
the time of ``frame_profiles`` on each 8-frame block both ways (CPU and wall, 2 FFT threads, the rows written
into a reused buffer as form_image writes them), alternated block by block over several rounds, and the
image both ways: the windowed image against the full one (SER) and each against the exact matched filter on a
sample of pixels. Also one chirp's cost: the full FFT against the chirp-z transform over window fractions.

    python benchmarks/range_window.py [--quick]

Writes docs/results/range_window.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "benchmarks")]

import imaging.profiles  # noqa: E402
from image_command import make_recording  # noqa: E402
from imaging.backprojection import backproject  # noqa: E402
from imaging.core.grid import Grid  # noqa: E402
from imaging.image_formation import ImagingOptions, RowBuffers, frame_profiles  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402
from imaging.core.windows import get_window  # noqa: E402
from imaging.range_window import fast_length, zoom_spectrum  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402


def ser_db(reference: np.ndarray, image: np.ndarray) -> float:
    return float(10 * np.log10(np.sum(np.abs(reference) ** 2) / np.sum(np.abs(image - reference) ** 2)))


def chirp_costs(rounds: int) -> dict:
    """Microseconds of CPU a chirp (8,192 chirps of the left-front radar's 175 samples, 16x: n_fft 2,800, one
    thread) for the full FFT and the chirp-z transform of windows of 5-50 % of the bins, alternated."""
    rng = np.random.default_rng(0)
    n, n_fft, n_p = 175, 2800, 8192
    x = (rng.standard_normal((n_p, n)) + 1j * rng.standard_normal((n_p, n))).astype(np.complex64)
    fractions = (0.05, 0.1, 0.17, 0.25, 0.35, 0.5)
    rows_full = np.empty((n_p, n_fft + 3), np.complex64)
    outs = {f: np.empty((n_p, int(f * n_fft) + 3), np.complex64) for f in fractions}
    times = {"full": [], **{f: [] for f in fractions}}
    weights = get_window("hann", n)
    weights = (weights / weights.sum()).astype(np.float32)
    for _ in range(rounds):
        for f in ("full", *fractions):
            t = time.process_time()
            if f == "full":
                range_compress(x, 77e9, 2.27e7, guarded=True, keep_samples=False, rows_out=rows_full)
            else:
                k = int(f * n_fft)  # range_compress's windowed path, also where it would take the full FFT
                outs[f][:, 0] = 0
                outs[f][:, -2:] = 0
                zoom_spectrum(x, weights, (n - 1) // 2, n_fft, 700, outs[f][:, 1:1 + k])
            times[f].append((time.process_time() - t) / n_p * 1e6)
    full = min(times["full"])
    return {"samples": n, "n_fft": n_fft, "chirps": n_p, "full_fft_us_per_chirp": full,
            "chirp_z": [{"window_fraction": f, "chirp_z_length": fast_length(n + int(f * n_fft) - 1),
                         "us_per_chirp": min(times[f]), "speedup_over_full": full / min(times[f])} for f in fractions]}


def measure_case(tmp: Path, name: str, n_frames: int, n_px: int, rounds: int, n_exact: int) -> dict:
    grid_text = f"-0.5:0.5:{1.0 / n_px},1.5:2.5:{1.0 / n_px},0.3"
    path = tmp / f"{name}.h5"
    make_recording(path, n_frames)
    grid = Grid.parse(grid_text, default_z_m=0.3)
    points = grid.points()
    box = (points.reshape(-1, 3).min(axis=0), points.reshape(-1, 3).max(axis=0))
    options = ImagingOptions()
    with Recording(path) as rec:
        radar, truth, order = rec.radar("left_front"), rec.truth(), rec.tdm_tx_order("left_front")
        n = rec.n_frames("left_front")
        blocks = [slice(b, min(b + 8, n)) for b in range(0, n, 8)]
        adc = {b.start: rec.adc("left_front", b) for b in blocks}
        ftimes = {b.start: rec.frame_time_ns("left_front", b) for b in blocks}

    def compress(b, windowed, buffers):
        return frame_profiles(adc[b.start], ftimes[b.start], radar, truth, order, options, row_buffers=buffers,
                              image_box_m=box if windowed else None)

    buffers = {True: RowBuffers(), False: RowBuffers()}
    for windowed in (True, False):  # each way's buffers made once, as a command's first blocks make them
        for b in blocks[:2]:
            buffers[windowed].give(compress(b, windowed, buffers[windowed]).profiles.rows)
    cpu, wall = {True: [], False: []}, {True: [], False: []}
    windows = []
    for r in range(rounds):
        for b in blocks:
            for windowed in ((True, False) if r % 2 == 0 else (False, True)):
                t, c = time.perf_counter(), time.process_time()
                prof = compress(b, windowed, buffers[windowed]).profiles
                cpu[windowed].append(time.process_time() - c)
                wall[windowed].append(time.perf_counter() - t)
                if windowed and r == 0:
                    windows.append({"first_bin": int(round(prof.range_start_m / prof.range_step_m)),
                                    "bins": prof.n_bins, "fraction_of_n_fft": prof.n_bins / 2800})
                buffers[windowed].give(prof.rows)
    per_round = {w: [sum(x[i:i + len(blocks)]) for i in range(0, len(x), len(blocks))] for w, x in cpu.items()}
    # The images: every block backprojected both ways; the exact matched filter on a sample of the pixels.
    rng = np.random.default_rng(1)
    flat = points.reshape(-1, 3)
    sample = flat[rng.choice(flat.shape[0], n_exact, replace=False)]
    images = {True: np.zeros(flat.shape[0], np.complex128), False: np.zeros(flat.shape[0], np.complex128)}
    exact = np.zeros(n_exact, np.complex128)
    for b in blocks:
        for windowed in (True, False):
            prof, tx, rx = compress(b, windowed, None)[:3]
            backproject(prof, tx, rx, flat, out=images[windowed])
        full = frame_profiles(adc[b.start], ftimes[b.start], radar, truth, order, ImagingOptions(mode="exact"))
        backproject(full.profiles, full.tx_m, full.rx_m, sample, mode="exact", out=exact)
    at = {w: images[w].reshape(-1)[[int(i) for i in _indices(flat, sample)]] for w in (True, False)}
    result = {
        "case": {"frames": n, "blocks_of_8_frames": len(blocks), "grid": grid_text, "grid_points": flat.shape[0]},
        "window_per_block": windows,
        "rounds": rounds,
        "cpu_s_per_image_compression": {"windowed": per_round[True], "all_bins": per_round[False]},
        "cpu_speedup_median_of_rounds": statistics.median(a / w for w, a in zip(per_round[True], per_round[False])),
        "wall_s_per_block_median": {"windowed": statistics.median(wall[True]), "all_bins": statistics.median(wall[False])},
        "ser_windowed_against_all_bins_db": ser_db(images[False], images[True]),
        "exact_pixels": n_exact,
        "ser_against_exact_db": {"windowed": ser_db(exact, at[True]), "all_bins": ser_db(exact, at[False])},
    }
    print(f"{name}: window {min(w['fraction_of_n_fft'] for w in windows):.3f}-{max(w['fraction_of_n_fft'] for w in windows):.3f}"
          f" of n_fft; CPU per image {statistics.median(per_round[True]):.3f} s windowed against "
          f"{statistics.median(per_round[False]):.3f} s ({result['cpu_speedup_median_of_rounds']:.2f}x); SER against all "
          f"bins {result['ser_windowed_against_all_bins_db']:.1f} dB; against exact {result['ser_against_exact_db']}",
          flush=True)
    return result


def _indices(flat: np.ndarray, sample: np.ndarray):
    """Each sampled point's index in ``flat``."""
    lookup = {tuple(p): i for i, p in enumerate(flat)}
    return [lookup[tuple(p)] for p in sample]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    cases = {"benchmark_case": (16, 256, 2, 200)} if args.quick else \
        {"benchmark_case": (16, 256, 5, 1000), "larger_case": (32, 512, 3, 1000)}
    costs = chirp_costs(2 if args.quick else 5)
    print("one chirp:", costs, flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        results = {name: measure_case(Path(tmp), name, *c) for name, c in cases.items()}
    assert imaging.profiles.worth_it  # the switch the cases' windows went through
    write_results("range_window_quick" if args.quick else "range_window",
                  {**results, "chirp_costs": costs, "quick": args.quick}, started_load=started_load)
    return 0


if __name__ == "__main__":
    sys.exit(main())
