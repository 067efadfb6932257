"""The autofocus decision: the contrast gate against the half-band consistency test, on passes with a
track error unlike the paper's (``imaging.sim.autofocus_scenes.INDEPENDENT_ERROR``: cubic and quadratic
drift, a 6.1 Hz vibration, a 2 % along-track scale error), at 77 GHz over a 0.6 m aperture at 2 m.

Reported per scene (a point target at several image SNRs, error-free and erroneous clutter) and per
decision ("consistency", the default; "contrast", the 20 dB gate; "forced", no gate at all), all with the
entropy method: whether the estimate was applied, the correlation of the image's magnitude with the true
image's (formed on the true track), and for the point target the cross-range width against the true
image's; for the consistency decision its margin and scope. Also the consistency test's false-alarm rate
on pairs of independent estimates of nothing (white and random-walk noise), against the stated rate.

    python benchmarks/autofocus_decision.py

Writes docs/results/autofocus_decision.json and autofocus_decision.png. Takes several minutes.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

from imaging import metrics  # noqa: E402
from imaging.autofocus import AutofocusOptions, backproject_blocks, estimate_track_error, nothing_to_focus_on  # noqa: E402
from imaging.autofocus.consistency import FALSE_ALARM, consistency_of  # noqa: E402
from imaging.sim.autofocus_scenes import INDEPENDENT_ERROR, NO_ERROR, RANGE_M, synthesise_pass  # noqa: E402

RESULTS = ROOT / "docs" / "results"
POINT_SNRS_DB = (14.0, 20.0, 26.0, 32.0)
CLUTTER_SNR_DB = 15.0


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two images' magnitudes."""
    a, b = np.abs(a).ravel(), np.abs(b).ravel()
    a, b = a - a.mean(), b - b.mean()
    return float(a @ b / np.sqrt((a @ a) * (b @ b)))


def width_m(img: np.ndarray, p) -> float:
    a = metrics.analyze_target(img, p.x_m, p.y_m, (0.0, 1.0, 0.0), near_m=(0.0, RANGE_M), radius_m=0.03, half_length_m=0.08)
    return float(a["cross_range"]["half_power_width_m"])


def run_scene(scene: str, error, snr_db: float, seed: int) -> dict:
    p = synthesise_pass(scene, error, snr_db, seed)
    plain = backproject_blocks(p.blocks, p.points_m)
    truth = backproject_blocks(p.true_blocks, p.points_m)
    row = {"scene": scene, "error": error is not NO_ERROR, "snr_db": snr_db, "seed": seed,
           "plain": {"correlation": correlation(plain, truth)}}
    if scene == "point":
        row["plain"]["width_ratio"] = width_m(plain, p) / width_m(truth, p)
    forced = estimate_track_error(lambda: p.blocks, plain, p.points_m, AutofocusOptions(decision="contrast", min_contrast_db=0.0))
    gate_open = not nothing_to_focus_on(plain, AutofocusOptions(decision="contrast"))
    consistent = estimate_track_error(lambda: p.blocks, plain, p.points_m, AutofocusOptions())
    for name, result in (("forced", forced), ("contrast", forced if gate_open else None), ("consistency", consistent)):
        applied = result is not None and result.applied
        img = backproject_blocks(p.blocks, p.points_m, result.track_error) if applied else plain
        out = {"applied": applied, "correlation": correlation(img, truth)}
        if scene == "point":
            out["width_ratio"] = width_m(img, p) / width_m(truth, p)
        if name == "consistency":
            c = result.consistency
            out.update({"margin_db": c.margin_db, "scope": c.scope or "none", "uncertainty_m": c.uncertainty_m,
                        "common_rms_m": c.common_rms_m})
        row[name] = out
    print(json.dumps(row), flush=True)
    return row


def false_alarm_rate(kind: str, trials: int = 2000, groups: int = 256) -> float:
    """The share of pairs of independent estimates of nothing that pass as one track error."""
    rng = np.random.default_rng(7)
    t = np.arange(groups, dtype=float)
    passed = 0
    for _ in range(trials):
        a, b = rng.standard_normal(groups), rng.standard_normal(groups)
        if kind == "random walk":
            a, b = np.cumsum(a), np.cumsum(b)
        passed += consistency_of(t, a, b)[0].passed
    return passed / trials


def flat(row: dict) -> dict:
    """One table row: the scene, then widths, correlations and the consistency's verdict per decision."""
    out = {k: row[k] for k in ("scene", "error", "snr_db", "seed")}
    names = ("plain", "forced", "contrast", "consistency")
    if "width_ratio" in row["plain"]:
        out.update({f"{n}_width": row[n]["width_ratio"] for n in names})
    out.update({f"{n}_corr": row[n]["correlation"] for n in names})
    out.update({f"{n}_applied": row[n]["applied"] for n in names[1:]})
    out.update({f"consistency_{k}": row["consistency"][k] for k in ("margin_db", "scope", "uncertainty_m", "common_rms_m")})
    return out


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    points = [r for r in rows if r["scene"] == "point" and r["error"]]
    snr = [r["snr_db"] for r in points]
    for name, style in (("plain", "k:"), ("forced", "C1-"), ("contrast", "C0--"), ("consistency", "C2-o")):
        ax1.plot(snr, [r[name]["width_ratio"] for r in points], style, label=name)
    ax1.axhspan(0.95, 1.05, color="0.9")
    ax1.set_xlabel("image SNR of the error-free point target (dB)")
    ax1.set_ylabel("cross-range width / true image's")
    ax1.set_title("point target with a track error")
    ax1.legend()
    clutter = [r for r in rows if r["scene"] == "clutter"]
    labels = [f"{'error' if r['error'] else 'no error'} #{r['seed']}" for r in clutter]
    x = np.arange(len(clutter))
    for i, name in enumerate(("plain", "forced", "contrast", "consistency")):
        ax2.bar(x + 0.2 * (i - 1.5), [r[name]["correlation"] for r in clutter], 0.2, label=name)
    ax2.set_xticks(x, labels)
    ax2.set_ylabel("correlation with the true image")
    ax2.set_title("clutter only")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    start = time.time()
    rows = [run_scene("point", INDEPENDENT_ERROR, snr, 1) for snr in POINT_SNRS_DB]
    rows.append(run_scene("point", NO_ERROR, POINT_SNRS_DB[0], 1))
    rows += [run_scene("clutter", err, CLUTTER_SNR_DB, seed) for err in (NO_ERROR, INDEPENDENT_ERROR) for seed in (1, 2)]
    out = {
        "what": "autofocus decision (entropy method): contrast gate vs half-band consistency; synthesised 77 GHz passes, "
                "0.6 m aperture at 2 m, track error: 0.5 mm quadratic + 1 mm cubic drift, 6.1 Hz 0.2 mm vibration, 2 % scale",
        "stated_false_alarm": FALSE_ALARM,
        "false_alarm_white": false_alarm_rate("white"),
        "false_alarm_random_walk": false_alarm_rate("random walk"),
        "rows": [flat(r) for r in rows],
        "load_average": os.getloadavg()[0],
        "seconds": time.time() - start,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    chart(rows, RESULTS / "autofocus_decision.png")
    (RESULTS / "autofocus_decision.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
