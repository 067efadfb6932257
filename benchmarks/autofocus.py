"""Autofocus: time per image against the plain backprojection of the same image, against image quality.

Two cases:

* the paper's vibration (3.83 Hz, 0.319 mm along the boresight), a point target at 2 m passed at 0.4 m/s,
  one TX/RX pair, a 301 x 101 grid, apertures 0.14-1.0 m. Quality: the peak against the image formed with
  the vibration known exactly (0 dB = perfect), the peak side lobe, and the residual track error;
* the AFRL Gotcha pass (real airborne data) with a quadratic plus sinusoidal phase error added, a
  625 x 625 grid: the peak against the uncorrupted image's.

Every estimator setting (method, slow-time groups) is timed in the same process as the plain image, the two
alternated (best of ``--repeats`` runs each, so that a load that changes over minutes changes both), and
reported as a ratio to it; the load average is recorded.

    python benchmarks/autofocus.py [--quick] [--repeats N]

Writes docs/results/autofocus.json and autofocus.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from imaging import metrics  # noqa: E402
from imaging.autofocus import AutofocusOptions, ProfileBlock, backproject_blocks, estimate_track_error  # noqa: E402
from imaging.core.track_error import TrackError  # noqa: E402
from imaging.core.geometry import Vibration  # noqa: E402
from imaging.core.grid import Grid  # noqa: E402
from imaging.image_formation import ImagingOptions, focus_image, form_image  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
VIBRATION = Vibration(3.83, 0.319e-3, 0.7)
ONE_PAIR = ImagingOptions(tx=(0,), rx=(0,))
RADAR = "left_front"


def best_of(fn, repeats: int):
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def best_alternated(plain, fn, repeats: int):
    """Best times of ``plain`` and ``fn`` run alternately ``repeats`` times each, and ``fn``'s last result."""
    t_plain, t_fn, out = np.inf, np.inf, None
    for _ in range(repeats):
        t_plain = min(t_plain, best_of(plain, 1)[0])
        t, out = best_of(fn, 1)
        t_fn = min(t_fn, t)
    return t_plain, t_fn, out


def peak_db(image) -> float:
    return float(20 * np.log10(np.abs(image).max()))


def vibration_case(work: Path, quick: bool, repeats: int) -> list[dict]:
    scene = dataclasses.replace(load_scene("paper_vibration"), vibration=VIBRATION, duration_s=4.0)
    path = work / "vibration.h5"
    simulate_recording(scene, path)
    xy = (0.0, 2.0)
    grid = Grid.from_ranges((-0.15, 0.15, 0.001), (1.9, 2.1, 0.002), 0.3)
    settings = [("pga", 256), ("entropy", 256)] if quick else [("pga", 64), ("pga", 256), ("entropy", 64), ("entropy", 128),
                                                               ("entropy", 256), ("entropy", 512)]
    rows = []
    with Recording(path) as rec:
        times = rec.frame_time_ns(RADAR)
        origin = int(times[0])
        truth = TrackError.of_vibration(VIBRATION, np.arange(0.0, 4.5, 0.0005), scene.start_time_ns, origin)
        mid = scene.start_time_ns + int((0.75 - 0.15) / 0.4 * 1e9)  # the radar abreast the target
        for la in ([0.14, 1.0] if quick else [0.14, 0.34, 0.6, 1.0]):
            half = int(la / 0.8 * 1e9)
            tw = (mid - half, mid + half)
            t_plain, plain = best_of(lambda: form_image(rec, RADAR, grid, scene.trajectory, options=ONE_PAIR, time_window_ns=tw), repeats)
            best = form_image(rec, RADAR, grid, scene.trajectory, options=ONE_PAIR, time_window_ns=tw, track_error=truth)
            ref = peak_db(best.image)

            def quality(img):
                a = metrics.analyze_target(img.image, img.x_m, img.y_m, img.attrs["look_direction"], near_m=xy,
                                           radius_m=0.05, half_length_m=0.1)
                return {"peak_vs_known_db": peak_db(img.image) - ref, "pslr_db": a["cross_range"]["pslr_db"],
                        "width_m": a["cross_range"]["half_power_width_m"]}

            rows.append({"case": "vibration", "aperture_m": la, "method": "none", "groups": 0, "seconds": t_plain,
                         "time_ratio": 1.0, **quality(plain)})
            plain_peak = rows[-1]["peak_vs_known_db"]
            rows.append({"case": "vibration", "aperture_m": la, "method": "known vibration", "groups": 0, "seconds": None,
                         "time_ratio": None, **quality(best)})
            for method, groups in settings:
                opts = AutofocusOptions(method=method, groups=groups)
                t_plain_here, t_af, img = best_alternated(
                    lambda: form_image(rec, RADAR, grid, scene.trajectory, options=ONE_PAIR, time_window_ns=tw),
                    lambda: focus_image(rec, RADAR, grid, scene.trajectory, options=ONE_PAIR, time_window_ns=tw,
                                        autofocus=opts), repeats)
                te = img.track_error
                resid = te.displacement_m - truth.at(te.time_s)
                a = np.column_stack([np.ones_like(te.time_s), te.time_s])
                resid = resid - a @ np.linalg.lstsq(a, resid, rcond=None)[0]
                rows.append({"case": "vibration", "aperture_m": la, "method": method, "groups": groups, "seconds": t_af,
                             "time_ratio": t_af / t_plain_here, "residual_rms_m": float(np.sqrt(np.mean(resid ** 2))),
                             **quality(img)})
                print(f"vibration La {la} m {method:8s} {groups:4d} groups: {t_af / t_plain_here:5.2f}x the plain image, "
                      f"peak {rows[-1]['peak_vs_known_db']:+.2f} dB vs known (plain {plain_peak:+.2f}), "
                      f"PSL {rows[-1]['pslr_db']:.1f} dB", flush=True)
    return rows


