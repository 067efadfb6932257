"""imaging.pocketfft: scipy's FFT without scipy.fft's import, the same numbers."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.fft

from imaging.pocketfft import _extension, fft_in_place


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize("workers", [None, 1, -1])
def test_the_transform_is_scipys_bit_for_bit_and_in_place(dtype, workers):
    """On range compression's layout (rows with guard bins, the transform on a strided view of them,
    16x zero-padded) and on a 3-D block: the same numbers as scipy.fft.fft, written over the input."""
    assert _extension() is not None  # loaded alone here, else this would test scipy.fft against itself
    rng = np.random.default_rng(3)
    rows = np.zeros((300, 2803), dtype)
    rows[:, 1:176] = rng.standard_normal((300, 175)) + 1j * rng.standard_normal((300, 175))
    view = rows[:, 1:2801]
    expected = scipy.fft.fft(view.copy(), axis=-1, overwrite_x=True, workers=workers)
    out = fft_in_place(view, workers)
    assert np.shares_memory(out, rows) and out.dtype == dtype
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(rows[:, 1:2801], expected)
    cube = (rng.standard_normal((4, 5, 96)) + 1j * rng.standard_normal((4, 5, 96))).astype(dtype)
    np.testing.assert_array_equal(fft_in_place(cube.copy(), workers), scipy.fft.fft(cube, axis=-1, workers=workers))


def test_input_scipy_would_convert_goes_to_scipy():
    """Real, integer or byte-swapped input: scipy.fft.fft's own result (it converts first)."""
    x = np.arange(12.0).reshape(3, 4)
    np.testing.assert_array_equal(fft_in_place(x.copy()), scipy.fft.fft(x, axis=-1))
    swapped = (np.arange(8) + 1j).astype(">c16")
    np.testing.assert_array_equal(fft_in_place(swapped.copy()), scipy.fft.fft(swapped))
    with pytest.raises(ValueError, match="workers"):
        fft_in_place(np.zeros(4, np.complex64), 0)


def test_range_compression_imports_no_scipy_fft_and_scipy_fft_works_after_it():
    """In a new process: range compression leaves scipy.fft unimported; importing it afterwards (as
    autofocus does) gives the same transform."""
    code = ("import sys, numpy as np; from imaging.range_compression import range_compress; "
            "rng = np.random.default_rng(0); s = (rng.standard_normal((6, 50)) + 1j * rng.standard_normal((6, 50))).astype(np.complex64); "
            "p = range_compress(s, 77e9, 1e6, guarded=True, workers=-1); before = 'scipy.fft' in sys.modules; "
            "import scipy.fft; from imaging.core.windows import get_window; "
            "w = (get_window('hann', 50) / get_window('hann', 50).sum()).astype(np.float32); m = 24; "
            "buf = np.zeros((6, 800), np.complex64); buf[:, :26] = s[:, m:] * w[m:]; buf[:, 800 - m:] = s[:, :m] * w[:m]; "
            "print(before, np.array_equal(scipy.fft.fft(buf, axis=-1), p.data))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["False", "True"]
