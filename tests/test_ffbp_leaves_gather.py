"""FFBP's leaves with the permute gather (imaging/bin_gather.py) against the scalar gather: the same images."""

import types

import numba
import numpy as np
import pytest

import imaging.ffbp_leaves as fl
from imaging.bin_gather import PERMUTE_GATHER
from imaging.factorized_backprojection import FactorizedOptions, _slice, plan_factorized, run_factorized

from test_factorized_backprojection import pass_case

needs_avx512 = pytest.mark.skipif(not PERMUTE_GATHER, reason="numba's target has no AVX2: the leaves keep the "
                                  "scalar gather, which test_factorized_backprojection covers")


def _copy(f, name: str, **globals_):
    return types.FunctionType(f.__code__, dict(f.__globals__, **globals_), name, f.__defaults__, f.__closure__)


def leaf_kernel_compiled_here(permute: bool):
    """The leaf kernel compiled in this process with the permute gather or as on a CPU without AVX-512
    (``PERMUTE_GATHER`` False), neither loaded from numba's cache (a cache-loaded kernel can differ from the
    same source compiled here in the last bit: tests/test_bin_gather.py)."""
    tag = "_permute" if permute else "_scalar_gather"
    block = numba.njit(fastmath=True, nogil=True)(_copy(fl._leaf_block.py_func, "_leaf_block" + tag,
                                                        PERMUTE_GATHER=permute))
    return numba.njit(fastmath=True, nogil=True)(_copy(fl._polar_leaves_kernel.py_func, "_polar_leaves_kernel" + tag,
                                                       _leaf_block=block))


@pytest.fixture(scope="module")
def kernels():
    return {permute: leaf_kernel_compiled_here(permute) for permute in (True, False)}


@needs_avx512
@pytest.mark.parametrize("leaf_profiles,spacing_m", [(128, 0.02), (512, 0.002), (128, 0.05)])
def test_the_leaves_are_the_same_with_either_gather(kernels, monkeypatch, leaf_profiles, spacing_m):
    """Leaves of a pass imaged by the kernel with the permute gather and with the scalar one: the same images
    bit for bit, reference ranges included; fine pixels (fine polar grids: most groups of 16 permuted) and
    coarse ones (grids whose groups span more bins than the window: the scalar gather inside the same block)."""
    prof, tx, rx = pass_case(4)
    x = np.arange(-0.3, 0.3, spacing_m)
    y = np.arange(1.8, 2.2, spacing_m)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz,
                           FactorizedOptions(leaf_profiles=leaf_profiles))
    leaves = sorted((n for n in plan.nodes() if not n.children), key=lambda n: n.start)[:4]
    a, b = leaves[0].start, leaves[-1].stop
    r_ref = np.random.default_rng(3).uniform(0, 0.05, tx.shape[0])
    images = {}
    for permute, kernel in kernels.items():
        with monkeypatch.context() as m:
            m.setattr(fl, "_polar_leaves_kernel", kernel)
            images[permute] = fl.image_leaves(leaves, _slice(prof, a, b), tx[a:b], rx[a:b], r_ref[a:b], a, 0.3, "linear")
    for permuted, scalar in zip(images[True], images[False]):
        assert np.abs(scalar).max() > 0  # something was imaged
        assert np.array_equal(permuted, scalar)


@needs_avx512
def test_a_whole_ffbp_image_is_the_same_with_either_gather(kernels, monkeypatch):
    prof, tx, rx = pass_case(8)
    x, y = np.arange(-0.3, 0.3, 0.004), np.arange(1.8, 2.2, 0.004)
    plan = plan_factorized(tx, rx, x, y, 0.3, prof.carrier_hz, prof.bandwidth_hz)
    assert plan.levels >= 1
    images = {}
    for permute, kernel in kernels.items():
        with monkeypatch.context() as m:
            m.setattr(fl, "_polar_leaves_kernel", kernel)
            images[permute] = run_factorized(plan, prof, tx, rx)
    assert np.abs(images[False]).max() > 0
    assert np.array_equal(images[True], images[False])
