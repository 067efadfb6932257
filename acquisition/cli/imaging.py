"""``sarbot simulate``, ``image``, ``analyze``, ``batch`` and ``experiment``: recordings into SAR images
and what they measure (see docs/formats/image.md)."""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

from imaging.core import strict_json
from imaging.core.errors import SarbotError

from . import options as opt
from . import STARTED, nothing_left_to_close
from .exit_codes import EXIT_OK, EXIT_USAGE
from .start_up import collector_paused

log = logging.getLogger(f"sarbot.{__name__}")

#: The studies ``sarbot experiment`` reproduces: name -> (module, function(out_dir, quick) -> report).
EXPERIMENTS = {"paper": ("acquisition.studies.paper", "run_paper")}


def register(sub) -> None:
    s = sub.add_parser("simulate", help="simulate a scene into a recording",
                       epilog="example: sarbot simulate --list; sarbot simulate paper_pass_0.4 -o pass.h5; sarbot simulate my_scene.toml -o rec.h5")
    opt.completes(s.add_argument("scene", nargs="?", help="built-in scene name (see --list) or scene TOML file"),
                  opt.ChoicesFrom("imaging.sim.scene", "builtin_scene_names"))
    s.add_argument("-o", "--output", help="recording file to write (.h5)")
    opt.overwrite_option(s)
    s.add_argument("--list", action="store_true", help="list the built-in scenes")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("image", help="form a SAR image by backprojection",
                       epilog="example: sarbot image pass.h5 -o img.h5 --radar left_front --frames 30:60 --grid -0.5:0.5:0.002,1.8:2.2:0.004")
    s.add_argument("recording")
    s.add_argument("-o", "--output", required=True, help="image file to write (.h5); a PNG goes beside it")
    opt.imaging_options(s)
    opt.rig_override_option(s)
    s.add_argument("--tx", help="TX channels, e.g. 0,2 (default all)")
    s.add_argument("--rx", help="RX channels, e.g. 0 (default all)")
    s.add_argument("--png", help="where to write the PNG (default: beside the image)")
    s.add_argument("--png-figure", action="store_true",
                   help="the PNG as a figure with axes in metres, a colour bar and the title (matplotlib; about half a "
                        "second more) instead of the image's pixels alone")
    s.add_argument("--autofocus-sinusoids", type=int, default=1, help="sinusoids in the entropy model (0-4, default 1)")
    s.add_argument("--autofocus-decision", default="consistency", choices=("consistency", "contrast"),
                   help="when an estimate is applied: consistency (default): the estimates from the lower and upper "
                        "half of the band must agree (1 %% false alarms); contrast: the former 20 dB contrast gate")
    s.add_argument("--imu-aided", action="store_true",
                   help="correct the track by the IMU on the radar's own mount first (a rig's [radar.NAME.imu]); "
                        "autofocus, if asked for, estimates what is left")
    opt.overwrite_option(s, "replace existing output files")
    s.set_defaults(func=cmd_image)

    from ..batch import DASHBOARD_ADDRESS, SWEEPABLE

    s = sub.add_parser("batch", help="many images on a Dask cluster: recordings, tiles of a long drive, parameter sweeps",
                       epilog="examples: sarbot batch a.h5 b.h5 c.h5 d.h5 --grid -0.5:0.5:0.004,1.5:2.5:0.004 -o images/; "
                              "sarbot batch drive.h5 --tile-frames 40 --grid ... -o tiles/; "
                              "sarbot batch pass.h5 --sweep aperture_m=0.14,0.34,1.0 --sweep autofocus=none,entropy "
                              "--grid ... -o sweep/ "
                              "--scheduler tcp://cluster:8786")
    s.add_argument("recordings", nargs="+", help="recording files")
    s.add_argument("-o", "--output", required=True, help="folder for the images and batch.json (one summary per image)")
    opt.imaging_options(s)
    s.add_argument("--tile-frames", type=int, help="one image per this many consecutive frames (a long drive, tile by tile)")
    s.add_argument("--sweep", action="append", metavar="KEY=V1,V2,...",
                   help=f"vary an option ({', '.join(SWEEPABLE)}; values as the option takes them); several --sweep "
                        "make every combination")
    s.add_argument("--png", action="store_true", help="a PNG beside every image")
    s.add_argument("--scheduler", metavar="ADDRESS", help="a running dask.distributed scheduler (tcp://host:8786); its "
                   "workers need sarbot and the files at the same paths. Default: a local cluster")
    s.add_argument("--workers", type=int, default=2, help="worker processes of the local cluster (default 2)")
    s.add_argument("--dashboard", default=DASHBOARD_ADDRESS, metavar="HOST:PORT",
                   help=f"where the local cluster serves Dask's dashboard (default {DASHBOARD_ADDRESS}; 'none': "
                        "nowhere); needs bokeh: pip install 'sarbot[dashboard]'")
    opt.overwrite_option(s, "replace existing images")
    s.set_defaults(func=cmd_batch)

    s = sub.add_parser("analyze", help="image quality metrics as JSON",
                       epilog="example: sarbot analyze img.h5 --at 0,2; sarbot analyze a.h5 b.h5 c.h5 (integration gain)")
    s.add_argument("images", nargs="+", help="image file(s); several with different frame counts also fit the integration gain")
    s.add_argument("--at", help="x,y: analyse the peak nearest this point (default: the strongest)")
    s.add_argument("--radius", type=float, default=0.1, help="search radius around --at, metres")
    s.add_argument("--vibration", action="store_true", help="infer f_vib and A_vib from paired cross-range side lobes")
    s.add_argument("--half-length", type=float, default=0.3, help="half length of the cuts, metres")
    s.set_defaults(func=cmd_analyze)

    s = sub.add_parser("experiment", help="reproduce a study on simulated data (paper: the reference robot-SAR study)")
    s.add_argument("name", help=", ".join(EXPERIMENTS))
    s.add_argument("-o", "--output", default="docs/results/paper", help="report folder (default docs/results/paper)")
    s.add_argument("--quick", action="store_true", help="fewer apertures, phases and amplitudes (a smoke run)")
    s.set_defaults(func=cmd_experiment)


