#!/usr/bin/env python3
"""Set up the project's virtual environment on first use, then run a command in it.

    python3 dev.py demo            # sarbot demo on the built-in scene
    python3 dev.py test            # the test suite (what CI runs)
    python3 dev.py bench           # the benchmarks, figures to docs/results/
    python3 dev.py results         # docs/results.md from the figures in docs/results/*.json
    python3 dev.py docs            # the documentation site (MkDocs, --strict) into site/
    python3 dev.py sarbot ARGS...  # any sarbot command
    python3 dev.py constraints     # pin the run-time dependencies as tested (constraints.txt)

Only the Python standard library is used here, so this works on a fresh machine with Python 3.11+.
The environment lives in .venv/ and is reinstalled when pyproject.toml changes.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".sarbot-installed"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")


def _pyproject_digest() -> str:
    return hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()


def ensure_environment() -> None:
    if sys.version_info < (3, 11):
        sys.exit(f"dev.py: sarbot needs Python 3.11 or newer, this is {sys.version.split()[0]}")
    if not (BIN / "python").exists():
        print(f"dev.py: creating virtual environment in {VENV}", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    if STAMP.exists() and STAMP.read_text() == _pyproject_digest():
        return
    print("dev.py: installing sarbot and its dependencies (once)", flush=True)
    subprocess.run([str(BIN / "python"), "-m", "pip", "install", "--quiet", "--upgrade", "pip"], check=True)
    subprocess.run([str(BIN / "python"), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "-e", f"{ROOT}[test]"],
                   check=True)
    STAMP.write_text(_pyproject_digest())


#: Writes constraints.txt: every package sarbot needs at run time (its dependencies and theirs), pinned to
#: the versions the tests passed with here, for the robot's install (``pip install -c constraints.txt``).
CONSTRAINTS = r"""
import re
from importlib.metadata import PackageNotFoundError, distribution
seen, todo = {}, ["sarbot"]
while todo:
    name = todo.pop()
    key = re.sub(r"[-_.]+", "-", name).lower()
    if key in seen:
        continue
    try:
        dist = distribution(name)
    except PackageNotFoundError:  # only under a marker that does not hold here (another platform)
        continue
    seen[key] = dist.version
    for req in dist.requires or []:
        if "extra ==" in req or "platform_system" in req and "Windows" in req:
            continue
        todo.append(re.split(r"[ ;<>=!~\[(]", req, maxsplit=1)[0])
seen.pop("sarbot")
lines = ["# Pinned run-time dependencies of sarbot, as tested (python3 dev.py constraints writes this file).",
         "# On the robot: sarbot install-unit uses it; or pip install -c constraints.txt ."]
open("constraints.txt", "w").write("\n".join(lines + [f"{k}=={v}" for k, v in sorted(seen.items())]) + "\n")
print(f"wrote constraints.txt ({len(seen)} packages)")
"""


def main(argv: list[str]) -> int:
    if not argv or argv[0] in {"-h", "--help"}:
        print(__doc__)
        return 0 if argv else 2
    command, rest = argv[0], argv[1:]
    if command == "results":  # the standard library only: no environment needed
        return subprocess.run([sys.executable, str(ROOT / "docs" / "gen_results.py"), *rest], cwd=ROOT).returncode
    ensure_environment()
    if command == "test":
        cmd = [str(BIN / "python"), "-m", "pytest", *rest]
    elif command == "bench":
        cmd = [str(BIN / "python"), str(ROOT / "benchmarks" / "run_all.py"), *rest]
    elif command == "demo":
        cmd = [str(BIN / "sarbot"), "demo", *rest]
    elif command == "sarbot":
        cmd = [str(BIN / "sarbot"), *rest]
    elif command == "docs":
        cmd = [str(BIN / "python"), "-m", "mkdocs", "build", "--strict", "--site-dir", str(ROOT / "site"), *rest]
    elif command == "constraints":
        return subprocess.run([str(BIN / "python"), "-c", CONSTRAINTS], cwd=ROOT).returncode
    else:
        print(f"dev.py: unknown command {command!r} (use demo, test, bench, results, docs, sarbot or constraints)", file=sys.stderr)
        return 2
    # The tests and benchmarks run from the project; sarbot and the demo where the caller is, so that
    # relative paths (recordings, -o) mean what the caller meant.
    return subprocess.run(cmd, cwd=ROOT if command in ("test", "bench", "docs") else None).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
