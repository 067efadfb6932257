"""The live map's work per frame, stage by stage, and what the "polar" path (each frame through its own
beams, ``imaging.stripmap.polar``) does to it and to the image.

    python benchmarks/stripmap_polar.py [--frames 60] [--repeats 3]

Data: the soak's scene (``soak_loop``: the reference waveform, 0.4 m/s, corner reflectors and clutter), the
left-front radar only, its first 9 s simulated once; frames from the first straight (the robot driving at
full speed, a reflector in the beam), as ``sarbot run`` maps them by default (``--map-aperture 0.3``,
``--map-pixel 0.01``, ``--map-range 1:4``, ``--map-presum auto`` at ``--max-speed 0.5``), int16 I/Q as they
arrive, the kernel on one thread as the live worker runs it.

Work per frame (process CPU, the best of ``--repeats`` runs, the two paths interleaved): pre-summing, antenna
placement, range compression, footprint (tiles and pixel masks), pixel lists, backprojection, tile updates;
for "polar" the beams (weights, one product, beam compression) and reading them at the pixels. Beside
them, what a refocusing map adds (the group images, direct kernel) and what publishing costs (the mosaic,
and one tile's message as the worker sends changed tiles twice a second). Then the whole ``add_frames`` of
both paths, interleaved in one process (a ratio: the machine's load cancels), one frame at a time and 8
together as a worker behind takes them, at the configured pre-summing and at the catch-up's (all of a
TX's chirps, then RX summed). Quality: each map against the map of every frame at presum 1 by the direct
kernel (correlation, error energy), and at the reflector its peak amplitude (ratio to that reference),
position, range and cross-range widths and peak side lobes. The load average is recorded.

Writes docs/results/stripmap_polar.json.
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
sys.path.insert(0, str(ROOT))

from imaging import metrics  # noqa: E402
from imaging.backprojection import backproject  # noqa: E402
from imaging.core.geometry import antenna_track  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.profiles import chirp_profiles  # noqa: E402
from imaging.sim.scene import load_scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.sim.targets import CornerReflector  # noqa: E402
from imaging.stripmap import StripMap, StripMapConfig, max_presum, presum_chirps  # noqa: E402
from imaging.stripmap.polar import beams_at_points, frame_beams  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RADAR = "left_front"
CONFIG = StripMapConfig(aperture_m=0.3, pixel_m=0.01, range_min_m=1.0, range_max_m=4.0, z_m=0.3)
FIRST_FRAME = 50  # the robot at full speed on the first straight


class Stages:
    """CPU seconds per named stage, summed."""

    def __init__(self):
        self.s: dict[str, float] = {}
        self._t = time.process_time()

    def lap(self, name: str) -> None:
        t = time.process_time()
        self.s[name] = self.s.get(name, 0.0) + t - self._t
        self._t = t


def frame_stages(sm: StripMap, radar, order, adc, t_ns: int, truth, polar: bool, st: Stages) -> None:
    """One frame through the map's stages as ``StripMap.add_frames`` runs them (one frame, no refocus)."""
    cfg, wf = sm.config, radar.waveform
    st.lap("other")
    sums, groups, tx_index = presum_chirps(adc, order, wf.n_tx, cfg.presum)
    offsets = np.round(np.arange(wf.chirps_per_frame) * wf.chirp_interval_s * 1e9).astype(np.int64)
    times = t_ns + offsets[groups].mean(axis=1).round().astype(np.int64)
    st.lap("presum")
    track = antenna_track(radar, truth, times, tx_index)
    st.lap("antenna placement")
    n = sums.shape[1]
    tx = np.repeat(track.tx_m, n, axis=0)
    rx = track.rx_m.reshape(-1, 3)
    if not polar:
        formed = chirp_profiles(sums, times, tx_index, radar, truth, window=cfg.window, oversample=cfg.oversample,
                                keep_samples=False)
        st.lap("range compression (with a second antenna placement)")
        profiles = formed.profiles
    look = track.boresight[:, :2].mean(axis=0)
    look /= np.linalg.norm(look)
    centre = (0.5 * (tx + rx))[:, :2].mean(axis=0)
    taken = sm._footprints(centre[None], look[None])
    touched, masks = taken.keys, taken.masks
    st.lap("footprint (tiles, pixel masks)")
    pts, where = [], []
    for key, mask in zip(touched, masks):
        x, y = sm.tile_points(key)
        iy, ix = np.nonzero(mask[0])
        pts.append(np.stack([x[ix], y[iy], np.full(iy.size, cfg.z_m)], axis=1))
        where.append((key, mask[0], iy.size))
    pts = np.concatenate(pts)
    st.lap("pixel lists")
    if polar:
        beams = frame_beams(sums.reshape(-1, wf.samples_per_chirp), tx, rx, pts, wf.f0_hz, wf.frequency_step_hz,
                            cfg.window, cfg.oversample, look)
        st.lap("beams (weights, product, beam compression)")
        values = beams_at_points(beams, pts)
        st.lap("beams read at the pixels")
    else:
        values = backproject(profiles, tx, rx, pts, mode=cfg.mode)
        st.lap("backprojection (pixels x profiles)")
    start = 0
    for key, taken, m in where:
        sm._tile(key)[taken] += values[start:start + m]
        start += m
    st.lap("tile updates")


