"""Many images at once: recordings, tiles of a long drive, parameter sweeps, on a Dask cluster.

An :class:`ImageJob` says everything one image needs (files by path, so it travels to another process or
machine as it is); :func:`run_job` forms and writes it exactly as ``sarbot image`` does, so an image made
in a batch is the image the single command makes, bit for bit. :func:`plan_jobs` expands recordings x
frame tiles x option sweeps into jobs; :func:`run_batch` runs them on a ``dask.distributed`` cluster (a
local one of worker processes by default, or a scheduler's address) and gathers one summary per job.

An autofocus method registered in the client's process only (``imaging.autofocus.register_method``: a
plug-in, a test's own) is unknown to the workers, which import sarbot afresh: :func:`run_batch` resolves the
methods the jobs name in the client and ships each job its estimator function (cloudpickle takes a function
that is not importable by value), and :func:`run_job` registers it in the worker before forming the image.

Each worker gives the backprojection kernel its share of the machine's cores (``threads``), so that two
workers on two cores do not run four threads. Files must be readable and writable at the same paths on
every worker (a shared file system for a real cluster).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
import time
from pathlib import Path

import numpy as np

from imaging.core.errors import SarbotError

log = logging.getLogger(f"sarbot.{__name__}")

#: What a sweep may vary, and how its values are read: ImagingOptions fields, the autofocus method and the
#: synthetic aperture (metres of track, centred in the frames).
IMAGING_OPTIONS = {"mode": str, "window": str, "oversample": int, "algorithm": str, "aperture_window": str}
SWEEPABLE = {**IMAGING_OPTIONS, "autofocus": str, "aperture_m": float}


@dataclasses.dataclass(frozen=True)
class ImageJob:
    """One image: what ``sarbot image`` takes, as plain values."""

    recording: str
    radar: str | None
    grid: str  # x0:x1:dx,y0:y1:dy[,z]
    output: str
    frames: tuple[int | None, int | None] = (None, None)
    trajectory: str = "truth"
    options: tuple[tuple[str, object], ...] = ()  # ImagingOptions fields
    png: bool = False
    threads: int | None = None  # backprojection threads in the worker
    autofocus: str = "none"  # AutofocusOptions.method
    aperture_m: float | None = None  # only the central metres of the frames' track

    @property
    def label(self) -> str:
        return Path(self.output).stem


def run_job(job: ImageJob, autofocus_estimator=None) -> dict:
    """Form and write one image; returns a summary (output, peak, seconds, error). Never raises for a bad
    input: the error goes into the summary, so one broken recording does not stop a batch.

    ``autofocus_estimator``: the function of the job's autofocus method, registered under its name here
    first (a worker process does not know a method registered only in the client's; ``run_batch``)."""
    started = time.perf_counter()
    try:
        import numba

        from imaging.autofocus import AutofocusOptions, register_method

        if autofocus_estimator is not None:
            register_method(job.autofocus, autofocus_estimator, replace=True)
        from imaging.image_formation import ImagingOptions, image_recording, image_title
        from imaging.io.image_file import write_image
        from imaging.io.recording import Recording

        if job.threads:
            numba.set_num_threads(max(1, min(job.threads, numba.config.NUMBA_NUM_THREADS)))
        with Recording(job.recording) as rec:
            img = image_recording(rec, job.radar, job.grid, job.trajectory, slice(*job.frames),
                                  ImagingOptions(**dict(job.options)), autofocus=AutofocusOptions(method=job.autofocus),
                                  aperture_m=job.aperture_m)
        path = write_image(job.output, img)
        if job.png:
            from imaging.plot import save_image_png

            save_image_png(Path(job.output).with_suffix(".png"), img.image, img.x_m, img.y_m, title=image_title(img))
        mag = np.abs(img.image)
        k = np.unravel_index(int(np.argmax(mag)), mag.shape)
        return {"output": str(path), "label": job.label, "radar": img.attrs["radar"], "frames": img.attrs["frames"],
                "options": dict(job.options), "autofocus": job.autofocus, "aperture_m": job.aperture_m,
                "aperture_length_m": float(img.attrs["aperture_length_m"]),
                "peak": float(mag[k]), "peak_index": [int(i) for i in k],
                "n_profiles": int(img.attrs["n_profiles"]), "seconds": time.perf_counter() - started,
                "worker_pid": os.getpid(), "error": None}
    except (SarbotError, OSError, ValueError) as exc:
        return {"output": job.output, "label": job.label, "error": f"{type(exc).__name__}: {exc}" if not isinstance(
            exc, SarbotError) else str(exc), "seconds": time.perf_counter() - started, "worker_pid": os.getpid()}


def parse_sweep(items: list[str] | None) -> list[dict]:
    """``["mode=linear,nearest", "oversample=8,16"]`` -> every combination as a dict of option values."""
    axes: dict[str, list] = {}
    for item in items or []:
        key, sep, values = item.partition("=")
        if not sep or key not in SWEEPABLE or not values:
            raise SarbotError(f"--sweep {item!r}: expected KEY=V1,V2,... with KEY one of {', '.join(SWEEPABLE)}")
        try:
            axes[key] = [SWEEPABLE[key](v) for v in values.split(",")]
        except ValueError:
            raise SarbotError(f"--sweep {item!r}: {key} takes {SWEEPABLE[key].__name__} values") from None
    if not axes:
        return [{}]
    return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]


