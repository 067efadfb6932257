"""``sarbot rio``: radar-inertial odometry of a recording into a trajectory (see docs/formats/trajectory.md)."""

from __future__ import annotations

import json
import sys

from imaging.core.errors import SarbotError

from . import options as opt
from .exit_codes import EXIT_FAILED, EXIT_OK


def register(sub) -> None:
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

    from ..progress import Progress

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
        return EXIT_FAILED
    path = write_trajectory(args.output, result.trajectory, result.covariance_diag)
    if args.tum:
        write_tum(args.tum, result.trajectory)
    summary = {"trajectory": str(path), "poses": int(result.trajectory.time_ns.size), **result.stats}
    if truth is not None:
        from rio.evaluation import drift_report

        summary["against_truth"] = drift_report(result.trajectory, truth)
    print(json.dumps(summary, indent=2, default=opt.json_default))
    return EXIT_OK
