"""Backprojection speed against accuracy.

For each interpolation mode and thread count: throughput in backprojections per second (one grid point x
one profile), as a ratio to the plain numpy reference run in the same process, and the image's
signal-to-error ratio against the exact matched filter. Also: what naive float32 geometry would do 5 km
from the origin (sarbot's block-relative float32 does not lose it), the cost of handing ``backproject``
profiles that are not in its guarded layout (one copy per call), a measured floor for the two unavoidable
parts of the kernel (float64 geometry, the gather), and, where torch and torchbp are importable
(benchmarks/README.md says how to install them), torchbp's Cartesian CPU kernel on the same problem.

    python benchmarks/backprojection.py [--quick]

Writes docs/results/backprojection.json and docs/results/backprojection.png.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from reference_backprojection import backproject_reference  # noqa: E402

from imaging.backprojection import BLOCK, backproject  # noqa: E402
from imaging.core.geometry import antenna_track, chirp_times_ns  # noqa: E402
from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import StraightLine  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402
from imaging.sim.simulator import simulate_frames  # noqa: E402
from imaging.sim.targets import PointTarget  # noqa: E402
from results_file import finite_or_none, load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def make_case(n_frames: int, nx: int, ny: int, origin=(0.0, 0.0)):
    """A 0.4 m/s pass of the left-front radar past five point targets: all 16 channels, real TDM timing."""
    radar = default_rig().radar("left_front")
    wf = radar.waveform
    ox, oy = origin
    traj = StraightLine(start_m=(ox - 0.15 - 0.4 * n_frames * wf.frame_interval_s / 2, oy - 0.2, 0.0), speed_mps=0.4)
    targets = [PointTarget((ox + dx, oy + 2.0 + dy, 0.3)) for dx, dy in [(0, 0), (-0.2, 0.1), (0.25, -0.2), (0.1, 0.3), (-0.3, -0.3)]]
    ft = np.arange(n_frames, dtype=np.int64) * int(wf.frame_interval_s * 1e9)
    adc = simulate_frames(radar, traj, targets, ft, snr_db=0.0, rng=np.random.default_rng(0))
    times = chirp_times_ns(ft, wf.chirps_per_frame, wf.chirp_interval_s).ravel()
    tx_index = np.tile(wf.tdm_tx_order(), n_frames)
    track = antenna_track(radar, traj, times, tx_index)
    samples = adc.reshape(-1, wf.samples_per_chirp)
    tx = np.repeat(track.tx_m, wf.n_rx, axis=0)
    rx = track.rx_m.reshape(-1, 3)
    x = ox + np.linspace(-0.5, 0.5, nx)
    y = oy + np.linspace(1.5, 2.5, ny)
    xx, yy = np.meshgrid(x, y)
    grid = np.stack([xx, yy, np.full_like(xx, 0.3)], axis=-1)
    return samples, wf, tx, rx, grid


def best_time(fn, repeats: int) -> float:
    fn()  # compile / warm
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def ser_db(image, exact) -> float:
    return float(20 * np.log10(np.linalg.norm(exact) / np.linalg.norm(image - exact)))


# -- floors: the two parts every backprojection must do ------------------------------------------------
@numba.njit(parallel=True, fastmath=True)
def _geometry_floor(tx, rx, gx, gy, gz, out):
    n_g = gx.size
    for blk in numba.prange((n_g + BLOCK - 1) // BLOCK):
        g0 = blk * BLOCK
        nb = min(g0 + BLOCK, n_g) - g0
        acc = np.zeros(nb)
        bx, by, bz = gx[g0:g0 + nb], gy[g0:g0 + nb], gz[g0:g0 + nb]
        for p in range(tx.shape[0]):
            t0, t1, t2 = tx[p, 0], tx[p, 1], tx[p, 2]
            r0, r1, r2 = rx[p, 0], rx[p, 1], rx[p, 2]
            for i in range(nb):
                a0, a1, a2 = bx[i] - t0, by[i] - t1, bz[i] - t2
                b0, b1, b2 = bx[i] - r0, by[i] - r1, bz[i] - r2
                acc[i] += math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) + math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        for i in range(nb):
            out[g0 + i] += acc[i]


@numba.njit(parallel=True, fastmath=True)
def _gather_floor(rows, idx, out):
    n_g = idx.shape[1]
    for blk in numba.prange((n_g + BLOCK - 1) // BLOCK):
        g0 = blk * BLOCK
        nb = min(g0 + BLOCK, n_g) - g0
        v0 = np.empty(nb, np.complex64)
        v1 = np.empty(nb, np.complex64)
        for p in range(rows.shape[0]):
            row = rows[p]
            for i in range(nb):
                j = idx[p % idx.shape[0], g0 + i]
                v0[i] = row[j]
                v1[i] = row[j + np.uint32(1)]
            out[g0] += v0[nb - 1] + v1[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a smaller case (for a smoke run)")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    n_frames, nx, ny, repeats = (4, 128, 128, 2) if args.quick else (16, 256, 256, 3)
    samples, wf, tx, rx, grid = make_case(n_frames, nx, ny)
    n_p, n_g = tx.shape[0], nx * ny
    print(f"case: {n_p} profiles (chirps x RX) x {n_g} grid points = {n_p * n_g / 1e9:.2f} G backprojections")
    sub = grid.reshape(-1, 3)[:: max(1, n_g // 2048)]  # accuracy subset for the exact matched filter

    profiles = {os_: range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=os_, guarded=True)
                for os_ in (8, 16, 32, 64)}
    exact_sub = backproject(profiles[16], tx, rx, sub, mode="exact")

    # numpy reference: linear mode, on a slice of profiles (its cost is linear in both).
    ref_p = 64
    ref_prof = range_compress(samples[:ref_p], wf.f0_hz, wf.frequency_step_hz, oversample=16)
    t_ref = best_time(lambda: backproject_reference(ref_prof, tx[:ref_p], rx[:ref_p], grid, mode="linear"), 1)
    numpy_bps = ref_p * n_g / t_ref
    print(f"numpy reference (linear): {numpy_bps / 1e6:.1f} M backprojections/s")

    configs = [("nearest", 16), ("nearest", 64), ("linear", 8), ("linear", 16), ("linear", 32), ("exact", 16)]
    rows = []
    for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
        numba.set_num_threads(threads)
        for mode, os_ in configs:
            prof = profiles[os_]
            if mode == "exact":
                pts = sub
                t = best_time(lambda: backproject(prof, tx, rx, pts, mode=mode), 1)
                bps = n_p * pts.shape[0] / t
                err = float("inf")
            else:
                t = best_time(lambda: backproject(prof, tx, rx, grid, mode=mode), repeats)
                bps = n_p * n_g / t
                err = ser_db(backproject(prof, tx, rx, sub, mode=mode), exact_sub)
            # The exact mode is the reference itself: its SER (infinite) is written as None.
            row = {"mode": mode, "oversample": os_, "threads": threads, "backprojections_per_s": bps,
                   "speedup_vs_numpy": bps / numpy_bps, "ser_db": finite_or_none(err), "default": mode == "linear" and os_ == 16}
            rows.append(row)
            print(f"threads {threads}  {mode:8s} x{os_:<3d} {bps / 1e9:6.3f} G/s  {bps / numpy_bps:7.1f}x numpy  "
                  f"SER {err:6.1f} dB" + ("  (default)" if row["default"] else ""))

    # Floors on 2 threads: float64 geometry alone, the gather alone.
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    unguarded = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16)  # the kernel must copy these
    t_copy = best_time(lambda: backproject(unguarded, tx, rx, grid), repeats)
    default_t = n_p * n_g / next(r for r in rows if r["default"] and r["threads"] == min(2, numba.config.NUMBA_NUM_THREADS))["backprojections_per_s"]
    copy_cost = {"backprojections_per_s": n_p * n_g / t_copy, "slowdown": t_copy / default_t,
                 "profile_bytes": int(profiles[16].rows.nbytes)}
    print(f"profiles not in the guarded layout: {n_p * n_g / t_copy / 1e9:.3f} G/s ({t_copy / default_t:.2f}x the time: "
          f"a {profiles[16].rows.nbytes / 1e6:.0f} MB copy per call)")
    # The float32 block kernel against the float64 one it replaced, interleaved runs on the same profiles.
    import imaging.backprojection as bp_module

    budget = bp_module.PHASE_ROUNDING_RAD
    t32, t64 = [], []
    for _ in range(repeats + 1):
        t32.append(best_time(lambda: backproject(profiles[16], tx, rx, grid), 1))
        bp_module.PHASE_ROUNDING_RAD = 0.0  # no block qualifies: the float64 kernel
        t64.append(best_time(lambda: backproject(profiles[16], tx, rx, grid), 1))
        bp_module.PHASE_ROUNDING_RAD = budget
    bp_module.PHASE_ROUNDING_RAD = 0.0
    ser64 = ser_db(backproject(profiles[16], tx, rx, sub), exact_sub)
    bp_module.PHASE_ROUNDING_RAD = budget
    float32_vs_float64 = {"float32_blocks_per_s": n_p * n_g / min(t32), "float64_per_s": n_p * n_g / min(t64),
                          "speedup": min(t64) / min(t32), "ser_float32_blocks_db": default_ser(rows), "ser_float64_db": ser64}
    print(f"float32 block kernel {n_p * n_g / min(t32) / 1e9:.3f} G/s against the float64 kernel {n_p * n_g / min(t64) / 1e9:.3f} "
          f"G/s: {min(t64) / min(t32):.2f}x, SER {default_ser(rows):.2f} dB against {ser64:.2f} dB")
    torchbp = torchbp_comparison(profiles[16], tx, rx, grid, wf, sub, exact_sub, n_p * n_g / default_t, repeats)
    print("torchbp: " + (f"{torchbp['backprojections_per_s'] / 1e9:.3f} G/s, SER {torchbp['ser_db']:.1f} dB on its monostatic "
                         f"geometry ({torchbp['bistatic_magnitude_ser_db']:.1f} dB against the bistatic image); "
                         f"sarbot is {torchbp['sarbot_ratio']:.2f}x"
                         if "backprojections_per_s" in torchbp else torchbp["status"]))
    g = grid.reshape(-1, 3)
    gx, gy, gz = (np.ascontiguousarray(g[:, k]) for k in range(3))
    out = np.zeros(n_g)
    t_geo = best_time(lambda: _geometry_floor(tx, rx, gx, gy, gz, out), repeats)
    rows16 = np.zeros((n_p, profiles[16].n_bins + 3), np.complex64)
    rng = np.random.default_rng(1)
    idx = np.sort(rng.integers(0, profiles[16].n_bins, (64, n_g)).astype(np.uint32), axis=1)
    outc = np.zeros(n_g, np.complex64)
    t_gather = best_time(lambda: _gather_floor(rows16, idx, outc), repeats)
    floors = {"geometry_float64_per_s": n_p * n_g / t_geo, "gather_per_s": n_p * n_g / t_gather}
    floors["geometry_plus_gather_per_s"] = 1.0 / (1.0 / floors["geometry_float64_per_s"] + 1.0 / floors["gather_per_s"])
    print(f"floors (2 threads): geometry {floors['geometry_float64_per_s'] / 1e9:.2f} G/s, gather {floors['gather_per_s'] / 1e9:.2f} G/s, "
          f"both {floors['geometry_plus_gather_per_s'] / 1e9:.2f} G/s")

    # Far from the origin: float64 geometry (ours) against float32 geometry (what breaks).
    samples_far, _, tx_far, rx_far, grid_far = make_case(2, 32, 32, origin=(4000.0, 3000.0))
    samples_near, _, tx_near, rx_near, grid_near = make_case(2, 32, 32)
    prof_far = range_compress(samples_far, wf.f0_hz, wf.frequency_step_hz)
    prof_near = range_compress(samples_near, wf.f0_hz, wf.frequency_step_hz)
    near_img = backproject(prof_near, tx_near, rx_near, grid_near)
    far_img = backproject(prof_far, tx_far, rx_far, grid_far)
    far32 = backproject_reference(prof_far, tx_far.astype(np.float32).astype(np.float64), rx_far.astype(np.float32).astype(np.float64),
                                  grid_far.astype(np.float32).astype(np.float64))
    far_origin = {"ser_sarbot_db": ser_db(far_img, near_img), "ser_naive_float32_positions_db": ser_db(far32, near_img)}
    print(f"5 km from the origin: SER against the same scene at the origin: sarbot (float64 positions, block-relative "
          f"float32) {far_origin['ser_sarbot_db']:.1f} dB, naive float32 positions {far_origin['ser_naive_float32_positions_db']:.1f} dB")

    default2 = next(r for r in rows if r["default"] and r["threads"] == max(x["threads"] for x in rows))
    result = {
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(), "numba": numba.__version__,
                    "numpy": np.__version__},
        "case": {"profiles": n_p, "grid_points": n_g, "samples_per_chirp": wf.samples_per_chirp, "quick": args.quick},
        "numpy_reference_backprojections_per_s": numpy_bps,
        "torchbp": torchbp,
        "unguarded_profiles": copy_cost,
        "float32_blocks_vs_float64": float32_vs_float64,
        "results": rows,
        "floors": floors,
        "far_from_origin": far_origin,
        "default_mode": {"mode": "linear", "oversample": 16, "backprojections_per_s": default2["backprojections_per_s"],
                         "speedup_vs_numpy": default2["speedup_vs_numpy"], "ser_db": default2["ser_db"],
                         "vs_torchbp": torchbp.get("sarbot_ratio"),
                         "fraction_of_floor": default2["backprojections_per_s"] / floors["geometry_plus_gather_per_s"]},
    }
    name = "backprojection_quick" if args.quick else "backprojection"
    write_results(name, result, started_load=started_load)
    chart(rows, numpy_bps, floors, torchbp, RESULTS / f"{name}.png")
    print(f"wrote {RESULTS / (name + '.json')} and {name}.png")
    return 0


def default_ser(rows) -> float:
    return next(r["ser_db"] for r in rows if r["default"])


def torchbp_comparison(prof, tx, rx, grid, wf, sub, exact_sub, sarbot_bps: float, repeats: int) -> dict:
    """torchbp's Cartesian CPU kernel (``backprojection_cart_2d``, monostatic) on the same profiles: each
    profile from the midpoint of its TX and RX (the phase centre), the grid plane shifted to z = 0 as its
    kernel assumes; the conjugate profiles, for its phase convention. Its time; its accuracy as the SER of
    its image against sarbot's exact matched filter on the same monostatic geometry (``ser_db``); and what
    the monostatic approximation itself costs, as the SER of its image's magnitude against sarbot's exact
    bistatic image (``bistatic_magnitude_ser_db``)."""
    try:
        import torch
        import torchbp
    except ImportError as exc:
        return {"status": f"skipped: {exc.name} is not importable (see benchmarks/README.md to install torch and torchbp)"}
    try:
        z = float(grid[0, 0, 2])
        pos = torch.from_numpy(((tx + rx) / 2 - [0.0, 0.0, z]).astype(np.float32))
        # torchbp multiplies by exp(+j 4 pi fc d / c) where sarbot (docs/signal-model.md) multiplies by exp(-j 2 pi fc r / c):
        # its data carry the conjugate phase, so it is given the conjugate profiles (its image is then the
        # conjugate of sarbot's, with the same magnitude).
        data = torch.from_numpy(np.conj(prof.data))
        x, y = grid[0, :, 0], grid[:, 0, 1]
        # torchbp's pixel i is at x0 + i * (x1 - x0) / nx: so x1 is one step past the last pixel.
        cart = {"x": (float(x[0]), float(x[0] + x.size * (x[1] - x[0]))),
                "y": (float(y[0]), float(y[0] + y.size * (y[1] - y[0]))), "nx": x.size, "ny": y.size}
        torch.set_num_threads(min(2, os.cpu_count() or 1))
        kw = dict(fc=prof.carrier_hz, r_res=prof.range_step_m / 2, pos=pos, d0=-prof.range_start_m / 2)

        def run():
            return torchbp.ops.backprojection_cart_2d(data, cart, **kw)

        t = best_time(run, repeats)
        img = run().numpy().reshape(x.size, y.size).T  # its image is [nx, ny]
        bps = prof.data.shape[0] * x.size * y.size / t
        theirs = np.conj(img.reshape(-1)[:: max(1, img.size // 2048)])  # at the points of ``sub``
        mid = (tx + rx) / 2
        exact_monostatic = backproject(prof, mid, mid, sub, mode="exact")
        ours, theirs_mag = np.abs(exact_sub), np.abs(theirs)
        scale = np.vdot(theirs_mag, ours).real / np.vdot(theirs_mag, theirs_mag).real
        return {"status": "measured", "version": getattr(torchbp, "__version__", "unknown"), "torch": torch.__version__,
                "backprojections_per_s": bps, "sarbot_ratio": sarbot_bps / bps,
                "ser_db": ser_db(theirs, exact_monostatic),
                "bistatic_magnitude_ser_db": ser_db(scale * theirs_mag, ours)}
    except Exception as exc:  # noqa: BLE001 - a comparison that fails is reported, not fatal
        return {"status": f"failed: {type(exc).__name__}: {exc}"}


def chart(rows, numpy_bps, floors, torchbp, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    threads = max(r["threads"] for r in rows)
    for r in rows:
        if r["threads"] != threads:
            continue
        ser = 120.0 if r["ser_db"] is None else min(r["ser_db"], 120.0)
        ax.scatter(r["backprojections_per_s"] / 1e9, ser, s=60, marker="*" if r["default"] else "o")
        label = f"{r['mode']} x{r['oversample']}" + (" (default)" if r["default"] else "") + ("  [exact: SER inf]" if r["mode"] == "exact" else "")
        ax.annotate(label, (r["backprojections_per_s"] / 1e9, ser), xytext=(5, 4), textcoords="offset points", fontsize=8)
    ax.axvline(numpy_bps / 1e9, color="grey", ls=":", label=f"numpy reference ({numpy_bps / 1e6:.0f} M/s)")
    if "backprojections_per_s" in torchbp:
        ax.scatter(torchbp["backprojections_per_s"] / 1e9, torchbp["ser_db"], s=70, marker="X", color="tab:red",
                   label="torchbp Cartesian CPU kernel (measured; monostatic)")
        ax.scatter(torchbp["backprojections_per_s"] / 1e9, torchbp["bistatic_magnitude_ser_db"], s=40, marker="x",
                   color="tab:red", label="torchbp against the bistatic image (|image|)")
    ax.axvline(floors["geometry_plus_gather_per_s"] / 1e9, color="tab:green", ls="-.", label="floor: float64 geometry + gather")
    ax.axhline(60, color="k", lw=0.5)
    ax.set_xscale("log")
    ax.set_xlabel(f"backprojections per second (G/s, {threads} threads)")
    ax.set_ylabel("signal-to-error vs exact matched filter (dB)")
    ax.set_title("Backprojection: speed against accuracy")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
