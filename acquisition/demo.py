"""``sarbot demo``: the built-in scene simulated, imaged and measured against theory.

Today this is the imaging demo (simulate -> backproject -> metrics); the strip-map issue turns it into
the whole live pipeline on emulated hardware.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from imaging import metrics
from imaging.geometry import antenna_track, chirp_times_ns
from imaging.grid import Grid
from imaging.image_formation import ImagingOptions, form_image
from imaging.imagefile import write_image
from imaging.plot import save_image_png
from imaging.recording import Recording
from imaging.scene import load_scene
from imaging.simulator import simulate_recording
from imaging.targets import CornerReflector, PointTarget, Rod

from .progress import Progress

log = logging.getLogger("sarbot.demo")

SCENE = "paper_pass_0.4"
RADAR = "left_front"
APERTURE_M = 0.34


def broadside_time_ns(rec: Recording, radar: str, target_xy) -> int:
    """Time at which the radar's phase centre passes the target (closest along-track approach)."""
    config = rec.radar(radar)
    times = rec.frame_time_ns(radar)
    track = antenna_track(config, rec.truth(), times, np.zeros(times.size, int))
    d = np.linalg.norm(track.tx_m[:, :2] - np.asarray(target_xy), axis=1)
    k = int(np.argmin(d))
    # Refine between frames with the chirp times around the closest frame.
    ct = chirp_times_ns(times[max(k - 1, 0):k + 2], config.waveform.chirps_per_frame, config.waveform.chirp_interval_s).ravel()
    fine = antenna_track(config, rec.truth(), ct, np.zeros(ct.size, int))
    return int(ct[np.argmin(np.linalg.norm(fine.tx_m[:, :2] - np.asarray(target_xy), axis=1))])


def _target_xy(target) -> tuple[float, float, str]:
    if isinstance(target, Rod):
        # The imaged scattering centre is the rod surface facing the radar.
        return target.position_m[0], target.position_m[1] - target.radius_m, "rod"
    if isinstance(target, CornerReflector):
        return target.position_m[0], target.position_m[1], "corner reflector"
    if isinstance(target, PointTarget):
        return target.position_m[0], target.position_m[1], "point"
    raise TypeError(type(target))


def run_demo(out_dir: Path) -> int:
    t_start = time.monotonic()
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = load_scene(SCENE)
    rec_path = out_dir / "recording.h5"
    print(f"sarbot demo: simulating scene {scene.name!r} ({scene.duration_s:.1f} s, radar {RADAR}, 0.4 m/s)")
    simulate_recording(scene, rec_path, progress=Progress("simulate"), overwrite=True)
    report: dict = {"scene": scene.name, "recording": str(rec_path), "targets": []}
    with Recording(rec_path) as rec:
        z = 0.3
        print("sarbot demo: backprojecting the whole pass (all 16 virtual channels)")
        grid = Grid.from_ranges((-1.0, 1.2, 0.004), (1.8, 2.2, 0.004), z)
        overview = form_image(rec, RADAR, grid, options=ImagingOptions(), progress=Progress("backproject"))
        write_image(out_dir / "image.h5", overview)
        marks = {}
        lines = []
        for target in scene.targets:
            tx, ty, label = _target_xy(target)
            marks[label] = (tx, ty)
            t_mid = broadside_time_ns(rec, RADAR, (tx, ty))
            half = int(APERTURE_M / (2 * scene.trajectory.speed_mps) * 1e9)
            zoom = Grid.from_ranges((tx - 0.1, tx + 0.1, 0.001), (ty - 0.15, ty + 0.15, 0.002), z)
            img = form_image(rec, RADAR, zoom, options=ImagingOptions(tx=(0,), rx=(0,)), time_window_ns=(t_mid - half, t_mid + half))
            name = label.replace(" ", "_")
            write_image(out_dir / f"{name}.h5", img)
            save_image_png(out_dir / f"{name}.png", img.image, img.x_m, img.y_m, title=f"{label}, aperture {img.attrs['aperture_length_m']:.2f} m")
            a = metrics.analyze_target(img.image, img.x_m, img.y_m, img.attrs["look_direction"])
            centre = img.attrs["aperture_centre_m"]
            r0 = float(np.hypot(a["peak_m"][0] - centre[0], a["peak_m"][1] - centre[1]))
            th_r = metrics.range_resolution_theory_m(img.attrs["bandwidth_hz"], "hann")
            th_x = metrics.cross_range_resolution_theory_m(img.attrs["wavelength_m"], r0, img.attrs["aperture_length_m"])
            entry = {
                "target": label, "true_position_m": [tx, ty], "peak_m": a["peak_m"], "range_m": r0,
                "aperture_length_m": img.attrs["aperture_length_m"],
                "range_width_m": a["range"]["half_power_width_m"], "range_width_theory_m": th_r,
                "cross_range_width_m": a["cross_range"]["half_power_width_m"], "cross_range_width_theory_m": th_x,
                "cross_range_pslr_db": a["cross_range"]["pslr_db"], "snr_db": a["snr_db"],
            }
            report["targets"].append(entry)
            lines.append(
                f"  {label:17s} at ({a['peak_m'][0]:+.3f}, {a['peak_m'][1]:.3f}) m, r0 {r0:.3f} m: "
                f"range width {100 * entry['range_width_m']:.2f} cm (theory {100 * th_r:.2f}), "
                f"cross-range {100 * entry['cross_range_width_m']:.2f} cm (theory {100 * th_x:.2f}, La {entry['aperture_length_m']:.2f} m)"
            )
        save_image_png(out_dir / "image.png", overview.image, overview.x_m, overview.y_m,
                       title=f"{scene.name}: whole pass, {overview.attrs['n_frames']} frames, 16 channels", marks=marks)
    report["elapsed_s"] = time.monotonic() - t_start
    (out_dir / "report.json").write_text(json.dumps(report, indent=2, default=lambda o: np.asarray(o).tolist()))
    print("sarbot demo: half-power widths against theory (one TX/RX pair, aperture %.2f m):" % APERTURE_M)
    print("\n".join(lines))
    print(f"sarbot demo: done in {report['elapsed_s']:.0f} s. Wrote to {out_dir.resolve()}/:")
    for name in ("recording.h5", "image.h5", "image.png", "rod.png", "corner_reflector.png", "report.json"):
        print(f"  {name}")
    return 0
