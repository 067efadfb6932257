"""sarbot's backprojection beside the real torchbp, in one process, on the same profiles.

torchbp (built from ``../shared/bench/``, its newest public source, by ``python3 dev.py bench --peers`` into
a benchmark-only environment: never a dependency of sarbot or its tests) runs its Cartesian CPU kernel
(``backprojection_cart_2d``) and its polar one (``backprojection_polar_2d``) beside sarbot's kernel
(``imaging.backprojection.backproject``, linear, 16x oversampled profiles) on two cases, and the two FFBPs
(``ops.ffbp`` and ``imaging.factorized_backprojection``) on the second, each against its own direct kernel:

``benchmark``    the backprojection benchmark's case: 16 frames of the left-front radar, all 16 bistatic
                 channels (16,384 profiles), onto 256 x 256 pixels (1 m x 1 m, 2 m away).
``one_antenna``  one TX and one RX channel of the same radar over 4,096 chirps, onto the same pixels.

Each measurement alternates the contenders call by call on the same 2 threads (so a load that comes and
goes hits all of them alike); a ratio is taken per round and the median of the rounds is reported, with
the spread. Accuracy: each image's signal-to-error ratio against sarbot's exact matched filter (the DTFT
of the raw samples) at 2,048 pixels -- sarbot's on its bistatic geometry, torchbp's on the monostatic
geometry it assumes (each profile at the midpoint of its TX and RX, the plane shifted to z = 0; it is given
the conjugate profiles, for its phase convention: see benchmarks/README.md), and, to show what the
midpoint and its float32 positions cost, torchbp's magnitude against the bistatic exact image; also both
5 km from the world origin.

    python benchmarks/peers.py [--quick] [--rounds N] [--cases one_antenna]

Writes docs/results/peers.json (``peers_quick.json`` with --quick). ``--cases`` with one case runs only that
case's kernels (no FFBP, not 5 km out) into ``peers_CASE.json``: a quick look, not the issue's figure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

import results_file  # noqa: E402
from backprojection import make_case, ser_db  # noqa: E402

from imaging.backprojection import backproject, compiled_target  # noqa: E402
from imaging.range_compression import range_compress  # noqa: E402

RESULTS = ROOT / "docs" / "results"
THREADS = 2
ACCURACY_POINTS = 2048


def one_antenna_case(n_profiles: int, nx: int, ny: int, origin=(0.0, 0.0)):
    """The benchmark case's drive, but only the profiles of TX 0 and RX 0: ``n_profiles`` chirps of one
    bistatic antenna pair."""
    from imaging.core.rig import default_rig

    wf = default_rig().radar("left_front").waveform
    chirps_per_frame_tx0 = wf.chirps_per_frame // wf.n_tx
    n_frames = -(-n_profiles // chirps_per_frame_tx0)
    samples, wf, tx, rx, grid = make_case(n_frames, nx, ny, origin)
    tx_of_chirp = np.tile(wf.tdm_tx_order(), n_frames)
    chirp = np.repeat(np.arange(tx_of_chirp.size), wf.n_rx)
    rx_of_profile = np.tile(np.arange(wf.n_rx), tx_of_chirp.size)
    keep = np.flatnonzero((tx_of_chirp[chirp] == tx_of_chirp[0]) & (rx_of_profile == 0))[:n_profiles]
    return samples[keep], wf, tx[keep], rx[keep], grid


def load_average() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return " ".join(str(round(x, 2)) for x in os.getloadavg())


class Torchbp:
    """torchbp's kernels on sarbot's profiles (monostatic midpoints, plane at z = 0, conjugate data)."""

    def __init__(self, prof, tx, rx, grid):
        import torch
        import torchbp

        self.torch, self.ops = torch, torchbp.ops
        torch.set_num_threads(THREADS)
        z = float(grid[0, 0, 2])
        self.mid = 0.5 * (tx + rx)
        self.pos = torch.from_numpy((self.mid - [0.0, 0.0, z]).astype(np.float32))
        self.data = torch.from_numpy(np.conj(prof.data))
        x, y = grid[0, :, 0], grid[:, 0, 1]
        # Its pixel i is at x0 + i (x1 - x0) / nx: x1 one step past the last pixel.
        self.cart = {"x": (float(x[0]), float(x[0] + x.size * (x[1] - x[0]))),
                     "y": (float(y[0]), float(y[0] + y.size * (y[1] - y[0]))), "nx": x.size, "ny": y.size}
        self.kw = dict(fc=prof.carrier_hz, r_res=prof.range_step_m / 2, d0=-prof.range_start_m / 2)
        self.shape = (y.size, x.size)
        # The polar grid over the same pixels, as many of them: its origin is the world's, its range axis
        # is torchbp's x and its angle (sin of) along its y; our track runs along x, so x and y swap places
        # (a mirror: distances, and so the image, are unchanged).
        r = np.hypot(grid[..., 0], grid[..., 1])
        theta = grid[..., 0] / r
        self.polar = {"r": (float(r.min()), float(r.max())), "theta": (float(theta.min()), float(theta.max())),
                      "nr": y.size, "ntheta": x.size}
        self.pos_polar = torch.from_numpy((self.mid[:, [1, 0, 2]] - [0.0, 0.0, z]).astype(np.float32))
        self.z = z

    def cartesian(self):
        return self.ops.backprojection_cart_2d(self.data, self.cart, pos=self.pos, **self.kw)

    def polar_image(self):
        return self.ops.backprojection_polar_2d(self.data, self.polar, pos=self.pos_polar, **self.kw)

    def cartesian_image(self) -> np.ndarray:
        """Its Cartesian image as [ny, nx] with sarbot's phase convention."""
        return np.conj(self.cartesian().numpy().reshape(self.shape[1], self.shape[0]).T)

    def polar_points(self) -> np.ndarray:
        """World points of its polar grid's pixels, [nr, ntheta, 3] (torchbp: pixel i at r0 + i (r1 - r0) / nr)."""
        p = self.polar
        r = p["r"][0] + np.arange(p["nr"]) * (p["r"][1] - p["r"][0]) / p["nr"]
        th = p["theta"][0] + np.arange(p["ntheta"]) * (p["theta"][1] - p["theta"][0]) / p["ntheta"]
        rr, tt = np.meshgrid(r, th, indexing="ij")
        h = self.z
        # torchbp's pixel: (x, y) = (r sqrt(1 - theta^2), r theta) in its frame, on its plane z = 0 (ours: z).
        return np.stack([rr * tt, rr * np.sqrt(1 - tt * tt), np.full_like(rr, h)], axis=-1)


