"""benchmarks/results_file.py: the one way a benchmark writes docs/results/NAME.json. What it writes is strict
JSON with the run's provenance, a NaN or an infinity is refused by its key path (and the result kept), and
every benchmark writes through it. (That every committed JSON parses strictly is
tests/test_strict_json.py's test_every_committed_json_file_is_strict_json.)"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
import results_file  # noqa: E402

sys.path.pop(0)


def strict_loads(text: str):
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_a_nan_is_refused_by_its_key_path_and_nothing_is_written(tmp_path, monkeypatch):
    monkeypatch.setattr(results_file.tempfile, "tempdir", str(tmp_path / "kept"))
    (tmp_path / "kept").mkdir()
    result = {"mode": "full", "rows": [{"error_db": -40.0}, {"error_db": float("nan")}],
              "cube": np.array([[1.0, 2.0], [np.inf, 3.0]], dtype=np.float32), "gain_db": np.float64(-np.inf)}
    with pytest.raises(ValueError) as refused:
        results_file.write_results("toy", result, started_load=[1.0, 1.0, 1.0], folder=tmp_path / "results")
    message = str(refused.value)
    assert "toy.json not written" in message
    assert "rows[1].error_db, cube[1, 0], gain_db" in message
    assert not (tmp_path / "results" / "toy.json").exists()
    kept = sorted((tmp_path / "kept").glob("toy.refused.*.json"))
    assert len(kept) == 1 and str(kept[0]) in message  # the long run's figures are not lost
    assert json.loads(kept[0].read_text())["rows"][0] == {"error_db": -40.0}


def test_non_numbers_names_every_place_and_passes_none():
    assert results_file.non_numbers({"a": None, "b": [1.0, {"c": float("-inf")}], "d": complex(0, float("nan")),
                                     "e": np.array([1, 2]), "f": np.zeros(3)}) == ["b[1].c", "d"]
    assert results_file.finite_or_none(-np.inf) is None and results_file.finite_or_none(np.float32(2.5)) == 2.5


def test_the_file_is_strict_json_with_the_runs_provenance_and_the_benchmarks_keys(tmp_path):
    result = {"rows": [{"x_m": np.float32(0.5), "n": np.int64(3)}], "error_db": None}
    path = results_file.write_results("toy", result, started_load=[3.5, 2.25, 1.0], folder=tmp_path, indent=1)
    assert path == tmp_path / "toy.json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["toy.json"]  # the temporary file was renamed, not left
    data = strict_loads(path.read_text())
    assert data["rows"] == [{"x_m": 0.5, "n": 3}] and data["error_db"] is None
    run = data["provenance"]
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    assert run["commit"] == head and isinstance(run["tree_dirty"], bool)
    assert run["load_average_start"] == [3.5, 2.25, 1.0] and len(run["load_average_end"]) == 3
    assert run["cpu_model"] and run["cpu_count"] >= 1
    assert run["command"].startswith("python ")
    assert path.read_text().endswith("}\n") and '\n "rows"' in path.read_text()  # indent 1


def test_a_result_written_again_keeps_the_run_that_measured_it(tmp_path):
    """A soak's JSON summarised anew (soak.py --summary-of): the provenance is of this writing, and the run
    that measured the figures stays as measured_by, however often it is written again."""
    path = results_file.write_results("soak", {"lag_s": 0.2}, started_load=[1.0, 1.0, 1.0], folder=tmp_path)
    measured = strict_loads(path.read_text())["provenance"]
    for load in (2.0, 3.0):
        again = strict_loads(path.read_text())
        results_file.write_results("soak", again, started_load=[load] * 3, folder=tmp_path)
    run = strict_loads(path.read_text())["provenance"]
    assert run["load_average_start"] == [3.0, 3.0, 3.0] and run["measured_by"] == measured


def test_a_part_replaces_one_key_and_keeps_the_rest_and_its_provenance(tmp_path):
    first = results_file.write_results("whole", {"speed": 2.0, "baseline_comparison": {"old": 1}},
                                       started_load=[1.0, 1.0, 1.0], folder=tmp_path)
    before = strict_loads(first.read_text())
    results_file.write_results("whole", {"ratio": 0.8}, started_load=[2.0, 2.0, 2.0], folder=tmp_path,
                               part="baseline_comparison")
    after = strict_loads(first.read_text())
    assert after["speed"] == 2.0 and after["provenance"] == before["provenance"]
    assert after["baseline_comparison"]["ratio"] == 0.8 and "old" not in after["baseline_comparison"]
    assert after["baseline_comparison"]["provenance"]["load_average_start"] == [2.0, 2.0, 2.0]




def test_every_benchmark_writes_its_json_through_write_results():
    """No benchmark writes a JSON file its own way (plain ``json.dumps`` writes NaN; most recorded neither
    commit nor load)."""
    own_way = re.compile(r"write_text\(\s*(strict_)?json\.dumps|json\.dump\(")
    scripts = sorted(p for p in BENCHMARKS.glob("*.py") if p.name != "results_file.py")
    assert len(scripts) > 30
    offenders = [p.name for p in scripts if own_way.search(p.read_text())]
    assert not offenders, f"write these through results_file.write_results: {offenders}"
    writers = [p.name for p in scripts if "write_results(" in p.read_text()]
    assert len(writers) >= 30, writers
