"""A module of this repository as it was at an earlier commit, loaded beside the checkout's: how the benchmarks
that compare old code with new in one process (driver_cpu_per_frame.py, odometry_cpu_per_scan.py) get the old."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def baseline_module(commit: str, path: str, name: str, in_file: bool = False):
    """``path`` (a module of this repository) as it was at ``commit``, loaded as ``name`` in the package the
    path names (its relative imports are the checkout's modules). ``in_file``: the source written to a file
    in the temporary folder first (one per commit) and compiled under that file's name, for a module of numba kernels with
    ``cache=True`` (numba keys its cache on the source file, and refuses a module without one)."""
    source = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout
    filename = f"{commit}:{path}"
    if in_file:  # one file per commit and name, rewritten only if it differs: numba's cache then holds
        folder = Path(tempfile.gettempdir()) / f"sarbot-baseline-{commit}"
        folder.mkdir(exist_ok=True)
        file = folder / f"{name}.py"
        if not file.exists() or file.read_text() != source:
            file.write_text(source)
        filename = str(file)
    package = path.rsplit("/", 1)[0].replace("/", ".")
    spec = importlib.util.spec_from_loader(f"{package}.{name}", loader=None)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = package
    sys.modules[spec.name] = module
    module.__file__ = filename
    exec(compile(source, filename, "exec"), module.__dict__)
    return module
