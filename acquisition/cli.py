"""The ``sarbot`` command line.

Every user mistake (a missing file, a wrong schema, a bad grid, frames out of range, an unknown radar,
an invalid configuration value) ends with one line ``sarbot: error: ...`` naming it, and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path

import numpy as np

from imaging.core.errors import ConfigError, HardwareError, SarbotError

from .processes import configure_logging, ensure_jit_cache_dir

log = logging.getLogger(f"sarbot.{__name__}")

EXIT_OK = 0
EXIT_USAGE = 2  # bad input: arguments, files, configuration
EXIT_DISK_FULL = 3  # recording stopped: no space left; the file is readable up to its last flush
EXIT_HARDWARE = 4  # a device did not answer or refused its configuration (DCA1000, radar CLI)
EXIT_INTERRUPTED = 130


def _parse_frames(text: str | None) -> slice:
    if not text:
        return slice(None)
    parts = text.split(":")
    try:
        if len(parts) == 1:
            a = int(parts[0])
            return slice(a, a + 1)
        if len(parts) == 2:
            return slice(int(parts[0]) if parts[0] else None, int(parts[1]) if parts[1] else None)
    except ValueError:
        pass
    raise SarbotError(f"--frames {text!r}: expected A:B (frame indices, B excluded)")


def _parse_channels(text: str | None, name: str) -> tuple[int, ...] | None:
    if text is None or text == "all":
        return None
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise SarbotError(f"--{name} {text!r}: expected comma-separated channel indices or 'all'") from None


def _parse_xy(text: str, option: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
        return x, y
    except ValueError:
        raise SarbotError(f"{option} {text!r}: expected x,y in metres") from None


def _new_output(path, overwrite: bool, option: str = "") -> Path:
    """An output file path; one that exists already only with ``--overwrite`` (nothing is destroyed unasked)."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise SarbotError(f"{option}{path}: exists already (use --overwrite to replace it)")
    return path


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    raise TypeError(type(obj))


# -- commands -------------------------------------------------------------------------------------------
def cmd_simulate(args) -> int:
    from imaging.sim.scene import builtin_scene_names, load_scene
    from imaging.sim.simulator import simulate_recording

    from .progress import Progress

    if args.list:
        for name in builtin_scene_names():
            scene = load_scene(name)
            print(f"{name:18s} {scene.description.splitlines()[0] if scene.description else ''}")
        return EXIT_OK
    if not args.scene or not args.output:
        raise SarbotError("simulate needs a SCENE and -o OUTPUT (or --list)")
    scene = load_scene(args.scene)
    out = _new_output(args.output, args.overwrite)
    counts = simulate_recording(scene, out, progress=Progress("simulate"), overwrite=args.overwrite)
    print(f"wrote {out}: scene {scene.name}, " + ", ".join(f"{n} frames of {r}" for r, n in counts.items()))
    return EXIT_OK


def cmd_image(args) -> int:
    from imaging.autofocus import AutofocusOptions
    from imaging.image_formation import ImagingOptions, image_recording, image_title
    from imaging.io.image_file import write_image
    from imaging.io.recording import Recording
    from imaging.plot import ImagePicture

    from .progress import Progress

    out = Path(args.output)
    png = Path(args.png) if args.png else out.with_suffix(".png")
    for path in (out, png):
        if path.exists() and path.resolve() == Path(args.recording).resolve():
            raise SarbotError(f"{path}: that is the recording being imaged; choose another output")
        _new_output(path, args.overwrite)
    options = ImagingOptions(mode=args.mode, window=args.window, oversample=args.oversample,
                             tx=_parse_channels(args.tx, "tx"), rx=_parse_channels(args.rx, "rx"), algorithm=args.algorithm,
                             aperture_window=args.aperture_window)
    autofocus = AutofocusOptions(method=args.autofocus, sinusoids=args.autofocus_sinusoids)
    with Recording(args.recording) as rec:
        img = image_recording(rec, args.radar, args.grid, args.trajectory, _parse_frames(args.frames), options,
                              progress=Progress("backproject"), autofocus=autofocus, imu_aided=args.imu_aided,
                              aperture_m=args.aperture)
    path = write_image(out, img)
    # Not laid out beside the backprojection: its kernel has every core, and the figure's Python then holds
    # the GIL the kernel's calls need (0.15 s slower than after it, benchmarks/image_command.py).
    ImagePicture(img.x_m, img.y_m).save(png, img.image, title=image_title(img))  # a volume: its maximum over height
    print(f"wrote {path} and {png}")
    if img.track_error is not None:
        print(autofocus_summary(img))
    return EXIT_OK


def autofocus_summary(img) -> str:
    """One line on what autofocus (and the radar's IMU) found and did."""
    a = img.attrs
    te = img.track_error
    if "autofocus" not in a:  # the radar's IMU alone
        return f"imu-aided: the radar's IMU moved it {1e3 * te.rms_m:.3f} mm rms along the boresight over {np.ptp(te.time_s):.2f} s"
    if not a.get("autofocus_applied"):
        return (f"autofocus ({a['autofocus']}): nothing to gain (image entropy {a['autofocus_entropy_before']:.3f}); "
                "the image is formed on the trajectory as it is")
    return (f"autofocus ({a['autofocus']}{' on the radar IMU' if a.get('imu_aided') else ''}): track error {1e3 * te.rms_m:.3f} mm rms along the boresight over "
            f"{np.ptp(te.time_s):.2f} s; entropy {a['autofocus_entropy_before']:.3f} -> {a['autofocus_entropy_after']:.3f}")


def cmd_batch(args) -> int:
    import json
    import os

    from .batch import parse_sweep, plan_jobs, run_batch
    from .progress import Progress

    if args.workers < 1:
        raise SarbotError(f"--workers {args.workers}: must be at least 1")
    if args.tile_frames is not None and args.tile_frames < 1:
        raise SarbotError(f"--tile-frames {args.tile_frames}: must be at least 1")
    frames = _parse_frames(args.frames)
    threads = None if args.scheduler else max(1, (os.cpu_count() or 1) // args.workers)
    base = {"mode": args.mode, "window": args.window, "oversample": args.oversample, "algorithm": args.algorithm,
            "aperture_window": args.aperture_window, "autofocus": args.autofocus, "aperture_m": args.aperture}
    jobs = plan_jobs(args.recordings, args.grid, args.output, radar=args.radar, frames=(frames.start, frames.stop),
                     tile_frames=args.tile_frames, sweep=parse_sweep(args.sweep), base_options=base,
                     trajectory=args.trajectory, png=args.png, threads=threads)
    out_dir = Path(args.output)
    out_dir.mkdir(parents=True, exist_ok=True)
    for job in jobs:
        _new_output(Path(job.output), args.overwrite)
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es)"
    log.info("%d image(s) on %s", len(jobs), where)
    results = run_batch(jobs, args.scheduler, args.workers, progress=Progress("batch", unit="image"))
    summary = out_dir / "batch.json"
    summary.write_text(json.dumps({"cluster": where, "jobs": results}, indent=2))
    failed = [r for r in results if r["error"]]
    for r in results:
        if not r["error"]:
            print(f"wrote {r['output']} ({r['seconds']:.1f} s)")
    for r in failed:
        print(f"sarbot: error: {r['label']}: {r['error']}", file=sys.stderr)
    print(f"wrote {summary}: {len(results) - len(failed)} of {len(results)} images")
    return EXIT_USAGE if failed else EXIT_OK