def cmd_simulate(args) -> int:
    from imaging.sim.scene import builtin_scene_names, load_scene
    from imaging.sim.simulator import simulate_recording

    from ..progress import Progress

    if args.list:
        import textwrap

        for name in builtin_scene_names():
            # the description's first sentence, whole: its TOML line breaks would cut it mid-sentence
            text = " ".join(load_scene(name).description.split())
            first = text.split(". ")[0].rstrip(".") + "." if text else ""
            print(textwrap.fill(first, width=110, initial_indent=f"{name:18s} ", subsequent_indent=" " * 19))
        return EXIT_OK
    if not args.scene or not args.output:
        raise SarbotError("simulate needs a SCENE and -o OUTPUT (or --list)")
    scene = load_scene(args.scene)
    out = opt.new_output(args.output, args.overwrite, "-o ", inputs=[args.scene])
    counts = opt.write_output(out, lambda p: simulate_recording(scene, p, progress=Progress("simulate"),
                                                                 overwrite=args.overwrite), "-o ")
    print(f"wrote {out}: scene {scene.name}, " + ", ".join(f"{n} frames of {r}" for r, n in counts.items()))
    return EXIT_OK


def cmd_image(args) -> int:
    # numba and the kernels are most of a new process's start; they are made ready on a thread of their own
    # from here on (imaging.kernel_import), while this one opens the recording and the first blocks are read
    # and range-compressed (imaging.image_formation.form_image waits for them before its first
    # backprojection, compressing further blocks meanwhile). All of that with the cyclic collector paused
    # (see start_up), a plain image's formation too: it makes next to no reference cycles. Autofocus's long
    # Python work runs with the collector as usual.
    from imaging import kernel_import
    from imaging.core.stage_clock import StageClock

    clock = StageClock()
    clock.add("before_command", time.perf_counter() - STARTED)
    began = time.perf_counter()
    plain = args.autofocus == "none" and not args.imu_aided
    with contextlib.ExitStack() as start_up:
        start_up.enter_context(collector_paused())  # the modules live as long as the process
        kernels = kernel_import.start_in_background(ffbp=args.algorithm == "ffbp")
        start_up.callback(kernels.join)  # a user's mistake found meanwhile ends the command after it
        from imaging.image_formation import ImagingOptions, image_recording
        from imaging.io.image_file import write_image
        from imaging.io.recording import Recording

        from ..progress import Progress

        out = Path(args.output)
        png = Path(args.png) if args.png else out.with_suffix(".png")
        inputs = [args.recording] + ([args.trajectory] if args.trajectory != "truth" else [])
        for path in (out, png):
            if path.exists() and path.resolve() == Path(args.recording).resolve():
                raise SarbotError(f"{path}: that is the recording being imaged; choose another output")
            opt.new_output(path, args.overwrite, inputs=inputs)
        options = ImagingOptions(mode=args.mode, window=args.window, oversample=args.oversample,
                                 tx=opt.parse_channels(args.tx, "tx"), rx=opt.parse_channels(args.rx, "rx"),
                                 algorithm=args.algorithm, aperture_window=args.aperture_window)
        autofocus = None
        if args.autofocus != "none":  # imaging.autofocus (scipy.optimize) costs 0.6 s to import: only when asked
            from imaging.autofocus import AutofocusOptions

            autofocus = AutofocusOptions(method=args.autofocus, sinusoids=args.autofocus_sinusoids,
                                         decision=args.autofocus_decision)
        if not plain:
            start_up.close()
        opened = time.perf_counter()
        clock.add("start_up", opened - began)
        with Recording(args.recording) as rec:
            opt.use_rig_file(rec, args.rig)
            clock.add("open_recording", time.perf_counter() - opened)
            with clock.stage("image_recording"):
                img = image_recording(rec, args.radar, args.grid, args.trajectory, opt.parse_frames(args.frames),
                                      options, progress=Progress("backproject"), autofocus=autofocus,
                                      imu_aided=args.imu_aided, aperture_m=args.aperture, clock=clock)
    if args.rig:  # the image says whose mounts placed its antennas
        img.attrs["rig"] = str(args.rig)
    with clock.stage("write_image"):
        path = opt.write_output(out, lambda p: write_image(p, img), "-o ")
    with clock.stage("write_png"):
        opt.write_output(png, lambda p: write_picture(p, img, args.png_figure), "--png ")
    print(f"wrote {path} and {png}")
    if img.track_error is not None:
        print(autofocus_summary(img))
    clock.add("command", time.perf_counter() - STARTED)
    # Where the time went (benchmarks/image_command.py reads this line): seconds since sarbot's command line
    # was imported ("command"): "before_command" (its parser, the arguments, the log set-up), then this
    # function's stages; form_image's own are inside "image_recording", its range-compression thread's
    # ("compress_thread.*") overlap them.
    log.debug("stage seconds: %s", strict_json.dumps(clock.seconds))
    nothing_left_to_close()  # the files are closed, the threads joined: the process may end at once
    return EXIT_OK


