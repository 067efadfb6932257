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
