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
from typing import TYPE_CHECKING

import numpy as np

from imaging.core import quaternion
from imaging.core.errors import ConfigError

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


@dataclasses.dataclass
class TrajectorySample:
    """Body states at N times; world frame unless the name says body."""

    time_ns: np.ndarray  # [N] int64
    position_m: np.ndarray  # [N, 3]
    orientation_xyzw: np.ndarray  # [N, 4], body -> world
    velocity_mps: np.ndarray  # [N, 3]
    angular_velocity_body_radps: np.ndarray  # [N, 3]
    acceleration_mps2: np.ndarray | None = None  # [N, 3] world, kinematic (gravity not included)

    @property
    def rotation(self) -> Rotation:
        """Body -> world as scipy's Rotation (imported here: the imaging path needs only the matrices,
        ``rotation_matrix``)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.orientation_xyzw)

    @property
    def rotation_matrix(self) -> np.ndarray:
        """Body -> world rotation matrices [N, 3, 3] (the same numbers as ``rotation.as_matrix()``)."""
        return quaternion.to_matrix(quaternion.normalized(self.orientation_xyzw))


class Trajectory(abc.ABC):
    """Anything that can say where the body is at a given time."""

    #: What the trajectory came from ("truth", "rio", a file name), written into image files.
    source: str = "model"

    @abc.abstractmethod
    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        """Body state at ``time_ns`` (int64 ns, any shape flattened to [N])."""

    def position(self, time_ns: np.ndarray) -> np.ndarray:
        return self.sample(time_ns).position_m

    def velocity(self, time_ns: np.ndarray) -> np.ndarray:
        """Velocity [N, 3] at ``time_ns``, m/s: ``sample(time_ns).velocity_mps``."""
        return self.sample(time_ns).velocity_mps


def _seconds(time_ns: np.ndarray, t0_ns: int) -> np.ndarray:
    # Subtract in integers first: float64 seconds since 1970 in ns would lose ~100 ns of precision.
    return (np.asarray(time_ns, dtype=np.int64).ravel() - np.int64(t0_ns)).astype(np.float64) * 1e-9


def _planar_sample(time_ns, xy, heading, speed, yaw_rate, z, accel_along=None) -> TrajectorySample:
    n = xy.shape[0]
    position = np.column_stack([xy, np.full(n, z)])
    c, s = np.cos(heading), np.sin(heading)
    velocity = np.column_stack([speed * c, speed * s, np.zeros(n)])
    orientation = quaternion.about_z(heading)
    omega = np.zeros((n, 3))
    omega[:, 2] = yaw_rate
    # Tangential plus centripetal (v * yaw rate, towards the inside of the turn).
    a_t = np.zeros(n) if accel_along is None else accel_along
    a_n = speed * yaw_rate
    accel = np.column_stack([a_t * c - a_n * s, a_t * s + a_n * c, np.zeros(n)])
    return TrajectorySample(np.asarray(time_ns, np.int64).ravel(), position, orientation, velocity, omega, accel)


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
        xy = start[:2] + np.outer(self.speed_mps * t, [math.cos(h), math.sin(h)])  # no acceleration
        return _planar_sample(time_ns, xy, np.full(t.size, h), np.full(t.size, self.speed_mps), np.zeros(t.size), start[2])


@dataclasses.dataclass
class PathWithTurns(Trajectory):
    """Straight segments and circular arcs on a level floor, driven with an optional speed profile.

    ``segments``: sequence of ``("straight", length_m)`` or ``("arc", radius_m, angle_deg)``; a positive
    angle turns left. Without ``accel_mps2`` the robot moves at ``speed_mps`` from t0 to the end (the
    constant-speed pass SAR theory assumes). With ``accel_mps2`` it starts after ``start_delay_s``
    standing still, speeds up and slows down with a smooth (raised-cosine) speed ramp whose peak
    acceleration is ``accel_mps2``, and halts for every ``(at_distance_m, duration_s)`` in ``stops``.
    Before the start and after the end it stands still.
    """

    segments: Sequence[tuple] = (("straight", 1.0),)
    start_m: Sequence[float] = (0.0, 0.0, 0.0)
    heading_deg: float = 0.0
    speed_mps: float = 0.4
    t0_ns: int = 0
    source: str = "truth"
    accel_mps2: float | None = None
    start_delay_s: float = 0.0
    stops: Sequence[tuple[float, float]] = ()

    def __post_init__(self) -> None:
        if self.speed_mps <= 0:
            raise ConfigError("trajectory.speed_mps", f"must be positive, got {self.speed_mps}")
        if self.accel_mps2 is not None and self.accel_mps2 <= 0:
            raise ConfigError("trajectory.accel_mps2", f"must be positive, got {self.accel_mps2}")
        if self.accel_mps2 is None and (self.stops or self.start_delay_s):
            raise ConfigError("trajectory.stops", "stops and a start delay need accel_mps2 (a speed profile)")
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
        self._phases = self._speed_profile()

    def _speed_profile(self) -> list[tuple]:
        """Phases (t_start, duration, s_start, kind, V): kind "still", "cruise", "up", "down"."""
        if self.accel_mps2 is None:
            return [(0.0, self.length_m / self.speed_mps, 0.0, "cruise", self.speed_mps)]
        phases = []
        t = 0.0
        if self.start_delay_s > 0:
            phases.append((0.0, self.start_delay_s, 0.0, "still", 0.0))
            t = self.start_delay_s
        legs, s_prev = [], 0.0
        for i, (at, duration) in enumerate(sorted(tuple(map(float, st)) for st in self.stops)):
            if not 0 < at < self.length_m or duration < 0:
                raise ConfigError(f"trajectory.stops[{i}]", f"must be (distance inside the path, duration >= 0), got {(at, duration)}")
            legs.append((s_prev, at, duration))
            s_prev = at
        legs.append((s_prev, self.length_m, 0.0))
        for s0, s1, pause in legs:
            length = s1 - s0
            v = self.speed_mps
            ramp_t = v * math.pi / (2 * self.accel_mps2)
            if v * ramp_t > length:  # too short to reach cruise speed: lower the peak speed
                v = math.sqrt(2 * self.accel_mps2 * length / math.pi)
                ramp_t = v * math.pi / (2 * self.accel_mps2)
            ramp_s = v * ramp_t / 2
            phases.append((t, ramp_t, s0, "up", v))
            t += ramp_t
            cruise = (length - 2 * ramp_s) / v
            if cruise > 0:
                phases.append((t, cruise, s0 + ramp_s, "cruise", v))
                t += cruise
            phases.append((t, ramp_t, s1 - ramp_s, "down", v))
            t += ramp_t
            if pause > 0:
                phases.append((t, pause, s1, "still", 0.0))
                t += pause
        return phases

    @property
    def duration_s(self) -> float:
        t0, dt, *_ = self._phases[-1]
        return t0 + dt

    def _arc_length(self, t: np.ndarray):
        """Distance along the path, speed and tangential acceleration at times t (s from t0)."""
        s = np.where(t <= 0, 0.0, self.length_m)
        v = np.zeros(t.size)
        a = np.zeros(t.size)
        for t0, dt, s0, kind, vmax in self._phases:
            m = (t >= t0) & (t < t0 + dt) if kind != "cruise" or self.accel_mps2 else (t >= t0) & (t <= t0 + dt)
            if not np.any(m):
                continue
            u = t[m] - t0
            if kind == "still":
                s[m] = s0
            elif kind == "cruise":
                s[m] = s0 + vmax * u
                v[m] = vmax
            else:
                w = math.pi / dt
                # raised-cosine speed: up v = V/2 (1 - cos w u), down v = V/2 (1 + cos w u)
                sign = 1.0 if kind == "up" else -1.0
                v[m] = 0.5 * vmax * (1 - sign * np.cos(w * u))
                s[m] = s0 + 0.5 * vmax * (u - sign * np.sin(w * u) / w)
                a[m] = sign * 0.5 * vmax * w * np.sin(w * u)
        return s, v, a

    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        t = _seconds(time_ns, self.t0_ns)
        s_all, speed, accel = self._arc_length(t)
        xy = np.empty((t.size, 2))
        heading = np.empty(t.size)
        curvature_all = np.zeros(t.size)
        starts = np.array([st[0] for st in self._starts])
        idx = np.clip(np.searchsorted(starts, s_all, side="right") - 1, 0, len(self._starts) - 1)
        for k, (s0, x0, y0, h0, kind, length, curvature) in enumerate(self._starts):
            m = idx == k
            if not np.any(m):
                continue
            ds = np.minimum(s_all[m] - s0, length)
            if kind == "straight":
                xy[m, 0] = x0 + ds * math.cos(h0)
                xy[m, 1] = y0 + ds * math.sin(h0)
                heading[m] = h0
            else:
                h = h0 + curvature * ds
                xy[m, 0] = x0 + (np.sin(h) - math.sin(h0)) / curvature
                xy[m, 1] = y0 - (np.cos(h) - math.cos(h0)) / curvature
                heading[m] = h
                curvature_all[m] = curvature
        return _planar_sample(time_ns, xy, heading, speed, curvature_all * speed, float(self.start_m[2]), accel)


def _quat_from_rotvec(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of rotation vectors [N, 3]."""
    angle = np.linalg.norm(v, axis=1)
    half = 0.5 * angle
    # sin(a/2)/a, by its series where a is tiny (a^4/3840 is below double precision there)
    scale = np.where(angle > 1e-4, np.sin(half) / np.where(angle > 1e-4, angle, 1.0), 0.5 - angle ** 2 / 48.0)
    return np.concatenate([v * scale[:, None], np.cos(half)[:, None]], axis=1)