def write_picture(path: Path, img, figure: bool) -> Path:
    """The PNG of ``img`` (a volume: its largest magnitude over height): its pixels in the colour map, or
    with ``figure`` matplotlib's figure of them (imported only then: it costs half a second)."""
    from imaging.image_formation import image_title

    if not figure:
        from imaging.plot import save_image_pixels_png

        return save_image_pixels_png(path, img.image, img.x_m, img.y_m, title=image_title(img))
    from imaging.plot import ImagePicture

    # Not laid out beside the backprojection: its kernel has every core, and the figure's Python then holds
    # the GIL the kernel's calls need (0.15 s slower than after it, benchmarks/image_command.py).
    return ImagePicture(img.x_m, img.y_m).save(path, img.image, title=image_title(img))


def autofocus_summary(img) -> str:
    """One line on what autofocus (and the radar's IMU) found and did."""
    a = img.attrs
    te = img.track_error
    if "autofocus" not in a:  # the radar's IMU alone
        return f"imu-aided: the radar's IMU moved it {1e3 * te.rms_m:.3f} mm rms along the boresight over {np.ptp(te.time_s):.2f} s"
    consistency = ""
    if "autofocus_consistency_margin_db" in a:  # the half-band estimates compared (imaging.autofocus.consistency)
        consistency = (f"; half-band consistency {a['autofocus_consistency_margin_db']:+.1f} dB at "
                       f"{100 * a['autofocus_consistency_false_alarm']:g} % false alarms "
                       f"({a['autofocus_consistency_scope']}, uncertainty {1e3 * a['autofocus_uncertainty_m']:.3f} mm)")
    if not a.get("autofocus_applied"):
        return (f"autofocus ({a['autofocus']}): nothing to gain (image entropy {a['autofocus_entropy_before']:.3f}){consistency}; "
                "the image is formed on the trajectory as it is")
    return (f"autofocus ({a['autofocus']}{' on the radar IMU' if a.get('imu_aided') else ''}): track error {1e3 * te.rms_m:.3f} mm rms along the boresight over "
            f"{np.ptp(te.time_s):.2f} s; entropy {a['autofocus_entropy_before']:.3f} -> {a['autofocus_entropy_after']:.3f}{consistency}")


