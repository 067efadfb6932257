"""The workers of ``sarbot run``: odometry feeding the live strip map."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from . import WorkerSpec
from .odometry import OdometryWorker, OdometryWorkerConfig
from .stripmap import MAX_THINNING, StripMapWorker, StripMapWorkerConfig

log = logging.getLogger(f"sarbot.{__name__}")

#: An FFBP block longer than this fraction of the aperture changes the map visibly against the direct
#: kernel's per-frame windows (benchmarks/stripmap_ffbp.py): said in a warning.
BLOCK_TRAVEL_PER_APERTURE = 8


def add_pipeline_workers(setup, out_dir: Path, stamp: str, config, max_speed_mps: float = 0.5,
                         map_radars: list[str] | None = None, rio_radars: list[str] | None = None,
                         presum: int | None = None, view: tuple[str, int] | None = None, map_threads: int = 1,
                         map_max_thinning: int = MAX_THINNING):
    """Give ``setup`` (``acquisition.daemon.Setup``) the odometry and strip-map workers.

    ``config`` is the ``imaging.stripmap.StripMapConfig``; ``presum`` None picks the largest pre-summing
    whose phase spread stays within pi/4 at ``max_speed_mps``. ``view`` (host, port): also serve the run
    on the Foxglove WebSocket protocol (``workers.view``). ``map_threads``: the map's backprojection threads
    (``StripMapWorkerConfig.threads``); ``map_max_thinning`` its ``max_thinning``.
    Returns the trajectory path, the map path and the
    strip-map settings used.
    """
    from imaging.stripmap import ffbp_block_travel_m, max_presum

    names = [link.name for link in setup.radars]
    map_radars = map_radars or names
    if presum is None:
        presum = min(max_presum(config, setup.rig.radar(n), max_speed_mps) for n in map_radars)
    if config.algorithm == "ffbp":
        travel = max(ffbp_block_travel_m(config, setup.rig.radar(n), max_speed_mps) for n in map_radars)
        if travel > config.aperture_m / BLOCK_TRAVEL_PER_APERTURE:
            log.warning("strip map: an FFBP block of %d frames spans %.2f m at %.2f m/s, more than 1/%d of the %.2f m "
                        "aperture: each pixel's aperture is set to within that (fewer --map-ffbp-block frames, or the "
                        "direct algorithm, for short apertures)", config.ffbp_block_frames, travel, max_speed_mps,
                        BLOCK_TRAVEL_PER_APERTURE, config.aperture_m)
    config = dataclasses.replace(config, presum=presum)
    out_dir.mkdir(parents=True, exist_ok=True)
    traj_path = out_dir / f"trajectory_{stamp}.h5"
    map_path = out_dir / f"stripmap_{stamp}.h5"
    # The map waits for the odometry's poses: the odometry is the upstream worker (niced less).
    odometry = WorkerSpec("rio", OdometryWorker, OdometryWorkerConfig(setup.rig, rio_radars or names, str(traj_path),
                                                                      publish_points=view is not None), upstream=True)
    stripmap = WorkerSpec("stripmap", StripMapWorker,
                          StripMapWorkerConfig(setup.rig, map_radars, config, odometry.endpoint, str(map_path),
                                               threads=map_threads, max_thinning=map_max_thinning))
    setup.workers = [odometry, stripmap]
    if view is not None:
        from ..processes import free_tcp_endpoint
        from .view import ViewWorker, ViewWorkerConfig

        if not setup.health_endpoint:  # the view shows health: it needs to know where it is published
            setup.health_endpoint = free_tcp_endpoint()
        mounts = {r.name: (r.mount.translation_m.tolist(), r.mount.rotation_xyzw.tolist()) for r in setup.rig.radars}
        setup.workers.append(WorkerSpec("view", ViewWorker, ViewWorkerConfig(
            view[0], view[1], stripmap.endpoint, odometry.endpoint, setup.health_endpoint, mounts=mounts)))
    return traj_path, map_path, config