def alternate(contenders: dict, rounds: int) -> dict:
    """Time each contender once per round, in turn; {name: [seconds per round]}."""
    for fn in contenders.values():
        fn()  # compile, warm caches
    times = {name: [] for name in contenders}
    for _ in range(rounds):
        for name, fn in contenders.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    return times


def ratio_stats(ours: list, theirs: list) -> dict:
    ratios = [b / a for a, b in zip(ours, theirs)]
    return {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios)}


def run_case(name: str, samples, wf, tx, rx, grid, rounds: int) -> dict:
    numba.set_num_threads(min(THREADS, numba.config.NUMBA_NUM_THREADS))
    prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, guarded=True)
    n_p, n_g = tx.shape[0], grid.shape[0] * grid.shape[1]
    tb = Torchbp(prof, tx, rx, grid)
    times = alternate({"sarbot": lambda: backproject(prof, tx, rx, grid),
                       "torchbp_cartesian": tb.cartesian, "torchbp_polar": tb.polar_image}, rounds)
    # Accuracy at a subset of pixels, against the exact matched filter of each one's geometry.
    flat = grid.reshape(-1, 3)
    step = max(1, n_g // ACCURACY_POINTS)
    sub = flat[::step]
    exact = backproject(prof, tx, rx, sub, mode="exact")
    exact_mono = backproject(prof, tb.mid, tb.mid, sub, mode="exact")
    ours = backproject(prof, tx, rx, grid).reshape(-1)[::step]
    theirs = tb.cartesian_image().reshape(-1)[::step]
    mag, theirs_mag = np.abs(exact), np.abs(theirs)
    scale = np.vdot(theirs_mag, mag).real / np.vdot(theirs_mag, theirs_mag).real
    polar_pts = tb.polar_points().reshape(-1, 3)[::step]
    theirs_polar = np.conj(tb.polar_image().numpy().reshape(-1)[::step])
    exact_polar = backproject(prof, tb.mid, tb.mid, polar_pts, mode="exact")
    work = n_p * n_g
    med = {k: statistics.median(v) for k, v in times.items()}
    result = {
        "profiles": n_p, "pixels": n_g, "rounds": rounds,
        "seconds_median": med,
        "backprojections_per_s": {k: work / v for k, v in med.items()},
        "sarbot_over_torchbp_cartesian": ratio_stats(times["sarbot"], times["torchbp_cartesian"]),
        "sarbot_over_torchbp_polar": ratio_stats(times["sarbot"], times["torchbp_polar"]),
        "ser_db": {"sarbot": ser_db(ours, exact), "torchbp_cartesian": ser_db(theirs, exact_mono),
                   "torchbp_polar": ser_db(theirs_polar, exact_polar),
                   "torchbp_cartesian_magnitude_vs_bistatic": ser_db(scale * theirs_mag, mag)},
    }
    r = result["sarbot_over_torchbp_cartesian"]
    print(f"{name}: {n_p} profiles x {n_g} pixels; sarbot {work / med['sarbot'] / 1e9:.3f} G/s, torchbp Cartesian "
          f"{work / med['torchbp_cartesian'] / 1e9:.3f} G/s, polar {work / med['torchbp_polar'] / 1e9:.3f} G/s; "
          f"sarbot/torchbp Cartesian {r['median']:.2f}x ({r['min']:.2f}-{r['max']:.2f}), polar "
          f"{result['sarbot_over_torchbp_polar']['median']:.2f}x; SER sarbot {result['ser_db']['sarbot']:.1f} dB, "
          f"torchbp Cartesian {result['ser_db']['torchbp_cartesian']:.1f} dB, polar {result['ser_db']['torchbp_polar']:.1f} dB",
          flush=True)
    return result


def ffbp_case(samples, wf, tx, rx, grid, rounds: int, stages: int = 8) -> dict:
    """Each FFBP beside its own direct kernel on the one-antenna pass: sarbot's (Cartesian pixels, default
    options, 8x oversampled profiles) and torchbp's (``ops.ffbp`` onto its polar grid over the same pixels,
    ``stages`` recursions, its default interpolation; both of its images range-dealiased, as its FFBP
    documents for comparison with the direct kernel). Time alternating; error = energy of FFBP's image minus
    the same tool's direct image, over the direct image's, dB."""
    from imaging.factorized_backprojection import backproject_factorized

    numba.set_num_threads(min(THREADS, numba.config.NUMBA_NUM_THREADS))
    prof8 = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=8, guarded=True)
    prof16 = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, guarded=True)
    tb = Torchbp(prof16, tx, rx, grid)
    x, y, z = grid[0, :, 0], grid[:, 0, 1], float(grid[0, 0, 2])

    def tb_direct():
        return tb.ops.backprojection_polar_2d(tb.data, tb.polar, pos=tb.pos_polar, dealias=True, **tb.kw)

    def tb_ffbp():
        return tb.ops.ffbp(tb.data, tb.polar, pos=tb.pos_polar, stages=stages, dealias=True, **tb.kw)

    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        times = alternate({"sarbot_ffbp": lambda: backproject_factorized(prof8, tx, rx, x, y, z),
                           "sarbot_direct": lambda: backproject(prof8, tx, rx, grid),
                           "torchbp_ffbp": tb_ffbp, "torchbp_direct_polar": tb_direct}, rounds)
        s_ffbp, s_direct = backproject_factorized(prof8, tx, rx, x, y, z), backproject(prof8, tx, rx, grid)
        t_ffbp, t_direct = tb_ffbp().numpy(), tb_direct().numpy()
    med = {k: statistics.median(v) for k, v in times.items()}

    def err(a, b):
        return float(20 * np.log10(np.linalg.norm(a - b) / np.linalg.norm(b)))

    out = {"aperture_m": float(np.ptp(tb.mid[:, 0])), "profiles": int(tx.shape[0]), "pixels": int(x.size * y.size),
           "torchbp_stages": stages, "seconds_median": med,
           "sarbot_ffbp_over_torchbp_ffbp": ratio_stats(times["sarbot_ffbp"], times["torchbp_ffbp"]),
           "speedup_over_own_direct": {"sarbot": med["sarbot_direct"] / med["sarbot_ffbp"],
                                       "torchbp": med["torchbp_direct_polar"] / med["torchbp_ffbp"]},
           "error_vs_own_direct_db": {"sarbot": err(s_ffbp, s_direct), "torchbp": err(t_ffbp, t_direct)},
           "torchbp_warnings": sorted({str(w.message)[:200] for w in caught})}
    print(f"FFBP, one-antenna pass ({out['aperture_m']:.2f} m): sarbot {med['sarbot_ffbp']:.2f} s "
          f"({out['speedup_over_own_direct']['sarbot']:.1f}x its direct kernel, {out['error_vs_own_direct_db']['sarbot']:.1f} dB), "
          f"torchbp {med['torchbp_ffbp']:.2f} s ({out['speedup_over_own_direct']['torchbp']:.1f}x its direct polar kernel, "
          f"{out['error_vs_own_direct_db']['torchbp']:.1f} dB); sarbot/torchbp "
          f"{out['sarbot_ffbp_over_torchbp_ffbp']['median']:.2f}x", flush=True)
    return out