def _quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton products p q of quaternions (x, y, z, w) [N, 4]: the rotation q, then p (scipy's p * q)."""
    px, py, pz, pw = p.T
    qx, qy, qz, qw = q.T
    return np.stack([pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw,
                     pw * qw - px * qx - py * qy - pz * qz], axis=1)


class SampledTrajectory(Trajectory):
    """A trajectory known at discrete times, interpolated in between (and held constant outside).

    ``stop_cut_short``: as its trajectory file says (``imaging.io.trajectory_file``): 1 when the live odometry
    was hurried at the daemon's stop and left its last poses out, 0 when not, None when not known (a
    trajectory not read from a file, or a file that does not say)."""

    def __init__(self, time_ns, position_m, orientation_xyzw, velocity_mps=None, source: str = "sampled",
                 stop_cut_short: int | None = None):
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
        self._accel = np.gradient(self.velocity_mps, self._t, axis=0)
        self._quat = quaternion.normalized(self.orientation_xyzw)
        # Per interval: the rotation vector log(R_k^T R_{k+1}), and from it the body angular rate.
        self._dt = np.diff(self._t)
        self._step_rotvec = quaternion.to_rotvec(quaternion.compose(quaternion.inverse(self._quat[:-1]), self._quat[1:]))
        self._omega_body = self._step_rotvec / self._dt[:, None]
        self.source = source
        self.stop_cut_short = stop_cut_short

    @classmethod
    def from_batches(cls, batches, source: str = "rio") -> SampledTrajectory:
        """The poses of ``batches`` as one trajectory: objects with ``time_ns`` [N], ``position_m`` [N, 3],
        ``orientation_xyzw`` [N, 4] and ``velocity_mps`` [N, 3] (the odometry's pose batches), in time order;
        empty ones add nothing."""
        done = [b for b in batches if b.time_ns.size]
        return cls(*(np.concatenate([getattr(b, f) for b in done])
                     for f in ("time_ns", "position_m", "orientation_xyzw", "velocity_mps")), source=source)

    def sample(self, time_ns: np.ndarray) -> TrajectorySample:
        """Linear in position, velocity and acceleration; attitude by slerp, R_k exp(u log(R_k^T R_{k+1}))
        (scipy's Slerp, in plain numpy: a live map samples a short trajectory thousands of times)."""
        t = np.clip(_seconds(time_ns, self.t0_ns), self._t[0], self._t[-1])
        k = np.clip(np.searchsorted(self._t, t, side="right") - 1, 0, self._dt.size - 1)
        u = ((t - self._t[k]) / self._dt[k])[:, None]

        def lerp(a: np.ndarray) -> np.ndarray:
            return a[k] + u * (a[k + 1] - a[k])

        quat = _quat_multiply(self._quat[k], _quat_from_rotvec(u * self._step_rotvec[k]))
        return TrajectorySample(np.asarray(time_ns, np.int64).ravel(), lerp(self.position_m), quat,
                                lerp(self.velocity_mps), self._omega_body[k], lerp(self._accel))

    def velocity(self, time_ns: np.ndarray) -> np.ndarray:
        """``sample(time_ns).velocity_mps`` without the rest of the sample (the attitude's slerp is most of a
        sample's cost, and the live map asks every frame whether the robot moves)."""
        t = np.clip(_seconds(time_ns, self.t0_ns), self._t[0], self._t[-1])
        k = np.clip(np.searchsorted(self._t, t, side="right") - 1, 0, self._dt.size - 1)
        u = ((t - self._t[k]) / self._dt[k])[:, None]
        return self.velocity_mps[k] + u * (self.velocity_mps[k + 1] - self.velocity_mps[k])

    @classmethod
    def from_trajectory(cls, trajectory: Trajectory, time_ns: np.ndarray, source: str | None = None):
        s = trajectory.sample(time_ns)
        return cls(s.time_ns, s.position_m, s.orientation_xyzw, s.velocity_mps, source or trajectory.source)
