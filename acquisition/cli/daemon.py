"""``sarbot record``, ``run``, ``replay`` and ``demo``: the daemon on real, replayed or emulated hardware.

The commands translate their options into plain values; what they mean is the daemon's
(``acquisition.daemon.Setup.for_devices``) and the workers' (``acquisition.workers.pipeline``).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from imaging.core.errors import ConfigError, SarbotError

from . import options as opt
from .exit_codes import EXIT_DISK_FULL, EXIT_OK


def register(sub) -> None:
    s = sub.add_parser("record", help="run the drivers and record everything to HDF5",
                       epilog="example: sarbot record --config rig.toml -o out/ --radar left_front=50001 --imu-port /dev/ttyUSB0 --split-time 600")
    opt.acquisition_options(s)
    s.set_defaults(func=cmd_record)

    s = sub.add_parser("run", help="the whole pipeline: drivers, recorder, odometry and the live strip map",
                       epilog="example: sarbot run --config rig.toml -o out/ --radar left_front=192.168.33.30:50001 --imu-port /dev/ttyUSB0 --view 8765")
    opt.acquisition_options(s)
    s.add_argument("--map-aperture", type=float, default=0.3, help="synthetic aperture per pixel, metres (default 0.3)")
    s.add_argument("--map-pixel", type=float, default=0.01, help="map pixel size, metres (default 0.01)")
    s.add_argument("--map-range", type=opt.range_pair, default=(1.0, 4.0), help="MIN:MAX look distance imaged, metres (default 1:4)")
    s.add_argument("--map-height", type=float, default=0.3, help="height of the map plane in the world frame, metres (default 0.3)")
    s.add_argument("--map-refocus", default="none", choices=opt.AUTOFOCUS_METHODS,
                   help="refocus each map tile on its strongest scatterers once the robot has passed it (autofocus "
                        "of the radar's track error over the tile's frames; default none)")
    s.add_argument("--map-imu-aided", action="store_true",
                   help="correct each map tile once passed by the IMUs on the radars' own mounts (--radar-imu) first, "
                        "then --map-refocus if given")
    s.add_argument("--map-algorithm", default="polar", choices=opt.MAP_ALGORITHMS,
                   help="polar: each frame through its own few beams, then once per pixel (default; the direct map to "
                        "about -50 dB); direct: every profile onto every pixel; ffbp: each radar's frames in blocks by "
                        "fast factorized backprojection, for long apertures (--map-aperture of a metre or more)")
    s.add_argument("--map-ffbp-block", type=int, default=8,
                   help="frames per block with --map-algorithm ffbp (default 8: 0.21 m at 0.5 m/s with the reference waveform); a pixel's aperture is "
                        "set to within a block's travel, so keep that a small part of --map-aperture (warned beyond 1/8)")
    s.add_argument("--map-presum", default="auto", help="chirps summed per virtual channel before imaging ('auto': the "
                   "most whose phase spread stays within pi/4 at --max-speed)")
    s.add_argument("--max-speed", type=float, default=0.5, help="fastest the robot drives, m/s (sets automatic pre-summing; "
                   f"above 0, at most {MAX_SPEED_MPS:g})")
    s.add_argument("--map-radars", help="radars to image (comma-separated; default all)")
    s.add_argument("--map-threads", type=int, default=1, help="threads of the map's backprojection (default 1: on a "
                   "machine shared with the drivers a second one costs more CPU than it saves time)")
    # No default here: it is the map worker's (MAX_THINNING), whose module is not imported for every command.
    s.add_argument("--map-max-thinning", type=int,
                   help="a map far behind, once it sums all of a TX's chirps, images only one frame of a radar in 2, "
                        "then in this many (default: the map's own limit, MAX_THINNING of acquisition.workers.stripmap; "
                        "counted as frames_thinned); 1: every frame, and on a machine short "
                        "of CPU the map falls further behind, up to its 10 s bound, where it drops the oldest")
    s.add_argument("--rio-radars", help="radars the odometry uses (comma-separated; default all)")
    s.add_argument("--rio-calibrate", action="store_true",
                   help="the odometry estimates every radar's mount and time offset online (in health and the "
                        "trajectory's /calibration)")
    s.add_argument("--rio-map-feedback", action="store_true",
                   help="the odometry takes the velocity errors the map's refocused tiles read (map/velocity_error; "
                        "needs --map-refocus) and learns the radars' Doppler scale from them")
    opt.worker_stop_options(s)
    opt.view_option(s)
    s.set_defaults(func=cmd_run)

    s = sub.add_parser("replay", help="send a recording through emulated hardware (UDP, pty, CAN)",
                       epilog="example: sarbot replay rec.h5 --radar left_front=127.0.0.1:50001 --imu-link /tmp/imu --speed 1")
    s.add_argument("recording")
    s.add_argument("--radar", action="append", help="NAME=HOST:PORT to send the radar's datagrams to (in its wire format, as recorded)")
    s.add_argument("--imu-link", help="create this symlink to the pty the emulated IMU writes to")
    s.add_argument("--radar-imu-link", action="append", metavar="NAME=PATH",
                   help="create this symlink to the pty an emulated IMU on that radar's mount writes to (repeat per radar)")
    opt.can_options(s)
    s.add_argument("--speed", type=float, default=1.0, help="multiple of real time; 0 for as fast as possible")
    s.add_argument("--start-delay", type=float, default=0.0, help="seconds to wait before sending (lets drivers start)")
    s.add_argument("--laps", type=int, default=1,
                   help="send the drive this many times, back to back, times and counters continuing (soak tests; "
                        "the drive should end where and as it started, at rest)")
    s.set_defaults(func=cmd_replay)

    s = sub.add_parser("demo", help="the whole pipeline on emulated hardware fed by a built-in scene",
                       epilog="example: sarbot demo; sarbot demo --view 8765 (watch it in Foxglove at ws://localhost:8765)")
    s.add_argument("-o", "--output", default="sarbot-demo", help="output folder (default ./sarbot-demo)")
    s.add_argument("--speed", type=float, default=0.5,
                   help="replay speed, a multiple of real time (default 0.5: the emulated hardware shares the two "
                        "cores with the daemon; on its own the daemon keeps up at 1x)")
    opt.worker_stop_options(s)
    opt.view_option(s)
    s.set_defaults(func=cmd_demo)


# -- record and run ---------------------------------------------------------------------------------------
#: Fastest ``run --max-speed``, m/s: it sets the pre-summing, which a wild value would make meaningless.
MAX_SPEED_MPS = 20.0
#: Longest ``replay --start-delay``, s.
MAX_START_DELAY_S = 24 * 3600.0


def dca1000_spec(item: str) -> str:
    """``--dca1000 NAME=[HOST:]PORT:CFG`` as the ``--radar`` text it is short for
    (``NAME=[HOST:]PORT,format=DCA1000,cfg=CFG``). HOST is where to listen: the DCA1000 sends to this host's
    address on its network (192.168.33.30 by TI's default), which loopback never receives."""
    name, sep, rest = item.partition("=")
    host, host_given = "", not rest.split(":", 1)[0].isdigit()
    if rest.startswith("["):  # [IPv6]:PORT:CFG
        host, _, rest = rest.partition("]:")
        host += "]"
    elif host_given:  # HOST:PORT:CFG
        host, _, rest = rest.partition(":")
    port, _, cfg_path = rest.partition(":")
    if not (sep and name and port.isdigit() and cfg_path) or (host_given and host.strip("[]") == ""):
        raise SarbotError(f"--dca1000 {item!r}: expected NAME=[HOST:]PORT:CFG_FILE, e.g. "
                          "ti=192.168.33.30:4098:xwr18xx.cfg")
    return f"{name}={host + ':' if host else ''}{port},format=DCA1000,cfg={cfg_path}"


def radar_link_specs(args) -> list[str]:
    """``--radar`` and the ``--dca1000 NAME=[HOST:]PORT:CFG`` shorthand, as ``--radar`` texts."""
    return [*(args.radar or []), *(dca1000_spec(item) for item in args.dca1000 or [])]


def record_setup(args):
    """The daemon's Setup from the ``record``/``run`` options (``options.acquisition_options``)."""
    from drivers.radar.link import parse_radar_link

    from ..daemon import Setup

    links = [parse_radar_link(spec, receive_stamps=getattr(args, "receive_stamps", "auto"))
             for spec in radar_link_specs(args)]
    device_options = {option: getattr(args, option.lstrip("-").replace("-", "_")) or []
                      for option in opt.CONTROL_OPTIONS}
    opt.check_duration(args.split_time, "--split-time")
    return Setup.for_devices(args.config, links, args.imu_port, opt.named_paths(args.radar_imu, "--radar-imu"),
                             opt.can_config(args), device_options, split_bytes=opt.size_bytes(args.split_size),
                             split_s=args.split_time, min_free_bytes=opt.size_bytes(args.min_free, "--min-free"),
                             health_endpoint=opt.bus_endpoint(args.health_endpoint), ptp4l_socket=getattr(args, "ptp4l", None),
                             phc2sys_log=getattr(args, "phc2sys_log", None), **opt.worker_stop_settings(args))


def _record(setup, out: Path, duration_s: float | None, extra_paths=(), **kwargs) -> int:
    """Run the daemon (``record`` and ``run``); say what it wrote, or that the disk filled up."""
    from ..daemon import record
    from ..recorder import DiskFullError

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
    opt.check_duration(args.duration)
    return _record(setup, Path(args.output), args.duration)


#: The strip map's settings (``StripMapConfig``) as ``sarbot run`` options.
MAP_OPTIONS = {"pixel_m": "--map-pixel", "aperture_m": "--map-aperture", "range_min_m": "--map-range",
               "range_max_m": "--map-range", "z_m": "--map-height", "refocus": "--map-refocus",
               "algorithm": "--map-algorithm", "ffbp_block_frames": "--map-ffbp-block"}


def map_config(args):
    """The ``--map-*`` options as a ``StripMapConfig``; its errors said in the options the user typed."""
    from imaging.stripmap import StripMapConfig

    try:
        return StripMapConfig(pixel_m=args.map_pixel, aperture_m=args.map_aperture, range_min_m=args.map_range[0],
                              range_max_m=args.map_range[1], z_m=args.map_height, refocus=args.map_refocus,
                              refocus_imu_aided=args.map_imu_aided, algorithm=args.map_algorithm,
                              ffbp_block_frames=args.map_ffbp_block)
    except ConfigError as e:
        option = MAP_OPTIONS.get(e.field)
        raise SarbotError(str(e).replace(f"{e.field}:", f"{option} ({e.field}):", 1) if option else str(e)) from None


def run_workers(setup, args, out_dir: Path, stamp: str):
    """Give ``setup`` the workers of ``sarbot run`` from its options (``workers.pipeline``); returns the
    trajectory path, the map path and the strip map's settings."""
    from ..workers.pipeline import add_pipeline_workers
    from ..workers.stripmap import MAX_THINNING, is_thinning

    names = {link.name for link in setup.radars}
    if not (math.isfinite(args.max_speed) and 0 < args.max_speed <= MAX_SPEED_MPS):
        raise SarbotError(f"--max-speed {args.max_speed}: must be a speed above 0 and at most {MAX_SPEED_MPS:g} m/s")
    if args.map_presum == "auto":
        presum = None
    elif args.map_presum.isdigit() and int(args.map_presum) >= 1:
        presum = int(args.map_presum)
    else:
        raise SarbotError(f"--map-presum {args.map_presum!r}: expected 'auto' or a positive integer")
    map_radars = opt.radar_names(args.map_radars, "--map-radars", names)
    config = map_config(args)
    if getattr(args, "rio_map_feedback", False) and config.refocus == "none":
        raise SarbotError("--rio-map-feedback needs --map-refocus: the velocity errors come from the tiles' refocus")
    if args.map_threads < 1:
        raise SarbotError(f"--map-threads {args.map_threads}: must be at least 1")
    max_thinning = MAX_THINNING if args.map_max_thinning is None else args.map_max_thinning
    if not is_thinning(max_thinning):
        raise SarbotError(f"--map-max-thinning {max_thinning}: must be 1, 2, 4, 8, ... (1: image every frame)")
    return add_pipeline_workers(setup, out_dir, stamp, config, args.max_speed, map_radars,
                                opt.radar_names(args.rio_radars, "--rio-radars", names), presum,
                                opt.view_address(args.view), args.map_threads, max_thinning,
                                getattr(args, "rio_calibrate", False), getattr(args, "rio_map_feedback", False))


def cmd_run(args) -> int:
    import time

    setup = record_setup(args)
    opt.check_duration(args.duration)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    out = Path(args.output)
    traj_path, map_path, config = run_workers(setup, args, out, stamp)
    print(f"sarbot run: strip map {config.pixel_m * 100:g} cm pixels, aperture {config.aperture_m} m, "
          f"pre-summing {config.presum}")
    return _record(setup, out, args.duration, (traj_path, map_path, map_path.with_suffix(".png")),
                   path=out / f"recording_{stamp}.h5")


# -- replay and demo --------------------------------------------------------------------------------------
def check_replay(args) -> dict[str, tuple[str, int]]:
    """The replay options, checked before anything is opened or sent; returns the radars' targets."""
    targets = opt.radar_targets(args.radar)
    opt.named_paths(args.radar_imu_link, "--radar-imu-link")
    if not math.isfinite(args.speed) or args.speed < 0:
        raise SarbotError(f"--speed {args.speed}: must be a multiple of real time >= 0 (0: as fast as possible)")
    if not (math.isfinite(args.start_delay) and 0 <= args.start_delay <= MAX_START_DELAY_S):
        raise SarbotError(f"--start-delay {args.start_delay}: must be a number of seconds from 0 to {MAX_START_DELAY_S:g}")
    if args.laps < 1:
        raise SarbotError(f"--laps {args.laps}: must be at least 1")
    opt.can_config(args)
    return targets


def cmd_replay(args) -> int:
    from ..replay import replay

    targets = check_replay(args)
    radar_imus = opt.named_paths(args.radar_imu_link, "--radar-imu-link")
    sent = replay(Path(args.recording), targets, args.imu_link, None if args.speed <= 0 else args.speed, args.start_delay,
                  can=opt.can_config(args), laps=args.laps, radar_imu_links=radar_imus)
    imus = (["the IMU"] if args.imu_link else []) + [f"the IMU on {name}" for name in radar_imus]
    print("replayed " + ", ".join(f"{n}: {k} {'frames' if n == 'can' else 'datagrams'}" for n, k in sent.items())
          + (" and " + ", ".join(imus) if imus else ""))
    return EXIT_OK


def cmd_demo(args) -> int:
    from ..studies.demo import run_demo

    if not (math.isfinite(args.speed) and args.speed > 0):
        raise SarbotError(f"--speed {args.speed}: must be positive")
    return run_demo(Path(args.output), speed=args.speed, view=opt.view_address(args.view),
                    stop_settings=opt.worker_stop_settings(args))
