"""Image grids in the world frame: parsing ``x0:x1:dx,y0:y1:dy[,z]`` and making the points."""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.core.errors import SarbotError


@dataclasses.dataclass(frozen=True)
class Grid:
    """A Cartesian grid: a plane at one height (``z_m`` of length 1) or a volume."""

    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray

    @property
    def shape(self) -> tuple[int, ...]:
        """Image shape: (ny, nx) for a plane, (nz, ny, nx) for a volume."""
        if self.z_m.size == 1:
            return (self.y_m.size, self.x_m.size)
        return (self.z_m.size, self.y_m.size, self.x_m.size)

    @property
    def n_points(self) -> int:
        return int(np.prod(self.shape))

    def points(self) -> np.ndarray:
        """Grid points, float64, shape ``shape + (3,)``."""
        z, y, x = np.meshgrid(self.z_m, self.y_m, self.x_m, indexing="ij")
        pts = np.stack([x, y, z], axis=-1)
        return pts[0] if self.z_m.size == 1 else pts

    @classmethod
    def from_ranges(cls, x: tuple[float, float, float], y: tuple[float, float, float], z: float | tuple = 0.0) -> "Grid":
        """Grid from (start, stop, step) per axis; stop is included when it falls on the step."""
        zs = np.array([float(z)]) if np.isscalar(z) else _axis("z", *z)
        return cls(_axis("x", *x), _axis("y", *y), zs)

    @classmethod
    def parse(cls, spec: str, default_z_m: float = 0.0) -> "Grid":
        """Parse ``x0:x1:dx,y0:y1:dy[,z]`` where z is a height or ``z0:z1:dz`` for a volume."""
        parts = [p.strip() for p in spec.split(",")]
        if len(parts) not in (2, 3):
            raise SarbotError(f"grid {spec!r}: expected x0:x1:dx,y0:y1:dy[,z]")
        axes = []
        for name, part in zip("xyz", parts):
            fields = part.split(":")
            try:
                values = [float(f) for f in fields]
            except ValueError:
                raise SarbotError(f"grid {spec!r}: {name} part {part!r} is not numbers") from None
            if name == "z" and len(values) == 1:
                axes.append(np.array(values))
                continue
            if len(values) != 3:
                raise SarbotError(f"grid {spec!r}: {name} part {part!r} must be start:stop:step")
            axes.append(_axis(name, *values, spec=spec))
        if len(axes) == 2:
            axes.append(np.array([default_z_m]))
        return cls(*axes)


def _axis(name: str, start: float, stop: float, step: float, spec: str | None = None) -> np.ndarray:
    where = f"grid {spec!r}: " if spec else "grid: "
    if not np.all(np.isfinite([start, stop, step])):
        raise SarbotError(f"{where}{name} axis has a value that is not finite")
    if step <= 0:
        raise SarbotError(f"{where}{name} step must be positive, got {step}")
    if stop < start:
        raise SarbotError(f"{where}{name} axis is empty ({start} to {stop}): the grid has no points")
    n = int(np.floor((stop - start) / step + 1e-9)) + 1
    if n > 100_000:
        raise SarbotError(f"{where}{name} axis has {n} points; that is more than 100000")
    return start + step * np.arange(n)
