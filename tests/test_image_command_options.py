"""benchmarks/image_command.py's options: a case it does not know, or no round, is a clear usage error."""

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "image_command.py"


@pytest.mark.parametrize("args, says", [
    (["--cases", "benchmark_case,huge_case"], "--cases: unknown case(s) huge_case; known: benchmark_case, larger_case"),
    (["--cases", ","], "--cases: unknown case(s) (none given)"),
    (["--rounds", "0"], "--rounds must be at least 1, got 0"),
])
def test_bad_options_are_refused_before_anything_is_measured(args, says):
    run = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300)
    assert run.returncode == 2
    assert says in run.stderr and "Traceback" not in run.stderr
