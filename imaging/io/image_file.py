"""The image file: HDF5 schema "sarbot.image" version 1 (DESIGN.md)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imaging.core.errors import FileFormatError
from imaging.core.track_error import TrackError
from imaging.io.schema import open_checked

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
    #: the track error where the image was autofocused (the file's /autofocus group)
    track_error: TrackError | None = None

    @property
    def wavelength_m(self) -> float:
        return float(self.attrs["wavelength_m"])


def write_image(path: str | Path, img: SarImage) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f.attrs["schema"] = SCHEMA
        f.attrs["schema_version"] = SCHEMA_VERSION
        for key, value in img.attrs.items():
            f.attrs[key] = value
        f.create_dataset("image", data=img.image.astype(np.complex64))
        f.create_dataset("x_m", data=img.x_m)
        f.create_dataset("y_m", data=img.y_m)
        if img.z_m is not None:
            f.create_dataset("z_m", data=np.atleast_1d(img.z_m))
        te = img.track_error
        if te is not None:
            g = f.create_group("autofocus")
            g.attrs["method"] = te.method
            g.attrs["time_origin_ns"] = np.int64(te.time_origin_ns)
            g.attrs["model"] = json.dumps(te.model) if te.model is not None else ""
            g.create_dataset("time_ns", data=np.int64(te.time_origin_ns) + np.round(te.time_s * 1e9).astype(np.int64))
            g.create_dataset("track_error_m", data=te.displacement_m)
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
            g = f["autofocus"]
            try:
                origin = int(g.attrs["time_origin_ns"])
                model = g.attrs.get("model", "")
                model = model.decode() if isinstance(model, bytes) else model
                track_error = TrackError((g["time_ns"][()] - origin) * 1e-9, g["track_error_m"][()], str(g.attrs["method"]),
                                         json.loads(model) if model else None, origin)
            except (KeyError, ValueError) as exc:
                raise FileFormatError(f"{path}: /autofocus is damaged ({exc})") from None
        return SarImage(f["image"][()], f["x_m"][()], f["y_m"][()], f["z_m"][()] if "z_m" in f else None, attrs,
                        track_error)
