"""A module of this repository as it was at an earlier commit, loaded beside the checkout's: how the benchmarks
that compare old code with new in one process (driver_cpu_per_frame.py, odometry_cpu_per_scan.py) get the old."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def baseline_module(commit: str, path: str, name: str):
    """``path`` (a module of this repository) as it was at ``commit``, loaded as ``name`` in the package the
    path names (its relative imports are the checkout's modules)."""
    source = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout
    package = path.rsplit("/", 1)[0].replace("/", ".")
    spec = importlib.util.spec_from_loader(f"{package}.{name}", loader=None)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = package
    sys.modules[spec.name] = module
    exec(compile(source, f"{commit}:{path}", "exec"), module.__dict__)
    return module