def far_from_origin(n_profiles: int) -> dict:
    """Both kernels on the one-antenna case 5 km from the world origin: SER against the same scene's exact
    image at the origin (sarbot's positions are float64; torchbp's are float32)."""
    out = {}
    images = {}
    for where, origin in (("origin", (0.0, 0.0)), ("far", (4000.0, 3000.0))):
        samples, wf, tx, rx, grid = one_antenna_case(n_profiles, 32, 32, origin)
        prof = range_compress(samples, wf.f0_hz, wf.frequency_step_hz, oversample=16, guarded=True)
        tb = Torchbp(prof, tx, rx, grid)
        images[where] = {"sarbot": backproject(prof, tx, rx, grid), "torchbp": tb.cartesian_image(),
                         "exact_mono": backproject(prof, tb.mid, tb.mid, grid, mode="exact")}
    out["sarbot_ser_db"] = ser_db(images["far"]["sarbot"], images["origin"]["sarbot"])
    out["torchbp_cartesian_ser_db"] = ser_db(images["far"]["torchbp"], images["origin"]["exact_mono"])
    print(f"5 km out, against the same scene at the origin: sarbot {out['sarbot_ser_db']:.1f} dB, torchbp "
          f"{out['torchbp_cartesian_ser_db']:.1f} dB", flush=True)
    return out


