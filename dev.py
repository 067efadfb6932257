#!/usr/bin/env python3
"""Set up the project's virtual environment on first use, then run a command in it.

    python3 dev.py demo            # sarbot demo on the built-in scene
    python3 dev.py test            # the test suite (what CI runs)
    python3 dev.py bench           # the benchmarks, figures to docs/results/
    python3 dev.py bench --peers [--bench-venv DIR] [--torch SPEC] [ARGS...]
                                   # sarbot beside the real torchbp (benchmarks/peers.py), built from
                                   # ../shared/bench/ into a benchmark-only environment (.bench-venv/)
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


#: torchbp's source snapshots (see shared/bench/README.md): benchmark-only, never a dependency of sarbot.
PEER_SOURCES = ROOT.parent / "shared" / "bench"
#: The torch the peer is built against: a CPU build (a plain ``torch`` takes a CUDA build of several GB).
DEFAULT_TORCH = "torch==2.13.0"


def ensure_peer_environment(venv_dir: Path, torch_spec: str) -> Path:
    """A virtual environment with torch, torchbp built from ``PEER_SOURCES`` and sarbot (editable), for
    benchmarks/peers.py alone; made once, remade when the torchbp snapshot or the torch asked for changes.
    Returns the path of the JSON that records the build (source, commit, compiler flags)."""
    import json
    import re
    import shutil
    import tarfile

    tarballs = sorted(PEER_SOURCES.glob("torchbp-*.tar.gz"))
    if not tarballs:
        sys.exit(f"dev.py: no torchbp-*.tar.gz in {PEER_SOURCES} (the peers benchmark builds torchbp from there)")
    tarball = tarballs[-1]
    digest = hashlib.sha256(tarball.read_bytes()).hexdigest()
    stamp = venv_dir / "torchbp-build.json"
    py = venv_dir / ("Scripts" if os.name == "nt" else "bin") / "python"
    if stamp.exists():
        built = json.loads(stamp.read_text())
        if built.get("source_sha256") == digest and built.get("torch_requested") == torch_spec and py.exists():
            return stamp
    print(f"dev.py: building the peers' environment in {venv_dir} ({torch_spec}, torchbp from {tarball.name}; minutes)",
          flush=True)
    if not py.exists():
        venv.EnvBuilder(with_pip=True).create(venv_dir)
    pip = [str(py), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    subprocess.run([*pip, torch_spec, "numpy", "setuptools", "wheel", "packaging"], check=True)
    src = venv_dir / "src"
    shutil.rmtree(src, ignore_errors=True)
    src.mkdir(parents=True)
    with tarfile.open(tarball) as tar:
        tar.extractall(src, filter="data")
    (tree,) = [d for d in src.iterdir() if d.is_dir()]
    # Its own build: CPU only, its setup.py's flags (recorded below), against the torch just installed.
    subprocess.run([*pip, "--no-build-isolation", str(tree)], check=True, env={**os.environ, "USE_CUDA": "0"})
    subprocess.run([*pip, "-e", str(ROOT)], check=True)
    setup = (tree / "setup.py").read_text()
    flags = list(dict.fromkeys(re.findall(r"\"(-O3|-march=[^\"]+|-f[a-z-]+)\"", setup.split("\"nvcc\"")[0])))
    readme = (PEER_SOURCES / "README.md").read_text() if (PEER_SOURCES / "README.md").exists() else ""
    commit = re.search(r"commit ([0-9a-f]{40})", readme)
    torch_version = subprocess.run([str(py), "-c", "import torch; print(torch.__version__)"], capture_output=True,
                                   text=True, check=True).stdout.strip()
    stamp.write_text(json.dumps({
        "source": tarball.name, "source_sha256": digest, "commit": commit.group(1) if commit else None,
        "build_flags": flags, "build_env": {"USE_CUDA": "0"}, "torch_requested": torch_spec, "torch": torch_version,
    }, indent=2))
    return stamp


def bench_peers(rest: list[str]) -> int:
    """``bench --peers``: set up the peers' environment, then run benchmarks/peers.py in it."""
    venv_dir, torch_spec, args = ROOT / ".bench-venv", DEFAULT_TORCH, []
    it = iter(rest)
    for arg in it:
        if arg == "--bench-venv":
            venv_dir = Path(next(it, "")).resolve()
        elif arg == "--torch":
            torch_spec = next(it, DEFAULT_TORCH)
        else:
            args.append(arg)
    stamp = ensure_peer_environment(venv_dir, torch_spec)
    py = venv_dir / ("Scripts" if os.name == "nt" else "bin") / "python"
    return subprocess.run([str(py), str(ROOT / "benchmarks" / "peers.py"), *args], cwd=ROOT,
                          env={**os.environ, "SARBOT_TORCHBP_BUILD": str(stamp)}).returncode


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
    elif command == "bench" and "--peers" in rest:
        return bench_peers([a for a in rest if a != "--peers"])
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
