"""imaging.frame_blocks: the blocks of frames form_image (and benchmarks/image_floor.py's steps) go through."""

from __future__ import annotations

import pytest

from imaging.frame_blocks import frame_blocks


@pytest.mark.parametrize("n_frames, per_block, starts, ends", [
    (0, 8, [], [0]),
    (1, 8, [0], [1]),
    (2, 8, [0], [2]),
    (16, 8, [0, 2, 10], [2, 10, 16]),
    (31, 8, [0, 2, 10, 18, 26], [2, 10, 18, 26, 31]),
    (3, 1, [0, 1, 2], [1, 2, 3]),
    (9, 4, [0, 1, 5], [1, 5, 9]),
])
def test_the_first_block_is_a_quarter_of_the_others_and_they_cover_every_frame_once(n_frames, per_block, starts, ends):
    got_starts, got_ends = frame_blocks(n_frames, per_block)
    assert (got_starts, got_ends) == (starts, ends)
    covered = [f for a, b in zip(got_starts, got_ends) for f in range(a, b)]
    assert covered == list(range(n_frames))
