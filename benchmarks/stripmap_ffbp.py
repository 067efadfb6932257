"""Live strip map with long apertures: the direct kernel against FFBP blocks, speed and error.

    python benchmarks/stripmap_ffbp.py [--quick]

Data: the demo scene, simulated once; the left-front radar's frames while it drives at full speed past the
rod and the reflector. For each synthetic aperture per pixel (``StripMapConfig.aperture_m``) at 4 mm pixels
(the cross-range resolution at 2 m range is 13 mm for 0.3 m, 2 mm for 2 m), the map is made by the direct
kernel (every profile onto every pixel of its frame's footprint, the baseline, run in the same process) and
by ``algorithm="ffbp"`` with blocks of 4, 8 and 16 frames, each on one thread as the live worker runs it.

Speed: frames per second, against one radar's rate (19.2 frames/s) and the four radars' (77).
Error, as error energy relative to the reference image, dB:

* ``ffbp_error_db``: against the same blocks imaged profile by profile (FFBP's own interpolation error),
  beside the plan's bound (``ffbp_error_bound_db``, the worst block's);
* ``error_vs_direct_db``: against the direct map, which decides the aperture window per frame rather than
  per block, over the pixels both integrate a whole aperture for (the map's two ends, where the drive
  covers part of a pixel's aperture, differ by where the last block ends). A pixel's window is then off
  its centre by up to half a block, which turns the complex image's phase across cross-range: hence also
  ``magnitude_error_vs_direct_db``, the same on |image|, which is what the map shows;
* the corner reflector's cross-range half-power width and peak, against the direct map's.

Writes docs/results/stripmap_ffbp.json and docs/results/stripmap_ffbp.png (``_quick`` with --quick).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.stripmap import StripMap, StripMapConfig  # noqa: E402
from reference_stripmap import block_reference  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RADAR = "left_front"
REFLECTOR_XY_M = (0.6, 2.0)
BASE = StripMapConfig(pixel_m=0.004, beam_half_angle_deg=60.0, range_min_m=1.0, range_max_m=4.0, z_m=0.3, presum=4)


def run(config: StripMapConfig, radar, order, frames, truth) -> tuple[StripMap, float]:
    """The map of ``frames`` [(adc, time)] and its wall time, after a warm-up that compiles every kernel."""
    import numba

    numba.set_num_threads(1)  # as the live worker runs it
    warm = StripMap(config)
    for adc, t in frames[:2]:
        warm.add_frame(radar, order, adc, t, truth)
    warm.flush()
    sm = StripMap(config)
    t0 = time.perf_counter()
    for adc, t in frames:
        sm.add_frame(radar, order, adc, t, truth)
    sm.flush()
    return sm, time.perf_counter() - t0


def error_db(sm: StripMap, ref: StripMap, x_range_m: tuple[float, float] | None = None, magnitude: bool = False) -> float:
    """Error energy of ``sm`` against ``ref`` relative to ``ref``'s, on their common pixels (those with x in
    ``x_range_m`` if given), dB; of their magnitudes with ``magnitude`` (what the map shows)."""
    img, x, y = sm.mosaic()
    r, xr, yr = ref.mosaic()
    pixel = sm.config.pixel_m
    cx = np.intersect1d(np.floor(x / pixel).astype(int), np.floor(xr / pixel).astype(int))
    cy = np.intersect1d(np.floor(y / pixel).astype(int), np.floor(yr / pixel).astype(int))
    if x_range_m is not None:
        cx = cx[((cx + 0.5) * pixel >= x_range_m[0]) & ((cx + 0.5) * pixel <= x_range_m[1])]

    def common(image, xs, ys):
        ix = np.searchsorted(np.floor(xs / pixel).astype(int), cx)
        iy = np.searchsorted(np.floor(ys / pixel).astype(int), cy)
        return image[np.ix_(iy, ix)]

    a, b = common(img, x, y), common(r, xr, yr)
    if magnitude:
        a, b = np.abs(a), np.abs(b)
    return float(10 * np.log10(np.sum(np.abs(a - b) ** 2) / np.sum(np.abs(b) ** 2)))


def reflector(sm: StripMap) -> dict:
    """The corner reflector's cross-range half-power width (mm) and peak (dB of the map's largest pixel)."""
    from imaging import metrics

    img, x, y = sm.mosaic()
    got = metrics.analyze_target(img, x, y, (0.0, 1.0), near_m=REFLECTOR_XY_M, radius_m=0.05, half_length_m=0.1)
    return {"cross_range_width_mm": 1e3 * got["cross_range"]["half_power_width_m"],
            "peak_amplitude": got["peak_amplitude"], "peak_m": got["peak_m"]}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames and settings")
    args = ap.parse_args(argv)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    work = Path(tempfile.mkdtemp(prefix="sarbot-bench-stripmap-ffbp-"))
    path = work / "demo_room.h5"
    print("simulating the demo scene ...", flush=True)
    simulate_recording(load_scene("demo_room"), path)
    rec = Recording(path)
    truth = rec.truth()
    radar, order = rec.radar(RADAR), rec.tdm_tx_order(RADAR)
    times = rec.frame_time_ns(RADAR)
    first = int((6.8 if args.quick else 2.4) / 0.052)  # moving (from 2 s); quick: passing the reflector
    count = 40 if args.quick else times.size - first
    frames = [(rec.adc(RADAR, slice(k, k + 1))[0], int(times[k])) for k in range(first, first + count)]
    ends = [StripMap(BASE).frame_profiles(radar, order, frames[i][0], frames[i][1], truth) for i in (0, -1)]
    track_x = [float(np.mean(0.5 * (e[1][:, 0] + e[2][:, 0]))) for e in ends]  # the radar's first and last x
    radar_fps = 1 / radar.waveform.frame_interval_s
    apertures = [0.3, 1.0] if args.quick else [0.3, 0.5, 1.0, 2.0]
    blocks = [8] if args.quick else [4, 8, 16]
    rows = []
    for aperture in apertures:
        direct_cfg = dataclasses.replace(BASE, aperture_m=aperture)
        direct, direct_s = run(direct_cfg, radar, order, frames, truth)
        direct_fps = len(frames) / direct_s
        target = reflector(direct)
        rows.append({"aperture_m": aperture, "algorithm": "direct", "block_frames": 1, "frames_per_s": direct_fps,
                     "radar_real_time_multiple": direct_fps / radar_fps, "ratio_to_baseline": 1.0,
                     "reflector_cross_range_width_mm": target["cross_range_width_mm"]})
        print(f"aperture {aperture:3.1f} m  direct       {direct_fps:7.1f} frames/s ({direct_fps / radar_fps:5.2f}x one radar)",
              flush=True)
        for b in blocks:
            cfg = dataclasses.replace(direct_cfg, algorithm="ffbp", ffbp_block_frames=b)
            sm, secs = run(cfg, radar, order, frames, truth)
            fps = len(frames) / secs
            own = error_db(sm, block_reference(cfg, radar, order, frames, truth))
            block_m = 0.4 * b * radar.waveform.frame_interval_s
            whole = (track_x[0] + aperture / 2 + block_m, track_x[1] - aperture / 2 - block_m)
            total = error_db(sm, direct, whole) if whole[1] > whole[0] else None
            shown = error_db(sm, direct, whole, magnitude=True) if whole[1] > whole[0] else None
            got = reflector(sm)
            rows.append({"aperture_m": aperture, "algorithm": "ffbp", "block_frames": b, "frames_per_s": fps,
                         "radar_real_time_multiple": fps / radar_fps, "ratio_to_baseline": fps / direct_fps,
                         "ffbp_error_db": own, "ffbp_error_bound_db": sm.ffbp_error_bound_db,
                         "ffbp_error_estimate_db": sm.ffbp_error_estimate_db, "error_vs_direct_db": total,
                         "ffbp_levels": sm.ffbp_levels, "ffbp_blocks_direct": sm.ffbp_blocks_direct,
                         "magnitude_error_vs_direct_db": shown,
                         "whole_aperture_x_m": list(whole) if total is not None else None,
                         "reflector_cross_range_width_mm": got["cross_range_width_mm"],
                         "reflector_peak_db_vs_direct": float(20 * np.log10(got["peak_amplitude"] / target["peak_amplitude"])),
                         "reflector_peak_offset_mm": float(1e3 * np.hypot(*np.subtract(got["peak_m"], target["peak_m"])))})
            vs = "n/a (no pixel has its whole aperture)" if total is None else f"{total:6.1f} dB (magnitude {shown:6.1f} dB)"
            print(f"aperture {aperture:3.1f} m  ffbp block {b:2d} {fps:7.1f} frames/s ({fps / direct_fps:5.2f}x direct), "
                  f"error {own:6.1f} dB (bound {sm.ffbp_error_bound_db:5.1f}), against the direct map {vs}, reflector "
                  f"{got['cross_range_width_mm']:.1f} mm wide (direct {target['cross_range_width_mm']:.1f})", flush=True)
    summary = {
        "scene": "demo_room", "radar": RADAR, "frames": len(frames), "radar_frames_per_s": radar_fps,
        "four_radars_frames_per_s": 4 * radar_fps, "settings": dataclasses.asdict(BASE), "kernel_threads": 1,
        "baseline": "the direct kernel at the same aperture, in the same process", "rows": rows,
    }
    stem = "stripmap_ffbp_quick" if args.quick else "stripmap_ffbp"  # a smoke run keeps the real figures
    write_results(stem, summary, started_load=started_load)
    plot(rows, radar_fps, RESULTS / f"{stem}.png")
    rec.close()
    path.unlink()
    print(f"wrote {RESULTS / (stem + '.json')}")
    return 0


def plot(rows, radar_fps: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    apertures = sorted({r["aperture_m"] for r in rows})
    for label, pick, style in [("direct", lambda r: r["algorithm"] == "direct", "k-o")] + [
            (f"ffbp, {b}-frame blocks", (lambda b: lambda r: r["algorithm"] == "ffbp" and r["block_frames"] == b)(b), f"C{i}-s")
            for i, b in enumerate(sorted({r["block_frames"] for r in rows if r["algorithm"] == "ffbp"}))]:
        sel = [r for r in rows if pick(r)]
        ax.plot([r["aperture_m"] for r in sel], [r["frames_per_s"] for r in sel], style, label=label)
        for r in sel:
            if r["algorithm"] == "ffbp":
                ax.annotate(f"{r['ffbp_error_db']:.0f} dB", (r["aperture_m"], r["frames_per_s"]), fontsize=7,
                            xytext=(4, 2), textcoords="offset points")
    for fps, text in ((radar_fps, "one radar, real time"), (4 * radar_fps, "four radars, real time")):
        ax.axhline(fps, color="grey", ls="--", lw=1)
        ax.text(apertures[0], fps, text, va="bottom", fontsize=8)
    ax.set_yscale("log")
    ax.set_xlabel("synthetic aperture per pixel, m (4 mm pixels)")
    ax.set_ylabel("frames per second, one kernel thread")
    ax.set_title("live strip map: direct kernel against FFBP blocks (labels: FFBP's own error)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
