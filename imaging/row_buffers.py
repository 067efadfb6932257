"""The profile rows of blocks already backprojected, handed on to the range compression of later blocks
(``imaging.image_formation.form_image``)."""

from __future__ import annotations

import threading

import numpy as np


class RowBuffers:
    """Profile buffers for ``range_compress``'s ``rows_out``: a block's profiles are hundreds of MB, and every
    new buffer's pages cost the system time of their first touch (about 0.05-0.5 s of CPU a block, more on
    a loaded machine), so the buffers of blocks already backprojected are handed on to later blocks.

    Blocks' range windows differ by a few bins (imaging.range_window), and whether a block's buffer is back
    before the next block is compressed depends on which thread is faster. So that reuse does not hang on
    that race: ``take`` hands out the smallest free buffer that fits (a larger one stays for a wider
    window) and leaves the others, too small ones included; a new buffer has ``HEADROOM_BINS`` more bins
    than asked, so a slightly wider window later still fits; past ``KEPT`` free buffers the smallest is
    dropped. Safe between two threads (a lock: ``take`` looks at every buffer before it takes one).
    """

    #: Buffers kept for reuse: a block backprojected while the next is compressed needs two.
    KEPT = 2
    #: Bins a new buffer has beyond the asked width: blocks' windows differ by a few bins, and a window is
    #: hundreds to thousands of bins wide (a few % more memory at most).
    HEADROOM_BINS = 16

    def __init__(self) -> None:
        self._free: list[np.ndarray] = []
        self._lock = threading.Lock()
        self.new_buffers = 0  # buffers made by take: the rest were reused

    def take(self, shape: tuple[int, int]) -> np.ndarray | None:
        """A C-contiguous view, shape ``shape`` (rows, bins + guards), of the start of the smallest free buffer
        holding at least that many elements (taken off the free ones), else of a new buffer of
        ``HEADROOM_BINS`` more bins (uninitialised: ``range_compress`` writes every element of a ``rows_out``);
        None for an empty shape."""
        size = shape[0] * shape[1]
        if size == 0:
            return None
        with self._lock:
            fits = [i for i, rows in enumerate(self._free) if rows.size >= size]
            if fits:
                rows = self._free.pop(min(fits, key=lambda i: self._free[i].size))
            else:
                rows = np.empty((shape[0], shape[1] + self.HEADROOM_BINS), np.complex64)
                self.new_buffers += 1
        return rows.reshape(-1)[:size].reshape(shape)

    def give(self, rows: np.ndarray | None) -> None:
        """Hand back a block's ``RangeProfiles.rows`` (the whole C-contiguous complex64 buffer it is the start
        of), once nothing reads them; anything else is left to the garbage collector."""
        if rows is None:
            return
        whole = rows if rows.base is None else rows.base
        if not (isinstance(whole, np.ndarray) and whole.ndim == 2 and whole.dtype == np.complex64
                and whole.flags.c_contiguous):
            return
        with self._lock:
            self._free.append(whole)
            if len(self._free) > self.KEPT:
                self._free.pop(min(range(len(self._free)), key=lambda i: self._free[i].size))

    def sizes(self) -> list[int]:
        """The element counts of the free buffers, in the order they were given back (for tests and logs)."""
        with self._lock:
            return [rows.size for rows in self._free]
