"""Numba's kernel cache follows every source file of imaging, not only the kernel's own (imaging/jit_cache.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from imaging.jit_cache import STALE_AFTER_S, key_jit_cache_to_sources, source_key

REPO = Path(__file__).resolve().parents[1]


def _package(tmp_path: Path, helper_value: float) -> Path:
    """A package like imaging: a cached kernel that inlines a helper from another module."""
    pkg = tmp_path / "kpkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text(textwrap.dedent(f"""
        import importlib.util
        # imaging/jit_cache.py by its path: importing imaging would key the cache to imaging's own sources
        spec = importlib.util.spec_from_file_location("jit_cache", {str(REPO / "imaging" / "jit_cache.py")!r})
        jit_cache = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(jit_cache)
        jit_cache.key_jit_cache_to_sources(__path__[0])
    """))
    (pkg / "helper.py").write_text(textwrap.dedent(f"""
        import numba
        @numba.njit(inline="always")
        def offset(x):
            return x + {helper_value}
    """))
    (pkg / "kernel.py").write_text(textwrap.dedent("""
        import numba
        from kpkg.helper import offset
        @numba.njit(cache=True)
        def kernel(x):
            return offset(x) * 2.0
    """))
    return pkg


def _run(tmp_path: Path, env: dict) -> float:
    out = subprocess.run([sys.executable, "-c", "from kpkg.kernel import kernel; print(kernel(1.0))"], cwd=tmp_path,
                         env=env, capture_output=True, text=True, timeout=300, check=True)
    return float(out.stdout.strip())


def test_an_edited_helper_recompiles_the_kernel_that_inlines_it(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    pkg = _package(tmp_path, 1.0)
    assert _run(tmp_path, env) == 4.0
    assert any((pkg / "__pycache__").rglob("*.nbi")), "the kernel was cached"
    _package(tmp_path, 10.0)  # only the helper changes; the kernel's own file does not
    os.utime(pkg / "helper.py", ns=(time.time_ns() + 10**9,) * 2)
    assert _run(tmp_path, env) == 22.0
    # What numba alone does with the same edit: its cache is keyed by the kernel's file, and serves the old one.
    fixed = {**env, "NUMBA_CACHE_DIR": str(tmp_path / "plain")}
    _package(tmp_path, 1.0)
    assert _run(tmp_path, fixed) == 4.0
    _package(tmp_path, 10.0)
    os.utime(pkg / "helper.py", ns=(time.time_ns() + 2 * 10**9,) * 2)
    assert _run(tmp_path, fixed) == 4.0


def test_the_key_follows_every_source_and_skips_the_cache_folders(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.py").write_text("y = 2\n")
    key = source_key(tmp_path)
    (tmp_path / "__pycache__").mkdir()
    (tmp_path / "__pycache__" / "c.py").write_text("not a source\n")
    assert source_key(tmp_path) == key
    (tmp_path / "sub" / "b.py").write_text("y = 3\n")
    os.utime(tmp_path / "sub" / "b.py", ns=(time.time_ns() + 10**9,) * 2)
    assert source_key(tmp_path) != key


def test_an_explicit_cache_folder_is_left_alone_and_stale_folders_go(tmp_path, monkeypatch):
    (tmp_path / "a.py").write_text("x = 1\n")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert key_jit_cache_to_sources(tmp_path) is None
    assert os.environ["NUMBA_CACHE_DIR"] == str(tmp_path / "mine")
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    old, recent = tmp_path / "__pycache__" / "numba-old", tmp_path / "__pycache__" / "numba-recent"
    old.mkdir(parents=True)
    recent.mkdir()
    long_ago = time.time() - 2 * STALE_AFTER_S
    os.utime(old, (long_ago, long_ago))
    folder = key_jit_cache_to_sources(tmp_path)
    assert folder == str(tmp_path / "__pycache__" / f"numba-{source_key(tmp_path)}")
    assert os.environ["NUMBA_CACHE_DIR"] == folder
    assert not old.exists() and recent.exists()  # a process started before an edit may still use its folder
