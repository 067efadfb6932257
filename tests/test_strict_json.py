"""Strict JSON: what sarbot writes parses with parsers that refuse NaN and Infinity (Python's json with
``parse_constant`` refusing, and node's ``JSON.parse`` where node is installed)."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imaging.core.strict_json import dumps, plain


def strict_loads(text: str):
    """``json.loads`` that refuses NaN, Infinity and -Infinity, as JSON itself does."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


@dataclasses.dataclass
class _Peak:
    snr_db: float
    at_m: tuple


def test_non_numbers_become_null_everywhere_and_numpy_becomes_plain():
    value = {"a": float("nan"), "b": [np.float32(np.inf), -np.inf, 1.5], "c": np.array([[1.0, np.nan]]),
             "d": np.int64(7), "e": np.bool_(True), "f": _Peak(np.float64(np.nan), (1, 2)), 3: Path("/x/y.h5")}
    text = dumps(value)
    assert strict_loads(text) == {"a": None, "b": [None, None, 1.5], "c": [[1.0, None]], "d": 7, "e": True,
                                  "f": {"snr_db": None, "at_m": [1, 2]}, "3": "/x/y.h5"}
    assert plain(np.float32(0.25)) == 0.25 and type(plain(np.float32(0.25))) is float
    with pytest.raises(ValueError, match="not JSON: NaN"):
        strict_loads(json.dumps({"a": float("nan")}))  # what the standard library writes by default


def test_a_value_json_has_no_form_for_is_refused_by_name():
    with pytest.raises(TypeError, match="no JSON form for object"):
        dumps({"x": object()})


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed (apt-get install nodejs)")
def test_node_json_parse_reads_it():
    text = dumps({"pslr_db": float("nan"), "width_m": [0.1, float("inf")]})
    res = subprocess.run(["node", "-e", "let s='';process.stdin.on('data',d=>s+=d).on('end',()=>"
                          "console.log(JSON.stringify(JSON.parse(s))))"], input=text, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == {"pslr_db": None, "width_m": [0.1, None]}


REPO = Path(__file__).resolve().parents[1]
CLI = [__import__("sys").executable, "-m", "acquisition.cli"]


def node_parses(text: str) -> None:
    """node's JSON.parse reads ``text`` (where node is installed)."""
    if shutil.which("node") is None:
        return
    res = subprocess.run(["node", "-e", "let s='';process.stdin.on('data',d=>s+=d).on('end',()=>JSON.parse(s))"],
                         input=text, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr[-500:]


def test_every_committed_json_file_is_strict_json():
    files = [p for p in REPO.rglob("*.json") if not {"node_modules", ".venv", ".git", "site"} & set(p.parts)]
    assert any(p.match("docs/results/paper/report.json") for p in files)
    for path in files:
        text = path.read_text()
        strict_loads(text)
        node_parses(text)


def test_info_json_and_analyze_print_strict_json(tmp_path):
    """A recording whose IMU clock drift is unknown (NaN in the file) and an image whose one bright cell has
    no side lobes (PSLR -inf): both once printed NaN or -Infinity."""
    from test_round_trip import make_source

    from imaging.io.image_file import SarImage, write_image

    rec = tmp_path / "rec.h5"
    make_source(rec, n_frames=3)
    x, y = np.arange(-0.5, 0.5, 0.01), np.arange(1.5, 2.5, 0.01)
    image = np.zeros((y.size, x.size), np.complex64)
    image[50, 50] = 1.0
    write_image(tmp_path / "img.h5", SarImage(image, x, y, np.array([0.0]), {"wavelength_m": 0.0039}))
    outputs = []
    for args in (["info", str(rec), "--json"], ["analyze", str(tmp_path / "img.h5")]):
        res = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        outputs.append(strict_loads(res.stdout))
        node_parses(res.stdout)
    info, analysis = outputs
    assert info["kind"] == "recording" and info["imu"]["clock_drift_ppm"] is None
    assert analysis["snr_db"] is None and analysis["peak_amplitude"] == 1.0  # the rest is there as numbers
