"""The backprojection kernels made ready on a thread of their own, while a new process reads and
range-compresses its first frames: numba's import, the kernels' module, numba's runtime and the kernels'
machine code loaded from numba's cache (about 0.3 s of a new ``sarbot image`` process,
benchmarks/image_command.py).

``imaging.image_formation.form_image`` asks :func:`in_progress` before its first backprojection: while
the kernels are still being made ready it range-compresses further blocks on its other thread instead of
waiting with one core idle.
"""

from __future__ import annotations

import threading

import numpy as np

_ready: threading.Event | None = None  # set once the background preparation has ended; None: none started


def start_in_background(ffbp: bool = False) -> threading.Thread:
    """Start :func:`prepare_kernels` on a thread of its own (name "import-kernels") and return it."""
    global _ready
    ready = _ready = threading.Event()

    def run() -> None:
        try:
            prepare_kernels(ffbp)
        finally:
            ready.set()

    thread = threading.Thread(target=run, name="import-kernels")
    thread.start()
    return thread


def in_progress() -> bool:
    """Whether a background preparation (:func:`start_in_background`) is still running."""
    return _ready is not None and not _ready.is_set()


def prepare_kernels(ffbp: bool = False) -> None:
    """Import the backprojection kernels' module (numba), its cached kernels set to load without numba's
    compiler registries first (imaging.numba_target.load_cached_kernels_lightly); what a first kernel
    call imports and starts besides: numpy.ma (numba's typeof asks of every array argument whether it is
    masked), numba.np.arrayobj (where the cached kernels' environments are rebuilt;
    numba.core.environment) and numba's runtime (NRT); then one backprojection of one profile onto one
    point, with the argument types of an image's, which loads the direct kernel's machine code from
    numba's cache (or compiles it), so that the first block's backprojection finds it loaded. With ``ffbp``
    also FFBP's plan passes and leaf kernel (imaging.ffbp_placement.load_passes, imaging.ffbp_leaves.load_kernel):
    their cache loads were most of what a process's first plan cost beyond a later one."""
    from imaging.numba_target import load_cached_kernels_lightly

    load_cached_kernels_lightly()
    import imaging.backprojection as bp  # first: it sets the CPU features numba's target is built with
    import numpy.ma  # noqa: F401
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.registry import cpu_target
    from numba.core.runtime import rtsys
    from numba.np import arrayobj  # noqa: F401

    with global_compiler_lock:  # numba's runtime, which every cache load starts (idempotent), started now
        rtsys.initialize(cpu_target.target_context)
    bp.backproject(_one_profile(), np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]]))
    if ffbp:
        from imaging.ffbp_leaves import load_kernel
        from imaging.ffbp_placement import load_passes

        load_passes()
        load_kernel()


def _one_profile():
    """One guarded complex64 profile of 8 bins (imaging.range_compression.RangeProfiles, ``rows`` set as
    range compression sets them), zero everywhere."""
    from imaging.range_compression import RangeProfiles

    rows = np.zeros((1, 11), np.complex64)
    return RangeProfiles(data=rows[:, 1:9], range_start_m=0.0, range_step_m=0.01, carrier_hz=77e9, f0_hz=77e9,
                         frequency_step_hz=1e6, rows=rows, bandwidth_hz=8e6)
