"""Numba's kernel cache keyed by every source file of ``imaging``, not only the kernel's own.

Numba stores a ``cache=True`` kernel with the time stamp and size of the file that defines it, and loads it
while that file is unchanged. The kernels inline helpers from other modules (``imaging.range_offsets`` into
the backprojection kernel, the backprojection's gather and phase into FFBP's leaves), so an edit to a helper,
or a ``git pull`` that changes one, would leave a kernel compiled from the old helper in use: silently wrong
images. :func:`key_jit_cache_to_sources` points numba's cache at a folder named by the stamps of all of
``imaging``'s sources, so any change to any of them compiles afresh, and clears out folders of earlier
sources. It runs on ``import imaging``, before any kernel is decorated.
"""

from __future__ import annotations

import hashlib
import os
import sys
import time
from pathlib import Path

#: Cache folders of other sources are removed once they have not been touched for this long (a process
#: started before the edit may still be using its folder).
STALE_AFTER_S = 3600.0


def source_key(root: str | os.PathLike) -> str:
    """A short hash of the path, modification time and size of every ``.py`` file under ``root``."""
    digest = hashlib.blake2b(digest_size=8)
    files = []
    for folder, subfolders, names in os.walk(root):
        subfolders[:] = [s for s in subfolders if s != "__pycache__"]  # thousands of cache files, no sources
        files += [os.path.join(folder, n) for n in names if n.endswith(".py")]
    for path in sorted(files):
        stat = os.stat(path)
        digest.update(f"{os.path.relpath(path, root)}:{stat.st_mtime_ns}:{stat.st_size}\n".encode())
    return digest.hexdigest()


def key_jit_cache_to_sources(root: str | os.PathLike | None = None) -> str | None:
    """Set ``NUMBA_CACHE_DIR`` to ``root/__pycache__/numba-KEY`` (``root`` this package) and return it.

    Left alone (returns None) where ``NUMBA_CACHE_DIR`` is set already (the user's or the acquisition's
    choice, see ``acquisition.processes.ensure_jit_cache_dir``), under a systemd unit with a
    ``CacheDirectory=`` (the acquisition puts the cache there), or where the sources are not writable (an
    installed package, whose files all change together when it is upgraded).
    """
    if os.environ.get("NUMBA_CACHE_DIR") or os.environ.get("CACHE_DIRECTORY"):  # CACHE_DIRECTORY: a systemd unit's
        return None
    root = Path(root) if root is not None else Path(__file__).resolve().parent
    if not os.access(root, os.W_OK):
        return None
    parent = root / "__pycache__"
    folder = parent / f"numba-{source_key(root)}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    _remove_stale(parent, folder)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba" in sys.modules:  # numba reads its configuration on import; re-read it if that was earlier
        from numba.core import config

        config.reload_config()
    return str(folder)


def _remove_stale(parent: Path, keep: Path) -> None:
    now = time.time()
    for other in parent.glob("numba-*"):
        try:
            if other != keep and now - other.stat().st_mtime > STALE_AFTER_S:
                import shutil

                shutil.rmtree(other, ignore_errors=True)
        except OSError:
            pass
