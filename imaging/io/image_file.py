"""The image file: HDF5 schema "sarbot.image" version 1 (see docs/formats/image.md)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imaging.core import strict_json
from imaging.core.errors import FileFormatError
from imaging.io.schema import open_checked, read

SCHEMA = "sarbot.image"
SCHEMA_VERSION = 1


@dataclasses.dataclass
class SarImage:
    """A complex image on a world-frame grid with what it was made from."""

    image: np.ndarray  # complex [ny, nx] or [nz, ny, nx]
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray | None = None
    attrs: dict[str, Any] = dataclasses.field(default_factory=dict)
    #: imaging.autofocus.TrackError where the image was autofocused (the file's /autofocus group)
    track_error: Any = None

    @property
    def wavelength_m(self) -> float:
        return float(self.attrs["wavelength_m"])


def _dataset(group: h5py.Group, name: str, data) -> None:
    """A dataset chunked (as HDF5 chooses) with each chunk's Fletcher-32 checksum: a byte changed on the
    disk is then a read error. An empty one cannot be chunked, and has nothing to check."""
    data = np.asarray(data)
    group.create_dataset(name, data=data, fletcher32=data.size > 0)


def write_image(path: str | Path, img: SarImage) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f.attrs["schema"] = SCHEMA
        f.attrs["schema_version"] = SCHEMA_VERSION
        for key, value in img.attrs.items():
            f.attrs[key] = value
        _dataset(f, "image", img.image.astype(np.complex64))
        _dataset(f, "x_m", img.x_m)
        _dataset(f, "y_m", img.y_m)
        if img.z_m is not None:
            _dataset(f, "z_m", np.atleast_1d(img.z_m))
        te = img.track_error
        if te is not None:
            g = f.create_group("autofocus")
            g.attrs["method"] = te.method
            g.attrs["time_origin_ns"] = np.int64(te.time_origin_ns)
            g.attrs["model"] = strict_json.dumps(te.model) if te.model is not None else ""
            _dataset(g, "time_ns", np.int64(te.time_origin_ns) + np.round(te.time_s * 1e9).astype(np.int64))
            _dataset(g, "track_error_m", te.displacement_m)
    return path


def read_image(path: str | Path) -> SarImage:
    path = Path(path)
    with open_checked(path, SCHEMA, SCHEMA_VERSION, "image") as f:
        for name in ("image", "x_m", "y_m"):
            if name not in f:
                raise FileFormatError(f"{path}: dataset /{name} is missing")
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        track_error = None
        if "autofocus" in f:
            from imaging.autofocus import TrackError

            g = f["autofocus"]
            try:
                origin = int(g.attrs["time_origin_ns"])
                model = g.attrs.get("model", "")
                model = model.decode() if isinstance(model, bytes) else model
                track_error = TrackError((read(g["time_ns"]) - origin) * 1e-9, read(g["track_error_m"]), str(g.attrs["method"]),
                                         json.loads(model) if model else None, origin)
            except (KeyError, ValueError) as exc:
                raise FileFormatError(f"{path}: /autofocus is damaged ({exc})") from None
        return SarImage(read(f["image"]), read(f["x_m"]), read(f["y_m"]), read(f["z_m"]) if "z_m" in f else None, attrs,
                        track_error)
