"""The workers of ``sarbot run``: odometry feeding the live strip map, and the live view of both.

Each is a factory in ``acquisition.workers.registry``, registered when this module is imported; the
run's options are a ``PipelineOptions``. ``add_pipeline_workers`` is the whole assembly: the run's checks,
the map's settings resolved, every registered factory asked.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

from imaging.core.errors import SarbotError

from . import WorkerSpec, registry
from .odometry import OdometryWorker, OdometryWorkerConfig
from .registry import WorkerRun
from .stripmap import MAX_THINNING, StripMapWorker, StripMapWorkerConfig

log = logging.getLogger(f"sarbot.{__name__}")

#: An FFBP block longer than this fraction of the aperture changes the map visibly against the direct
#: kernel's per-frame windows (benchmarks/stripmap_ffbp.py): said in a warning.
BLOCK_TRAVEL_PER_APERTURE = 8


@dataclasses.dataclass(frozen=True)
class PipelineOptions:
    """The run's options for its workers. ``map`` is the ``imaging.stripmap.StripMapConfig`` with its
    pre-summing resolved; ``view`` (host, port) or None; radars None: all of the setup's."""

    map: Any
    map_radars: list[str]
    rio_radars: list[str]
    view: tuple[str, int] | None = None
    map_threads: int = 1
    map_max_thinning: int = MAX_THINNING
    rio_calibrate: bool = False  # the odometry estimates every radar's mount and time offset online
    rio_map_feedback: bool = False  # the odometry takes the map's velocity errors (map/velocity_error)


def trajectory_path(run: WorkerRun) -> Path:
    return run.out_dir / f"trajectory_{run.stamp}.h5"


def map_path(run: WorkerRun) -> Path:
    return run.out_dir / f"stripmap_{run.stamp}.h5"


def odometry_workers(setup, run: WorkerRun) -> list[WorkerSpec]:
    # The map waits for the odometry's poses: the odometry is the upstream worker (niced less).
    options = run.options
    config = OdometryWorkerConfig(setup.rig, options.rio_radars, str(trajectory_path(run)),
                                  publish_points=options.view is not None, calibrate=options.rio_calibrate,
                                  map_feedback=getattr(options, "rio_map_feedback", False))
    return [WorkerSpec("rio", OdometryWorker, config, upstream=True)]


def stripmap_workers(setup, run: WorkerRun) -> list[WorkerSpec]:
    options = run.options
    spec = WorkerSpec("stripmap", StripMapWorker, StripMapWorkerConfig(
        setup.rig, options.map_radars, options.map, run.workers["rio"].endpoint, str(map_path(run)),
        threads=options.map_threads, max_thinning=options.map_max_thinning))
    rio = run.workers["rio"].config
    if getattr(rio, "map_feedback", False):
        # The odometry is made first (the map needs its poses' endpoint); it learns the map's here.
        rio.map_endpoint = spec.endpoint
    return [spec]


def view_workers(setup, run: WorkerRun) -> list[WorkerSpec]:
    if run.options.view is None:
        return []
    from ..processes import bus_endpoint
    from .view import ViewWorker, ViewWorkerConfig

    if not setup.health_endpoint:  # the view shows health: it needs to know where it is published
        setup.health_endpoint = bus_endpoint("health")
    mounts = {r.name: (r.mount.translation_m.tolist(), r.mount.rotation_xyzw.tolist()) for r in setup.rig.radars}
    host, port = run.options.view
    return [WorkerSpec("view", ViewWorker, ViewWorkerConfig(
        host, port, run.workers["stripmap"].endpoint, run.workers["rio"].endpoint, setup.health_endpoint,
        mounts=mounts))]


registry.register("rio", odometry_workers)
registry.register("stripmap", stripmap_workers)
registry.register("view", view_workers)


def resolve_map_config(setup, config, map_radars: list[str], max_speed_mps: float, presum: int | None):
    """``config`` with its pre-summing set: ``presum``, or None for the largest whose phase spread stays
    within pi/4 at ``max_speed_mps``; an FFBP block long against the aperture is warned of."""
    from imaging.stripmap import ffbp_block_travel_m, max_presum

    if presum is None:
        presum = min(max_presum(config, setup.rig.radar(n), max_speed_mps) for n in map_radars)
    if config.algorithm == "ffbp":
        travel = max(ffbp_block_travel_m(config, setup.rig.radar(n), max_speed_mps) for n in map_radars)
        if travel > config.aperture_m / BLOCK_TRAVEL_PER_APERTURE:
            log.warning("strip map: an FFBP block of %d frames spans %.2f m at %.2f m/s, more than 1/%d of the %.2f m "
                        "aperture: each pixel's aperture is set to within that (fewer --map-ffbp-block frames, or the "
                        "direct algorithm, for short apertures)", config.ffbp_block_frames, travel, max_speed_mps,
                        BLOCK_TRAVEL_PER_APERTURE, config.aperture_m)
    return dataclasses.replace(config, presum=presum)


def check_pipeline_setup(setup, map_radars: list[str], imu_aided: bool) -> None:
    """What the pipeline needs of the devices: SarbotError otherwise."""
    if not setup.imu_port:
        raise SarbotError("run needs --imu-port: the strip map is placed by radar-inertial odometry")
    if imu_aided and not set(setup.radar_imu_ports) & set(map_radars):
        raise SarbotError("--map-imu-aided: no mapped radar has an IMU of its own; give --radar-imu NAME=DEVICE "
                          f"for one of {', '.join(map_radars)}")


def add_pipeline_workers(setup, out_dir: Path, stamp: str, config, max_speed_mps: float = 0.5,
                         map_radars: list[str] | None = None, rio_radars: list[str] | None = None,
                         presum: int | None = None, view: tuple[str, int] | None = None, map_threads: int = 1,
                         map_max_thinning: int = MAX_THINNING, rio_calibrate: bool = False,
                         rio_map_feedback: bool = False):
    """Give ``setup`` (``acquisition.daemon.Setup``) the workers of every registered factory: the odometry,
    the strip map, the live view if asked, and any registered besides (``registry.register``).

    ``config`` is the ``imaging.stripmap.StripMapConfig``; ``presum`` None picks the largest pre-summing
    whose phase spread stays within pi/4 at ``max_speed_mps``. ``view`` (host, port): also serve the run
    on the Foxglove WebSocket protocol (``workers.view``). ``map_threads``: the map's backprojection threads
    (``StripMapWorkerConfig.threads``); ``map_max_thinning`` its ``max_thinning``. ``rio_map_feedback``: the
    odometry takes the map's velocity errors (``rio.map_feedback``), subscribed to the map worker's endpoint.
    Returns the trajectory path, the map path and the strip-map settings used.
    """
    names = [link.name for link in setup.radars]
    map_radars = map_radars or names
    check_pipeline_setup(setup, map_radars, config.refocus_imu_aided)
    config = resolve_map_config(setup, config, map_radars, max_speed_mps, presum)
    options = PipelineOptions(config, map_radars, rio_radars or names, view, map_threads, map_max_thinning, rio_calibrate,
                              rio_map_feedback)
    out_dir.mkdir(parents=True, exist_ok=True)
    run = WorkerRun(out_dir, stamp, options)
    setup.workers = registry.assemble(setup, run)
    return trajectory_path(run), map_path(run), config
