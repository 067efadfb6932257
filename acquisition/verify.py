"""Checking a sarbot HDF5 file (recording, trajectory, image) chunk by chunk for damage.

Every chunked dataset sarbot writes carries HDF5's Fletcher-32 checksum per chunk (see
docs/formats/recording.md): a byte changed on the disk makes reading that chunk fail. ``verify_file``
reads every chunk of every dataset and says which fail, one ``Finding`` each, so a damaged file is known
before a long job trips over it; ``format_findings`` puts them one to a line (``sarbot info --verify``).
Variable-length strings (``/events``, ``/trigger/source``) take no filter in HDF5: they are read, and a
failure is reported, but a changed byte there is not caught.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import h5py


@dataclasses.dataclass(frozen=True)
class Finding:
    """One damaged place: the dataset, its chunk (index in the chunk index and first element), the chunk's
    byte offset in the file, and HDF5's words. ``chunk_index`` is None for the whole file or a dataset that
    is not chunked."""

    path: str
    dataset: str
    chunk_index: int | None
    chunk_offset: tuple[int, ...] | None
    file_offset: int | None
    reason: str

    def line(self) -> str:
        where = "" if self.chunk_index is None else (
            f" chunk {self.chunk_index} (from element {list(self.chunk_offset)}, file byte {self.file_offset})")
        return f"{self.path}: {self.dataset}{where}: {self.reason}"


def _reason(exc: Exception) -> str:
    """HDF5's own words, without its call-stack preamble."""
    text = str(exc)
    return text[text.find("(") + 1:text.rfind(")")] if "(" in text else text


def _open(path: Path) -> h5py.File:
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        text = str(exc).lower()
        if "unable to lock file" in text or "already open for" in text:  # being written: read it as SWMR does
            return h5py.File(path, "r", swmr=True)
        raise


def _check_dataset(path: str, ds: h5py.Dataset) -> tuple[list[Finding], int]:
    """Findings of one dataset, and how many chunks (or whole datasets) were read."""
    if ds.chunks is None:
        try:
            ds[()]
        except (OSError, ValueError, RuntimeError) as exc:
            return [Finding(path, ds.name, None, None, None, _reason(exc))], 1
        return [], 1
    out = []
    n = ds.id.get_num_chunks()
    for i in range(n):
        info = ds.id.get_chunk_info(i)
        selection = tuple(slice(o, min(o + c, size)) for o, c, size in zip(info.chunk_offset, ds.chunks, ds.shape))
        try:
            ds[selection]  # through the filter pipeline: the Fletcher-32 checksum is checked here
        except (OSError, ValueError, RuntimeError) as exc:
            out.append(Finding(path, ds.name, i, tuple(int(o) for o in info.chunk_offset), int(info.byte_offset),
                               _reason(exc)))
    return out, n


def verify_file(path: str | Path) -> list[Finding]:
    """Read every chunk of every dataset of the HDF5 file at ``path``; a Finding for each one that fails
    (its checksum, or the file's structure). An empty list: nothing damaged that a checksum would show."""
    path = Path(path)
    name = str(path)
    if not path.exists():
        return [Finding(name, "/", None, None, None, "no such file")]
    try:
        f = _open(path)
    except OSError as exc:
        return [Finding(name, "/", None, None, None, f"not a readable HDF5 file ({_reason(exc)})")]
    findings: list[Finding] = []
    with f:
        datasets: list[str] = []

        def collect(key, obj):
            if isinstance(obj, h5py.Dataset):
                datasets.append(key)

        try:
            f.visititems(collect)
        except (OSError, KeyError, RuntimeError, ValueError) as exc:
            findings.append(Finding(name, "/", None, None, None, f"damaged HDF5 metadata ({_reason(exc)})"))
        for key in datasets:
            try:
                ds = f[key]
                found, _ = _check_dataset(name, ds)
            except (OSError, KeyError, RuntimeError, ValueError) as exc:  # its header or chunk index
                found = [Finding(name, f"/{key}", None, None, None, f"damaged ({_reason(exc)})")]
            findings += found
    return findings


def format_findings(findings: list[Finding], path: str | Path | None = None) -> str:
    """One line per finding; one line saying so when there are none (naming ``path`` if given)."""
    if not findings:
        return f"{path}: " * (path is not None) + "no damage found: every chunk read back, its checksum matched"
    return "\n".join(f.line() for f in findings)
