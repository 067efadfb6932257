"""benchmarks/image_floor.py's floor steps do what they say: step (d) makes the profiles form_image makes, (c) and
(d) run without numba and (e) with it, and the bound is the formula the JSON states."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
import image_floor  # noqa: E402
from image_command import make_recording  # noqa: E402

sys.path.remove(str(BENCHMARKS))

#: A small grid over the benchmark case's 1 x 1 m box (the same range window as its 256 x 256 grid).
GRID = image_floor.grid_of(16)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """image_command's scene, 12 frames simulated: more than one of form_image's blocks (2, then 8 at a time)."""
    path = tmp_path_factory.mktemp("floor") / "rec.h5"
    make_recording(path, 12)
    return path


def test_step_d_makes_the_profiles_form_image_backprojects(recording, tmp_path, monkeypatch):
    import imaging.backprojection
    from imaging.core.grid import Grid
    from imaging.image_formation import form_image
    from imaging.io.recording import Recording

    seen = []

    def keep(profiles, tx_m, rx_m, points, mode="linear", out=None):
        seen.append((profiles.data.copy(), profiles.range_start_m, tx_m.copy(), rx_m.copy()))

    monkeypatch.setattr(imaging.backprojection, "backproject", keep)
    with Recording(recording) as rec:
        form_image(rec, "left_front", Grid.parse(GRID, default_z_m=0.3))
    step = image_floor.run_step("d", recording, GRID, dump=tmp_path / "d.npz")
    made = np.load(tmp_path / "d.npz")
    assert len(seen) >= 2 and len(made.files) == 4 * len(seen)
    for i, (data, start_m, tx_m, rx_m) in enumerate(seen):
        # a window of the bins, not every one of the 16 x 175 (the chirp-z path the command takes)
        assert data.shape[1] < 0.5 * 16 * 175
        np.testing.assert_array_equal(made[f"data{i}"], data)
        assert float(made[f"start{i}"]) == start_m
        np.testing.assert_array_equal(made[f"tx{i}"], tx_m)
        np.testing.assert_array_equal(made[f"rx{i}"], rx_m)
    marks = step["marks_wall_s"]
    assert list(marks) == ["start", "numpy", "h5py", "sarbot's modules", "open", "first block", "all blocks"]
    assert list(marks.values()) == sorted(marks.values()) and marks["all blocks"] <= step["wall_s"]


def test_steps_c_and_d_import_no_numba_and_e_loads_the_kernel(recording):
    found = {s: image_floor.run_step(s, recording, GRID) for s in "cde"}
    assert not found["c"]["numba_imported"] and not found["d"]["numba_imported"]
    assert found["e"]["numba_imported"]
    assert {"kernels ready", "4 pixels"} <= set(found["e"]["marks_wall_s"])
    assert "kernels ready" not in found["d"]["marks_wall_s"]
    for s in "ab":
        assert image_floor.run_step(s)["wall_s"] > 0


def test_an_unknown_step_is_refused():
    with pytest.raises(ValueError, match="no floor step 'g'"):
        image_floor.run_step("g")


def test_the_bound_charges_what_cannot_overlap_the_kernel():
    d = {"marks_wall_s": {"first block": 0.3}, "marks_cpu_s": {"first block": 0.25, "all blocks": 0.75}}
    # the kernel leaves 2 * 1.0 - 1.8 = 0.2 core-seconds idle; 0.5 - 0.2 = 0.3 CPU-s take both cores' time: 0.15 s
    b = image_floor.bound(1.0, 1.8, d)
    assert b["overhead_s"] == pytest.approx(0.45)
    assert b["fraction"] == pytest.approx(1 / 1.45)
    assert b["break_even_kernel_s"] == pytest.approx(0.85 / 0.15 * 0.45)
    # all of it fits in the idle core time: only the serial part counts
    assert image_floor.bound(1.0, 1.0, d)["overhead_s"] == pytest.approx(0.3)
