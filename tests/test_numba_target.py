"""How numba is set up for sarbot's kernels (imaging.numba_target): cache loads without the compiler's
registries, and compiling as before after them."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

# In a new process: the kernel loaded from numba's cache without the registries (its first call in the
# process), then a function that is in no cache, using numpy inside: compiling it builds the registries.
LOAD_THEN_COMPILE = r"""
import sys
import numpy as np
from imaging.numba_target import load_cached_kernels_lightly
from imaging.backprojection import backproject
from imaging.range_compression import range_compress
assert load_cached_kernels_lightly() and load_cached_kernels_lightly()  # twice: installed once
rng = np.random.default_rng(1)
samples = (rng.standard_normal((8, 64)) + 1j * rng.standard_normal((8, 64))).astype(np.complex64)
profiles = range_compress(samples, 77e9, 1e6, guarded=True, keep_samples=False)
tx = np.zeros((8, 3)); tx[:, 0] = np.linspace(-0.1, 0.1, 8); rx = tx + [0.002, 0.0, 0.0]
points = np.stack([np.linspace(-0.2, 0.2, 5), np.full(5, 2.0), np.zeros(5)], axis=1)
image = backproject(profiles, tx, rx, points)
loaded_alone = "numba.np.arraymath" not in sys.modules
import numba
@numba.njit
def fresh(x):
    return np.sum(np.sqrt(x)) + np.linalg.norm(x)
x = np.arange(10.0)
assert fresh(x) == np.sum(np.sqrt(x)) + np.linalg.norm(x)
np.save(sys.argv[1], image)
print(loaded_alone, "numba.np.arraymath" in sys.modules)
"""


def test_a_cached_kernel_loads_without_the_registries_and_a_new_one_still_compiles(tmp_path):
    """The first run compiles the kernel into numba's cache (if it is not there); the second loads it
    without numba's registries, the same image bit for bit; in both, a function in no cache compiles
    afterwards, with numpy's implementations in numba (the registries built then)."""
    outputs = []
    for run in range(2):
        out = tmp_path / f"image{run}.npy"
        res = subprocess.run([sys.executable, "-c", LOAD_THEN_COMPILE, str(out)], capture_output=True, text=True,
                             timeout=300)
        assert res.returncode == 0, res.stderr
        outputs.append(out)
    assert res.stdout.split() == ["True", "True"]
    import numpy as np

    np.testing.assert_array_equal(np.load(outputs[0]), np.load(outputs[1]))


def test_image_formation_and_its_options_import_no_numba():
    """``imaging.image_formation`` and its options' checks import no numba (form_image imports the kernels
    after its first block is read: ``sarbot image`` imports them meanwhile on a thread of its own); its
    list of modes is the kernels'."""
    code = ("import sys; from imaging.image_formation import MODES, ImagingOptions; "
            "from imaging.core.config import ConfigError; ImagingOptions(mode='exact'); "
            "exec('try:\\n ImagingOptions(mode=\"cubic\")\\nexcept ConfigError as e:\\n print(e)'); "
            "print('numba' in sys.modules); import imaging.backprojection as bp; print(bp.MODES == MODES)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert "must be nearest, linear or exact" in lines[0] and "cubic" in lines[0]
    assert lines[1:] == ["False", "True"]


# A numba function made before sarbot's kernels are imported: numba's target machine is built with its
# default 256-bit vectors, and the cache key must then say so too.
TARGET_BUILT_FIRST = r"""
import os, numba
@numba.njit
def first(x):
    return x + 1
from numba.core.registry import cpu_target
cpu_target.target_context  # built, as any numba function's first call builds it
import imaging.backprojection
from imaging.numba_target import compiled_target
from numba.core import config
target = compiled_target()
print(target["prefer_256_bit_off"], "-prefer-256-bit" in (config.CPU_FEATURES or ""))
"""


def test_a_target_built_before_the_kernels_keeps_its_width_and_says_so():
    """The cache key (numba's config) and the code (its target machine) agree on the vector width, whichever
    was imported first: before, the config said 512 bits over a 256-bit target machine, and kernels compiled
    so were cached under the 512-bit key (found by tests/test_bin_gather.py, whose two kernels differed in
    their last bits when one came from such a cache entry)."""
    res = subprocess.run([sys.executable, "-c", TARGET_BUILT_FIRST], capture_output=True, text=True, timeout=300,
                         env={k: v for k, v in os.environ.items()
                              if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME")})
    assert res.returncode == 0, res.stderr[-2000:]
    machine_wide, config_wide = res.stdout.split()
    assert machine_wide == config_wide


#: Every module that makes numba functions, each of which may be the first a process imports.
NUMBA_MODULES = ("rio.strapdown", "rio.ego_velocity", "rio.ekf", "imaging.sim.simulator", "imaging.stripmap.footprint",
                 "imaging.stripmap.presum", "imaging.stripmap.polar", "imaging.stripmap.map", "imaging.ffbp_placement",
                 "imaging.ffbp_leaves", "imaging.ffbp_merge", "imaging.block_profiles", "imaging.range_offsets",
                 "imaging.bin_gather", "imaging.backprojection")


def test_whichever_kernel_module_a_process_imports_first_it_compiles_at_full_width():
    """The image's bits (and the kernels' speed) do not hang on import order: before, a process that imported
    the odometry or the simulator first (``sarbot demo``, the odometry worker) built numba's 256-bit target."""
    import llvmlite.binding as llvm

    if not llvm.get_host_cpu_features().get("avx512f"):
        pytest.skip("this CPU has no AVX-512: numba's default width is the full one")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME")}
    for module in NUMBA_MODULES:
        code = f"import {module}\nfrom imaging.numba_target import compiled_target\nprint(compiled_target()['vector_bits'])"
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
        assert res.returncode == 0, (module, res.stderr[-2000:])
        assert res.stdout.split()[-1] == "512", module
