"""HDF5's Fletcher-32 chunk checksum computed by sarbot (imaging.io.fletcher32): the kernel against a plain
word-by-word reference, and both against the chunks HDF5 itself stores."""

from pathlib import Path

import h5py
import numpy as np
import pytest

from imaging.io.fletcher32 import checksummed_chunk, fletcher32, fletcher32_reference


@pytest.mark.parametrize("n_bytes", [0, 1, 2, 3, 718, 719, 720, 721, 722, 1441, 20_001, 716_800])
def test_the_kernel_is_the_word_by_word_reference(n_bytes):
    """Sizes around the 360-word folds and odd lengths (the last byte a word's high byte), random bytes and
    all 0xFF (the sums at their largest: the folds, not a modulo, decide the value)."""
    rng = np.random.default_rng(n_bytes)
    for data in (rng.integers(0, 256, n_bytes, dtype=np.uint8), np.full(n_bytes, 0xFF, np.uint8)):
        assert fletcher32(data) == fletcher32_reference(data)
        assert fletcher32(data.tobytes()) == fletcher32_reference(data)
    if n_bytes:
        assert fletcher32(np.full(n_bytes, 0xFF, np.uint8)) != fletcher32(np.zeros(n_bytes, np.uint8))


@pytest.mark.parametrize("dtype, shape", [(np.int16, (64, 4, 37, 2)), (np.complex64, (16, 2, 33)), (np.uint8, (1441,))])
def test_a_checksummed_chunk_is_the_chunk_hdf5_stores(tmp_path, dtype, shape):
    """HDF5 filters a row written the usual way; the chunk it stores (data then checksum) is byte for byte
    what checksummed_chunk builds, and a chunk written directly reads back through HDF5's own check."""
    rng = np.random.default_rng(4)
    rows = [(rng.normal(size=shape) * 3000).astype(dtype) if dtype != np.complex64 else
            (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(dtype) for _ in range(3)]
    rows.append(np.full(shape, -1 if dtype == np.int16 else 255, dtype) if dtype != np.complex64 else rows[0] * 0)
    zeros = (0,) * len(shape)
    with h5py.File(tmp_path / "f.h5", "w") as f:
        usual = f.create_dataset("usual", (len(rows), *shape), dtype, chunks=(1, *shape), fletcher32=True)
        direct = f.create_dataset("direct", (len(rows), *shape), dtype, chunks=(1, *shape), fletcher32=True)
        buffer = np.empty(rows[0].nbytes + 4, np.uint8)
        for k, row in enumerate(rows):
            usual[k] = row
            direct.id.write_direct_chunk((k, *zeros), checksummed_chunk(row, buffer))
    with h5py.File(tmp_path / "f.h5", "r") as f:
        for k, row in enumerate(rows):
            mask, stored = f["usual"].id.read_direct_chunk((k, *zeros))
            assert mask == 0 and stored == checksummed_chunk(row, buffer).tobytes()
            assert stored[-4:] == fletcher32_reference(row).to_bytes(4, "little")
        assert np.array_equal(f["direct"][...], np.stack(rows))


def test_a_chunk_buffer_of_the_wrong_size_is_refused():
    with pytest.raises(ValueError, match="chunk buffer of 10 bytes"):
        checksummed_chunk(np.zeros(8, np.int16), np.empty(10, np.uint8))


def test_reading_a_recording_does_not_import_numba():
    """The checksum kernel is loaded where frames are written only: a reader (``sarbot image``, ``info``, the
    viewer) would otherwise pay numba's import (0.27 s, ~45 MB) on its main thread before anything else."""
    import subprocess
    import sys

    code = ("import sys, imaging.io.recording, imaging.io.columns; "
            "print(sorted(m for m in sys.modules if m == 'numba' or m == 'imaging.io.fletcher32'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "[]"