def torchbp_build() -> dict:
    """What ``dev.py bench --peers`` recorded of the torchbp build (source, commit, flags), if it did."""
    import torch
    import torchbp

    info = {"torch": torch.__version__, "torchbp_version": getattr(torchbp, "__version__", "unknown")}
    stamp = os.environ.get("SARBOT_TORCHBP_BUILD")
    if stamp and Path(stamp).exists():
        info.update(json.loads(Path(stamp).read_text()))
    return info


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller cases (a smoke run)")
    ap.add_argument("--rounds", type=int, default=None, help="alternating rounds per case (default 7, 2 with --quick)")
    ap.add_argument("--cases", nargs="+", choices=("benchmark", "one_antenna"), default=["benchmark", "one_antenna"])
    args = ap.parse_args()
    everything = set(args.cases) == {"benchmark", "one_antenna"}
    try:
        import torchbp  # noqa: F401
    except ImportError:
        print("peers.py: torchbp is not importable here; run it through `python3 dev.py bench --peers`, which builds "
              "it into a benchmark-only environment", file=sys.stderr)
        return 2
    started_load = results_file.load_average()
    results_file.probe_machine()  # the VM's speed before; write_results probes after
    rounds = args.rounds or (2 if args.quick else 7)
    frames, one, px = (4, 1024, 128) if args.quick else (16, 4096, 256)
    load_before = load_average()
    one_antenna = one_antenna_case(one, px, px)
    cases = {}
    if "benchmark" in args.cases:
        cases["benchmark"] = run_case("benchmark", *make_case(frames, px, px), rounds)
    if "one_antenna" in args.cases:
        cases["one_antenna"] = run_case("one_antenna", *one_antenna, rounds)
    ffbp = ffbp_case(*one_antenna, max(2, rounds // 2)) if everything else None
    far = far_from_origin(512 if args.quick else 1024) if everything else None
    result = {
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(), "numba": numba.__version__,
                    "numpy": np.__version__, "numba_target": compiled_target(), "threads": THREADS},
        "load": {"before": load_before, "after": load_average()},
        "torchbp": torchbp_build(),
        "method": "one process; each round runs sarbot, torchbp Cartesian, torchbp polar in turn on the same profiles and "
                  "2 threads; ratios per round, median over rounds; SER against sarbot's exact matched filter on each "
                  "one's own geometry (torchbp: monostatic midpoints, plane at z = 0)",
        "cases": cases,
    }
    if everything:
        result.update({"ffbp_one_antenna": ffbp, "far_from_origin_5km": far})
    name = ("peers_quick" if args.quick else "peers") if everything else "peers_" + "_".join(args.cases)
    results_file.write_results(name, result, started_load=started_load)
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
