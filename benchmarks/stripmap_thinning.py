"""What the live map's catch-up costs the image and saves in CPU: pre-summing all of a TX's chirps, then
summing each TX's RX channels, then imaging one frame of a radar in 2 or 4 (weighted by that factor), each
against every frame at the default pre-summing.

    python benchmarks/stripmap_thinning.py

Data: the demo scene (the left-front radar at 0.4 m/s past the rod and the reflector), simulated once; 60
frames over the targets, placed on the true trajectory (the odometry's errors are another question). Each
step of the catch-up ladder images the frames as the live worker would, frame by frame, one frame in ``k``
kept (every phase of the ``k`` is imaged and the worst is reported). Per step: the map's error energy against
the reference (every frame, default pre-summing), dB; for each rod or reflector in the map, its peak
amplitude as a ratio to the reference's, the shift of its peak, its cross-range width, peak side lobe and
SNR; and the CPU per frame of sensor data (process time / frames the radar sent; one frame per call, int16
I/Q as received, the kernel on one thread as the live worker runs it, one run: a guide, benchmarks/stripmap.py
measures speed), with the reference's as the baseline ratio. Writes docs/results/stripmap_thinning.json and
.png (the maps side by side).
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
sys.path.insert(0, str(ROOT))

from acquisition.studies.common import label_of, target_xy  # noqa: E402
from imaging import metrics  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.sim.targets import CornerReflector, Rod  # noqa: E402
from imaging.stripmap import StripMap, StripMapConfig, max_presum  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RADAR = "left_front"
CONFIG = StripMapConfig(aperture_m=0.3, range_min_m=1.0, range_max_m=4.0, z_m=0.3)


def image(rec: Recording, frames: range, presum: int, thinning: int, phase: int, sum_rx: bool = False) -> tuple[StripMap, float]:
    """The map of ``frames`` keeping one in ``thinning`` (from ``phase``), each kept frame weighted by it,
    and the process CPU it took, s."""
    radar, order, truth = rec.radar(RADAR), rec.tdm_tx_order(RADAR), rec.truth()
    sm = StripMap(dataclasses.replace(CONFIG, presum=presum))
    times = rec.frame_time_ns(RADAR)
    kept = [k for k in frames if (k - frames.start) % thinning == phase]
    iq = rec.adc_iq(RADAR, slice(frames.start, frames.stop))  # int16 I/Q pairs, as frames arrive live
    c0 = time.process_time()
    for k in kept:
        sm.add_frames(radar, order, [iq[k - frames.start]], [int(times[k])], truth, weight=float(thinning), sum_rx=sum_rx)
    return sm, time.process_time() - c0


def error_db(img: np.ndarray, ref: np.ndarray) -> float:
    return float(10 * np.log10(np.sum(np.abs(img - ref) ** 2) / np.sum(np.abs(ref) ** 2)))


def on_grid(sm: StripMap, ref: StripMap) -> np.ndarray:
    """``sm``'s mosaic on ``ref``'s pixels (a thinned map may reach fewer tiles; those pixels are zero)."""
    img, x, y = sm.mosaic()
    r, xr, yr = ref.mosaic()
    out = np.zeros_like(r)
    ix0, iy0 = int(round((x[0] - xr[0]) / CONFIG.pixel_m)), int(round((y[0] - yr[0]) / CONFIG.pixel_m))
    out[max(iy0, 0):iy0 + img.shape[0], max(ix0, 0):ix0 + img.shape[1]] = \
        img[max(-iy0, 0):r.shape[0] - iy0, max(-ix0, 0):r.shape[1] - ix0]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="accepted from `dev.py bench --quick`: this benchmark has one mode")
    ap.parse_args()
    import numba

    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    numba.set_num_threads(1)  # as the live worker runs its kernel
    scene = load_scene("demo_room")
    work = Path(tempfile.mkdtemp(prefix="sarbot-bench-thinning-"))
    path = work / "demo_room.h5"
    print("simulating the demo scene ...", flush=True)
    simulate_recording(scene, path)
    rec = Recording(path)
    radar = rec.radar(RADAR)
    wf = radar.waveform
    first = int(3.2 / 0.052)  # driving at full speed, the rod and reflector in the beam of the left radars
    frames = range(first, first + 60)
    auto = max_presum(CONFIG, radar, 0.5)
    all_chirps = wf.chirps_per_frame // wf.n_tx
    image(rec, range(first, first + 2), auto, 1, 0)  # compile
    ref, ref_cpu = image(rec, frames, auto, 1, 0)
    r, xr, yr = ref.mosaic()
    # the map lies in the recording's world frame, the scene's: the targets where the scene puts them, those
    # the frames mapped
    targets = [(label_of(t), np.array(target_xy(t))) for t in scene.targets if isinstance(t, (Rod, CornerReflector))
               and xr[0] + 0.2 < target_xy(t)[0] < xr[-1] - 0.2 and yr[0] + 0.2 < target_xy(t)[1] < yr[-1] - 0.2]
    assert targets, "no rod or reflector in the mapped frames' footprint"
    steps = [("every frame, presum %d (reference)" % auto, auto, False, 1),
             (f"every frame, presum {all_chirps} (all chirps)", all_chirps, False, 1),
             (f"every frame, presum {all_chirps}, RX summed", all_chirps, True, 1),
             (f"1 in 2, presum {all_chirps}, RX summed", all_chirps, True, 2),
             (f"1 in 4, presum {all_chirps}, RX summed", all_chirps, True, 4)]
    rows, panels = [], []
    for label, presum, sum_rx, thinning in steps:
        worst = None
        for phase in range(thinning):
            sm, cpu = (ref, ref_cpu) if (presum, sum_rx, thinning) == (auto, False, 1) else \
                image(rec, frames, presum, thinning, phase, sum_rx)
            img = on_grid(sm, ref)
            row = {"step": label, "presum": presum, "rx_summed": sum_rx, "thinning": thinning, "phase": phase,
                   "cpu_ms_per_sensor_frame": 1e3 * cpu / len(frames), "cpu_ratio_to_reference": ref_cpu / cpu,
                   "error_db": None if sm is ref else error_db(img, r),
                   "targets": {}}
            for name, p in targets:
                a_ref = metrics.analyze_target(r, xr, yr, (0.0, 1.0), near_m=(p[0], p[1]), radius_m=0.1, half_length_m=0.15)
                a = metrics.analyze_target(img, xr, yr, (0.0, 1.0), near_m=(p[0], p[1]), radius_m=0.1, half_length_m=0.15)
                row["targets"][name] = {
                    "peak_ratio_to_reference": a["peak_amplitude"] / a_ref["peak_amplitude"],
                    "peak_shift_m": float(np.hypot(a["peak_m"][0] - a_ref["peak_m"][0], a["peak_m"][1] - a_ref["peak_m"][1])),
                    "cross_range_width_m": a["cross_range"]["half_power_width_m"],
                    "cross_range_pslr_db": a["cross_range"]["pslr_db"],
                    "snr_db": a["snr_db"]}
            if worst is None or (row["error_db"] or -np.inf) > (worst[0]["error_db"] or -np.inf):
                worst = (row, img)
        rows.append(worst[0])
        panels.append((label, worst[1]))
        t = worst[0]["targets"]
        print(f"{label:38s} error {worst[0]['error_db'] or -np.inf:6.1f} dB  CPU {worst[0]['cpu_ms_per_sensor_frame']:5.2f} ms/frame "
              f"({worst[0]['cpu_ratio_to_reference']:.1f}x)  "
              + "  ".join(f"{n}: peak {v['peak_ratio_to_reference']:.2f}, PSLR {v['cross_range_pslr_db']:.1f} dB"
                          for n, v in t.items()), flush=True)
    result = {"radar": RADAR, "frames": len(frames), "aperture_m": CONFIG.aperture_m, "pixel_m": CONFIG.pixel_m,
              "speed_mps": 0.4, "frame_spacing_m": 0.4 * wf.frame_interval_s, "rows": rows}
    write_results("stripmap_thinning", result, started_load=started_load, indent=1)
    chart(panels, xr, yr, targets, RESULTS / "stripmap_thinning.png")
    print(f"wrote {RESULTS / 'stripmap_thinning.json'} and stripmap_thinning.png")
    rec.close()
    return 0


def chart(panels, x, y, targets, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    peak = max(np.abs(img).max() for _, img in panels)
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 4.4), sharex=True, sharey=True)
    for ax, (label, img) in zip(axes, panels):
        db = 20 * np.log10(np.abs(img) / peak + 1e-12)
        ax.imshow(db, origin="lower", extent=(x[0], x[-1], y[0], y[-1]), vmin=-40, vmax=0, cmap="viridis")
        for _, p in targets:
            ax.plot(p[0], p[1], "r+", ms=10)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("x, m")
    axes[0].set_ylabel("y, m")
    fig.suptitle("live map catch-up: pre-summing all chirps, then 1 frame in 2 or 4 (dB to the reference's peak)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
