"""Opening sarbot's HDF5 files with their schema checked, so every reader fails the same clear way."""

from __future__ import annotations

from pathlib import Path

import h5py

from imaging.core.errors import FileFormatError


def open_checked(path: str | Path, schema: str, version: int, kind: str, **kwargs) -> h5py.File:
    """Open ``path`` read-only and check its ``schema`` and ``schema_version`` attributes.

    ``kind`` names the file in messages ("recording", "image", "trajectory"). Raises FileFormatError
    naming the file when it is missing, not HDF5, of another schema or of another version.
    """
    path = Path(path)
    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r", **kwargs)
    except OSError as exc:
        raise FileFormatError(f"{path}: not a readable HDF5 file ({exc.__class__.__name__})") from None
    found = f.attrs.get("schema")
    found = found.decode() if isinstance(found, bytes) else found
    if found != schema:
        f.close()
        raise FileFormatError(f"{path}: not a sarbot {kind} (schema attribute is {found!r}, expected {schema!r})")
    found_version = int(f.attrs.get("schema_version", -1))
    if found_version != version:
        f.close()
        raise FileFormatError(f"{path}: {kind} schema version {found_version} is not supported (this is version {version})")
    return f