def cmd_analyze(args) -> int:
    from imaging import metrics
    from imaging.io.image_file import read_image

    results = []
    for name in args.images:
        img = read_image(name)
        if img.image.ndim != 2:
            raise SarbotError(f"{name}: analyze works on 2-D images; this one is {img.image.ndim}-D")
        near = _parse_xy(args.at, "--at") if args.at else None
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
    print(json.dumps(output if len(results) > 1 else {**results[0], **{k: v for k, v in output.items() if k != "images"}},
                     indent=2, default=_json_default))
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


def cmd_rio(args) -> int:
    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import write_trajectory, write_tum
    from rio.ekf import EkfConfig
    from rio.odometry import (
        RioOptions,
        imu_from_recording,
        run_rio,
        scans_from_recording,
    )

    from .progress import Progress

    with Recording(args.recording) as rec:
        radars = tuple(args.radar) if args.radar else None
        for name in radars or ():
            rec.radar(name)  # a clear error for an unknown name
        imu = imu_from_recording(rec)
        scans = scans_from_recording(rec, radars)
        if not scans:
            raise SarbotError(f"{args.recording}: no radar detections to run odometry on")
        truth = rec.truth()
    start = {}
    if args.start_from_truth:
        if truth is None:
            raise SarbotError(f"{args.recording}: --start-from-truth needs /truth, and this recording has none")
        first = truth.sample(imu.time_ns[:1])
        start = {"initial_position_m": tuple(first.position_m[0]),
                 "initial_yaw_rad": float(first.rotation.as_euler("ZYX")[0, 0])}
    options = RioOptions(ekf=EkfConfig(planar=args.planar, radar_velocity_sigma_floor_mps=args.velocity_floor),
                         joint_radars=args.joint, static_init_s=args.static_init, **start)
    try:
        result = run_rio(imu, scans, options, progress=Progress("rio"))
    except FloatingPointError as exc:
        print(f"sarbot: odometry failed: {exc}", file=sys.stderr)
        return 1
    path = write_trajectory(args.output, result.trajectory, result.covariance_diag)
    if args.tum:
        write_tum(args.tum, result.trajectory)
    summary = {"trajectory": str(path), "poses": int(result.trajectory.time_ns.size), **result.stats}
    if truth is not None:
        from rio.evaluation import drift_report

        summary["against_truth"] = drift_report(result.trajectory, truth)
    print(json.dumps(summary, indent=2, default=_json_default))
    return EXIT_OK


def cmd_import_bag(args) -> int:
    from .importers.bag import import_bag
    from .progress import Progress

    out = _new_output(args.output, args.overwrite)
    counts = import_bag(args.bag, args.calib, out, radar_name=args.radar_name, overwrite=args.overwrite,
                        progress=Progress("import"))
    print(f"wrote {out}: " + ", ".join(f"{k} {v:.6g}" for k, v in counts.items()))
    return EXIT_OK


def cmd_import_ti(args) -> int:
    from .importers.ti_capture import import_ti_capture
    from .progress import Progress

    velocity = _floats(args.velocity, 3, "--velocity")
    out = _new_output(args.output, args.overwrite)
    swap = {"auto": None, "yes": True, "no": False}[args.iq_swap]
    got = import_ti_capture(args.capture, args.cfg, out, layout=args.layout, sample_format=args.sample_format,
                            iq_swap=swap, radar_name=args.radar_name, velocity_mps=velocity, overwrite=args.overwrite,
                            progress=Progress("import"))
    print(f"wrote {out}: {got['frames']} frames, layout {got['layout']}{' (Q before I)' if got['iq_swap'] else ''}, "
          f"{got['sample_format']} samples, sideband ratio {got['sideband_db']:+.1f} dB")
    return EXIT_OK


