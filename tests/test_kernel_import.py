"""The kernels made ready on a thread of their own (imaging.kernel_import), form_image's range compression
ahead of its first backprojection meanwhile, and the stages it times (imaging.core.stage_clock)."""

from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pytest
from conftest import RADAR

from imaging import kernel_import
from imaging.core.grid import Grid
from imaging.core.stage_clock import StageClock
from imaging.image_formation import ImagingOptions, _BlockReader, form_image
from imaging.io.recording import Recording

#: Blocks of two frames (the first of one): a pass of the session's recordings makes several.
SMALL_BLOCKS = ImagingOptions(tx=(0,), rx=(0,), frames_per_block=2)


def _grid() -> Grid:
    return Grid.from_ranges((-0.05, 0.05, 0.005), (1.9, 2.1, 0.005), 0.3)


def test_form_image_compresses_ahead_while_the_kernels_are_made_ready(pass_recordings, monkeypatch):
    """While a background preparation runs, form_image range-compresses further blocks before its first
    backprojection (here: the preparation ends during the third block, so three blocks are compressed
    before it; without the preparation at most two are), and the image is the same bit for bit."""
    import imaging.backprojection as bp

    with Recording(pass_recordings[0.4]) as rec:
        expected = form_image(rec, RADAR, _grid(), options=SMALL_BLOCKS).image
        ready = threading.Event()
        monkeypatch.setattr(kernel_import, "_ready", ready)
        compressed, at_first_backprojection = [], []
        block, backproject = _BlockReader.block, bp.backproject

        def counted_block(self, b, n_frames=None):
            compressed.append(b)
            if len(compressed) == 3:
                ready.set()  # the kernels ready during the third block
            return block(self, b, n_frames)

        def counted_backproject(*args, **kwargs):
            at_first_backprojection.append(len(compressed))
            return backproject(*args, **kwargs)

        monkeypatch.setattr(_BlockReader, "block", counted_block)
        monkeypatch.setattr(bp, "backproject", counted_backproject)
        clock = StageClock()
        img = form_image(rec, RADAR, _grid(), options=SMALL_BLOCKS, clock=clock)
    assert at_first_backprojection[0] == 3 and len(compressed) > 4
    np.testing.assert_array_equal(img.image, expected)
    assert {"open_frames", "wait_for_block", "kernel_import_wait", "backproject", "attributes",
            "compress_thread.read_frames", "compress_thread.range_compress_and_place"} <= set(clock.seconds)
    assert all(s >= 0.0 for s in clock.seconds.values())


def test_no_background_preparation_is_not_in_progress(monkeypatch):
    monkeypatch.setattr(kernel_import, "_ready", None)
    assert not kernel_import.in_progress()


# In a new process: the preparation in progress once started, ended after its thread, and the direct
# kernel's machine code then loaded with the one signature an image's backprojection uses.
PREPARE = r"""
import sys
import numpy as np
from imaging import kernel_import
from imaging.core.grid import Grid
from imaging.image_formation import ImagingOptions, form_image
from imaging.io.recording import Recording
thread = kernel_import.start_in_background()
started = kernel_import.in_progress()
thread.join()
import imaging.backprojection as bp
loaded = list(bp._bp_interp_blocks.signatures)
with Recording(sys.argv[1]) as rec:
    form_image(rec, "left_front", Grid.from_ranges((-0.05, 0.05, 0.005), (1.9, 2.1, 0.005), 0.3),
               options=ImagingOptions(tx=(0,), rx=(0,)))
print(started, kernel_import.in_progress(), len(loaded), list(bp._bp_interp_blocks.signatures) == loaded)
"""


def test_the_background_preparation_loads_the_kernel_an_image_uses(pass_recordings):
    res = subprocess.run([sys.executable, "-c", PREPARE, str(pass_recordings[0.4])], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["True", "False", "1", "True"]


def test_stage_clock_sums_each_stage():
    clock = StageClock()
    clock.add("a", 0.25)
    clock.add("a", 0.5)
    with clock.stage("b"):
        pass
    assert clock.seconds["a"] == pytest.approx(0.75) and 0.0 <= clock.seconds["b"] < 0.1


def test_form_image_hands_a_blocks_buffer_on_to_later_blocks(pass_recordings, monkeypatch):
    """After the first blocks every block's profiles are written into the buffer of one backprojected before
    it (imaging.image_formation.RowBuffers), and the image is the one of new buffers, bit for bit."""
    import imaging.image_formation as formation

    with Recording(pass_recordings[0.4]) as rec:
        monkeypatch.setattr(formation.RowBuffers, "take", lambda self, shape: None)  # always a new buffer
        expected = form_image(rec, RADAR, _grid(), options=SMALL_BLOCKS).image
        monkeypatch.undo()
        reused = []
        take = formation.RowBuffers.take

        def counted_take(self, shape):
            made = self.new_buffers
            rows = take(self, shape)
            reused.append(self.new_buffers == made)
            return rows

        monkeypatch.setattr(formation.RowBuffers, "take", counted_take)
        img = form_image(rec, RADAR, _grid(), options=SMALL_BLOCKS)
    assert sum(reused) >= len(reused) - 3 and len(reused) > 5
    np.testing.assert_array_equal(img.image, expected)