def cmd_batch(args) -> int:
    import os

    from ..batch import parse_sweep, plan_jobs, run_batch
    from ..progress import Progress

    if args.workers < 1:
        raise SarbotError(f"--workers {args.workers}: must be at least 1")
    if args.tile_frames is not None and args.tile_frames < 1:
        raise SarbotError(f"--tile-frames {args.tile_frames}: must be at least 1")
    frames = opt.parse_frames(args.frames)
    threads = None if args.scheduler else max(1, (os.cpu_count() or 1) // args.workers)
    jobs = plan_jobs(args.recordings, args.grid, args.output, radar=args.radar, frames=(frames.start, frames.stop),
                     tile_frames=args.tile_frames, sweep=parse_sweep(args.sweep), base_options=opt.imaging_values(args),
                     trajectory=args.trajectory, png=args.png, threads=threads)
    out_dir = opt.new_output_folder(args.output)
    inputs = [*args.recordings] + ([args.trajectory] if args.trajectory != "truth" else [])
    for job in jobs:
        opt.new_output(Path(job.output), args.overwrite, inputs=inputs)
        if args.png:
            opt.new_output(Path(job.output).with_suffix(".png"), args.overwrite, inputs=inputs)
    opt.new_output(out_dir / "batch.json", args.overwrite, inputs=inputs)
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es)"
    log.info("%d image(s) on %s", len(jobs), where)
    results = run_batch(jobs, args.scheduler, args.workers, progress=Progress("batch", unit="image"),
                        dashboard_address=None if args.dashboard.lower() == "none" else args.dashboard,
                        on_dashboard=_say_dashboard)
    summary = out_dir / "batch.json"
    summary.write_text(strict_json.dumps({"cluster": where, "jobs": results}, indent=2))
    failed = [r for r in results if r["error"]]
    for r in results:
        if not r["error"]:
            print(f"wrote {r['output']} ({r['seconds']:.1f} s)")
    for r in failed:
        print(f"sarbot: error: {r['label']}: {r['error']}", file=sys.stderr)
    print(f"wrote {summary}: {len(results) - len(failed)} of {len(results)} images")
    return EXIT_USAGE if failed else EXIT_OK


