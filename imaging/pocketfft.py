"""scipy's FFT (pocketfft) along the last axis, without importing ``scipy.fft``.

``scipy.fft`` costs about 0.2 s of CPU to import, most of a process that only range-compresses and
backprojects: its array-API layer copies numpy's namespace (which imports numpy.f2py, numpy.testing and
numpy.ma) and parses its functions' docstrings, and its FFTLog imports scipy.special
(benchmarks/image_command.py, ``command_imports``). The transform itself is one function of one
extension module, ``scipy.fft._pocketfft.pypocketfft``, which needs none of that. :func:`fft_in_place`
loads that module from scipy's folder alone and calls it as ``scipy.fft.fft(x, axis=-1,
overwrite_x=True, workers=...)`` does (``scipy/fft/_pocketfft/basic.py``: ``c2c``), so the numbers are
scipy's, bit for bit; where the module cannot be loaded so (another scipy layout), or for input scipy
would first convert, it calls ``scipy.fft.fft`` itself.
"""

from __future__ import annotations

import functools
import importlib.machinery
import importlib.util
import os

import numpy as np

#: scipy's name for its pocketfft extension module.
EXTENSION = "scipy.fft._pocketfft.pypocketfft"


@functools.cache
def _extension():
    """scipy's pocketfft extension module, loaded from its file without scipy.fft's package; None where
    it is not found or has no ``c2c``."""
    try:
        scipy_spec = importlib.util.find_spec("scipy")
        folder = os.path.join(scipy_spec.submodule_search_locations[0], "fft", "_pocketfft")
        path = next(p for p in (os.path.join(folder, "pypocketfft" + suffix)
                                for suffix in importlib.machinery.EXTENSION_SUFFIXES) if os.path.isfile(p))
        loader = importlib.machinery.ExtensionFileLoader(EXTENSION, path)
        module = importlib.util.module_from_spec(importlib.util.spec_from_file_location(EXTENSION, path, loader=loader))
        loader.exec_module(module)
    except (ImportError, AttributeError, TypeError, StopIteration, OSError):
        return None
    return module if callable(getattr(module, "c2c", None)) else None


def _threads(workers: int | None) -> int:
    """scipy.fft's ``workers`` as a thread count (``scipy/fft/_pocketfft/helper.py``: ``_workers``)."""
    if workers is None:
        return 1
    cores = os.cpu_count() or 1
    if workers < 0:
        if workers < -cores:
            raise ValueError(f"workers value out of range; got {workers}, must not be less than {-cores}")
        return workers + 1 + cores
    if workers == 0:
        raise ValueError("workers must not be zero")
    return workers


def fft_in_place(x: np.ndarray, workers: int | None = None) -> np.ndarray:
    """The forward FFT of ``x`` along its last axis, unnormalised, written over ``x`` where it can be:
    ``scipy.fft.fft(x, axis=-1, overwrite_x=True, workers=workers)``, the same numbers.

    Parameters
    ----------
    x : ndarray, complex64 or complex128
        Overwritten with its transform (returned) when complex, aligned, in native byte order and
        non-empty along the last axis; anything else goes to ``scipy.fft.fft``, which converts it.
    workers : int, optional
        Threads (scipy.fft's meaning: -1 all cores, None one).
    """
    module = _extension()
    if (module is None or x.dtype not in (np.complex64, np.complex128) or not x.flags.aligned
            or not x.dtype.isnative or x.ndim == 0 or x.shape[-1] < 1):
        import scipy.fft

        return scipy.fft.fft(x, axis=-1, overwrite_x=True, workers=workers)
    return module.c2c(x, (-1,), True, 0, x, _threads(workers))


def ifft_in_place(x: np.ndarray, workers: int | None = None) -> np.ndarray:
    """The inverse FFT of ``x`` along its last axis, unnormalised (no 1 / n), written over ``x`` where it can
    be: ``scipy.fft.ifft(x, axis=-1, norm="forward", overwrite_x=True, workers=workers)``, the same numbers."""
    module = _extension()
    if (module is None or x.dtype not in (np.complex64, np.complex128) or not x.flags.aligned
            or not x.dtype.isnative or x.ndim == 0 or x.shape[-1] < 1):
        import scipy.fft

        return scipy.fft.ifft(x, axis=-1, norm="forward", overwrite_x=True, workers=workers)
    return module.c2c(x, (-1,), False, 0, x, _threads(workers))
