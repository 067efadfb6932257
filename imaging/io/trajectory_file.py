"""Trajectory files: HDF5 schema "sarbot.trajectory" version 1, and TUM text for evo and other tools.

The root attribute ``stop_cut_short`` (optional, added within version 1) says whether the writer was hurried
at the daemon's stop and left poses out: 1 then, 0 for a file written to its end. It is written at ``close``,
so a file whose writer never closed it (killed) lacks it, as do files older than it: ``read_trajectory``
gives None for those (not known), never 0, since such a file may well be cut short."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from imaging.core.errors import FileFormatError
from imaging.core.trajectory import SampledTrajectory
from imaging.io.schema import open_checked, read

SCHEMA = "sarbot.trajectory"
SCHEMA_VERSION = 1


_FIELDS = (("time_ns", np.int64, ()), ("position_m", np.float64, (3,)), ("orientation_xyzw", np.float64, (4,)),
           ("velocity_mps", np.float64, (3,)))


#: Poses gathered before they are written without a flush (the datasets' chunk).
WRITE_EVERY_POSES = 4096


class TrajectoryWriter:
    """A trajectory file written as the poses come (appendable datasets, flushed on request): a long run's
    poses live on disk, not in memory. Appends are gathered and written a chunk at a time, at ``flush`` and
    at ``close``: the live odometry appends every few milliseconds, and eight HDF5 calls per append cost it an
    eighth of its CPU; what a crash would lose is what it loses anyway before a flush.

    ``close(stop_cut_short=...)`` says in the file whether its poses end where they should (module docstring);
    left by an exception (``with``), the file does not say it: its end is not known."""

    def __init__(self, path: str | Path, source: str, covariance_width: int | None = None):
        self.path = Path(path)
        self._f = h5py.File(self.path, "w")
        self._f.attrs["schema"] = SCHEMA
        self._f.attrs["schema_version"] = SCHEMA_VERSION
        self._f.attrs["source"] = source
        g = self._f.create_group("trajectory")
        fields = list(_FIELDS) + ([("covariance_diag", np.float64, (covariance_width,))] if covariance_width else [])
        for name, dtype, tail in fields:
            g.create_dataset(name, (0, *tail), dtype, maxshape=(None, *tail), chunks=(WRITE_EVERY_POSES, *tail),
                             fletcher32=True)
        self.n = 0  # poses appended (written or gathered)
        self._written = 0
        self._pending: list[dict] = []

    def append(self, time_ns, position_m, orientation_xyzw, velocity_mps, covariance_diag=None) -> None:
        values = dict(zip((f[0] for f in _FIELDS), (time_ns, position_m, orientation_xyzw, velocity_mps)))
        if covariance_diag is not None:
            values["covariance_diag"] = covariance_diag
        k = int(np.asarray(time_ns).size)
        if k:
            self._pending.append({name: np.array(value) for name, value in values.items()})
            self.n += k
        if self.n - self._written >= WRITE_EVERY_POSES:
            self._write()

    def _write(self) -> None:
        if not self._pending:
            return
        g = self._f["trajectory"]
        for name in self._pending[0]:
            ds = g[name]  # once per field: an HDF5 lookup costs as much as the copy of a few hundred appends
            tail = ds.shape[1:]
            value = np.concatenate([np.reshape(p[name], (-1, *tail)) for p in self._pending])
            ds.resize(self.n, axis=0)
            ds[self._written:] = value
        self._written = self.n
        self._pending.clear()

    def flush(self) -> None:
        self._write()
        self._f.flush()

    def close(self, stop_cut_short: bool | None = False) -> None:
        """Write what is gathered and close. ``stop_cut_short``: True when the writer was hurried at the
        daemon's stop and left poses out (the attribute 1), False when the poses go to the end (0), None to
        leave the attribute out (not known: an error cut the writing short)."""
        if self._f.id.valid:
            self._write()
            if stop_cut_short is not None:
                self._f.attrs["stop_cut_short"] = int(bool(stop_cut_short))
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        self.close(stop_cut_short=None if exc_type is not None else False)


def write_trajectory(path: str | Path, traj: SampledTrajectory, covariance_diag: np.ndarray | None = None) -> Path:
    width = None if covariance_diag is None else np.asarray(covariance_diag).shape[1]
    with TrajectoryWriter(path, traj.source, width) as w:
        w.append(traj.time_ns, traj.position_m, traj.orientation_xyzw, traj.velocity_mps, covariance_diag)
        # A trajectory read from a hurried file and written again still says so; any other is whole.
        w.close(stop_cut_short=bool(traj.stop_cut_short))
    return Path(path)


def read_trajectory(path: str | Path) -> SampledTrajectory:
    """The trajectory file at ``path``; its ``stop_cut_short`` (1, 0, or None where the file does not say:
    older files and files never closed) on the trajectory's attribute of that name."""
    path = Path(path)
    with open_checked(path, SCHEMA, SCHEMA_VERSION, "trajectory") as f:
        g = f["trajectory"]
        try:
            cut_short = int(f.attrs["stop_cut_short"]) if "stop_cut_short" in f.attrs else None
            return SampledTrajectory(read(g["time_ns"]), read(g["position_m"]), read(g["orientation_xyzw"]),
                                     read(g["velocity_mps"]) if "velocity_mps" in g else None,
                                     source=str(f.attrs.get("source", path.name)), stop_cut_short=cut_short)
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


#: The calibration axes of /calibration/NAME's ``sigma`` (rio.calibration.AXIS_KEYS): rotation about the
#: sensor's x, y, z (rad), lever arm along body x, y, z (m), time offset (s).
CALIBRATION_AXES = ("roll", "pitch", "yaw", "lever_x", "lever_y", "lever_z", "time_offset")


def write_calibration(path: str | Path, radars: dict[str, dict], history: dict[str, dict] | None = None) -> None:
    """Add the odometry's online calibration to a trajectory file: ``/calibration/NAME`` per radar with attrs
    mount_translation_m [3], mount_rotation_xyzw [4], time_offset_s, sigma [7] (CALIBRATION_AXES) and,
    given ``history`` (per radar: time_ns [K], rotation_change_rad [K, 3] from the rig's mount, lever_arm_m
    [K, 3], time_offset_s [K], sigma [K, 7]), those datasets: how the estimate converged."""
    with h5py.File(path, "a") as f:
        top = f.require_group("calibration")
        top.attrs["axes"] = list(CALIBRATION_AXES)
        for name, values in radars.items():
            g = top.require_group(name)
            for key in ("mount_translation_m", "mount_rotation_xyzw", "time_offset_s", "sigma"):
                g.attrs[key] = np.asarray(values[key], float)
            for key, array in (history or {}).get(name, {}).items():
                if key in g:
                    del g[key]
                g.create_dataset(key, data=np.asarray(array))


def read_calibration(path: str | Path) -> dict[str, dict]:
    """``/calibration`` of a trajectory file: per radar its attrs (and no history); {} where there is none."""
    with open_checked(Path(path), SCHEMA, SCHEMA_VERSION, "trajectory") as f:
        if "calibration" not in f:
            return {}
        return {name: {k: (v.item() if np.ndim(v) == 0 else np.asarray(v)) for k, v in g.attrs.items()}
                for name, g in f["calibration"].items()}
