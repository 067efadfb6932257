"""benchmarks/results_file.py: the one way a benchmark writes docs/results/NAME.json. What it writes is strict
JSON with the run's provenance, a NaN or an infinity is refused by its key path (and the result kept), and
every benchmark writes through it. Every benchmark that times things probes the machine's speed before and
after (benchmarks/machine_speed.py, recorded as provenance.machine_speed). (That every committed JSON parses strictly is
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
import machine_speed  # noqa: E402
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


# -- the machine's speed beside every speed figure (benchmarks/machine_speed.py) ---------------------------------
#: What a benchmark's timing looks like in its source.
TIMES_THINGS = re.compile(r"perf_counter|process_time|thread_time|best_time\(|time\.monotonic\(|time\.time\(\)")

#: Benchmarks that time something but need not probe the machine, and why: their figures are accuracies and
#: the time they record is only how long the run took.
MAY_SKIP_THE_PROBE = {
    "autofocus_decision.py": "accuracy; records only the run's length",
    "autofocus_per_profile.py": "accuracy; records each method's seconds only as a run length",
    "autofocus_taper.py": "accuracy; records each method's seconds only as a run length",
    "autofocus_weak_point.py": "false-alarm rates; the time is its budget (--minutes)",
    "calibration.py": "calibration errors; records only the run's length",
    "calibration_elevation.py": "calibration errors; records only the run's length",
    "calibration_pitch.py": "calibration errors; records only the run's length",
    "calibration_states.py": "calibration errors; records only the run's length",
    "map_feedback.py": "odometry accuracy; records only the run's length",
    "map_feedback_live_drive.py": "odometry accuracy; records only the run's length",
    "map_feedback_settling.py": "odometry accuracy; records only the run's length",
    "map_feedback_sigma.py": "odometry accuracy; prints the run's length",
    "map_feedback_wild.py": "odometry accuracy; records only the run's length",
    "soak.py": "writes checkpoints throughout a live run (a probe at each would load the daemon it measures); "
               "its figures are against the sensors' rate, with its own CPU accounting",
}


def unprobed(scripts: list[Path]) -> list[str]:
    """The benchmarks among ``scripts`` that time things and write a result but never call ``probe_machine(``
    and are not in MAY_SKIP_THE_PROBE."""
    return [p.name for p in scripts if p.name not in MAY_SKIP_THE_PROBE and "write_results(" in p.read_text()
            and TIMES_THINGS.search(p.read_text()) and "probe_machine(" not in p.read_text()]


def test_every_benchmark_that_times_things_probes_the_machine():
    scripts = sorted(p for p in BENCHMARKS.glob("*.py") if p.name not in ("results_file.py", "machine_speed.py"))
    assert not unprobed(scripts), "call results_file.probe_machine() at the start of these (or say in " \
                                  f"MAY_SKIP_THE_PROBE why they need not): {unprobed(scripts)}"
    probed = [p.name for p in scripts if "probe_machine(" in p.read_text()]
    for name in ("peers.py", "kernel_versions.py", "kernel_parts.py", "ffbp.py", "image_command.py",
                 "odometry_speed.py", "ffbp_leaves_permute.py", "backprojection.py"):
        assert name in probed
    assert not set(MAY_SKIP_THE_PROBE) - {p.name for p in scripts}, "an opt-out for a benchmark that is gone"


def test_a_benchmark_that_times_things_without_the_probe_is_caught(tmp_path):
    body = "import time\nfrom results_file import load_average, write_results\nt = time.perf_counter()\n" \
           "write_results('toy', {'s': time.perf_counter() - t}, started_load=load_average())\n"
    (tmp_path / "toy.py").write_text(body)
    (tmp_path / "probed.py").write_text(body.replace("t = time", "probe_machine()\nt = time"))
    (tmp_path / "accuracy.py").write_text("from results_file import write_results\n"
                                          "write_results('a', {}, started_load=[])\n")
    assert unprobed(sorted(tmp_path.glob("*.py"))) == ["toy.py"]


def test_the_provenance_carries_the_probe_before_and_after(tmp_path, monkeypatch):
    probes = iter([{"kernel_gbp_per_s": 1.5}, {"kernel_gbp_per_s": 1.2}, {"kernel_gbp_per_s": 9.0}])
    monkeypatch.setattr(machine_speed, "probe", lambda: next(probes))
    monkeypatch.setattr(results_file, "_probe_before", None)
    path = results_file.write_results("accuracy", {"error_db": -40.0}, started_load=[1.0] * 3, folder=tmp_path)
    assert "machine_speed" not in strict_loads(path.read_text())["provenance"]  # no probe asked, none taken
    assert results_file.probe_machine() == {"kernel_gbp_per_s": 1.5}
    path = results_file.write_results("speed", {"speed": 2.0}, started_load=[1.0] * 3, folder=tmp_path)
    assert strict_loads(path.read_text())["provenance"]["machine_speed"] == {
        "before": {"kernel_gbp_per_s": 1.5}, "after": {"kernel_gbp_per_s": 1.2}}


def test_the_probe_gives_plausible_positive_figures_under_the_right_keys():
    probe = machine_speed.probe(repeats=2)
    assert set(probe) == {"utc", "kernel_gbp_per_s", "kernel_cycles_per_backprojection", "fma_gflops",
                          "fma_flops_per_cycle", "copy_gb_per_s", "wall", "worst_over_best", "repeats", "nominal_hz", "widest_vectors",
                          "probe_s", "setup_s", "steal_fraction", "load_average"}
    # Bounds 100x either side of this machine's (about 0.8 G backprojections/s on one thread, 9 GFLOP/s, 10 GB/s):
    # a wrong count of the work (bytes, FLOPs, points) would leave them, a slow hour would not.
    assert 0.01 < probe["kernel_gbp_per_s"] < 100
    assert 0.1 < probe["fma_gflops"] < 1000
    assert 0.1 < probe["copy_gb_per_s"] < 1000
    if probe["nominal_hz"] is not None:
        assert probe["kernel_cycles_per_backprojection"] == pytest.approx(
            probe["nominal_hz"] / (probe["kernel_gbp_per_s"] * 1e9))
        assert 0.01 < probe["fma_flops_per_cycle"] < 100
    assert set(probe["wall"]) == {"kernel_gbp_per_s", "fma_gflops", "copy_gb_per_s"}
    for key, wall_speed in probe["wall"].items():  # CPU time is at most the wall time (one thread): never faster
        assert 0 < wall_speed <= probe[key] * 1.05
    assert all(ratio >= 1.0 for ratio in probe["worst_over_best"].values()) and probe["repeats"] == 2
    assert probe["probe_s"] > 0 and probe["setup_s"] > 0 and len(probe["load_average"]) == 3
    assert probe["widest_vectors"] in (None, "avx512f", "avx2", "avx", "sse2", "other")
    assert probe["steal_fraction"] is None or 0.0 <= probe["steal_fraction"] <= 1.0


def test_the_fma_loop_computes_what_numpy_does():
    x0 = np.linspace(1.0, 2.0, machine_speed.FMA_CHAINS)
    for multiplier, addend, steps in [(0.999999, 1e-6, 10_000), (1.0, 0.5, 100), (0.5, 1.0, 3)]:
        assert machine_speed.fma_chains(x0, multiplier, addend, steps) == pytest.approx(
            machine_speed.fma_reference(x0, multiplier, addend, steps), rel=1e-9)


def test_the_watch_refuses_bad_arguments_with_a_message(capsys):
    for argv in (["--repeats", "0"], ["--watch", "-1"]):
        with pytest.raises(SystemExit) as exited:
            machine_speed.main(argv)
        assert exited.value.code == 2
        assert "must be" in capsys.readouterr().err


def test_the_results_page_shows_each_runs_probes_beside_its_load(tmp_path):
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import gen_results
    finally:
        sys.path.remove(str(ROOT / "docs"))
    probe = {"utc": "2026-11-26T21:04:18+00:00", "kernel_gbp_per_s": 1.234, "fma_gflops": 7.41,
             "copy_gb_per_s": 15.4, "widest_vectors": "avx2"}
    provenance = {"load_average_start": [1.0, 1.0, 1.0], "load_average_end": [2.0, 2.0, 2.0],
                  "machine_speed": {"before": probe, "after": {**probe, "kernel_gbp_per_s": 0.9}}}
    (tmp_path / "toy.json").write_text(json.dumps({"speed": 2.0, "provenance": provenance,
                                                   "part": {"ratio": 1.1, "provenance": provenance}}))
    lines = gen_results.render(tmp_path).splitlines()
    before = "| `provenance.machine_speed.before` | kernel 1.23 G bp/s, FMA 7.41 GFLOP/s, copy 15.4 GB/s, avx2, " \
             "at 21:04:18 UTC |"
    assert before in lines
    assert lines.index(before) == lines.index("| `provenance.load_average_end` | [2, 2, 2] |") + 1
    assert "| `provenance.machine_speed.after` | kernel 0.9 G bp/s, FMA 7.41 GFLOP/s, copy 15.4 GB/s, avx2, " \
           "at 21:04:18 UTC |" in lines
    assert any(line.startswith("| `part.provenance.machine_speed.before` | kernel 1.23 G bp/s") for line in lines)
