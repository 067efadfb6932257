import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A worker's pattern: arrays of a few MB, each followed by a smaller allocation that outlives them (here
# 200 kB straight from malloc), after one large array was freed. "plain" runs it in a plain process,
# "worker" in a sarbot child process's worker loop (run_worker) on a real bus socket, which then runs on for
# 1.5 s. Prints the MB the process still holds once the arrays are gone.
HEAP_PATTERN = """
import ctypes, json, sys, threading, time
import numpy as np
from acquisition.bus import BusPublisher, BusSubscriber
from acquisition.processes import become_child
from acquisition.workers import Worker, run_worker
def rss_mb():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 1e6
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
pins = []
def pattern():
    big = np.ones(16 << 20, np.uint8)
    del big
    arrays = []
    for _ in range(100):
        arrays.append(np.ones(3 << 20, np.uint8))
        pins.append(libc.malloc(200_000))
class Pattern(Worker):
    def __init__(self, stop):
        self.stop, self.done_at = stop, None
    def step(self):
        if self.done_at is None:
            pattern()
            self.done_at = time.monotonic()
        elif time.monotonic() - self.done_at > 1.5:
            self.stop.set()
base = rss_mb()
if sys.argv[1] == "worker":
    become_child("heap-test")
    stop = threading.Event()
    pub = BusPublisher("tcp://127.0.0.1:0")
    sub = BusSubscriber(pub.endpoint)
    run_worker(Pattern(stop), sub, stop)
    sub.close(); pub.close()
else:
    pattern()
print(json.dumps({"retained_mb": rss_mb() - base}))
"""


def run_pattern(mode: str) -> float:
    # glibc's defaults: any MALLOC_* setting (dask's LocalCluster, started by other tests in this process,
    # leaves MALLOC_TRIM_THRESHOLD_ in the environment) turns off the raising being tested.
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    out = subprocess.run([sys.executable, "-c", HEAP_PATTERN, mode], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])["retained_mb"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc and /proc")
def test_a_worker_gives_freed_arrays_back():
    plain = run_pattern("plain")
    if plain < 100:
        pytest.skip(f"this C library keeps only {plain:.0f} MB of the pattern: nothing to show")
    worker = run_pattern("worker")
    assert worker < 10, f"a sarbot worker still holds {worker:.0f} MB of freed arrays (a plain process {plain:.0f} MB)"


# How far become_child nices a process of the given kind, relative to the process that started it.
NICE_PROBE = """
import os, sys
from acquisition.processes import become_child
base = os.nice(0)
become_child("nice-test", realtime=sys.argv[1] == "driver", background=sys.argv[1] != "driver",
             upstream=sys.argv[1] == "upstream")
print(os.nice(0) - base)
"""


def niced_by(kind: str, worker_nice: str | None) -> int:
    env = {k: v for k, v in os.environ.items() if k != "SARBOT_WORKER_NICE"}
    if worker_nice is not None:
        env["SARBOT_WORKER_NICE"] = worker_nice
    out = subprocess.run([sys.executable, "-c", NICE_PROBE, kind], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=60, check=True)
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not hasattr(os, "nice"), reason="POSIX niceness")
def test_the_map_is_niced_below_the_odometry_it_waits_for(tmp_path):
    """The pipeline's odometry is its upstream worker: the map cannot image a frame before the odometry's poses
    cover it, so on a saturated machine the odometry (whose CPU is bounded: it thins scans) is niced half as
    much as the map, below the drivers and the recorder all the same. Read off real child processes."""
    from acquisition.daemon import Setup
    from acquisition.workers.pipeline import add_pipeline_workers
    from drivers.can_driver import CanConfig
    from drivers.radar.link import RadarLink
    from imaging.core.rig import default_rig
    from imaging.stripmap import StripMapConfig

    setup = Setup(default_rig(), [RadarLink("left_front", 50001)], imu_port="/nonexistent/imu",
                  can=CanConfig("virtual", "nice"))
    add_pipeline_workers(setup, tmp_path, "t", StripMapConfig())
    assert {w.role: w.upstream for w in setup.workers} == {"rio": True, "stripmap": False}
    assert [niced_by(kind, None) for kind in ("driver", "upstream", "worker")] == [0, 5, 10]  # the defaults
    assert [niced_by(kind, "7") for kind in ("upstream", "worker")] == [3, 7]  # SARBOT_WORKER_NICE, as the unit sets it
    assert [niced_by(kind, "0") for kind in ("upstream", "worker")] == [0, 0]
