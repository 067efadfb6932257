"""Opening sarbot's HDF5 files with their schema checked, so every reader fails the same clear way; the
checksums their data carries, and reading it so a failed one is a clear error too."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from imaging.core.errors import FileFormatError


def open_checked(path: str | Path, schema: str, version: int, kind: str, **kwargs) -> h5py.File:
    """Open ``path`` read-only and check its ``schema`` and ``schema_version`` attributes.

    ``kind`` names the file in messages ("recording", "image", "trajectory"). Raises FileFormatError
    naming the file when it is missing, not HDF5, of another schema or of another version.
    """
    path = Path(path)
    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    swmr = kwargs.pop("swmr", False)
    try:
        # Read-only first: SWMR read mode retries damaged metadata for minutes before it gives up, where a
        # plain open fails at once. SWMR only for a file that is still being written (and locked for it).
        f = h5py.File(path, "r", **kwargs)
    except OSError as exc:
        if not (swmr and _held_for_writing(exc)):
            raise FileFormatError(f"{path}: not a readable HDF5 file, damaged or cut short ({_reason(exc)})") from None
        try:
            f = h5py.File(path, "r", swmr=True, **kwargs)
        except OSError as exc2:
            raise FileFormatError(f"{path}: not a readable HDF5 file ({_reason(exc2)})") from None
    try:
        found = f.attrs.get("schema")
        found_version = int(f.attrs.get("schema_version", -1))
        # Every object's header once, now: damaged metadata is then one clear error here, not a KeyError
        # or OSError deep inside whatever reads the file first.
        f.visititems(_touch)
    except (KeyError, OSError, RuntimeError, ValueError) as exc:
        f.close()
        raise FileFormatError(f"{path}: damaged HDF5 metadata ({_reason(exc)})") from None
    found = found.decode() if isinstance(found, bytes) else found
    if found != schema:
        f.close()
        raise FileFormatError(f"{path}: not a sarbot {kind} (schema attribute is {found!r}, expected {schema!r})")
    if found_version != version:
        f.close()
        raise FileFormatError(f"{path}: {kind} schema version {found_version} is not supported (this is version {version})")
    return f


def _touch(name: str, obj) -> None:
    list(obj.attrs.keys())
    if isinstance(obj, h5py.Dataset):
        obj.shape, obj.dtype  # noqa: B018 - reading the header is the point
        if obj.chunks is not None:
            # Walks the chunk index (a B-tree or array with its own checksums): a damaged index is then
            # caught here, not as a raw OSError from the first read of the data it points to.
            obj.id.get_num_chunks()


def _held_for_writing(exc: OSError) -> bool:
    text = str(exc).lower()  # HDF5's words for a file that a writer holds (file locking, SWMR flags)
    return "unable to lock file" in text or "already open for" in text


def _reason(exc: OSError) -> str:
    """HDF5's own words, without its call-stack preamble ("Unable to synchronously open file (...)")."""
    text = str(exc)
    return text[text.find("(") + 1:text.rfind(")")] if "(" in text else text


def checksummed(dtype) -> dict:
    """Keyword arguments of ``create_dataset`` that give every chunk HDF5's Fletcher-32 checksum, so a byte
    changed on the disk is a read error, not a wrong number. HDF5 takes no filter on variable-length data
    (strings): those are written as they are."""
    return {} if h5py.check_vlen_dtype(np.dtype(dtype)) is not None else {"fletcher32": True}


def read(ds: h5py.Dataset, selection=()) -> np.ndarray:
    """``ds[selection]``; a chunk whose checksum fails (h5py's OSError) is a FileFormatError naming the file
    and the dataset (``sarbot info --verify`` says which chunks)."""
    try:
        return ds[selection]
    except OSError as exc:
        raise FileFormatError(f"{ds.file.filename}: {ds.name}: damaged data, a chunk's checksum fails "
                              f"({_reason(exc)})") from None
