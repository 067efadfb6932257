"""Wild tiles on the live test's drive: which map measurements go wild, what the live worker can tell them by,
and the Doppler scale learnt without and with the wild gate (``MapFeedbackConfig.wild_gate_chi2``) and the
start-up settling (``scale_settle_s``, ``single_tile_settle_s``).

    python benchmarks/map_feedback_wild.py [--seeds 0 1 2 3 4 5 6 7] [--jobs 2] [--runs 0 1 2 3]

The live test's drive (acquisition.studies.map_feedback_live: noise seed ``seed``, the radars' Doppler 2 % low)
run offline as the live workers run it (benchmarks/map_feedback_live_drive.py: rio.feedback_drive's loop on
scans from the raw frames, ``EkfConfig()``). For every measurement: its truth (rio.map_feedback_truth), error
over its claimed sigma, what the live worker knows of it (its sigma, tiles, the residual's chi2 against the
filter's velocity, its sigma and the scale's: ``MapUpdate.wild_chi2``), its tiles' refocus figures (groups,
coverage, entropy before and after) and when its span began after the start. A measurement is called wild here
where it errs by more than 4 of its sigmas and 20 mm/s (the truth, for the table only). Runs: the defaults, the
same with single tiles settling as long as several (``single_tile_settle_s`` 0), the wild gate alone, the old
defaults (no wild gate, no settling). Writes
docs/results/map_feedback_wild.json. Each seed in a process of its own; a few minutes a seed on a quiet machine.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import rio.feedback_drive as feedback_drive  # noqa: E402
from acquisition.studies.map_feedback_live import TRUE_SCALE_PPM  # noqa: E402
from map_feedback_live_drive import live_drive  # noqa: E402
from results_file import load_average, write_results  # noqa: E402
from rio.ekf import EkfConfig  # noqa: E402
from rio.map_feedback import MapFeedbackConfig, group_coverage  # noqa: E402
from rio.map_feedback_truth import measurement_truths  # noqa: E402

RUNS = {"defaults (wild gate, scale_settle_s 1.5, single_tile_settle_s 3)": MapFeedbackConfig(),
        "wild gate, scale_settle_s 1.5 (single tiles too)": MapFeedbackConfig(scale_settle_s=1.5, single_tile_settle_s=0.0),
        "wild gate": MapFeedbackConfig(scale_settle_s=0.0),
        "old defaults (no wild gate, no settling)": MapFeedbackConfig(wild_gate_chi2=np.inf, scale_settle_s=0.0)}
WILD_SIGMAS = 4.0
WILD_MPS = 0.02


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def run(drive, start_ns: int, config: MapFeedbackConfig) -> dict:
    """One loop over ``drive`` with ``config``: the scale learnt and every measurement with its truth."""
    saved = feedback_drive.SIM_EKF, feedback_drive.T0
    feedback_drive.SIM_EKF, feedback_drive.T0 = EkfConfig(), start_ns
    try:
        result = feedback_drive.run_feedback_loop(drive, True, feedback_config=config)
    finally:
        feedback_drive.SIM_EKF, feedback_drive.T0 = saved
    fb = result.feedback
    truths = {id(t.measurement): t for t in measurement_truths(result.tile_sets, drive.truth, result.trajectory)}
    refocus = {id(r.track_error): r for r in result.refocus_map.refocus_results.values()}
    first_start_ns = fb.motion_starts_ns[0] if fb.motion_starts_ns else None
    tiles_of = {id(m): tiles for tiles, ms in result.tile_sets for m in ms}
    rows = []
    for u in fb.updates:
        m = u.measurement
        t = truths.get(id(m))
        results = [refocus.get(id(te)) for te, _ in tiles_of.get(id(m), [])]
        error = None if t is None else m.velocity_error_mps - t.true_mps
        rows.append({
            "time_s": (m.time_ns - start_ns) * 1e-9,
            "span_began_after_start_s": None if first_start_ns is None else (m.time_ns - 0.5 * m.span_s * 1e9 - first_start_ns) * 1e-9,
            "measured_mps": m.velocity_error_mps, "sigma_mps": m.sigma_mps, "tiles": m.tiles, "radars": list(m.radars),
            "true_mps": None if t is None else t.true_mps, "error_mps": error,
            "error_sigmas": None if error is None else error / m.sigma_mps,
            "wild": error is not None and abs(error) > max(WILD_SIGMAS * m.sigma_mps, WILD_MPS),
            "wild_chi2": _finite(u.wild_chi2), "filter_chi2": _finite(u.chi2),
            "groups": [int(te.time_s.size) for te, _ in tiles_of.get(id(m), [])],
            "coverage": [group_coverage(g.time_s) for _, g in tiles_of.get(id(m), [])],
            "entropy_drop": [None if r is None else float(r.entropy_before - r.entropy_after) for r in results],
            "verdict": u.line().split(": ")[-1].split(";")[0], "line": u.line()})
    scale_ppm = (fb.doppler_scale - 1) * 1e6
    return {"scale_ppm": scale_ppm, "scale_sigma_ppm": fb.scale_sigma * 1e6,
            "scale_error_sigmas": (scale_ppm - TRUE_SCALE_PPM) / (fb.scale_sigma * 1e6),
            "taken": len(fb.measurements), "wild_not_taken": fb.wild_not_taken,
            "settling_not_taken": fb.settling_not_taken, "spanning_update": fb.spanning_update,
            "refused": fb.rejected, "measurements": rows}


def one_seed(seed: int, runs: list[str]) -> dict:
    """The runs ``runs`` (names in ``RUNS``) on the drive of ``seed``."""
    with tempfile.TemporaryDirectory() as tmp:
        drive, start_ns = live_drive(seed, Path(tmp))
    out = {}
    for name in runs:
        config = RUNS[name]
        out[name] = run(drive, start_ns, config)
        r = out[name]
        print(f"seed {seed}, {name}: scale {r['scale_ppm']:+.0f} +- {r['scale_sigma_ppm']:.0f} ppm "
              f"({r['scale_error_sigmas']:+.2f} sigma), {r['taken']} taken, {r['wild_not_taken']} wild", flush=True)
    return out


def separation(runs: dict) -> dict:
    """Over every measurement of ``runs`` (all seeds; its chi2 against the wild gate's sigma, taken or not):
    the wild_chi2 of the wild ones and of the rest, and each tile figure's range for both."""
    rows = [m for r in runs.values() for m in r["measurements"]
            if m["wild_chi2"] is not None and m["error_mps"] is not None]
    out = {}
    for label, sel in (("wild", [m for m in rows if m["wild"]]), ("sound", [m for m in rows if not m["wild"]])):
        def span(key, rows=sel):
            values = [v for m in rows for v in (m[key] if isinstance(m[key], list) else [m[key]]) if v is not None]
            return [min(values), max(values)] if values else None
        out[label] = {"count": len(sel), "wild_chi2": span("wild_chi2"), "sigma_mps": span("sigma_mps"),
                      "abs_error_mps": [min(abs(m["error_mps"]) for m in sel), max(abs(m["error_mps"]) for m in sel)] if sel else None,
                      "groups": span("groups"), "coverage": span("coverage"), "entropy_drop": span("entropy_drop"),
                      "span_began_after_start_s": span("span_began_after_start_s")}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=list(range(8)))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--runs", type=int, nargs="*", default=list(range(len(RUNS))),
                    help="which of RUNS (0: the defaults, 1: single tiles settling as long as several, 2: the wild "
                         "gate alone, 3: the old defaults)")
    args = ap.parse_args(argv)
    names = [list(RUNS)[i] for i in args.runs]
    started_load = load_average()
    t0 = time.perf_counter()
    with mp.get_context("spawn").Pool(max(1, min(args.jobs, len(args.seeds)))) as pool:
        per_seed = dict(zip(args.seeds, pool.starmap(one_seed, [(seed, names) for seed in args.seeds])))
    runs = {f"seed {seed}, {name}": r for seed, rs in per_seed.items() for name, r in rs.items()}
    out = {"scenario": "the live test's drive (tests/test_map_feedback_live.py) with noise seeds "
                       f"{args.seeds}, odometry from raw frames and the refocusing map in time, offline",
           "truth_scale_ppm": TRUE_SCALE_PPM,
           "wild": f"a measurement erring by more than {WILD_SIGMAS:g} of its sigmas and {WILD_MPS * 1e3:g} mm/s (truth)",
           "summary": {name: {"scale_ppm": [per_seed[s][name]["scale_ppm"] for s in args.seeds],
                              "scale_sigma_ppm": [per_seed[s][name]["scale_sigma_ppm"] for s in args.seeds],
                              "scale_error_sigmas": [per_seed[s][name]["scale_error_sigmas"] for s in args.seeds],
                              "within_2_sigma": all(abs(per_seed[s][name]["scale_error_sigmas"]) < 2 for s in args.seeds),
                              "wild_taken": sum(m["wild"] and m["verdict"] == "accepted"
                                                for s in args.seeds for m in per_seed[s][name]["measurements"])}
                       for name in names},
           "separation": separation({k: v for k, v in runs.items() if k.endswith(f", {names[0]}")}),
           "runs": runs, "seconds": time.perf_counter() - t0}
    path = write_results("map_feedback_wild", out, started_load=started_load)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
