"""Trajectory files: HDF5 schema "sarbot.trajectory" version 1, and TUM text for evo and other tools."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from imaging.core.errors import FileFormatError
from imaging.core.trajectory import SampledTrajectory
from imaging.io.schema import open_checked

SCHEMA = "sarbot.trajectory"
SCHEMA_VERSION = 1


def write_trajectory(path: str | Path, traj: SampledTrajectory, covariance_diag: np.ndarray | None = None) -> Path:
    path = Path(path)
    with h5py.File(path, "w") as f:
        f.attrs["schema"] = SCHEMA
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["source"] = traj.source
        g = f.create_group("trajectory")
        g["time_ns"] = traj.time_ns
        g["position_m"] = traj.position_m
        g["orientation_xyzw"] = traj.orientation_xyzw
        g["velocity_mps"] = traj.velocity_mps
        if covariance_diag is not None:
            g["covariance_diag"] = covariance_diag
    return path


def read_trajectory(path: str | Path) -> SampledTrajectory:
    path = Path(path)
    with open_checked(path, SCHEMA, SCHEMA_VERSION, "trajectory") as f:
        g = f["trajectory"]
        try:
            return SampledTrajectory(g["time_ns"][()], g["position_m"][()], g["orientation_xyzw"][()],
                                     g["velocity_mps"][()] if "velocity_mps" in g else None,
                                     source=str(f.attrs.get("source", path.name)))
        except (KeyError, ValueError) as exc:
            raise FileFormatError(f"{path}: {exc}") from None


def write_tum(path: str | Path, traj: SampledTrajectory) -> Path:
    """TUM format: ``t tx ty tz qx qy qz qw`` per line, t in seconds."""
    path = Path(path)
    t = traj.time_ns // 1_000_000_000
    frac = traj.time_ns % 1_000_000_000
    with path.open("w") as fh:
        for i in range(traj.time_ns.size):
            p, q = traj.position_m[i], traj.orientation_xyzw[i]
            fh.write(f"{t[i]}.{frac[i]:09d} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
    return path
