"""How numba is set up for sarbot's kernels: full-width AVX-512 vectors where the CPU has them, no
search for numba extensions, which the kernels do not use, and (for a command that only runs cached
kernels) cache loads without the compiler's registries.

``imaging.backprojection`` calls :func:`prefer_full_width_vectors` and :func:`skip_extension_search` on
import, before any of its kernels compiles; benchmarks report :func:`compiled_target`.
"""

from __future__ import annotations

import os


def prefer_full_width_vectors() -> str | None:
    """Let numba's LLVM use all 512 bits of AVX-512 where the CPU has it; returns the feature string set.

    LLVM tunes Intel's AVX-512 server and client cores to prefer 256-bit vectors (``prefer-256-bit``), so
    numba's loops run 8 float32 lanes wide where 16 fit; turning that tuning off makes the float32 block
    kernel about 1.25x faster here. numba reads its target once, when it first compiles anything in the
    process: this has to run before that (it does on import, before any kernel of this package is called),
    and it affects every numba function of the process (all are vectorised the same way, only wider). An
    explicit ``NUMBA_CPU_FEATURES`` or ``NUMBA_CPU_NAME`` is left alone.
    """
    if os.environ.get("NUMBA_CPU_FEATURES") or os.environ.get("NUMBA_CPU_NAME"):
        return None
    import llvmlite.binding as llvm
    from numba.core import config
    from numba.core.registry import cpu_target

    if "_toplevel_target_context" in getattr(cpu_target, "__dict__", {}):
        # numba built its target machine already (a numba function was made before this call, as by a
        # module imported before this package's kernels): its vector width is fixed. A config saying
        # otherwise would file this process's 256-bit kernels in numba's cache under the 512-bit target's
        # key, where a later process loads them as its own and images differ in their last bits.
        return None

    try:
        features = llvm.get_host_cpu_features()
    except RuntimeError:  # a host LLVM cannot describe: leave numba's default
        return None
    if not features.get("avx512f"):
        return None
    # The environment, not only numba's config: numba re-reads its config from NUMBA_* variables when they
    # change, and the acquisition's worker processes compile with the same target.
    os.environ["NUMBA_CPU_FEATURES"] = features.flatten() + ",-prefer-256-bit"
    config.reload_config()
    return os.environ["NUMBA_CPU_FEATURES"]


def compiled_target() -> dict:
    """The CPU name and features numba compiles for in this process (benchmarks report it)."""
    from numba.core.registry import cpu_target

    codegen = cpu_target.target_context.codegen()
    features = codegen._tm_features  # noqa: SLF001 - what the JIT really uses, not what the config says
    wide = "-prefer-256-bit" in features and "+avx512f" in features
    return {"cpu": codegen._get_host_cpu_name(), "vector_bits": 512 if wide else 256 if "+avx" in features else 128,  # noqa: SLF001
            "prefer_256_bit_off": "-prefer-256-bit" in features}


def skip_extension_search() -> None:
    """Tell numba its extensions are loaded already, so that it does not look for any.

    Before its first compilation or cache load numba runs every installed ``numba_extensions`` entry point,
    and to find them it reads the metadata of every installed distribution (importlib.metadata): about
    0.1 s of every process that images, more the more packages the environment holds. sarbot's kernels
    use numba's own types and functions only; a process that needs a numba extension imports it itself.
    """
    from numba.core import entrypoints

    entrypoints._already_initialized = True  # noqa: SLF001 - numba's flag that the search was done


def load_cached_kernels_lightly() -> bool:
    """Let numba load a cached kernel without first building the registries its compiler needs.

    Before each cache load numba refreshes its target (``numba.core.caching.Cache.load_overload``): it
    imports its implementations of Python and numpy, and with them scipy.linalg for BLAS, and builds its
    typing and lowering registries (about 0.2 s of CPU; benchmarks/image_command.py, ``process_start``).
    Loading machine code from the cache needs none of that, only numba's runtime (NRT), which that refresh
    would also have started; a kernel that is not in the cache still compiles, and compiling refreshes the
    target itself (``numba.core.compiler.compile_extra``). So this makes every cache load of the process
    start the runtime alone. ``sarbot image`` calls it in its start-up; the image is the same bit for bit.

    Returns False, changing nothing, where numba's cache has not the shape this relies on (another numba
    version): loads then refresh as before.
    """
    from numba.core import caching

    cache = caching.Cache
    if getattr(cache.load_overload, "runtime_only", False):
        return True
    if not all(callable(getattr(cache, name, None))
               for name in ("load_overload", "_load_overload", "_guard_against_spurious_io_errors")):
        return False
    from numba.core.runtime import rtsys

    refreshing_load = cache.load_overload

    def load_overload(self, sig, target_context):
        rtsys.initialize(target_context)  # what the loaded code calls into (idempotent)
        try:
            with self._guard_against_spurious_io_errors():
                return self._load_overload(sig, target_context)
        except Exception:  # noqa: BLE001 - e.g. a symbol only a registry defines: load as numba does
            return refreshing_load(self, sig, target_context)

    load_overload.runtime_only = True
    cache.load_overload = load_overload
    return True


def compiles_for_avx512() -> bool:
    """Whether numba compiles this process's kernels for a CPU with AVX-512 (F): the features it is told
    (``NUMBA_CPU_FEATURES``, as :func:`prefer_full_width_vectors` sets them), else, unless told a CPU by
    name (``NUMBA_CPU_NAME``: a portable target, whose features are not the host's), the host's."""
    return _compiles_for("avx512f")


def compiles_for_avx2() -> bool:
    """Whether numba compiles this process's kernels for a CPU with AVX2 (every CPU with AVX-512 has it):
    decided as :func:`compiles_for_avx512` is."""
    return _compiles_for("avx2")


def _compiles_for(feature: str) -> bool:
    """Whether numba's target for this process has the LLVM CPU feature ``feature`` (``"avx2"``)."""
    from numba.core import config

    if config.CPU_FEATURES:
        return "+" + feature in config.CPU_FEATURES.split(",")
    if config.CPU_NAME:
        return False
    import llvmlite.binding as llvm

    try:
        return bool(llvm.get_host_cpu_features().get(feature))
    except RuntimeError:
        return False
