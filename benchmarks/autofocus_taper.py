"""Autofocus under a Taylor aperture taper on passes with errors unlike the paper's: PGA against entropy.

Point-target passes synthesised straight from the signal model (``imaging.sim.autofocus_scenes``: 30 dB image
SNR, 2 m range, 0.4 m/s, one antenna every 2 mm), each with one independent error the imaging does not know:
a cubic drift (1 mm at the aperture's ends), a heading error (0.3 degrees), an along-track scale error (2 %)
and a 6.1 Hz, 0.2 mm vibration, over 1.2 m; and all of them together (with a 0.5 mm quadratic) over 0.6 m.
Every profile is weighted by the Taylor window (nbar 4, -35 dB) along the aperture, as ``sarbot image
--aperture-window taylor`` does, before the estimate and the image.

Per case and method (the contrast decision, so that the estimators are compared, not the decision): the
cross-range peak side lobe, the half-power width over the clean image's (the same taper on the true track)
and the peak against the clean image's, and the time of the estimate.

    python benchmarks/autofocus_taper.py

Writes docs/results/autofocus_taper.json and autofocus_taper.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

from imaging import metrics  # noqa: E402
from imaging.autofocus import AutofocusOptions, backproject_blocks, estimate_track_error  # noqa: E402
from imaging.core.windows import window_at  # noqa: E402
from imaging.sim.autofocus_scenes import INDEPENDENT_ERROR, RANGE_M, TrackErrorKind, synthesise_pass  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
METHODS = ("pga", "entropy")
SNR_DB = 30.0


@dataclasses.dataclass(frozen=True)
class HeadingError:
    """The true track turned by ``angle_rad`` in the ground plane from the assumed one (about its start)."""

    angle_rad: float

    def displacement_m(self, x_m: np.ndarray, half_m: float, time_s: np.ndarray) -> np.ndarray:
        d = np.zeros((x_m.size, 3))
        d[:, 0] = x_m * (math.cos(self.angle_rad) - 1.0)
        d[:, 1] = x_m * math.sin(self.angle_rad)
        return d


CASES = [
    ("cubic drift 1 mm", 1.2, TrackErrorKind(cubic_m=1e-3)),
    ("heading 0.3 deg", 1.2, HeadingError(math.radians(0.3))),
    ("scale 2 %", 1.2, TrackErrorKind(scale=0.02)),
    ("vibration 6.1 Hz 0.2 mm", 1.2, TrackErrorKind(vibration_hz=6.1, vibration_m=0.2e-3)),
    ("all together", 0.6, INDEPENDENT_ERROR),
]


def tapered(blocks: list) -> list:
    """The blocks with every profile weighted by the Taylor window along the (straight, x) aperture."""
    out = []
    for blk in blocks:
        x = blk.tx_m[:, 0]
        w = window_at("taylor", (x - x.min()) / np.ptp(x))[:, None].astype(np.float32)
        out.append(dataclasses.replace(blk, profiles=dataclasses.replace(blk.profiles, data=blk.profiles.data * w)))
    return out


def cross_range(img: np.ndarray, p) -> tuple[float, float, float]:
    a = metrics.analyze_target(img, p.x_m, p.y_m, (0.0, 1.0, 0.0), near_m=(0.0, RANGE_M), radius_m=0.05,
                               half_length_m=0.08)
    return a["cross_range"]["half_power_width_m"], a["cross_range"]["pslr_db"], a["peak_amplitude"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="accepted from `dev.py bench --quick`: this benchmark has one mode")
    ap.parse_args()
    started_load = load_average()
    rows = []
    for name, aperture_m, error in CASES:
        p = synthesise_pass("point", error, SNR_DB, 1, aperture_m=aperture_m, pixel_m=0.001)
        blocks, true_blocks = tapered(p.blocks), tapered(p.true_blocks)
        w_clean, psl_clean, peak_clean = cross_range(backproject_blocks(true_blocks, p.points_m), p)
        plain = backproject_blocks(blocks, p.points_m)

        def row(method, img, seconds=None, iterations=None):
            w, psl, peak = cross_range(img, p)
            rows.append({"case": name, "aperture_m": aperture_m, "method": method, "pslr_db": psl,
                         "width_vs_clean": w / w_clean, "peak_vs_clean_db": 20 * math.log10(peak / peak_clean),
                         "seconds": seconds, "iterations": iterations})
            print(f"{name:24s} {aperture_m} m {method:8s} PSLR {psl:6.1f} dB  width {w / w_clean:5.3f}  "
                  f"peak {rows[-1]['peak_vs_clean_db']:+.2f} dB", flush=True)

        row("clean", backproject_blocks(true_blocks, p.points_m))
        row("none", plain)
        for method in METHODS:
            t = time.perf_counter()
            result = estimate_track_error(lambda: blocks, plain, p.points_m,
                                          AutofocusOptions(method=method, decision="contrast"))
            seconds = time.perf_counter() - t
            row(method, backproject_blocks(blocks, p.points_m, result.track_error), seconds, result.iterations)
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = write_results("autofocus_taper", {"mode": "full (the only mode: every case and method)", "snr_db": SNR_DB,
                                            "window": "taylor (nbar 4, -35 dB)",
                                            "load_average": list(os.getloadavg()), "rows": rows},
                        started_load=started_load)
    chart(rows, RESULTS / "autofocus_taper.png")
    print(f"wrote {out}")
    return 0


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = list(dict.fromkeys(r["case"] for r in rows))
    methods = ["none", "clean", *METHODS]
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4))
    for i, m in enumerate(methods):
        sel = {r["case"]: r for r in rows if r["method"] == m}
        x = np.arange(len(cases)) + (i - 1.5) * 0.2
        a.bar(x, [sel[c]["pslr_db"] for c in cases], 0.2, label=m)
        b.bar(x, [sel[c]["width_vs_clean"] for c in cases], 0.2, label=m)
    labels = [f"{c}\n{next(r['aperture_m'] for r in rows if r['case'] == c)} m" for c in cases]
    for ax in (a, b):
        ax.set_xticks(np.arange(len(cases)), labels, fontsize=7)
    a.set(ylabel="cross-range peak side lobe, dB", title="Taylor taper: PSLR per method")
    b.set(ylabel="half-power width / clean image's", title="width", ylim=(0.9, 1.2))
    a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