def stage_breakdown(rec, frames, presum, repeats) -> dict:
    radar, order, truth = rec.radar(RADAR), rec.tdm_tx_order(RADAR), rec.truth()
    iq, times = rec.adc_iq(RADAR, slice(frames.start, frames.stop)), rec.frame_time_ns(RADAR)
    best = {}
    cfg = dataclasses.replace(CONFIG, presum=presum)
    for _ in range(repeats):
        for name, polar in (("direct", False), ("polar", True)):
            st = Stages()
            sm = StripMap(cfg)
            for k in frames:
                frame_stages(sm, radar, order, iq[k - frames.start], int(times[k]), truth, polar, st)
            st.lap("other")
            per = {s: 1e3 * v / len(frames) for s, v in st.s.items() if s != "other"}
            if name not in best or sum(per.values()) < sum(best[name].values()):
                best[name] = per
    # What a refocusing map adds per frame (its group images by the direct kernel) and what publishing costs.
    sm = StripMap(dataclasses.replace(cfg, algorithm="direct", refocus="pga"))
    c0 = time.process_time()
    for k in frames:
        sm.add_frames(radar, order, [iq[k - frames.start]], [int(times[k])], truth)
    refocus_ms = 1e3 * (time.process_time() - c0) / len(frames)
    c0 = time.process_time()
    for _ in range(10):
        sm.mosaic()
    mosaic_ms = 1e3 * (time.process_time() - c0) / 10
    from acquisition.messages import MapTile

    key = next(iter(sm.tiles))
    c0 = time.process_time()
    for _ in range(100):
        MapTile(key, cfg.pixel_m, cfg.tile_px, sm.tiles[key]).to_parts()
    tile_message_ms = 1e3 * (time.process_time() - c0) / 100
    out = {n: {"stages_ms": v, "total_ms": sum(v.values())} for n, v in best.items()}
    out["refocusing_map_add_frames_ms"] = refocus_ms
    out["mosaic_ms_per_call"] = mosaic_ms
    out["tile_message_ms"] = tile_message_ms
    out["tiles_in_map"] = len(sm.tiles)
    return out


def whole_ratio(rec, frames, presum, batch, sum_rx, repeats) -> dict:
    """CPU per frame of ``add_frames`` for "direct" and "polar", interleaved, best of ``repeats``."""
    radar, order, truth = rec.radar(RADAR), rec.tdm_tx_order(RADAR), rec.truth()
    iq, times = rec.adc_iq(RADAR, slice(frames.start, frames.stop)), rec.frame_time_ns(RADAR)
    cpu = {"direct": [], "polar": []}
    for _ in range(repeats):
        for name in cpu:
            sm = StripMap(dataclasses.replace(CONFIG, presum=presum, algorithm=name))
            c0 = time.process_time()
            for a in range(0, len(frames), batch):
                ks = list(frames)[a:a + batch]
                sm.add_frames(radar, order, [iq[k - frames.start] for k in ks], [int(times[k]) for k in ks], truth,
                              sum_rx=sum_rx)
            cpu[name].append(1e3 * (time.process_time() - c0) / len(frames))
    d, p = min(cpu["direct"]), min(cpu["polar"])
    return {"presum": presum, "batch_frames": batch, "rx_summed": sum_rx, "direct_cpu_ms_per_frame": d,
            "polar_cpu_ms_per_frame": p, "ratio_direct_to_polar": d / p,
            "ratios_each_round": [a / b for a, b in zip(cpu["direct"], cpu["polar"])]}


