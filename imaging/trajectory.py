"""Robot body trajectories: pose, velocity and angular rate as functions of time.

A trajectory gives the body frame ``b`` (x forward, y left, z up, at the IMU) in the world frame ``n``
at any int64 nanosecond time. Built-ins: a straight line at constant speed, a path of straight segments
and circular turns at constant speed, and a sampled trajectory (truth, RIO output, a file) interpolated
linearly in position and spherically (slerp) in attitude.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .errors import ConfigError


@dataclasses.dataclass
class TrajectorySample:
    """Body states at N times; world frame unless the name says body."""

    time_ns: np.ndarray  # [N] int64
    position_m: np.ndarray  # [N, 3]
    orientation_xyzw: np.ndarray  # [N, 4], body -> world
    velocity_mps: np.ndarray  # [N, 3]
    angular_velocity_body_radps: np.ndarray  # [N, 3]

    @property
    def rotation(self) -> Rotation:
        return Rotation.from_quat(self.orientation_xyzw)


class Trajectory(abc.ABC):
    """Anything that can say where the body is at a given time."""

    #: What the trajectory came from ("truth", "rio", a file name), written into image files.
    source: str = "model"

    @abc.abstractmethod
    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        """Body state at ``time_ns`` (int64 ns, any shape flattened to [N])."""

    def position(self, time_ns: np.ndarray) -> np.ndarray:
        return self.sample(time_ns).position_m


def _seconds(time_ns: np.ndarray, t0_ns: int) -> np.ndarray:
    # Subtract in integers first: float64 seconds since 1970 in ns would lose ~100 ns of precision.
    return (np.asarray(time_ns, dtype=np.int64).ravel() - np.int64(t0_ns)).astype(np.float64) * 1e-9


def _planar_sample(time_ns, xy, heading, speed, yaw_rate, z) -> TrajectorySample:
    n = xy.shape[0]
    position = np.column_stack([xy, np.full(n, z)])
    velocity = np.column_stack([speed * np.cos(heading), speed * np.sin(heading), np.zeros(n)])
    orientation = Rotation.from_euler("z", heading[:, None]).as_quat()
    omega = np.zeros((n, 3))
    omega[:, 2] = yaw_rate
    return TrajectorySample(np.asarray(time_ns, np.int64).ravel(), position, orientation, velocity, omega)


@dataclasses.dataclass
class StraightLine(Trajectory):
    """Constant speed along a level straight line, body x along the direction of travel."""

    start_m: Sequence[float] = (0.0, 0.0, 0.0)
    heading_deg: float = 0.0
    speed_mps: float = 0.4
    t0_ns: int = 0
    source: str = "truth"

    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        t = _seconds(time_ns, self.t0_ns)
        h = math.radians(self.heading_deg)
        start = np.asarray(self.start_m, dtype=np.float64)
        xy = start[:2] + np.outer(self.speed_mps * t, [math.cos(h), math.sin(h)])
        return _planar_sample(time_ns, xy, np.full(t.size, h), np.full(t.size, self.speed_mps), np.zeros(t.size), start[2])


@dataclasses.dataclass
class PathWithTurns(Trajectory):
    """Straight segments and circular arcs driven at constant speed on a level floor.

    ``segments``: sequence of ``("straight", length_m)`` or ``("arc", radius_m, angle_deg)``; a positive
    angle turns left. Before the start and after the end the robot stands still at the end points.
    """

    segments: Sequence[tuple] = (("straight", 1.0),)
    start_m: Sequence[float] = (0.0, 0.0, 0.0)
    heading_deg: float = 0.0
    speed_mps: float = 0.4
    t0_ns: int = 0
    source: str = "truth"

    def __post_init__(self) -> None:
        if self.speed_mps <= 0:
            raise ConfigError("trajectory.speed_mps", f"must be positive, got {self.speed_mps}")
        # Pre-compute the start state (x, y, heading) and cumulative length of every segment.
        x, y, h = float(self.start_m[0]), float(self.start_m[1]), math.radians(self.heading_deg)
        self._starts = []
        s = 0.0
        for i, seg in enumerate(self.segments):
            kind = seg[0]
            if kind == "straight":
                length = float(seg[1])
                if length <= 0:
                    raise ConfigError(f"trajectory.segments[{i}]", f"straight length must be positive, got {length}")
                self._starts.append((s, x, y, h, kind, length, 0.0))
                x += length * math.cos(h)
                y += length * math.sin(h)
            elif kind == "arc":
                radius, angle = float(seg[1]), math.radians(float(seg[2]))
                if radius <= 0 or angle == 0:
                    raise ConfigError(f"trajectory.segments[{i}]", "arc needs a positive radius and a non-zero angle")
                length = radius * abs(angle)
                curvature = math.copysign(1.0 / radius, angle)
                self._starts.append((s, x, y, h, kind, length, curvature))
                x += (math.sin(h + angle) - math.sin(h)) / curvature
                y -= (math.cos(h + angle) - math.cos(h)) / curvature
                h += angle
            else:
                raise ConfigError(f"trajectory.segments[{i}]", f"unknown segment kind {kind!r} (straight, arc)")
            s += length
        self.length_m = s
        self._end = (x, y, h)

    @property
    def duration_s(self) -> float:
        return self.length_m / self.speed_mps

    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        t = _seconds(time_ns, self.t0_ns)
        s_all = np.clip(t, 0.0, self.duration_s) * self.speed_mps
        moving = (t >= 0) & (t <= self.duration_s)
        xy = np.empty((t.size, 2))
        heading = np.empty(t.size)
        yaw_rate = np.zeros(t.size)
        starts = np.array([st[0] for st in self._starts])
        idx = np.clip(np.searchsorted(starts, s_all, side="right") - 1, 0, len(self._starts) - 1)
        for k, (s0, x0, y0, h0, kind, length, curvature) in enumerate(self._starts):
            m = idx == k
            if not np.any(m):
                continue
            ds = s_all[m] - s0
            if kind == "straight":
                xy[m, 0] = x0 + ds * math.cos(h0)
                xy[m, 1] = y0 + ds * math.sin(h0)
                heading[m] = h0
            else:
                h = h0 + curvature * ds
                xy[m, 0] = x0 + (np.sin(h) - math.sin(h0)) / curvature
                xy[m, 1] = y0 - (np.cos(h) - math.cos(h0)) / curvature
                heading[m] = h
                yaw_rate[m] = curvature * self.speed_mps
        speed = np.where(moving, self.speed_mps, 0.0)
        yaw_rate = np.where(moving, yaw_rate, 0.0)
        return _planar_sample(time_ns, xy, heading, speed, yaw_rate, float(self.start_m[2]))


class SampledTrajectory(Trajectory):
    """A trajectory known at discrete times, interpolated in between (and held constant outside)."""

    def __init__(self, time_ns, position_m, orientation_xyzw, velocity_mps=None, source: str = "sampled"):
        self.time_ns = np.asarray(time_ns, dtype=np.int64)
        self.position_m = np.asarray(position_m, dtype=np.float64)
        self.orientation_xyzw = np.asarray(orientation_xyzw, dtype=np.float64)
        n = self.time_ns.size
        if n < 2 or self.position_m.shape != (n, 3) or self.orientation_xyzw.shape != (n, 4):
            raise ValueError(
                f"sampled trajectory needs >= 2 samples with position [N,3] and orientation [N,4]; got "
                f"time {self.time_ns.shape}, position {self.position_m.shape}, orientation {self.orientation_xyzw.shape}"
            )
        if np.any(np.diff(self.time_ns) <= 0):
            raise ValueError("sampled trajectory times must increase strictly")
        self.t0_ns = int(self.time_ns[0])
        self._t = _seconds(self.time_ns, self.t0_ns)
        if velocity_mps is None:
            velocity_mps = np.gradient(self.position_m, self._t, axis=0)
        self.velocity_mps = np.asarray(velocity_mps, dtype=np.float64)
        self._rotations = Rotation.from_quat(self.orientation_xyzw)
        self._slerp = Slerp(self._t, self._rotations)
        # Body angular rate per interval from consecutive attitudes: log(R_k^T R_{k+1}) / dt.
        rel = self._rotations[:-1].inv() * self._rotations[1:]
        self._omega_body = rel.as_rotvec() / np.diff(self._t)[:, None]
        self.source = source

    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        t = np.clip(_seconds(time_ns, self.t0_ns), self._t[0], self._t[-1])
        pos = np.column_stack([np.interp(t, self._t, self.position_m[:, k]) for k in range(3)])
        vel = np.column_stack([np.interp(t, self._t, self.velocity_mps[:, k]) for k in range(3)])
        quat = self._slerp(t).as_quat()
        k = np.clip(np.searchsorted(self._t, t, side="right") - 1, 0, self._omega_body.shape[0] - 1)
        return TrajectorySample(np.asarray(time_ns, np.int64).ravel(), pos, quat, vel, self._omega_body[k])

    @classmethod
    def from_trajectory(cls, trajectory: Trajectory, time_ns: np.ndarray, source: str | None = None):
        s = trajectory.sample(time_ns)
        return cls(s.time_ns, s.position_m, s.orientation_xyzw, s.velocity_mps, source or trajectory.source)
