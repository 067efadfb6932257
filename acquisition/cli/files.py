"""``sarbot info``, ``export``, ``import-bag`` and ``import-ti``: what files hold, and files of other tools
into recordings and back (see docs/formats/recording.md and docs/export.md)."""

from __future__ import annotations

import json
import sys

from imaging.core.errors import SarbotError

from . import options as opt
from .exit_codes import EXIT_OK

#: ``import-ti --iq-swap``: whether Q comes before I (None: as found in the data).
IQ_SWAP = {"auto": None, "yes": True, "no": False}


def register(sub) -> None:
    s = sub.add_parser("info", help="what a recording, trajectory or image holds (--json for scripts)",
                       epilog="examples: sarbot info rec.h5 | sarbot info traj.h5 --json | "
                              "sarbot info rec.h5 --tum truth.txt (then: evo_ape tum truth.txt traj.txt)")
    s.add_argument("files", nargs="+", help="sarbot HDF5 files")
    s.add_argument("--json", action="store_true", help="JSON instead of text")
    s.add_argument("--tum", help="also write the recording's /truth or the trajectory in TUM format to this file")
    opt.overwrite_option(s, "replace an existing --tum file")
    s.set_defaults(func=cmd_info)

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
    opt.overwrite_option(s)
    s.set_defaults(func=cmd_export)

    s = sub.add_parser("import-bag", help="convert a ROS 1 or ROS 2 bag (IMU, radar point clouds, trigger) to a recording",
                       epilog="example: sarbot import-bag demo.bag --calib calib.yaml -o rec.h5 (a ROS 2 bag: give its folder)")
    s.add_argument("bag")
    s.add_argument("--calib", required=True, help="calibration YAML (topics, radar extrinsics, frame length)")
    s.add_argument("-o", "--output", required=True)
    s.add_argument("--radar-name", default="radar")
    opt.overwrite_option(s)
    s.set_defaults(func=cmd_import_bag)

    s = sub.add_parser("import-ti", help="convert a TI raw ADC capture (adc_data.bin and the radar's .cfg) to a recording",
                       epilog="example: sarbot import-ti adc_data.bin --cfg profile.cfg -o rec.h5 --velocity 0,0.05,0 "
                              "(a radar on a rail moving 5 cm/s to its left; layout and sample format are found from the data)")
    s.add_argument("capture", nargs="+", help="capture file(s), in order (mmWave Studio splits long captures)")
    s.add_argument("--cfg", required=True, help="the TI .cfg the radar ran (waveform, chirps, RX, frame period)")
    s.add_argument("-o", "--output", required=True)
    s.add_argument("--layout", default="auto", choices=opt.ChoicesFrom("drivers.radar.ti_capture", "LAYOUTS", ("auto",)),
                   help="lvds2: xWR16xx/18xx/68xx; lvds4: xWR12xx/14xx; interleaved: channel-interleaved I/Q pairs "
                        "(default auto: the reading whose beat signal is one-sided)")
    s.add_argument("--sample-format", default="auto",
                   choices=opt.ChoicesFrom("drivers.radar.ti_capture", "SAMPLE_FORMATS", ("auto",)),
                   help="two's complement or offset binary (default auto)")
    s.add_argument("--iq-swap", default="auto", choices=list(IQ_SWAP),
                   help="Q before I (default: as found, or as the .cfg's adcbufCfg says when --layout is given)")
    s.add_argument("--velocity", default="0,0,0", help="VX,VY,VZ: the radar's constant velocity in m/s, world frame; it "
                   "starts at the origin looking along +x (default 0,0,0: at rest). Written to /truth")
    s.add_argument("--radar-name", default="ti")
    opt.overwrite_option(s)
    s.set_defaults(func=cmd_import_ti)


def cmd_info(args) -> int:
    from ..info import format_info, info

    if args.tum and len(args.files) != 1:
        raise SarbotError("--tum: give one file (a recording's /truth or a trajectory)")
    reports = [info(path) for path in args.files]
    if args.json:
        print(json.dumps(reports if len(reports) > 1 else reports[0], indent=2, default=opt.json_default))
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
        out = opt.new_output(args.tum, args.overwrite, "--tum ")
        write_tum(out, traj)
        print(f"wrote {out} ({traj.time_ns.size} poses, TUM format for evo)", file=sys.stderr if args.json else sys.stdout)
    return EXIT_OK


def cmd_export(args) -> int:
    from ..exporters.mcap_file import export_mcap
    from ..exporters.ros2_bag import export_ros2
    from ..progress import Progress

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


def cmd_import_bag(args) -> int:
    from ..importers.bag import import_bag
    from ..progress import Progress

    out = opt.new_output(args.output, args.overwrite)
    counts = import_bag(args.bag, args.calib, out, radar_name=args.radar_name, overwrite=args.overwrite,
                        progress=Progress("import"))
    print(f"wrote {out}: " + ", ".join(f"{k} {v:.6g}" for k, v in counts.items()))
    return EXIT_OK


def cmd_import_ti(args) -> int:
    from ..importers.ti_capture import import_ti_capture
    from ..progress import Progress

    velocity = opt.parse_floats(args.velocity, 3, "--velocity")
    out = opt.new_output(args.output, args.overwrite)
    got = import_ti_capture(args.capture, args.cfg, out, layout=args.layout, sample_format=args.sample_format,
                            iq_swap=IQ_SWAP[args.iq_swap], radar_name=args.radar_name, velocity_mps=velocity,
                            overwrite=args.overwrite, progress=Progress("import"))
    print(f"wrote {out}: {got['frames']} frames, layout {got['layout']}{' (Q before I)' if got['iq_swap'] else ''}, "
          f"{got['sample_format']} {got['adc_output']} samples, {got['measure']} {got['score_db']:+.1f} dB")
    return EXIT_OK
