import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A worker's pattern: arrays of a few MB, each followed by a smaller allocation that outlives them (here
# 200 kB straight from malloc), after one large array was freed. Prints the MB the process still holds
# once the arrays are gone.
HEAP_PATTERN = """
import ctypes, json, sys
import numpy as np
from acquisition.processes import become_child
if sys.argv[1] == "child":
    become_child("heap-test")
def rss_mb():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 1e6
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
big = np.ones(16 << 20, np.uint8)
del big
base = rss_mb()
arrays, pins = [], []
for _ in range(100):
    arrays.append(np.ones(3 << 20, np.uint8))
    pins.append(libc.malloc(200_000))
del arrays
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
def test_a_child_process_gives_freed_arrays_back():
    plain = run_pattern("plain")
    if plain < 100:
        pytest.skip(f"this C library keeps only {plain:.0f} MB of the pattern: nothing to show")
    child = run_pattern("child")
    assert child < 5, f"a sarbot child process still holds {child:.0f} MB of freed arrays (a plain process {plain:.0f} MB)"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_the_environment_s_own_malloc_setting_is_left_alone():
    code = ("from acquisition.processes import limit_heap_retention; import os, sys; "
            "sys.exit(0 if limit_heap_retention() is False else 1)")
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "4194304"}
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, timeout=60).returncode == 0