def quality(rec, frames, presum) -> dict:
    """Each map against every frame at presum 1 by the direct kernel."""
    radar, order, truth = rec.radar(RADAR), rec.tdm_tx_order(RADAR), rec.truth()
    iq, times = rec.adc_iq(RADAR, slice(frames.start, frames.stop)), rec.frame_time_ns(RADAR)
    maps = {}
    for name, alg, p in (("direct, presum 1 (reference)", "direct", 1), (f"direct, presum {presum}", "direct", presum),
                         (f"polar, presum {presum}", "polar", presum), ("polar, presum 1", "polar", 1)):
        sm = StripMap(dataclasses.replace(CONFIG, presum=p, algorithm=alg))
        for k in frames:
            sm.add_frames(radar, order, [iq[k - frames.start]], [int(times[k])], truth)
        maps[name] = sm.mosaic()
    ref, x, y = maps["direct, presum 1 (reference)"]
    scene = load_scene("soak_loop")
    reflectors = [np.asarray(t.position_m[:2]) for t in scene.targets if isinstance(t, CornerReflector)
                  and x[0] + 0.2 < t.position_m[0] < x[-1] - 0.2 and y[0] + 0.2 < t.position_m[1] < y[-1] - 0.2]
    rows = {}
    for name, (img, xi, yi) in maps.items():
        assert img.shape == ref.shape and np.allclose(xi, x) and np.allclose(yi, y)
        row = {"correlation": float(np.abs(np.vdot(ref, img)) / (np.linalg.norm(ref) * np.linalg.norm(img))),
               "error_db": None if img is ref else float(10 * np.log10(np.sum(np.abs(img - ref) ** 2) / np.sum(np.abs(ref) ** 2))),
               "reflectors": []}
        for p in reflectors:
            a_ref = metrics.analyze_target(ref, x, y, (0.0, 1.0), near_m=tuple(p), radius_m=0.15, half_length_m=0.3)
            a = metrics.analyze_target(img, x, y, (0.0, 1.0), near_m=tuple(p), radius_m=0.15, half_length_m=0.3)
            row["reflectors"].append({
                "position_m": p.tolist(), "peak_ratio_to_reference": a["peak_amplitude"] / a_ref["peak_amplitude"],
                "peak_shift_m": float(np.hypot(*(np.array(a["peak_m"]) - a_ref["peak_m"]))),
                **{f"{c}_{m}": a[c][m] for c in ("range", "cross_range") for m in ("half_power_width_m", "pslr_db")}})
        rows[name] = row
    return rows


def main(argv: list[str]) -> int:
    import numba

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    numba.set_num_threads(1)  # as the live worker runs its kernel
    scene = dataclasses.replace(load_scene("soak_loop"), radars=[RADAR], duration_s=9.0, imu=False)
    work = Path(tempfile.mkdtemp(prefix="sarbot-bench-polar-"))
    path = work / "soak_loop_left_front.h5"
    print("simulating the soak scene's first 9 s, left-front radar ...", flush=True)
    simulate_recording(scene, path)
    rec = Recording(path)
    radar = rec.radar(RADAR)
    presum = max_presum(CONFIG, radar, 0.5)
    all_chirps = radar.waveform.chirps_per_frame // radar.waveform.n_tx
    frames = range(FIRST_FRAME, FIRST_FRAME + args.frames)
    load_before = os.getloadavg()
    whole_ratio(rec, range(FIRST_FRAME, FIRST_FRAME + 2), presum, 1, False, 1)  # compile
    print("stages ...", flush=True)
    stages = stage_breakdown(rec, frames, presum, args.repeats)
    print({n: round(v["total_ms"], 2) for n, v in stages.items() if isinstance(v, dict)}, flush=True)
    print("whole add_frames, interleaved ...", flush=True)
    ratios = [whole_ratio(rec, frames, p, b, rx, args.repeats)
              for p, b, rx in ((presum, 1, False), (presum, 8, False), (all_chirps, 8, False), (all_chirps, 8, True))]
    for r in ratios:
        print(r, flush=True)
    print("quality ...", flush=True)
    q = quality(rec, frames, presum)
    out = {"scene": "soak_loop (first 9 s)", "radar": RADAR, "frames": args.frames, "first_frame": FIRST_FRAME,
           "presum_configured": presum, "pixel_m": CONFIG.pixel_m, "aperture_m": CONFIG.aperture_m,
           "range_m": [CONFIG.range_min_m, CONFIG.range_max_m], "stages": stages, "add_frames": ratios, "quality": q,
           "load_average_before": list(load_before), "load_average_after": list(os.getloadavg()),
           "cpu_count": os.cpu_count()}
    write_results("stripmap_polar", out, started_load=started_load, indent=1)
    print(f"wrote {RESULTS / 'stripmap_polar.json'}")
    rec.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
