"""``sarbot rio``: radar-inertial odometry of a recording into a trajectory (see docs/formats/trajectory.md);
``sarbot calibrate``: every radar's mount and time offset from a calibration drive, into a rig file (see
docs/config/rig.md)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from imaging.core import strict_json
from imaging.core.errors import SarbotError

from . import options as opt
from .exit_codes import EXIT_FAILED, EXIT_OK


def register(sub) -> None:
    s = sub.add_parser("rio", help="radar-inertial odometry: a trajectory from IMU and radar detections",
                       epilog="example: sarbot simulate rio_room_drive -o drive.h5; sarbot rio drive.h5 -o traj.h5 --tum traj.txt")
    s.add_argument("recording")
    s.add_argument("-o", "--output", required=True, help="trajectory file to write (.h5)")
    s.add_argument("--tum", help="also write TUM text (t x y z qx qy qz qw) for evo")
    opt.overwrite_option(s, "replace existing output files (-o, --tum)")
    s.add_argument("--radar", action="append", help="radar to use (repeat; default all with detections)")
    s.add_argument("--joint", action="store_true", help="solve simultaneous scans of all radars together")
    s.add_argument("--planar", action="store_true", help="robot on a flat floor: no vertical velocity")
    s.add_argument("--static-init", type=float, default=1.0, help="seconds of standstill at the start (default 1)")
    s.add_argument("--start-from-truth", action="store_true",
                   help="start at the first /truth pose instead of the origin (simulations; to image in the scene's frame)")
    s.add_argument("--velocity-floor", type=float, default=0.05,
                   help="m/s added to every radar velocity's uncertainty: timing jitter, Doppler quantisation, "
                        "motion within a frame (default 0.05; 0.1 for a hand-held rig)")
    s.add_argument("--calibrate", action="store_true",
                   help="estimate every radar's mount and time offset online; the estimates and their standard "
                        "deviations go into the trajectory file's /calibration")
    opt.rig_override_option(s)
    s.set_defaults(func=cmd_rio)

    c = sub.add_parser("calibrate", help="every radar's mount and time offset from a calibration drive, into a rig file",
                       epilog="example: sarbot calibrate drive.h5 -o rig.toml   (drive with turns both ways, starts "
                              "and stops; axes the drive did not show keep the rig's values, and it says why)")
    c.add_argument("recording")
    c.add_argument("-o", "--output", required=True, help="rig file to write (.toml)")
    c.add_argument("--rig", help="rig file to start from (default: the mounts the recording holds)")
    c.add_argument("--no-time-offset", action="store_true", help="leave the radars' time offsets as they are")
    c.add_argument("--iterations", type=int, default=1,
                   help="run the filter again from its last estimate (default 1: once)")
    c.add_argument("--static-init", type=float, default=1.0, help="seconds of standstill at the start (default 1)")
    c.add_argument("--velocity-floor", type=float, default=0.05,
                   help="m/s added to every radar velocity's uncertainty (default 0.05)")
    c.add_argument("--force", action="store_true", help="overwrite the output file")
    c.set_defaults(func=cmd_calibrate)


def check_rio_options(args) -> None:
    """The options of ``rio``, before the recording is read: numbers in range, outputs that destroy nothing."""
    if not (math.isfinite(args.static_init) and args.static_init >= 0):
        raise SarbotError(f"--static-init {args.static_init}: must be a number of seconds >= 0")
    if not (math.isfinite(args.velocity_floor) and args.velocity_floor >= 0):
        raise SarbotError(f"--velocity-floor {args.velocity_floor}: must be a speed in m/s >= 0")
    out = opt.new_output(args.output, args.overwrite, "-o ", inputs=[args.recording])
    if args.tum:
        tum = opt.new_output(args.tum, args.overwrite, "--tum ", inputs=[args.recording])
        if tum.resolve() == out.resolve():
            raise SarbotError(f"--tum {tum}: the same file as -o; give each its own")


def cmd_rio(args) -> int:
    from imaging.io.recording import Recording
    from imaging.io.trajectory_file import write_trajectory, write_tum
    from rio.calibration import rig_of_recording
    from rio.ekf import EkfConfig
    from rio.odometry import (
        RioOptions,
        imu_from_recording,
        run_rio,
        scans_from_recording,
    )

    from ..progress import Progress

    check_rio_options(args)
    with Recording(args.recording) as rec:
        opt.use_rig_file(rec, args.rig)
        radars = tuple(args.radar) if args.radar else None
        for name in radars or ():
            rec.radar(name)  # a clear error for an unknown name
        imu = imu_from_recording(rec)
        scans = scans_from_recording(rec, radars)
        if not scans:
            raise SarbotError(f"{args.recording}: no radar detections to run odometry on")
        truth = rec.truth()
        # The rig's clock offsets (and, calibrating, its uncertainties) as the filter's starting point.
        priors = rig_of_recording(rec).calibration_priors()
    start = {}
    if args.start_from_truth:
        if truth is None:
            raise SarbotError(f"{args.recording}: --start-from-truth needs /truth, and this recording has none")
        first = truth.sample(imu.time_ns[:1])
        start = {"initial_position_m": tuple(first.position_m[0]),
                 "initial_yaw_rad": float(first.rotation.as_euler("ZYX")[0, 0])}
    if args.calibrate and args.joint:
        raise SarbotError("--calibrate needs each radar's own updates: leave out --joint")
    options = RioOptions(ekf=EkfConfig(planar=args.planar, radar_velocity_sigma_floor_mps=args.velocity_floor),
                         joint_radars=args.joint, static_init_s=args.static_init, calibrate_extrinsics=args.calibrate,
                         calibrate_time_offset=args.calibrate, calibration_priors=priors, **start)
    try:
        result = run_rio(imu, scans, options, progress=Progress("rio"))
    except FloatingPointError as exc:
        print(f"sarbot: odometry failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    path = opt.write_output(Path(args.output), lambda p: write_trajectory(p, result.trajectory, result.covariance_diag),
                            "-o ")
    if args.tum:
        opt.write_output(Path(args.tum), lambda p: write_tum(p, result.trajectory), "--tum ")
    summary = {"trajectory": str(path), "poses": int(result.trajectory.time_ns.size), **result.stats}
    if result.calibration:
        from imaging.io.trajectory_file import write_calibration
        from rio.calibration import calibration_for_file

        radars, history = calibration_for_file(result)
        write_calibration(path, radars, history)
        summary["calibration"] = radars
    if truth is not None:
        from rio.evaluation import drift_report

        summary["against_truth"] = drift_report(result.trajectory, truth)
    print(strict_json.dumps(summary, indent=2))
    return EXIT_OK


def cmd_calibrate(args) -> int:
    from pathlib import Path

    from imaging.core.rig import load_rig
    from rio.calibration import calibrate_recording
    from rio.ekf import EkfConfig
    from rio.odometry import RioOptions

    out = Path(args.output)
    if out.exists() and not args.force:
        raise SarbotError(f"{out}: exists already (--force to overwrite)")
    if args.iterations < 1:
        raise SarbotError(f"--iterations must be 1 or more, got {args.iterations}")
    rig = load_rig(args.rig) if args.rig else None
    options = RioOptions(ekf=EkfConfig(radar_velocity_sigma_floor_mps=args.velocity_floor), static_init_s=args.static_init)
    try:
        result = calibrate_recording(args.recording, out, rig, options, time_offset=not args.no_time_offset,
                                     iterations=args.iterations)
    except FloatingPointError as exc:
        print(f"sarbot: calibration failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyError as exc:
        raise SarbotError(f"{args.recording}: radar {exc} is not in the rig {args.rig}") from None
    print(result.report())
    taken = sum(int(r.accepted.sum()) for r in result.radars.values())
    print(f"wrote {out}: {taken} of {7 * len(result.radars)} axes refined, the others as the rig had them")
    return EXIT_OK