def _floats(text: str, n: int, option: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise SarbotError(f"{option} {text!r}: expected {n} finite numbers separated by commas")
    return values


def _radar_targets(items: list[str] | None) -> dict[str, tuple[str, int]]:
    """``--radar NAME=[HOST:]PORT`` of replay: where to send each radar's datagrams."""
    out = {}
    for item in items or []:
        try:
            name, where = item.split("=", 1)
            host, port = where.rsplit(":", 1) if ":" in where else ("127.0.0.1", where)
            out[name] = (host, int(port))
        except ValueError:
            raise SarbotError(f"--radar {item!r}: expected NAME=[HOST:]PORT") from None
        if not name or not host or not 0 < out[name][1] < 65536:
            raise SarbotError(f"--radar {item!r}: expected NAME=[HOST:]PORT with a port in 1..65535")
    return out


def _named_paths(items: list[str] | None, option: str) -> dict[str, str]:
    """``OPTION NAME=PATH`` given once per radar: radar -> path."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, path = item.partition("=")
        if not (sep and name and path):
            raise SarbotError(f"{option} {item!r}: expected NAME=PATH")
        if name in out:
            raise SarbotError(f"{option} {item!r}: radar {name} given twice")
        out[name] = path
    return out


def _can_config(args):
    if not args.can:
        return None
    from drivers.can_driver import CanConfig

    interface, _, channel = args.can.partition(":")
    options = {}
    for item in args.can_arg or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SarbotError(f"--can-arg {item!r}: expected KEY=VALUE")
        options[key] = int(value) if value.lstrip("-").isdigit() else value
    try:
        trigger = int(args.can_trigger_id, 0) if args.can_trigger_id.lower() != "none" else None
    except ValueError:
        raise SarbotError(f"--can-trigger-id {args.can_trigger_id!r}: expected an arbitration id such as 0x100, or none") from None
    return CanConfig(interface, channel or None, trigger, options)


def _size_bytes(text: str | None, option: str = "--split-size") -> int | None:
    if text is None:
        return None
    units = {"k": 1e3, "m": 1e6, "g": 1e9}
    t = text.strip().lower().removesuffix("b")
    try:
        value = float(t[:-1]) * units[t[-1]] if t and t[-1] in units else float(t)
    except ValueError:
        raise SarbotError(f"{option} {text!r}: expected a size such as 500M or 2G") from None
    if not (math.isfinite(value) and value > 0):
        raise SarbotError(f"{option} {text!r}: must be a positive size")
    return int(value)


def check_duration(value: float | None, option: str = "--duration") -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise SarbotError(f"{option} {value}: must be a positive number of seconds")


def check_replay(args) -> dict[str, tuple[str, int]]:
    """The replay options, checked before anything is opened or sent; returns the radars' targets."""
    targets = _radar_targets(args.radar)
    _named_paths(args.radar_imu_link, "--radar-imu-link")
    if not math.isfinite(args.speed) or args.speed < 0:
        raise SarbotError(f"--speed {args.speed}: must be a multiple of real time >= 0 (0: as fast as possible)")
    if not math.isfinite(args.start_delay) or args.start_delay < 0:
        raise SarbotError(f"--start-delay {args.start_delay}: must be a number of seconds >= 0")
    if args.laps < 1:
        raise SarbotError(f"--laps {args.laps}: must be at least 1")
    _can_config(args)
    return targets


def record_setup(args):
    """The daemon's Setup from record/run options (shared by both commands)."""
    import dataclasses

    from drivers.radar.link import parse_radar_link
    from imaging.core.rig import AntennaArray, Rig, load_rig

    from .daemon import Setup

    rig = load_rig(args.config)
    specs = list(args.radar or [])
    for item in args.dca1000 or []:  # shorthand: NAME=PORT:CFG is NAME=PORT,format=DCA1000,cfg=CFG
        name, sep, rest = item.partition("=")
        port, sep2, cfg_path = rest.partition(":")
        if not (sep and sep2 and port.isdigit()):
            raise SarbotError(f"--dca1000 {item!r}: expected NAME=PORT:CFG_FILE")
        specs.append(f"{name}={port},format=DCA1000,cfg={cfg_path}")
    links = [parse_radar_link(spec) for spec in specs]
    radars = {r.name: r for r in rig.radars}
    for link in links:
        if link.name not in radars:
            raise SarbotError(f"radar {link.name}: no such radar in {args.config} (radars: {', '.join(rig.radar_names)})")
        wf = link.waveform(radars[link.name].waveform)
        if wf != radars[link.name].waveform:  # the link's configuration says what the radar sends; the rig where it sits
            radars[link.name] = dataclasses.replace(radars[link.name], waveform=wf, array=AntennaArray.uniform_tdm(wf))
    rig = Rig(tuple(radars.values()), rig.imu)
    radar_imu_ports = _named_paths(args.radar_imu, "--radar-imu")
    for name, port in radar_imu_ports.items():
        if name not in radars:
            raise SarbotError(f"--radar-imu {name}={port}: no such radar in {args.config} (radars: {', '.join(rig.radar_names)})")
        if radars[name].imu is None:
            raise SarbotError(f"--radar-imu {name}={port}: {args.config} declares no IMU on radar {name}; add a "
                              f"[radar.{name}.imu] table with its rate_hz (its axes are the radar's)")
    can = _can_config(args)
    if not links and not args.imu_port and not radar_imu_ports and can is None:
        raise SarbotError("nothing to record: give --radar NAME=[HOST:]PORT, --dca1000 NAME=PORT:CFG, --imu-port DEVICE, "
                          "--radar-imu NAME=DEVICE and/or --can")
    check_duration(args.split_time, "--split-time")
    return Setup(rig, links, args.imu_port, can, radar_imu_ports=radar_imu_ports,
                 split_bytes=_size_bytes(args.split_size), split_s=args.split_time,
                 min_free_bytes=_size_bytes(args.min_free, "--min-free"), health_endpoint=args.health_endpoint,
                 controls=_ti_controls(args, links))


def _ti_controls(args, links) -> list:
    """What --dca1000-arm and --radar-cli ask sarbot to drive, one TiRadarControl per radar."""
    from drivers.radar.ti_arming import TiRadarControl, parse_arm_option

    dca_links = {link.name: link for link in links if link.wire_format == "DCA1000"}
    per_radar: dict[str, dict] = {}

    def link_of(name: str, option: str):
        if name not in dca_links:
            raise SarbotError(f"{option} {name}: not a DCA1000 radar of this recording (give it with --dca1000 "
                              f"{name}=PORT:CFG{'; DCA1000 radars: ' + ', '.join(dca_links) if dca_links else ''})")
        return dca_links[name]

    for item in getattr(args, "dca1000_arm", None) or []:
        try:
            name, kwargs = parse_arm_option(item)
        except ValueError as exc:
            raise SarbotError(f"--dca1000-arm {item!r}: {exc}") from None
        link_of(name, "--dca1000-arm")
        per_radar.setdefault(name, {}).update(kwargs)
    for item in getattr(args, "radar_cli", None) or []:
        name, sep, device = item.partition("=")
        if not (name and sep and device):
            raise SarbotError(f"--radar-cli {item!r}: expected NAME=DEVICE")
        link_of(name, "--radar-cli")
        if not Path(device).exists():
            raise SarbotError(f"--radar-cli {item!r}: no such device {device}")
        per_radar.setdefault(name, {})["cli_port"] = device
    return [TiRadarControl(name, str(dca_links[name].options["cfg"]), dca_links[name].port, **kwargs)
            for name, kwargs in per_radar.items()]


def _record(setup, out: Path, duration_s: float | None, extra_paths=(), **kwargs) -> int:
    """Run the daemon (``record`` and ``run``); say what it wrote, or that the disk filled up."""
    from .daemon import record
    from .recorder import DiskFullError

    try:
        paths = record(setup, out, duration_s=duration_s, **kwargs)
    except DiskFullError as exc:
        print(f"sarbot: error: {exc.strerror} (the file holds everything up to the last flush)", file=sys.stderr)
        return EXIT_DISK_FULL
    for path in [*paths, *extra_paths]:
        if path.exists():
            print(f"wrote {path}")
    return EXIT_OK


def cmd_record(args) -> int:
    setup = record_setup(args)
    check_duration(args.duration)
    return _record(setup, Path(args.output), args.duration)


#: The strip map's settings (``StripMapConfig``) as ``sarbot run`` options.
MAP_OPTIONS = {"pixel_m": "--map-pixel", "aperture_m": "--map-aperture", "range_min_m": "--map-range",
               "range_max_m": "--map-range", "z_m": "--map-height", "refocus": "--map-refocus",
               "algorithm": "--map-algorithm", "ffbp_block_frames": "--map-ffbp-block"}


def run_workers(setup, args, out_dir: Path, stamp: str):
    """Add the RIO and strip-map workers to ``setup`` from the run options."""
    from imaging.stripmap import StripMapConfig

    from .workers.pipeline import add_pipeline_workers

    if not setup.imu_port:
        raise SarbotError("run needs --imu-port: the strip map is placed by radar-inertial odometry")
    names = {link.name for link in setup.radars}
    if args.map_presum == "auto":
        presum = None
    elif args.map_presum.isdigit() and int(args.map_presum) >= 1:
        presum = int(args.map_presum)
    else:
        raise SarbotError(f"--map-presum {args.map_presum!r}: expected 'auto' or a positive integer")
    map_radars = _names(args.map_radars, "--map-radars", names)
    if args.map_imu_aided and not set(setup.radar_imu_ports) & set(map_radars):
        raise SarbotError("--map-imu-aided: no mapped radar has an IMU of its own; give --radar-imu NAME=DEVICE "
                          f"for one of {', '.join(map_radars)}")
    try:
        config = StripMapConfig(pixel_m=args.map_pixel, aperture_m=args.map_aperture, range_min_m=args.map_range[0],
                                range_max_m=args.map_range[1], z_m=args.map_height, refocus=args.map_refocus,
                                refocus_imu_aided=args.map_imu_aided, algorithm=args.map_algorithm,
                                ffbp_block_frames=args.map_ffbp_block)
    except ConfigError as e:  # say it in the options the user typed
        option = MAP_OPTIONS.get(e.field)
        raise SarbotError(str(e).replace(f"{e.field}:", f"{option} ({e.field}):", 1) if option else str(e)) from None
    if args.map_threads < 1:
        raise SarbotError(f"--map-threads {args.map_threads}: must be at least 1")
    from .workers.stripmap import is_thinning

    if not is_thinning(args.map_max_thinning):
        raise SarbotError(f"--map-max-thinning {args.map_max_thinning}: must be 1, 2, 4, 8, ... (1: image every frame)")
    view = None
    if args.view:
        from .workers.view import parse_view_address

        view = parse_view_address(args.view)
    return add_pipeline_workers(setup, out_dir, stamp, config, args.max_speed,
                                map_radars, _names(args.rio_radars, "--rio-radars", names),
                                presum, view, args.map_threads, args.map_max_thinning)


def _names(text: str | None, option: str, known: set[str]) -> list[str]:
    if not text:
        return sorted(known)
    names = [n.strip() for n in text.split(",") if n.strip()]
    for n in names:
        if n not in known:
            raise SarbotError(f"{option} {n}: not a radar being recorded ({', '.join(sorted(known))})")
    return names


def cmd_run(args) -> int:
    import time

    setup = record_setup(args)
    check_duration(args.duration)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    out = Path(args.output)
    traj_path, map_path, config = run_workers(setup, args, out, stamp)
    print(f"sarbot run: strip map {config.pixel_m * 100:g} cm pixels, aperture {config.aperture_m} m, "
          f"pre-summing {config.presum}")
    return _record(setup, out, args.duration, (traj_path, map_path, map_path.with_suffix(".png")),
                   path=out / f"recording_{stamp}.h5")


def cmd_replay(args) -> int:
    from .replay import replay

    targets = check_replay(args)
    radar_imus = _named_paths(args.radar_imu_link, "--radar-imu-link")
    sent = replay(Path(args.recording), targets, args.imu_link, None if args.speed <= 0 else args.speed, args.start_delay,
                  can=_can_config(args), laps=args.laps, radar_imu_links=radar_imus)
    imus = (["the IMU"] if args.imu_link else []) + [f"the IMU on {name}" for name in radar_imus]
    print("replayed " + ", ".join(f"{n}: {k} {'frames' if n == 'can' else 'datagrams'}" for n, k in sent.items())
          + (" and " + ", ".join(imus) if imus else ""))
    return EXIT_OK


def cmd_export(args) -> int:
    from .exporters.mcap_file import export_mcap
    from .exporters.ros2_bag import export_ros2
    from .progress import Progress

    progress = Progress("export", unit="frame")
    if args.ros2 and (args.map or args.trajectory):
        raise SarbotError("--map and --trajectory go into MCAP only (ROS 2 has no message for a dB map); leave out --ros2")
    if args.ros2:
        counts = export_ros2(args.recording, args.output, storage=args.storage, progress=progress)
    else:
        counts = export_mcap(args.recording, args.output, overwrite=args.overwrite, progress=progress,
                             maps=args.map or (), trajectories=args.trajectory or ())
    print(f"wrote {args.output}: " + ", ".join(f"{topic} {n}" for topic, n in counts.items()))
    return EXIT_OK


def cmd_info(args) -> int:
    from .info import format_info, info

    if args.tum and len(args.files) != 1:
        raise SarbotError("--tum: give one file (a recording's /truth or a trajectory)")
    reports = [info(path) for path in args.files]
    if args.json:
        print(json.dumps(reports if len(reports) > 1 else reports[0], indent=2, default=_json_default))
    else:
        print("\n".join(format_info(r) for r in reports))
    if args.tum:
        from imaging.io.recording import Recording
        from imaging.io.trajectory_file import read_trajectory, write_tum

        report = reports[0]
        if report["kind"] == "trajectory":
            traj = read_trajectory(args.files[0])
        elif report["kind"] == "recording":
            with Recording(args.files[0]) as rec:
                traj = rec.truth()
            if traj is None:
                raise SarbotError(f"--tum: {args.files[0]} has no /truth to export")
        else:
            raise SarbotError(f"--tum: {args.files[0]} is an image; give a recording or a trajectory")
        out = _new_output(args.tum, args.overwrite, "--tum ")
        write_tum(out, traj)
        print(f"wrote {out} ({traj.time_ns.size} poses, TUM format for evo)", file=sys.stderr if args.json else sys.stdout)
    return EXIT_OK


def bash_completion(parser: argparse.ArgumentParser) -> str:
    """A bash completion script for ``parser``: the commands, and each command's options."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    top = [o for a in parser._actions for o in a.option_strings]
    cases = []
    for name, p in sub.choices.items():
        options = " ".join(o for a in p._actions for o in a.option_strings)
        cases.append(f'        {name}) opts="{options}" ;;')
    return "\n".join([
        "# bash completion for sarbot: eval \"$(sarbot completion bash)\" (e.g. in ~/.bashrc)",
        "_sarbot() {",
        '    local cur="${COMP_WORDS[COMP_CWORD]}" cmd="" opts="" w',
        '    for w in "${COMP_WORDS[@]:1:COMP_CWORD-1}"; do case "$w" in -*) ;; *) cmd="$w"; break ;; esac; done',
        '    if [ -z "$cmd" ]; then',
        f'        COMPREPLY=($(compgen -W "{" ".join(sub.choices)} {" ".join(top)}" -- "$cur")); return',
        "    fi",
        '    case "$cmd" in',
        *cases,
        "    esac",
        '    if [[ "$cur" == -* ]]; then COMPREPLY=($(compgen -W "$opts" -- "$cur")); else COMPREPLY=($(compgen -f -- "$cur")); fi',
        "}",
        "complete -o filenames -F _sarbot sarbot",
        ""])


def cmd_completion(args) -> int:
    print(bash_completion(build_parser()), end="")
    return EXIT_OK


def cmd_install_unit(args) -> int:
    from .install import InstallPlan, install_unit

    plan = InstallPlan(root=Path(args.root), venv=args.venv, user=args.user,
                       config=Path(args.config) if args.config else None, command=args.command, devices=args.devices,
                       source=args.source or "", constraints=Path(args.constraints) if args.constraints else None,
                       no_deps=args.no_deps)
    done = install_unit(plan)
    for kind, paths in done.items():
        for path in paths:
            print(f"{kind}: {path}")
    staged = Path(args.root) != Path("/")
    print(("staged under " + args.root + "; on the robot: " if staged else "installed; next: ")
          + "systemctl daemon-reload && systemctl enable --now sarbot.target"
          + " (edit /etc/sarbot/sarbot.env for this robot's devices first)")
    return EXIT_OK


def cmd_experiment(args) -> int:
    from .studies.paper import run_paper

    if args.name != "paper":
        raise SarbotError(f"experiment {args.name!r}: unknown (known: paper)")
    out = Path(args.output)
    report = run_paper(out, quick=args.quick)
    print(f"sarbot experiment paper: done in {report['elapsed_s']:.0f} s; wrote {out / 'report.md'} and its figures")
    return EXIT_OK


def cmd_demo(args) -> int:
    from .studies.demo import run_demo

    if not (math.isfinite(args.speed) and args.speed > 0):
        raise SarbotError(f"--speed {args.speed}: must be positive")
    view = None
    if args.view:
        from .workers.view import parse_view_address

        view = parse_view_address(args.view)
    return run_demo(Path(args.output), speed=args.speed, view=view)


# -- parser ---------------------------------------------------------------------------------------------
def _range_pair(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected MIN:MAX in metres") from None
    if not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"{text!r}: need 0 <= MIN < MAX")
    return lo, hi


def _can_options(s) -> None:
    s.add_argument("--can", help="python-can INTERFACE[:CHANNEL], e.g. socketcan:can0 or udp_multicast:239.74.163.2")
    s.add_argument("--can-arg", action="append", help="KEY=VALUE passed to python-can's Bus (repeat), e.g. port=43113")
    s.add_argument("--can-trigger-id", default="0x100", help="arbitration id of the sync box's trigger frame (default 0x100; 'none')")


def _acquisition_options(s) -> None:
    s.add_argument("--config", required=True, help="rig TOML")
    s.add_argument("-o", "--output", required=True, help="folder for the recording")
    s.add_argument("--radar", action="append", metavar="NAME=[HOST:]PORT[,format=FORMAT][,OPTION=VALUE]",
                   help="where a radar's datagrams arrive (repeat per radar); HOST is the address to listen on "
                        "(default 127.0.0.1); FORMAT one of the registered wire formats (default SRF1), e.g. "
                        "format=DCA1000,cfg=xwr18xx.cfg")
    s.add_argument("--dca1000", action="append", metavar="NAME=PORT:CFG",
                   help="shorthand for --radar NAME=PORT,format=DCA1000,cfg=CFG (a TI radar through a DCA1000)")
    s.add_argument("--dca1000-arm", action="append", metavar="NAME[=HOST[:PORT]][,listen=[HOST:]PORT][,lanes=2|4][,delay_us=US]",
                   help="arm that --dca1000 radar's capture card before recording and stop it after (its configuration "
                        "protocol; default address 192.168.33.180:4096, replies on this host's port 4096, 2 LVDS lanes "
                        "(4 for xWR12xx/14xx), packet delay 25 us)")
    s.add_argument("--radar-cli", action="append", metavar="NAME=DEVICE",
                   help="send that --dca1000 radar's .cfg to its CLI serial port (each line must be answered Done), "
                        "sensorStart once the DCA1000 records, sensorStop at the end")
    s.add_argument("--imu-port", help="serial device of the Xsens IMU (or the pty replay links)")
    s.add_argument("--radar-imu", action="append", metavar="NAME=DEVICE",
                   help="serial device of the Xsens IMU on that radar's own mount (repeat per radar; the rig declares it "
                        "as [radar.NAME.imu]); recorded in /radar/NAME/imu for `sarbot image --imu-aided`")
    _can_options(s)
    s.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C / SIGTERM)")
    s.add_argument("--split-size", help="start a new file at this size (e.g. 2G)")
    s.add_argument("--split-time", type=float, help="start a new file after this many seconds")
    s.add_argument("--min-free", default="64M", help="stop recording cleanly when less disk space than this is left (default 64M)")
    s.add_argument("--health-endpoint", help="ZeroMQ endpoint to publish health on (default: a free loopback port, logged)")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("sarbot")
    except PackageNotFoundError:  # run from a checkout that is not installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    from imaging.autofocus import METHODS  # autofocus methods registered by now are offered
    p = argparse.ArgumentParser(prog="sarbot", description="SAR imaging and radar-inertial odometry for mobile robots.")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only (no progress, no info lines)")
    p.add_argument("--version", action="version", version=f"sarbot {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("simulate", help="simulate a scene into a recording",
                       epilog="example: sarbot simulate --list; sarbot simulate paper_pass_0.4 -o pass.h5; sarbot simulate my_scene.toml -o rec.h5")
    s.add_argument("scene", nargs="?", help="built-in scene name or scene TOML file")
    s.add_argument("-o", "--output", help="recording file to write (.h5)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    s.add_argument("--list", action="store_true", help="list the built-in scenes")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("image", help="form a SAR image by backprojection",
                       epilog="example: sarbot image pass.h5 -o img.h5 --radar left_front --frames 30:60 --grid -0.5:0.5:0.002,1.8:2.2:0.004")
    s.add_argument("recording")
    s.add_argument("-o", "--output", required=True, help="image file to write (.h5); a PNG goes beside it")
    s.add_argument("--radar", help="radar name (needed when the recording has several)")
    s.add_argument("--frames", help="frame range A:B (B excluded); all by default")
    s.add_argument("--aperture", type=float, metavar="METRES",
                   help="image only the central METRES of the frames' track (a synthetic aperture of that length)")
    s.add_argument("--grid", required=True, help="x0:x1:dx,y0:y1:dy[,z or z0:z1:dz] in metres, world frame")
    s.add_argument("--trajectory", default="truth", help="'truth' or a trajectory HDF5 file")
    s.add_argument("--mode", default="linear", choices=["nearest", "linear", "exact"])
    s.add_argument("--window", default="hann", choices=["rectangular", "hann", "hamming", "taylor"])
    s.add_argument("--oversample", type=int, default=16, help="range FFT zero-padding factor (default 16: >= 60 dB signal-to-error with linear interpolation)")
    s.add_argument("--aperture-window", default="rectangular", choices=["rectangular", "hann", "hamming", "taylor"],
                   help="slow-time taper over the aperture (default rectangular: -13.3 dB side lobes across range; "
                        "taylor: -35 dB, a 1.34x wider main lobe; analyze's theory allows for it)")
    s.add_argument("--algorithm", default="direct", choices=["direct", "ffbp"],
                   help="direct: every profile onto every pixel (default); ffbp: fast factorized backprojection, "
                        "a horizontal plane to one side of the track, about 25x faster on a 2 m aperture at about "
                        "-44 dB from the direct image (its bound and estimate go into the file)")
    s.add_argument("--tx", help="TX channels, e.g. 0,2 (default all)")
    s.add_argument("--rx", help="RX channels, e.g. 0 (default all)")
    s.add_argument("--png", help="where to write the PNG (default: beside the image)")
    s.add_argument("--autofocus", default="none", choices=list(METHODS),
                   help="estimate the radar's track error along its boresight (vibration, odometry drift) from the "
                        "image and form it again: pga (phase gradient) or entropy (minimum entropy over a bend plus "
                        "sinusoids; the default choice for vibration). The estimate goes into the file; analyze reports it")
    s.add_argument("--autofocus-sinusoids", type=int, default=1, help="sinusoids in the entropy model (0-4, default 1)")
    s.add_argument("--imu-aided", action="store_true",
                   help="correct the track by the IMU on the radar's own mount first (a rig's [radar.NAME.imu]); "
                        "autofocus, if asked for, estimates what is left")
    s.add_argument("--overwrite", action="store_true", help="replace existing output files")
    s.set_defaults(func=cmd_image)

    s = sub.add_parser("batch", help="many images on a Dask cluster: recordings, tiles of a long drive, parameter sweeps",
                       epilog="examples: sarbot batch a.h5 b.h5 c.h5 d.h5 --grid -0.5:0.5:0.004,1.5:2.5:0.004 -o images/; "
                              "sarbot batch drive.h5 --tile-frames 40 --grid ... -o tiles/; "
                              "sarbot batch pass.h5 --sweep aperture_m=0.14,0.34,1.0 --sweep autofocus=none,entropy "
                              "--grid ... -o sweep/ "
                              "--scheduler tcp://cluster:8786")
    s.add_argument("recordings", nargs="+", help="recording files")
    s.add_argument("--grid", required=True, help="x0:x1:dx,y0:y1:dy[,z] in metres, world frame (as for image)")
    s.add_argument("-o", "--output", required=True, help="folder for the images and batch.json (one summary per image)")
    s.add_argument("--radar", help="radar name (needed when a recording has several)")
    s.add_argument("--frames", help="frame range A:B (B excluded) of every recording; all by default")
    s.add_argument("--tile-frames", type=int, help="one image per this many consecutive frames (a long drive, tile by tile)")
    s.add_argument("--sweep", action="append", metavar="KEY=V1,V2,...",
                   help="vary an option (mode, window, oversample, algorithm, aperture_window, autofocus, aperture_m); several --sweep "
                        "make every combination")
    s.add_argument("--trajectory", default="truth", help="'truth' or a trajectory HDF5 file, for every recording")
    s.add_argument("--mode", default="linear", choices=["nearest", "linear", "exact"])
    s.add_argument("--window", default="hann", choices=["rectangular", "hann", "hamming", "taylor"])
    s.add_argument("--oversample", type=int, default=16)
    s.add_argument("--aperture-window", default="rectangular", choices=["rectangular", "hann", "hamming", "taylor"],
                   help="as for image (default rectangular)")
    s.add_argument("--algorithm", default="direct", choices=["direct", "ffbp"], help="as for image (default direct)")
    s.add_argument("--autofocus", default="none", choices=list(METHODS), help="as for image (default none)")
    s.add_argument("--aperture", type=float, metavar="METRES", help="as for image: only the central METRES of each track")
    s.add_argument("--png", action="store_true", help="a PNG beside every image")
    s.add_argument("--scheduler", metavar="ADDRESS", help="a running dask.distributed scheduler (tcp://host:8786); its "
                   "workers need sarbot and the files at the same paths. Default: a local cluster")
    s.add_argument("--workers", type=int, default=2, help="worker processes of the local cluster (default 2)")
    s.add_argument("--overwrite", action="store_true", help="replace existing images")
    s.set_defaults(func=cmd_batch)

    s = sub.add_parser("analyze", help="image quality metrics as JSON",
                       epilog="example: sarbot analyze img.h5 --at 0,2; sarbot analyze a.h5 b.h5 c.h5 (integration gain)")
    s.add_argument("images", nargs="+", help="image file(s); several with different frame counts also fit the integration gain")
    s.add_argument("--at", help="x,y: analyse the peak nearest this point (default: the strongest)")
    s.add_argument("--radius", type=float, default=0.1, help="search radius around --at, metres")
    s.add_argument("--vibration", action="store_true", help="infer f_vib and A_vib from paired cross-range side lobes")
    s.add_argument("--half-length", type=float, default=0.3, help="half length of the cuts, metres")
    s.set_defaults(func=cmd_analyze)

    s = sub.add_parser("rio", help="radar-inertial odometry: a trajectory from IMU and radar detections",
                       epilog="example: sarbot simulate rio_room_drive -o drive.h5; sarbot rio drive.h5 -o traj.h5 --tum traj.txt")
    s.add_argument("recording")
    s.add_argument("-o", "--output", required=True, help="trajectory file to write (.h5)")
    s.add_argument("--tum", help="also write TUM text (t x y z qx qy qz qw) for evo")
    s.add_argument("--radar", action="append", help="radar to use (repeat; default all with detections)")
    s.add_argument("--joint", action="store_true", help="solve simultaneous scans of all radars together")
    s.add_argument("--planar", action="store_true", help="robot on a flat floor: no vertical velocity")
    s.add_argument("--static-init", type=float, default=1.0, help="seconds of standstill at the start (default 1)")
    s.add_argument("--start-from-truth", action="store_true",
                   help="start at the first /truth pose instead of the origin (simulations; to image in the scene's frame)")
    s.add_argument("--velocity-floor", type=float, default=0.05,
                   help="m/s added to every radar velocity's uncertainty: timing jitter, Doppler quantisation, "
                        "motion within a frame (default 0.05; 0.1 for a hand-held rig)")
    s.set_defaults(func=cmd_rio)

    s = sub.add_parser("import-bag", help="convert a ROS 1 or ROS 2 bag (IMU, radar point clouds, trigger) to a recording",
                       epilog="example: sarbot import-bag demo.bag --calib calib.yaml -o rec.h5 (a ROS 2 bag: give its folder)")
    s.add_argument("bag")
    s.add_argument("--calib", required=True, help="calibration YAML (topics, radar extrinsics, frame length)")
    s.add_argument("-o", "--output", required=True)
    s.add_argument("--radar-name", default="radar")
    s.add_argument("--overwrite", action="store_true")
    s.set_defaults(func=cmd_import_bag)

    s = sub.add_parser("import-ti", help="convert a TI raw ADC capture (adc_data.bin and the radar's .cfg) to a recording",
                       epilog="example: sarbot import-ti adc_data.bin --cfg profile.cfg -o rec.h5 --velocity 0,0.05,0 "
                              "(a radar on a rail moving 5 cm/s to its left; layout and sample format are found from the data)")
    s.add_argument("capture", nargs="+", help="capture file(s), in order (mmWave Studio splits long captures)")
    s.add_argument("--cfg", required=True, help="the TI .cfg the radar ran (waveform, chirps, RX, frame period)")
    s.add_argument("-o", "--output", required=True)
    s.add_argument("--layout", default="auto", choices=["auto", "lvds2", "lvds4", "interleaved"],
                   help="lvds2: xWR16xx/18xx/68xx; lvds4: xWR12xx/14xx; interleaved: channel-interleaved I/Q pairs "
                        "(default auto: the reading whose beat signal is one-sided)")
    s.add_argument("--sample-format", default="auto", choices=["auto", "twos", "offset"],
                   help="two's complement or offset binary (default auto)")
    s.add_argument("--iq-swap", default="auto", choices=["auto", "yes", "no"],
                   help="Q before I (default: as found, or as the .cfg's adcbufCfg says when --layout is given)")
    s.add_argument("--velocity", default="0,0,0", help="VX,VY,VZ: the radar's constant velocity in m/s, world frame; it "
                   "starts at the origin looking along +x (default 0,0,0: at rest). Written to /truth")
    s.add_argument("--radar-name", default="ti")
    s.add_argument("--overwrite", action="store_true")
    s.set_defaults(func=cmd_import_ti)

    s = sub.add_parser("record", help="run the drivers and record everything to HDF5",
                       epilog="example: sarbot record --config rig.toml -o out/ --radar left_front=50001 --imu-port /dev/ttyUSB0 --split-time 600")
    _acquisition_options(s)
    s.set_defaults(func=cmd_record)

    s = sub.add_parser("run", help="the whole pipeline: drivers, recorder, odometry and the live strip map",
                       epilog="example: sarbot run --config rig.toml -o out/ --radar left_front=192.168.33.30:50001 --imu-port /dev/ttyUSB0 --view 8765")
    _acquisition_options(s)
    s.add_argument("--map-aperture", type=float, default=0.3, help="synthetic aperture per pixel, metres (default 0.3)")
    s.add_argument("--map-pixel", type=float, default=0.01, help="map pixel size, metres (default 0.01)")
    s.add_argument("--map-range", type=_range_pair, default=(1.0, 4.0), help="MIN:MAX look distance imaged, metres (default 1:4)")
    s.add_argument("--map-height", type=float, default=0.3, help="height of the map plane in the world frame, metres (default 0.3)")
    s.add_argument("--map-refocus", default="none", choices=list(METHODS),
                   help="refocus each map tile on its strongest scatterers once the robot has passed it (autofocus "
                        "of the radar's track error over the tile's frames; default none)")
    s.add_argument("--map-imu-aided", action="store_true",
                   help="correct each map tile once passed by the IMUs on the radars' own mounts (--radar-imu) first, "
                        "then --map-refocus if given")
    s.add_argument("--map-algorithm", default="direct", choices=["direct", "ffbp"],
                   help="direct: every profile onto every pixel (default); ffbp: each radar's frames in blocks by fast "
                        "factorized backprojection, for long apertures (--map-aperture of a metre or more)")
    s.add_argument("--map-ffbp-block", type=int, default=8,
                   help="frames per block with --map-algorithm ffbp (default 8: 0.21 m at 0.5 m/s with the reference waveform); a pixel's aperture is "
                        "set to within a block's travel, so keep that a small part of --map-aperture (warned beyond 1/8)")
    s.add_argument("--map-presum", default="auto", help="chirps summed per virtual channel before imaging ('auto': the "
                   "most whose phase spread stays within pi/4 at --max-speed)")
    s.add_argument("--max-speed", type=float, default=0.5, help="fastest the robot drives, m/s (sets automatic pre-summing)")
    s.add_argument("--map-radars", help="radars to image (comma-separated; default all)")
    s.add_argument("--map-threads", type=int, default=1, help="threads of the map's backprojection (default 1: on a "
                   "machine shared with the drivers a second one costs more CPU than it saves time)")
    s.add_argument("--map-max-thinning", type=int, default=4,
                   help="a map far behind, once it sums all of a TX's chirps, images only one frame of a radar in 2, "
                        "then in this many (default 4; counted as frames_thinned); 1: every frame, and on a machine short "
                        "of CPU the map falls further behind, up to its 10 s bound, where it drops the oldest")
    s.add_argument("--rio-radars", help="radars the odometry uses (comma-separated; default all)")
    s.add_argument("--view", metavar="[HOST:]PORT",
                   help="serve the live map, pose, health and events on the Foxglove WebSocket protocol (loopback "
                        "unless HOST is given), e.g. --view 8765, then open ws://localhost:8765 in Foxglove")
    s.set_defaults(func=cmd_run)

    s = sub.add_parser("replay", help="send a recording through emulated hardware (UDP, pty, CAN)",
                       epilog="example: sarbot replay rec.h5 --radar left_front=127.0.0.1:50001 --imu-link /tmp/imu --speed 1")
    s.add_argument("recording")
    s.add_argument("--radar", action="append", help="NAME=HOST:PORT to send the radar's datagrams to (SRF1 or DCA1000, as recorded)")
    s.add_argument("--imu-link", help="create this symlink to the pty the emulated IMU writes to")
    s.add_argument("--radar-imu-link", action="append", metavar="NAME=PATH",
                   help="create this symlink to the pty an emulated IMU on that radar's mount writes to (repeat per radar)")
    _can_options(s)
    s.add_argument("--speed", type=float, default=1.0, help="multiple of real time; 0 for as fast as possible")
    s.add_argument("--start-delay", type=float, default=0.0, help="seconds to wait before sending (lets drivers start)")
    s.add_argument("--laps", type=int, default=1,
                   help="send the drive this many times, back to back, times and counters continuing (soak tests; "
                        "the drive should end where and as it started, at rest)")
    s.set_defaults(func=cmd_replay)

    s = sub.add_parser("completion", help="print a shell completion script: eval \"$(sarbot completion bash)\"")
    s.add_argument("shell", choices=["bash"], help="the shell (bash; zsh runs it with bashcompinit)")
    s.set_defaults(func=cmd_completion)

    s = sub.add_parser("export", help="a recording as MCAP (Foxglove and the mcap tools) or a ROS 2 bag",
                       epilog="examples: sarbot export rec.h5 -o rec.mcap --map stripmap.h5 --trajectory traj.h5 (then open it in Foxglove); "
                              "sarbot export rec.h5 -o rec_bag --ros2 (then: ros2 bag play rec_bag)")
    s.add_argument("recording")
    s.add_argument("-o", "--output", required=True, help="the .mcap file, or with --ros2 the bag folder, to write")
    s.add_argument("--ros2", action="store_true", help="a ROS 2 bag (standard messages; raw frames as sarbot_msgs)")
    s.add_argument("--storage", default="mcap", help="ROS 2 bag storage: mcap (default) or sqlite3")
    s.add_argument("--map", action="append", metavar="IMAGE.h5",
                   help="add a SAR image or strip map (sarbot run's stripmap_*.h5, sarbot image) as /map, a foxglove.Grid in dB")
    s.add_argument("--trajectory", action="append", metavar="TRAJ.h5",
                   help="add an odometry trajectory (sarbot run's trajectory_*.h5, sarbot rio) as /pose")
    s.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    s.set_defaults(func=cmd_export)

    s = sub.add_parser("info", help="what a recording, trajectory or image holds (--json for scripts)",
                       epilog="examples: sarbot info rec.h5 | sarbot info traj.h5 --json | "
                              "sarbot info rec.h5 --tum truth.txt (then: evo_ape tum truth.txt traj.txt)")
    s.add_argument("files", nargs="+", help="sarbot HDF5 files")
    s.add_argument("--json", action="store_true", help="JSON instead of text")
    s.add_argument("--tum", help="also write the recording's /truth or the trajectory in TUM format to this file")
    s.add_argument("--overwrite", action="store_true", help="replace an existing --tum file")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("install-unit", help="install sarbot as a systemd service: user, venv under /opt, config, units",
                       description="Create the service user (systemd-sysusers), a virtual environment with sarbot, "
                                   "/etc/sarbot/{rig.toml,sarbot.env} (kept when present) and the systemd units, "
                                   "verified with systemd-analyze. Enables nothing: it prints the commands that do.",
                       epilog="example: sudo sarbot install-unit --command run --devices "
                              "'--radar left_front=192.168.33.30:4098 --imu-port /dev/ttyUSB0'")
    s.add_argument("--root", default="/", help="install under this folder instead of / (staging a package or image)")
    s.add_argument("--venv", default="/opt/sarbot/.venv", help="virtual environment on the robot (default /opt/sarbot/.venv)")
    s.add_argument("--user", default="sarbot", help="service user and group (default sarbot)")
    s.add_argument("--config", help="rig TOML to install as /etc/sarbot/rig.toml (default: the reference rig)")
    s.add_argument("--command", default="record", help="what the service runs: record or run (default record)")
    s.add_argument("--devices", default="", help="the robot's --radar/--imu-port/--can options, in quotes")
    s.add_argument("--source", help="what pip installs (default: this checkout, or this version of sarbot)")
    s.add_argument("--constraints", help="pip constraints file pinning the dependencies")
    s.add_argument("--no-deps", action="store_true", help="install sarbot alone (dependencies already there)")
    s.set_defaults(func=cmd_install_unit)

    s = sub.add_parser("experiment", help="reproduce a study on simulated data (paper: the reference robot-SAR study)")
    s.add_argument("name", help="paper")
    s.add_argument("-o", "--output", default="docs/results/paper", help="report folder (default docs/results/paper)")
    s.add_argument("--quick", action="store_true", help="fewer apertures, phases and amplitudes (a smoke run)")
    s.set_defaults(func=cmd_experiment)

    s = sub.add_parser("demo", help="the whole pipeline on emulated hardware fed by a built-in scene",
                       epilog="example: sarbot demo; sarbot demo --view 8765 (watch it in Foxglove at ws://localhost:8765)")
    s.add_argument("-o", "--output", default="sarbot-demo", help="output folder (default ./sarbot-demo)")
    s.add_argument("--speed", type=float, default=0.5,
                   help="replay speed, a multiple of real time (default 0.5: the emulated hardware shares the two "
                        "cores with the daemon; on its own the daemon keeps up at 1x)")
    s.add_argument("--view", metavar="[HOST:]PORT",
                   help="watch it live: the map, pose, health and events on the Foxglove WebSocket protocol, "
                        "e.g. --view 8765, then open ws://localhost:8765 in Foxglove")
    s.set_defaults(func=cmd_demo)
    return p


#: Options whose values often start with a minus sign (negative coordinates), which argparse would
#: otherwise take for an option: ``--grid -1:1:0.01,...`` is joined to ``--grid=-1:1:0.01,...``.
_NEGATIVE_VALUE_OPTIONS = ("--grid", "--at")


def _join_negative_values(argv: list[str]) -> list[str]:
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in _NEGATIVE_VALUE_OPTIONS and i + 1 < len(argv):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    configure_logging(-1 if args.quiet else args.verbose)  # also every process the command starts (environment)
    ensure_jit_cache_dir()  # before numba is imported, here or in a child
    try:
        return args.func(args)
    except HardwareError as exc:
        print(f"sarbot: error: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    except SarbotError as exc:
        print(f"sarbot: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("sarbot: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
