"""The autofocus decision: the contrast gate against the half-band consistency test, on passes with a
track error unlike the paper's (``imaging.sim.autofocus_scenes.INDEPENDENT_ERROR``: cubic and quadratic
drift, a 6.1 Hz vibration, a 2 % along-track scale error), at 77 GHz over a 0.6 m aperture at 2 m.

Reported per scene (a point target at several image SNRs, error-free and erroneous clutter) and per
decision ("consistency", the default; "contrast", the 20 dB gate; "forced", no gate at all), all with the
entropy method: whether the estimate was applied, the correlation of the image's magnitude with the true
image's (formed on the true track), and for the point target the cross-range width against the true
image's; for the consistency decision its margin and scope ("point": the half-bands disagreed and the
weak-point test, ``imaging.autofocus.weak_point``, decided). Also the consistency test's false-alarm rate
on pairs of independent estimates of nothing (white and random-walk noise), against the stated rate; the
weak point target (14 dB) over several noise seeds; and clutter over more seeds (error-free and
erroneous): the weak-point test's detection, the only way clutter reaches its fit, on every seed's image,
and the whole default decision where it detects.

    python benchmarks/autofocus_decision.py

Writes docs/results/autofocus_decision.json and autofocus_decision.png. Runs on 2 processes; takes
tens of minutes on a loaded machine (a clutter pass costs seconds to synthesise on a quiet one).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
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
from imaging.autofocus.weak_point import detect_point  # noqa: E402
from imaging.sim.autofocus_scenes import INDEPENDENT_ERROR, NO_ERROR, RANGE_M, synthesise_pass  # noqa: E402
from results_file import load_average, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
POINT_SNRS_DB = (14.0, 20.0, 26.0, 32.0)
CLUTTER_SNR_DB = 15.0
WEAK_SEEDS = (1, 2, 3)  # the 14 dB point target with the error, over noise seeds
CLUTTER_SEEDS = tuple(range(3, 11))  # more clutter passes per kind (seeds 1-2 are full rows): 10 in all, for time


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
    row = {"scene": scene, "error": error != NO_ERROR, "snr_db": snr_db, "seed": seed,
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
                        "common_rms_m": c.common_rms_m,
                        "point_detected": bool(c.point is not None and c.point.detected),
                        "point_margin_db": None if c.point is None else c.point.margin_db,
                        "point_contrast_db": None if c.point is None else 10 * math.log10(max(c.point.contrast, 1e-12))})
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
    out.update({f"consistency_{k}": row["consistency"][k] for k in ("margin_db", "scope", "uncertainty_m", "common_rms_m",
                                                                   "point_detected", "point_margin_db", "point_contrast_db")})
    return out


def clutter_seed(error, seed: int) -> dict:
    """One clutter pass: the weak-point test's detection on its image (as the decision sees it: the whole
    image is the estimation pixels here) and, where it detects, the whole default decision."""
    p = synthesise_pass("clutter", error, CLUTTER_SNR_DB, seed)
    plain = backproject_blocks(p.blocks, p.points_m)
    _, contrast, threshold = detect_point(np.abs(plain) ** 2, FALSE_ALARM)
    row = {"error": error != NO_ERROR, "seed": seed, "contrast_db": 10 * math.log10(contrast),
           "threshold_db": 10 * math.log10(threshold), "detected": contrast > threshold, "applied": False, "harmed": False}
    if row["detected"]:
        truth = backproject_blocks(p.true_blocks, p.points_m)
        result = estimate_track_error(lambda: p.blocks, plain, p.points_m, AutofocusOptions())
        if result.applied:
            img = backproject_blocks(p.blocks, p.points_m, result.track_error)
            row.update(applied=True, harmed=correlation(img, truth) < correlation(plain, truth))
    print(json.dumps(row), flush=True)
    return row


def clutter_summary(rows: list[dict], full_rows: list[dict]) -> dict:
    """Per kind: passes, the weak-point detection's false alarms, and passes the default decision changed
    or moved further from the true image (over the extra seeds and the full rows together)."""
    out = {}
    for kind, error in (("error_free", False), ("erroneous", True)):
        extra = [r for r in rows if r["error"] is error]
        full = [r for r in full_rows if r["scene"] == "clutter" and r["error"] is error]
        detected = sum(r["detected"] for r in extra) + sum(r["consistency"]["point_detected"] for r in full)
        out[kind] = {"passes": len(extra) + len(full), "point_detections": int(detected),
                     "applied": int(sum(r["applied"] for r in extra) + sum(r["consistency"]["applied"] for r in full)),
                     "moved_further": int(sum(r["harmed"] for r in extra) + sum(
                         r["consistency"]["correlation"] < r["plain"]["correlation"] - 1e-9 for r in full)),
                     "highest_contrast_minus_threshold_db": max(r["contrast_db"] - r["threshold_db"] for r in extra)}
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
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="accepted from `dev.py bench --quick`: this benchmark has one mode")
    ap.parse_args()
    started_load = load_average()
    start, load_start = time.time(), started_load[0]
    specs = [("point", INDEPENDENT_ERROR, snr, 1) for snr in POINT_SNRS_DB]
    specs.append(("point", NO_ERROR, POINT_SNRS_DB[0], 1))
    specs += [("clutter", err, CLUTTER_SNR_DB, seed) for err in (NO_ERROR, INDEPENDENT_ERROR) for seed in (1, 2)]
    weak_specs = [("point", INDEPENDENT_ERROR, POINT_SNRS_DB[0], seed) for seed in WEAK_SEEDS if seed != 1]
    with multiprocessing.Pool(2) as pool:
        clutter_async = pool.starmap_async(clutter_seed, [(err, seed) for err in (NO_ERROR, INDEPENDENT_ERROR)
                                                          for seed in CLUTTER_SEEDS])
        rows = pool.starmap(run_scene, specs + weak_specs)
        clutter_rows = clutter_async.get()
    rows, weak_rows = rows[:len(specs)], [rows[0]] + rows[len(specs):]
    out = {
        "what": "autofocus decision (entropy method): contrast gate vs half-band consistency; synthesised 77 GHz passes, "
                "0.6 m aperture at 2 m, track error: 0.5 mm quadratic + 1 mm cubic drift, 6.1 Hz 0.2 mm vibration, 2 % scale",
        "mode": "full (the only mode: every scene and seed above)",
        "stated_false_alarm": FALSE_ALARM,
        "false_alarm_white": false_alarm_rate("white"),
        "false_alarm_random_walk": false_alarm_rate("random walk"),
        "rows": [flat(r) for r in rows],
        "weak_point_seeds": [{"seed": r["seed"], "plain_width": r["plain"]["width_ratio"],
                              "consistency_width": r["consistency"]["width_ratio"], "scope": r["consistency"]["scope"],
                              "margin_db": r["consistency"]["margin_db"]} for r in weak_rows],
        "clutter_seeds": clutter_summary(clutter_rows, rows),
        "clutter_seed_rows": clutter_rows,
        "load_average_start": load_start,
        "load_average": os.getloadavg()[0],
        "seconds": time.time() - start,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    chart(rows, RESULTS / "autofocus_decision.png")
    write_results("autofocus_decision", out, started_load=started_load, indent=1)


if __name__ == "__main__":
    main()