def _say_dashboard(link: str | None) -> None:
    from ..batch import dashboard_available

    if link:  # an info line: -q leaves it out with the progress
        log.info("Dask dashboard: %s", link)
    elif not dashboard_available():
        log.info("no Dask dashboard: it needs bokeh (pip install 'sarbot[dashboard]')")


def cmd_analyze(args) -> int:
    from imaging import metrics
    from imaging.io.image_file import read_image

    for option, value in (("--radius", args.radius), ("--half-length", args.half_length)):
        if not (math.isfinite(value) and value > 0):
            raise SarbotError(f"{option} {value}: must be a positive number of metres")
    near = opt.parse_xy(args.at, "--at") if args.at else None
    if near is not None and not all(math.isfinite(v) for v in near):
        raise SarbotError(f"--at {args.at}: expected finite x,y in metres")
    results = []
    for name in args.images:
        img = read_image(name)
        if img.image.ndim != 2:
            raise SarbotError(f"{name}: analyze works on 2-D images; this one is {img.image.ndim}-D")
        look = img.attrs.get("look_direction", [0.0, 1.0, 0.0])
        try:
            res = metrics.analyze_target(img.image, img.x_m, img.y_m, look, near_m=near, radius_m=args.radius)
        except ValueError as exc:
            raise SarbotError(f"{name}: {exc}") from None
        res["file"] = str(name)
        res["n_frames"] = int(img.attrs.get("n_frames", 0))
        metrics.compare_with_theory(res, img.image, img.x_m, img.y_m, img.attrs, img.wavelength_m,
                                    vibration=args.vibration, half_length_m=args.half_length)
        if img.track_error is not None:
            res["track_error"] = track_error_report(img)
        results.append(res)
    output: dict = {"images": results}
    counts = [r["n_frames"] for r in results]
    snrs = [r["snr_db"] for r in results]
    if len(set(counts)) >= 2 and not np.all(np.isfinite(snrs)):
        output["integration_gain"] = {"note": "an image has no background outside the target to measure SNR on; use a larger grid"}
    elif len(set(counts)) >= 2:
        alpha, g0 = metrics.fit_integration_gain(counts, [r["snr_db"] for r in results])
        output["integration_gain"] = {"alpha": alpha, "snr_db_at_one_frame": g0, "n_frames": counts}
    print(strict_json.dumps(output if len(results) > 1 else {**results[0], **{k: v for k, v in output.items() if k != "images"}},
                     indent=2))
    return EXIT_OK


def track_error_report(img) -> dict:
    """What ``analyze`` says of an autofocused image's estimated track error (and the vibration in it)."""
    from imaging.autofocus import fit_vibration

    te = img.track_error
    out = {"method": te.method, "applied": bool(img.attrs.get("autofocus_applied", 1)),
           "entropy_before": img.attrs.get("autofocus_entropy_before"), "entropy_after": img.attrs.get("autofocus_entropy_after"),
           "rms_m": te.rms_m, "peak_to_peak_m": float(np.ptp(te.displacement_m)), "duration_s": float(np.ptp(te.time_s)),
           "model": te.model}
    if out["applied"] and te.time_s.size >= 8:
        try:
            vib = fit_vibration(te)
        except ValueError:  # nothing that oscillates: no vibration to report
            out["vibration"] = None
        else:
            out["vibration"] = {"frequency_hz": vib.frequency_hz, "amplitude_m": vib.amplitude_m,
                                "phase_rad": vib.phase_rad, "phase_reference_time_ns": te.time_origin_ns}
    return out


def cmd_experiment(args) -> int:
    import importlib

    if args.name not in EXPERIMENTS:
        raise SarbotError(f"experiment {args.name!r}: unknown (known: {', '.join(EXPERIMENTS)})")
    module, function = EXPERIMENTS[args.name]
    out = Path(args.output)
    report = getattr(importlib.import_module(module), function)(out, quick=args.quick)
    print(f"sarbot experiment {args.name}: done in {report['elapsed_s']:.0f} s; wrote {out / 'report.md'} and its figures")
    return EXIT_OK