def plan_jobs(recordings, grid: str, out_dir, *, radar: str | None = None, frames=(None, None),
              tile_frames: int | None = None, sweep: list[dict] = ({},), base_options: dict | None = None,
              trajectory: str = "truth", png: bool = False, threads: int | None = None) -> list[ImageJob]:
    """Recordings x tiles (``tile_frames`` consecutive frames each, within ``frames``) x sweep points."""
    from imaging.autofocus import AutofocusOptions
    from imaging.image_formation import ImagingOptions, check_aperture_m, choose_radar
    from imaging.io.recording import Recording

    out_dir = Path(out_dir)
    jobs = []
    for rec_path in recordings:
        rec_path = Path(rec_path)
        if not rec_path.is_file():
            raise SarbotError(f"{rec_path}: no such recording")
        if tile_frames:
            with Recording(rec_path) as rec:
                start, stop, _ = slice(*frames).indices(rec.n_frames(choose_radar(rec, radar)))
            tiles = [(a, min(a + tile_frames, stop)) for a in range(start, stop, tile_frames)]
        else:
            tiles = [tuple(frames)]
        for (a, b), point in itertools.product(tiles, sweep):
            chosen = {**(base_options or {}), **point}
            options = {k: v for k, v in chosen.items() if k in IMAGING_OPTIONS}
            ImagingOptions(**options)  # bad values fail here, before any work is sent
            autofocus = AutofocusOptions(method=chosen.get("autofocus", "none")).method
            aperture_m = chosen.get("aperture_m")
            if aperture_m is not None:
                check_aperture_m(aperture_m)  # before any work is sent
            parts = [rec_path.stem] + ([f"f{a}-{b}"] if tile_frames else []) + [f"{k}{v}" for k, v in point.items()]
            jobs.append(ImageJob(str(rec_path), radar, grid, str(out_dir / ("_".join(parts) + ".h5")), (a, b), trajectory,
                                 tuple(sorted(options.items())), png, threads, autofocus, aperture_m))
    outputs = [j.output for j in jobs]
    if len(set(outputs)) != len(outputs):
        raise SarbotError("two jobs would write the same file (two recordings of the same name?); give them distinct names")
    return jobs


#: Where a local cluster serves its dashboard by default: loopback only (a port in use: Dask takes another).
DASHBOARD_ADDRESS = "127.0.0.1:8787"


def dashboard_available() -> bool:
    """Whether Dask can serve its dashboard here: it needs bokeh, the optional ``sarbot[dashboard]`` extra."""
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def run_batch(jobs: list[ImageJob], scheduler: str | None = None, n_workers: int = 2, progress=None,
              client=None, dashboard_address: str | None = DASHBOARD_ADDRESS, on_dashboard=None) -> list[dict]:
    """Run ``jobs`` on a Dask cluster; summaries in the order of ``jobs``.

    ``scheduler``: the address of a running ``dask.distributed`` scheduler (``tcp://host:8786``); None
    starts a local cluster of ``n_workers`` worker processes, one thread each, for the time of the batch.
    ``client``: a ``dask.distributed.Client`` to use instead (left open).
    ``dashboard_address``: where the local cluster serves Dask's dashboard (None: nowhere); served only
    where bokeh is installed (``pip install sarbot[dashboard]``).
    ``on_dashboard``: called with the dashboard's URL (a remote scheduler's too) once the cluster is up and
    before any job runs; with None where there is no dashboard.
    """
    if logging.getLogger().level > logging.DEBUG:  # below -vv, Dask's own INFO lines are noise here
        os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")  # read by this process and its workers
    from dask.distributed import Client, LocalCluster, as_completed

    logging.getLogger("distributed").setLevel(logging.getLevelName(os.environ.get("DASK_LOGGING__DISTRIBUTED", "info").upper()))
    cluster = None
    own_client = client is None
    serve = None
    if client is not None:
        pass
    elif scheduler is None:
        serve = dashboard_address if dashboard_address and dashboard_available() else None
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=serve)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise SarbotError(f"--scheduler {scheduler}: cannot reach it ({exc})") from None
    try:
        if on_dashboard is not None:
            # a local cluster without a dashboard still runs its HTTP server (health, metrics): not a dashboard
            on_dashboard(None if cluster is not None and serve is None else _dashboard_link(client))
        from imaging.autofocus import METHODS

        # Each job carries its method's function: the workers know only the methods sarbot registers itself.
        futures = {client.submit(run_job, job, METHODS.get(job.autofocus), pure=False): i for i, job in enumerate(jobs)}
        results: list[dict | None] = [None] * len(jobs)
        for done, future in enumerate(as_completed(futures), 1):
            results[futures[future]] = future.result()
            if progress is not None:
                progress(done, len(jobs))
        return results  # type: ignore[return-value]
    finally:
        if own_client:
            client.close()
        if cluster is not None:
            cluster.close()


def _dashboard_link(client) -> str | None:
    """The dashboard's URL, or None where the scheduler serves none."""
    try:
        services = client.scheduler_info().get("services", {})
    except Exception:  # noqa: BLE001 -- a scheduler that cannot say serves nothing we can name
        return None
    return client.dashboard_link if "dashboard" in services else None

