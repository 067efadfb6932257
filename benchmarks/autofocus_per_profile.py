"""Pulse-to-pulse phase errors on real data: the AFRL Gotcha pass with a random walk of 0.3 rad per pulse
plus a fifth-order polynomial of 11 rad added, each autofocus method estimating one value per pulse.

Reported per method: the peak against the clean image's (dB), and what is left of the added error,
``added + 2 k (estimate(corrupted) - estimate(clean))`` less its line: its pulse-to-pulse step std and rms
(rad). The clean pass has phase errors of its own (its per-profile estimate, also reported, holds steps of
0.28 rad); measuring against it keeps them out of the residual. The residual's spectrum of the "combined"
method (what the per-group values add to the entropy model) is charted.

    python benchmarks/autofocus_per_profile.py

Writes docs/results/autofocus_per_profile.json and autofocus_per_profile.png. Takes minutes (one
estimate per method and one of the clean pass).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from imaging.autofocus import AutofocusOptions, ProfileBlock, backproject_blocks, estimate_track_error  # noqa: E402
from imaging.core.constants import SPEED_OF_LIGHT_MPS  # noqa: E402
from imaging.core.track_error import remove_line  # noqa: E402
from imaging.io.phase_history import read_afrl_gotcha  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
GOTCHA = ROOT.parent / "shared" / "data" / "afrl_gotcha_pass1_hh"
METHODS = ("pga", "entropy", "per-profile", "combined")


def grid(step_m: float) -> np.ndarray:
    x = np.arange(-25.0, 25.0, step_m)
    xx, yy = np.meshgrid(x, x)
    return np.stack([xx, yy, np.zeros_like(xx)], axis=-1)


def blocks_of(ph, samples):
    prof = range_compress(samples, ph.f0_hz, ph.frequency_step_hz, window="rectangular", signed=True, guarded=True)
    los = -ph.antenna_m / np.linalg.norm(ph.antenna_m, axis=1, keepdims=True)
    return [ProfileBlock(prof, ph.antenna_m, ph.antenna_m, np.arange(ph.samples.shape[0], dtype=float), los,
                         ph.reference_range_m)]


def main() -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, nargs="?", default=GOTCHA, help="the Gotcha pass (default: the shared data's)")
    ap.add_argument("--quick", action="store_true", help="accepted from `dev.py bench --quick`: this benchmark has one mode")
    folder = ap.parse_args().folder
    started_load = load_average()
    ph = read_afrl_gotcha(folder)
    n = ph.samples.shape[0]
    rng = np.random.default_rng(33)
    tau = np.linspace(-1, 1, n)
    poly = np.polynomial.legendre.Legendre([0, 0, 4, 2, -3, 2])(tau)
    added = np.cumsum(rng.normal(0.0, 0.3, n)) + 11.0 * poly / np.abs(poly).max()
    fine, coarse = grid(0.08), grid(0.2)
    clean_blocks = blocks_of(ph, ph.samples)
    blocks = blocks_of(ph, (ph.samples * np.exp(1j * added)[:, None]).astype(np.complex64))
    k = 2 * np.pi * ph.f0_hz / SPEED_OF_LIGHT_MPS
    pulses = np.arange(n, dtype=float)

    def options(method):
        return AutofocusOptions(method=method, groups=n, scatterers=8, pga_iterations=20)

    def peak_db(im):
        return float(20 * np.log10(np.abs(im).max()))

    clean_peak = peak_db(backproject_blocks(clean_blocks, fine))
    native = estimate_track_error(lambda: clean_blocks, backproject_blocks(clean_blocks, coarse), coarse, options("per-profile"))
    native_phase = 2 * k * native.track_error.at(pulses)
    corrupted_coarse = backproject_blocks(blocks, coarse)
    out = {"pulses": n, "added": {"random_walk_rad_per_pulse": 0.3, "polynomial_order": 5, "polynomial_peak_rad": 11.0,
                                  "seed": 33},
           "clean_pass_own_error": {"step_std_rad": float(np.std(np.diff(native_phase))),
                                    "rms_rad": float(np.std(remove_line(pulses, native_phase))),
                                    "peak_gain_db": peak_db(backproject_blocks(clean_blocks, fine, native.track_error)) - clean_peak},
           "corrupted_peak_db": peak_db(backproject_blocks(blocks, fine)) - clean_peak, "methods": {}}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for method in METHODS:
        t0 = time.perf_counter()
        result = estimate_track_error(lambda: blocks, corrupted_coarse, coarse, options(method))
        seconds = time.perf_counter() - t0
        left = remove_line(pulses, added + 2 * k * result.track_error.at(pulses) - native_phase)
        steps = np.angle(np.exp(1j * np.diff(left)))
        row = {"peak_db": peak_db(backproject_blocks(blocks, fine, result.track_error)) - clean_peak,
               "residual_step_std_rad": float(np.std(steps)), "residual_rms_rad": float(np.std(left)),
               "applied": bool(result.applied), "seconds": seconds}
        model = result.track_error.model or {}
        if "residual_spectrum" in model:
            row["residual_spectrum"] = model["residual_spectrum"]
        out["methods"][method] = row
        print(method, {k_: v for k_, v in row.items() if k_ != "residual_spectrum"}, flush=True)
        axes[0].plot(pulses, left, lw=0.8, label=f"{method}: steps {row['residual_step_std_rad']:.3f} rad std")
    spec = out["methods"]["combined"]["residual_spectrum"]
    edges = np.asarray(spec["band_edges_hz"])
    axes[1].bar(edges[:-1], 2 * k * np.asarray(spec["band_rms_m"]), width=np.diff(edges), align="edge", edgecolor="k")
    axes[1].set(xscale="log", xlabel="frequency, cycles per pulse", ylabel="rms in the band, rad",
                title="combined: what the per-pulse values add to the model")
    axes[0].set(xlabel="pulse", ylabel="added error left, rad", title="Gotcha, 0.3 rad/pulse walk + polynomial")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    RESULTS.mkdir(parents=True, exist_ok=True)
    fig.savefig(RESULTS / "autofocus_per_profile.png", dpi=110)
    write_results("autofocus_per_profile", out, started_load=started_load, indent=1)


if __name__ == "__main__":
    main()
