"""The blocks of frames ``imaging.image_formation.form_image`` reads, range-compresses and backprojects in turn."""

from __future__ import annotations


def frame_blocks(n_frames: int, frames_per_block: int) -> tuple[list[int], list[int]]:
    """The blocks' first frames and their ends (exclusive), as two lists, over ``n_frames`` frames.

    The first block is a quarter of the others (at least one frame): nothing overlaps its range compression, so
    the kernel starts sooner; every later block, ``frames_per_block`` frames but the last, is compressed while the
    one before it is backprojected. No frames, no blocks.
    """
    first = max(1, frames_per_block // 4)
    starts = [0, *range(first, n_frames, frames_per_block)] if n_frames else []
    return starts, [*starts[1:], n_frames]
