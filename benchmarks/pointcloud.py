"""Point-cloud detection on a raw frame: what each live odometry scan costs before the filter sees it.

Times every stage of ``rio.pointcloud.detect`` on one simulated frame of the default radar (256 chirps,
4 TX x 4 RX, 175 samples, 30 point targets at 0 dB SNR), and the in-place range-Doppler cube against the
plain per-TX reference of the tests (double precision, numpy FFT), run in the same process.

    python benchmarks/pointcloud.py [--quick]

Writes docs/results/pointcloud.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.samples import complex_to_iq, iq_to_complex  # noqa: E402
from imaging.core.trajectory import StraightLine  # noqa: E402
from imaging.sim.simulator import simulate_frames  # noqa: E402
from imaging.sim.targets import PointTarget  # noqa: E402
from reference_pointcloud import reference_cube  # noqa: E402
from rio.pointcloud import PointCloudConfig, cfar_2d, detect, range_doppler_cube  # noqa: E402
from results_file import load_average, probe_machine, write_results  # noqa: E402

RESULTS = ROOT / "docs" / "results"
SCANS_PER_S_PER_RADAR = 10.0  # the odometry worker's default scan rate
RADARS = 4


def best_ms(fn, repeats: int) -> float:
    """Best of ``repeats`` calls after one warm-up, in ms: the cost without the machine's other load."""
    fn()
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    started_load = load_average()
    probe_machine()  # the VM's speed before; write_results probes after
    repeats = 5 if args.quick else 50
    radar = default_rig().radar("left_front")
    wf = radar.waveform
    rng = np.random.default_rng(0)
    targets = [PointTarget((x, y, 0.3)) for x, y in zip(rng.uniform(-3, 3, 30), rng.uniform(1, 6, 30))]
    frame = simulate_frames(radar, StraightLine(start_m=(0, 0, 0), speed_mps=0.5), targets, np.array([0]),
                            snr_db=0.0, rng=rng)[0]
    iq = complex_to_iq(frame, 1000.0)  # as the bus carries it
    order = np.asarray(wf.tdm_tx_order())
    config = PointCloudConfig()
    samples = iq_to_complex(iq)
    cube = range_doppler_cube(samples, radar, order, config)[0]

    stages = {
        "iq_to_complex": best_ms(lambda: iq_to_complex(iq), repeats),
        "range_doppler_cube": best_ms(lambda: range_doppler_cube(samples, radar, order, config), repeats),
        "power_and_cfar": best_ms(lambda: cfar_2d(np.sum(np.abs(cube) ** 2, axis=1), config), repeats),
    }
    detect_ms = best_ms(lambda: detect(samples, radar, order, config), repeats)
    stages["detections_to_points"] = detect_ms - stages["range_doppler_cube"] - stages["power_and_cfar"]
    reference_ms = best_ms(lambda: reference_cube(samples, radar, order, config), max(3, repeats // 5))
    want = reference_cube(samples, radar, order, config)[0]
    cube_error = float(np.abs(cube - want).max() / np.abs(want).max())
    scan_ms = stages["iq_to_complex"] + detect_ms
    n_points = detect(samples, radar, order, config).xyz_m.shape[0]
    out = {
        "frame_shape": list(frame.shape),
        "detections": n_points,
        "stage_ms": stages,
        "detect_ms": detect_ms,
        "scan_ms": scan_ms,
        "reference_cube_ms": reference_ms,
        "cube_speedup_vs_reference": reference_ms / stages["range_doppler_cube"],
        "cube_max_error_vs_reference": cube_error,
        "core_fraction_at_default_rate": scan_ms * 1e-3 * SCANS_PER_S_PER_RADAR * RADARS,
        "note": f"core_fraction: {RADARS} radars at {SCANS_PER_S_PER_RADAR:g} scans/s each, detection only",
    }
    print(f"frame {tuple(frame.shape)}: {n_points} detections")
    for name, ms in stages.items():
        print(f"  {name:22s} {ms:6.2f} ms")
    print(f"scan (iq -> points): {scan_ms:.2f} ms; {RADARS} radars at {SCANS_PER_S_PER_RADAR:g}/s: "
          f"{out['core_fraction_at_default_rate']:.2f} of a core")
    print(f"cube: {out['cube_speedup_vs_reference']:.1f}x the plain reference ({reference_ms:.1f} ms), "
          f"max error {cube_error:.1e} of the peak")
    write_results("pointcloud_quick" if args.quick else "pointcloud", out, started_load=started_load)
    return 0


if __name__ == "__main__":
    sys.exit(main())
