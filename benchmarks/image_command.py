"""`sarbot image` as a whole command against its backprojection kernel alone, on the backprojection
benchmark's case (16 frames of the left-front radar, all 16 channels, a 256 x 256 grid).

The command is timed as a new process (``python -m acquisition.cli image ...``: its imports, numba's cache
load and all), as a user runs it; the kernel in this process, on the same profiles, alternating with it.

The command reads the recording, range-compresses (the next block while the kernel backprojects this
one), places the antennas, backprojects, writes the image and its PNG. ``form_image`` is the same without
the files. Its throughput (grid points x profiles per second of wall time) is printed as a fraction of
the kernel's on the same profiles in the same process, with the time of each stage.

    python benchmarks/image_command.py [--quick]

Writes docs/results/image_command.json.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from backprojection import best_time  # noqa: E402

from imaging.backprojection import backproject  # noqa: E402
from imaging.core.grid import Grid  # noqa: E402
from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import StraightLine  # noqa: E402
from imaging.image_formation import ImagingOptions, form_image, frame_profiles  # noqa: E402
from imaging.io.image_file import write_image  # noqa: E402
from imaging.io.recording import Recording  # noqa: E402
from imaging.sim.scene import DEFAULT_START_TIME_NS, Scene  # noqa: E402
from imaging.sim.simulator import simulate_recording  # noqa: E402
from imaging.sim.targets import PointTarget  # noqa: E402
from imaging.core import strict_json  # noqa: E402

RESULTS = ROOT / "docs" / "results"


def make_recording(path: Path, n_frames: int) -> None:
    rig = default_rig()
    wf = rig.radar("left_front").waveform
    duration = n_frames * wf.frame_interval_s
    traj = StraightLine(start_m=(-0.15 - 0.4 * duration / 2, -0.2, 0.0), speed_mps=0.4, t0_ns=DEFAULT_START_TIME_NS)
    targets = [PointTarget((dx, 2.0 + dy, 0.3)) for dx, dy in [(0, 0), (-0.2, 0.1), (0.25, -0.2), (0.1, 0.3), (-0.3, -0.3)]]
    scene = Scene(name="bench", rig=rig, trajectory=traj, targets=targets, duration_s=duration - 1e-3,
                  radars=["left_front"], snr_db=0.0, seed=0, adc_counts_per_unit=2000.0)  # int16, as a radar sends
    simulate_recording(scene, path)


def import_times(cmd: list) -> dict:
    """What the command's imports cost (``python -X importtime``): the total of the top-level imports and
    the largest of them, seconds (cumulative, each with what it imports)."""
    err = subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True).stderr
    top = {}
    for line in err.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cumulative, name = line[len("import time:"):].split("|")
        if not name.startswith("  "):  # top level: one space after the bar, nested ones indented further
            top[name.strip()] = top.get(name.strip(), 0.0) + int(cumulative) * 1e-6
    largest = dict(sorted(top.items(), key=lambda kv: -kv[1])[:10])
    return {"total_s": sum(top.values()), "largest_s": largest}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    n_frames, n_px, repeats = (4, 128, 1) if args.quick else (16, 256, 5)
    grid_text = f"-0.5:0.5:{1.0 / n_px},1.5:2.5:{1.0 / n_px},0.3"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rec_path = tmp / "bench.h5"
        make_recording(rec_path, n_frames)
        grid = Grid.parse(grid_text, default_z_m=0.3)
        points = grid.points()
        options = ImagingOptions()
        with Recording(rec_path) as rec:
            radar = rec.radar("left_front")
            truth = rec.truth()
            n = rec.n_frames("left_front")

            def compress():
                return frame_profiles(rec.adc("left_front"), rec.frame_time_ns("left_front"), radar, truth,
                                      rec.tdm_tx_order("left_front"), options)

            profiles, tx_m, rx_m, _, _ = compress()
            n_p = profiles.data.shape[0]
            backproject(profiles, tx_m, rx_m, points[:2, :2])  # compile
            t_kernel = best_time(lambda: backproject(profiles, tx_m, rx_m, points), repeats)
            t_compress = best_time(compress, repeats)
            image = backproject(profiles, tx_m, rx_m, points)
            profiles_again = profiles  # for the rounds against the command
            # The library call behind the command: read, range-compress (overlapped), backproject.
            t_form = best_time(lambda: form_image(rec, "left_front", grid, truth, options=options), repeats)

        from imaging.io.image_file import SarImage
        from imaging.plot import ImagePicture

        img = SarImage(image, grid.x_m, grid.y_m, grid.z_m, {"wavelength_m": 0.0039})
        t_write = best_time(lambda: write_image(tmp / "w.h5", img), repeats)
        # The PNG: laying its figure out (axes, ticks, colour bar: all from the grid), then drawing the pixels.
        t_png_layout = best_time(lambda: ImagePicture(grid.x_m, grid.y_m), repeats)
        picture = ImagePicture(grid.x_m, grid.y_m)
        t_png = best_time(lambda: picture.save(tmp / "w.png", image, title="bench"), repeats)

        def command() -> float:
            for f in ("img.h5", "img.png"):
                (tmp / f).unlink(missing_ok=True)
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "acquisition.cli", "-q", "image", str(rec_path), "-o", str(tmp / "img.h5"),
                            "--grid", grid_text], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
            return time.perf_counter() - t

        command()  # warm: the kernels compiled into numba's cache, files in the page cache
        imports = import_times([sys.executable, "-X", "importtime", "-m", "acquisition.cli", "-q", "image", str(rec_path),
                                "-o", str(tmp / "imp.h5"), "--grid", grid_text])
        # Alternating: the whole command as a new process, then the kernel alone here; ratio per round.
        rounds = []
        for _ in range(repeats):
            t_cmd = command()
            t = time.perf_counter()
            backproject(profiles_again, tx_m, rx_m, points)
            rounds.append((t_cmd, time.perf_counter() - t))
        t_command = min(r[0] for r in rounds)
        command_fraction_rounds = [k / c for c, k in rounds]
    work = n_p * points.reshape(-1, 3).shape[0]
    result = {
        "case": {"frames": n, "profiles": n_p, "grid_points": int(points.size // 3), "quick": args.quick},
        "kernel_backprojections_per_s": work / t_kernel,
        "command_backprojections_per_s": work / t_command,
        "command_fraction_of_kernel": t_kernel / t_command,
        "command_fraction_of_kernel_per_round": {"median": statistics.median(command_fraction_rounds),
                                                 "min": min(command_fraction_rounds), "max": max(command_fraction_rounds)},
        "command_is": "a new process: python -m acquisition.cli image",
        "load_average": os.getloadavg(),
        "form_image_fraction_of_kernel": t_kernel / t_form,
        "command_imports": imports,
        "seconds": {"command": t_command, "form_image": t_form, "kernel": t_kernel, "read_and_range_compress": t_compress,
                    "write_image": t_write, "png_layout": t_png_layout, "png_draw": t_png,
                    "command_minus_form_image_write_png": t_command - t_form - t_write - t_png_layout - t_png},
    }
    s = result["seconds"]
    print(f"kernel {work / t_kernel / 1e9:.3f} G/s, form_image {work / t_form / 1e9:.3f} G/s ({100 * t_kernel / t_form:.0f} %), "
          f"sarbot image {work / t_command / 1e9:.3f} G/s ({100 * t_kernel / t_command:.0f} % of the kernel); seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in s.items()))
    RESULTS.mkdir(parents=True, exist_ok=True)
    name = "image_command_quick" if args.quick else "image_command"
    (RESULTS / f"{name}.json").write_text(strict_json.dumps(result, indent=2))
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
