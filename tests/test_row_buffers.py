"""imaging.row_buffers.RowBuffers on its own: which buffer a block's profiles are written into."""

from __future__ import annotations

import itertools

import numpy as np

from imaging.row_buffers import RowBuffers


def _buffer(rows: int, cols: int) -> np.ndarray:
    return np.zeros((rows, cols), np.complex64)


def _owner(view: np.ndarray) -> np.ndarray:
    return view if view.base is None else view.base


def test_the_smallest_free_buffer_that_fits_whatever_order_they_came_back_in():
    """A window 2 bins wider than one buffer, given before or after a larger one: the larger one is taken,
    and the smaller stays for a later narrower window (it used to be popped and dropped when it came last)."""
    for order in itertools.permutations([(40, 100), (40, 103)]):
        buffers = RowBuffers()
        given = {shape: _buffer(*shape) for shape in order}
        for shape in order:
            buffers.give(given[shape])
        rows = buffers.take((40, 102))
        assert rows.shape == (40, 102) and rows.flags.c_contiguous, order
        assert _owner(rows) is given[(40, 103)] and buffers.new_buffers == 0, order
        assert buffers.sizes() == [4000]  # the too-small one is kept
        assert _owner(buffers.take((39, 100))) is given[(40, 100)]
        assert buffers.sizes() == [] and buffers.new_buffers == 0


def test_of_three_that_fit_the_smallest_is_taken_and_none_that_fits_makes_a_new_one_with_headroom():
    for order in itertools.permutations([(10, 50), (10, 60), (10, 55)]):
        buffers = RowBuffers()
        buffers.KEPT = 3
        given = {shape: _buffer(*shape) for shape in order}
        for shape in order:
            buffers.give(given[shape])
        new = buffers.take((10, 61))  # none fits: a new one, and all are kept
        assert buffers.new_buffers == 1 and len(buffers.sizes()) == 3
        assert new.shape == (10, 61) and _owner(new).shape == (10, 61 + RowBuffers.HEADROOM_BINS)
        assert _owner(buffers.take((10, 52))) is given[(10, 55)]
        assert _owner(buffers.take((10, 52))) is given[(10, 60)]
        assert buffers.sizes() == [500] and buffers.new_buffers == 1
        buffers.give(new)  # two bins wider than it was made for still fits it
        assert _owner(buffers.take((10, 63))) is _owner(new) and buffers.new_buffers == 1
        assert buffers.take((0, 63)) is None and buffers.sizes() == [500]  # nothing to write: no buffer


def test_at_most_kept_buffers_the_smallest_dropped():
    for order in itertools.permutations([(2, 30), (2, 10), (2, 20)]):
        buffers = RowBuffers()
        for shape in order:
            buffers.give(_buffer(*shape))
        assert sorted(buffers.sizes()) == [40, 60], order  # KEPT = 2: the (2, 10) one went


def test_a_view_given_back_returns_its_whole_buffer_and_other_arrays_are_not_kept():
    buffers = RowBuffers()
    whole = _buffer(8, 20)
    buffers.give(whole)
    view = buffers.take((5, 19))
    assert view.ctypes.data == whole.ctypes.data and _owner(view) is whole
    buffers.give(view)
    assert buffers.sizes() == [160]
    buffers.give(None)
    buffers.give(np.zeros((4, 4), np.complex128))  # not complex64
    buffers.give(np.zeros((4, 4, 2), np.complex64))  # not rows
    assert buffers.sizes() == [160]


def test_blocks_windows_a_few_bins_apart_reuse_whichever_thread_is_first():
    """The widths of test_kernel_import's pass (bins + guards: wide at its ends, narrow at broadside), the
    first block half as many rows. Whether block n's buffer is back before block n + 1 takes one is a race
    between the two threads: whichever wins at each block, at most three buffers are ever made in the pass
    (test_kernel_import's image counts on it)."""
    widths = [105, 103, 102, 102, 100, 99, 98, 99, 100, 102, 102, 104, 105]
    for back_in_time in itertools.product((False, True), repeat=len(widths)):
        buffers = RowBuffers()
        in_use = [buffers.take((64, 104))]  # the first block's, backprojected while the next is compressed
        made = [buffers.new_buffers]
        for width, in_time in zip(widths, back_in_time):
            if in_time:  # the block before this one's done: its buffer is back first
                buffers.give(in_use.pop(0))
            before = buffers.new_buffers
            in_use.append(buffers.take((128, width)))
            made.append(buffers.new_buffers - before)
            if len(in_use) > 1:
                buffers.give(in_use.pop(0))
        assert sum(made) <= 3, back_in_time
