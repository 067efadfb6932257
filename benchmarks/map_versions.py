"""The live strip map at a baseline commit beside the checkout's, for the benchmarks that compare them
(``stripmap_presum.py``, ``map_cpu_per_frame.py``): the soak's map settings, the baseline's ``StripMap`` class
loaded from git, and a warmed-up daemon worker holding either class."""

from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import stripmap_capacity as capacity  # noqa: E402
from acquisition.bus import BusPublisher  # noqa: E402
from acquisition.processes import bus_endpoint  # noqa: E402
from acquisition.workers import pipeline  # noqa: E402
from acquisition.workers.stripmap import StripMapWorker, StripMapWorkerConfig  # noqa: E402
from git_baseline import baseline_module  # noqa: E402
from imaging.core.rig import load_rig  # noqa: E402


def soak_map_settings():
    """The soak's rig and ``sarbot run``'s map settings for its radars (``stripmap_capacity``'s)."""
    rig = load_rig(capacity.RIG)
    map_config = pipeline.resolve_map_config(types.SimpleNamespace(rig=rig), capacity.MAP, capacity.RADARS,
                                             capacity.MAX_SPEED_MPS, None)
    return rig, map_config


def baseline_map(commit: str, modules: list[str]):
    """The baseline's ``StripMap`` class and the modules loaded: ``imaging/stripmap/map.py`` at ``commit``, with
    the names it imported from the other ``modules`` (those the commit has) bound to the baseline's versions of
    them. Each is compiled from a file (``baseline_module``'s ``in_file``), so numba caches its kernels."""
    loaded = {}
    for path in ["imaging/stripmap/map.py", *[m for m in modules if m != "imaging/stripmap/map.py"]]:
        exists = subprocess.run(["git", "cat-file", "-e", f"{commit}:{path}"], cwd=ROOT, capture_output=True)
        if exists.returncode == 0:
            loaded[path] = baseline_module(commit, path, "_baseline_" + Path(path).stem, in_file=True)
    mapping = loaded["imaging/stripmap/map.py"]
    for path, module in loaded.items():
        if module is mapping:
            continue
        for name in dir(module):  # rebind what map.py imported from the checkout's module to the baseline's
            if not name.startswith("__") and name in mapping.__dict__ and callable(getattr(module, name)):
                setattr(mapping, name, getattr(module, name))
    return mapping.StripMap, sorted(loaded)


def make_worker(rig, radars, map_config, map_class, endpoint: str):
    """A daemon map worker whose map (and its warm-up's scratch maps) are ``map_class``, warmed up (kernels
    compiled), and its publisher."""
    import imaging.stripmap

    saved = imaging.stripmap.StripMap
    imaging.stripmap.StripMap = map_class  # what the worker's __init__ and warm_up import
    try:
        pub = BusPublisher(bus_endpoint(endpoint))
        worker = StripMapWorker(StripMapWorkerConfig(rig, radars, map_config, "inproc://none", "unused.h5"), pub)
        worker.warm_up()
    finally:
        imaging.stripmap.StripMap = saved
    return worker, pub