def gotcha_case(repeats: int) -> list[dict]:
    from imaging.io.phase_history import read_afrl_gotcha
    from imaging.range_compression import range_compress

    folder = ROOT.parent / "shared" / "data" / "afrl_gotcha_pass1_hh"
    if not folder.exists():
        print(f"gotcha: skipped ({folder} missing)")
        return []
    ph = read_afrl_gotcha(folder)
    tau = np.linspace(-1, 1, ph.samples.shape[0])
    error = 6 * np.pi * tau ** 2 + 2.0 * np.sin(2 * np.pi * 2.5 * tau + 0.5)

    def blocks(samples):
        prof = range_compress(samples, ph.f0_hz, ph.frequency_step_hz, window="rectangular", signed=True, guarded=True)
        los = -ph.antenna_m / np.linalg.norm(ph.antenna_m, axis=1, keepdims=True)
        return [ProfileBlock(prof, ph.antenna_m, ph.antenna_m, np.arange(tau.size, dtype=float), los, ph.reference_range_m)]

    x = np.arange(-25.0, 25.0, 0.08)
    xx, yy = np.meshgrid(x, x)
    pts = np.stack([xx, yy, np.zeros_like(xx)], axis=-1)
    clean = peak_db(backproject_blocks(blocks(ph.samples), pts))
    bad = blocks((ph.samples * np.exp(1j * error)[:, None]).astype(np.complex64))
    t_plain, corrupted = best_of(lambda: backproject_blocks(bad, pts), repeats)
    rows = [{"case": "gotcha", "method": "none", "seconds": t_plain, "time_ratio": 1.0, "peak_vs_clean_db": peak_db(corrupted) - clean}]
    for method in ("pga", "entropy"):
        def run():
            res = estimate_track_error(lambda: bad, corrupted, pts, AutofocusOptions(method=method))
            return backproject_blocks(bad, pts, res.track_error)
        t_plain_here, t_af, img = best_alternated(lambda: backproject_blocks(bad, pts), run, repeats)
        # The whole job: the plain image, the estimate and the image again.
        rows.append({"case": "gotcha", "method": method, "seconds": t_af + t_plain_here,
                     "time_ratio": (t_af + t_plain_here) / t_plain_here,
                     "peak_vs_clean_db": peak_db(img) - clean})
        print(f"gotcha {method:8s}: {rows[-1]['time_ratio']:5.2f}x the plain image, peak {rows[-1]['peak_vs_clean_db']:+.2f} dB "
              f"vs clean (corrupted {rows[0]['peak_vs_clean_db']:+.2f})", flush=True)
    return rows


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    vib = [r for r in rows if r["case"] == "vibration" and r["time_ratio"] is not None]
    for method, marker in (("none", "x"), ("pga", "s"), ("entropy", "o")):
        sel = [r for r in vib if r["method"] == method]
        a.scatter([r["time_ratio"] for r in sel], [r["peak_vs_known_db"] for r in sel], marker=marker, label=method)
        for r in sel:
            a.annotate(f"{r['aperture_m']} m" + (f", {r['groups']}" if r["groups"] else ""), (r["time_ratio"], r["peak_vs_known_db"]),
                       fontsize=6)
        b.scatter([r["time_ratio"] for r in sel], [r["pslr_db"] for r in sel], marker=marker, label=method)
    a.set(xlabel="time / plain backprojection of the same image", ylabel="peak against the known vibration's image, dB",
          title="paper's vibration: speed against focus")
    b.axhline(-13.26, color="0.6", ls="--", lw=0.8, label="rectangular aperture")
    b.set(xlabel="time / plain backprojection", ylabel="peak side lobe, dB", title="side lobes")
    a.legend(fontsize=8)
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, help="timed runs per image, alternated with the plain image's "
                                                "(default 3, 1 with --quick)")
    args = ap.parse_args()
    repeats = args.repeats or (1 if args.quick else 3)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    load_start = started_load[0]
    with tempfile.TemporaryDirectory() as tmp:
        rows = vibration_case(Path(tmp), args.quick, repeats)
    rows += gotcha_case(repeats)
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "autofocus_quick" if args.quick else "autofocus"  # a smoke run keeps the real figures
    out = write_results(stem, {"mode": "quick" if args.quick else "full", "quick": args.quick, "repeats": repeats,
                               "load_average_start": load_start, "load_average_end": os.getloadavg()[0], "rows": rows},
                        started_load=started_load)
    chart(rows, RESULTS / f"{stem}.png")
    print(f"wrote {out} and {RESULTS / (stem + '.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
