"""HDF5's Fletcher-32 chunk checksum computed here, so the recorder can hand HDF5 whole checksummed chunks.

A radar frame is one chunk of ``/radar/NAME/adc`` (716,800 bytes at the reference waveform). Written the usual
way, HDF5 copies the frame into its chunk cache, later copies it again into the filter's buffer and computes
the checksum one 16-bit word at a time: in a four-radar run that was the largest part of the recorder's CPU per
frame. :func:`checksummed_chunk` builds the chunk as it is stored (the data, then the checksum) for
``write_direct_chunk``; the file holds the same bytes as if HDF5 had filtered it.

The algorithm is HDF5's ``H5_checksum_fletcher32`` (H5checksum.c), stored little-endian after the data
(H5Zfletcher32.c): the data read as big-endian 16-bit words in blocks of 360, both sums folded to 17 bits
after each block (not reduced modulo 65535: the exact folding decides the stored value), an odd last byte
as the high byte of a word, and a final fold to 16 bits. :func:`fletcher32_reference` is the same in plain
numpy, against which the kernel is tested (and both against HDF5's own chunks).
"""

from __future__ import annotations

import numba
import numpy as np

#: Words between two folds of the sums; HDF5's, chosen so the second sum never overflows 32 bits.
BLOCK_WORDS = 360

# Within a block, the second sum gains sum_j (t - j) * word_j: the weights, 360 down to 1.
_WEIGHTS = np.arange(BLOCK_WORDS, 0, -1).astype(np.uint32)


@numba.njit(cache=True, nogil=True)
def _fletcher32(data_u8, weights):
    n_words = data_u8.size // 2
    sum1 = np.int64(0)
    sum2 = np.int64(0)
    k = 0
    while k < n_words:
        t = min(BLOCK_WORDS, n_words - k)
        block = data_u8[2 * k: 2 * (k + t)]
        w = weights[BLOCK_WORDS - t:]
        # HDF5 adds word by word (sum1 += x; sum2 += sum1). Over a block that is sum1 + sum(x) and
        # sum2 + t*sum1 + sum((t - j) x_j): independent sums the compiler vectorises, exact in uint32
        # (at most 360*361/2 * 65535 < 2**32).
        a = np.uint32(0)
        b = np.uint32(0)
        for j in range(t):
            x = (np.uint32(block[2 * j]) << np.uint32(8)) | np.uint32(block[2 * j + 1])
            a += x
            b += w[j] * x
        sum2 += t * sum1 + np.int64(b)
        sum1 += np.int64(a)
        sum1 = (sum1 & 0xFFFF) + (sum1 >> 16)
        sum2 = (sum2 & 0xFFFF) + (sum2 >> 16)
        k += t
    if data_u8.size % 2:
        sum1 += np.int64(data_u8[data_u8.size - 1]) << 8
        sum2 += sum1
        sum1 = (sum1 & 0xFFFF) + (sum1 >> 16)
        sum2 = (sum2 & 0xFFFF) + (sum2 >> 16)
    sum1 = (sum1 & 0xFFFF) + (sum1 >> 16)
    sum2 = (sum2 & 0xFFFF) + (sum2 >> 16)
    return (sum2 << 16) | sum1


def fletcher32(data) -> int:
    """HDF5's Fletcher-32 checksum of ``data``'s bytes (any C-contiguous array or bytes-like), as uint32."""
    return int(_fletcher32(np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray)
                           else np.ascontiguousarray(data).reshape(-1).view(np.uint8), _WEIGHTS))


def fletcher32_reference(data) -> int:
    """The same checksum, word by word as HDF5 writes it, in plain numpy and Python (slow: for tests)."""
    raw = np.frombuffer(bytes(memoryview(data).cast("B")) if not isinstance(data, np.ndarray)
                        else np.ascontiguousarray(data).tobytes(), np.uint8)
    words = (raw[: raw.size // 2 * 2:2].astype(np.int64) << 8) | raw[1: raw.size // 2 * 2:2]
    sum1 = sum2 = 0
    for start in range(0, words.size, BLOCK_WORDS):
        for x in words[start:start + BLOCK_WORDS].tolist():
            sum1 += x
            sum2 += sum1
        sum1 = (sum1 & 0xFFFF) + (sum1 >> 16)
        sum2 = (sum2 & 0xFFFF) + (sum2 >> 16)
    if raw.size % 2:
        sum1 += int(raw[-1]) << 8
        sum2 += sum1
        sum1 = (sum1 & 0xFFFF) + (sum1 >> 16)
        sum2 = (sum2 & 0xFFFF) + (sum2 >> 16)
    sum1 = (sum1 & 0xFFFF) + (sum1 >> 16)
    sum2 = (sum2 & 0xFFFF) + (sum2 >> 16)
    return (sum2 << 16) | sum1


def checksummed_chunk(row: np.ndarray, out: np.ndarray) -> np.ndarray:
    """One chunk as a Fletcher-32 dataset stores it: ``row``'s bytes (C order) then the checksum, 4 bytes
    little-endian. ``out``: a uint8 buffer of ``row.nbytes + 4`` bytes, filled and returned (reused by the
    caller across rows: no allocation per frame)."""
    data = np.ascontiguousarray(row).reshape(-1).view(np.uint8)
    if out.dtype != np.uint8 or out.size != data.size + 4:
        raise ValueError(f"chunk buffer of {out.size} bytes ({out.dtype}) for a row of {data.size} bytes (+4 for the checksum)")
    out[:-4] = data
    out[-4:] = np.frombuffer(int(_fletcher32(data, _WEIGHTS)).to_bytes(4, "little"), np.uint8)
    return out
