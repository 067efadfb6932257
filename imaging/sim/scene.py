"""Simulation scenes: a rig, a trajectory, targets, vibration and noise, from TOML; a few built in.

A scene file::

    name = "my_pass"
    duration_s = 6.0
    radars = ["left_front"]        # default: every radar of the rig
    snr_db = 30.0                  # per-sample SNR of an amplitude-1 return; omit for no noise
    rig = "default"                # or a rig TOML path, relative to the scene file

    [trajectory]
    kind = "straight"              # or "path" with segments = [["straight", 2.0], ["arc", 1.0, 90.0]]
    start_m = [-1.2, -0.2, 0.0]
    speed_mps = 0.4

    [vibration]                    # optional: displacement along every radar's boresight
    frequency_hz = 4.2
    amplitude_m = 0.35e-3

    [[target]]
    kind = "point"                 # point | rod | corner
    position_m = [0.0, 2.0, 0.3]
"""

from __future__ import annotations

import dataclasses
import math
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from imaging.core.config import ConfigError, from_dict, read_toml
from imaging.core.geometry import Vibration
from imaging.core.rig import Rig, default_rig, load_rig
from imaging.core.trajectory import PathWithTurns, StraightLine, Trajectory
from imaging.sim.detection_simulator import DetectionModel, Person, room_scatterers
from imaging.sim.imu_simulator import ImuErrors
from imaging.sim.targets import TARGET_KINDS, PointTarget

DEFAULT_START_TIME_NS = 1_700_000_000_000_000_000  # a TAI time in November 2023; any epoch works


@dataclasses.dataclass
class Scene:
    """Everything the simulator needs for one run."""

    name: str
    rig: Rig
    trajectory: Trajectory
    targets: list
    duration_s: float
    radars: list[str]
    description: str = ""
    snr_db: float | None = None
    vibration: Vibration | None = None
    intra_chirp_motion: bool = True
    seed: int = 0
    start_time_ns: int = DEFAULT_START_TIME_NS
    truth_rate_hz: float = 1000.0
    imu: bool = False
    imu_errors: ImuErrors | None = None
    #: When set, radars deliver point clouds (detections) instead of ADC frames.
    detection_model: DetectionModel | None = None
    static_points_m: np.ndarray | None = None
    people: list = dataclasses.field(default_factory=list)
    #: Store the ADC as the radar would send it: int16 I/Q counts, this many per unit amplitude. None keeps
    #: complex64 (exact; what imaging studies use).
    adc_counts_per_unit: float | None = None


def builtin_scene_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("imaging.sim.scenes").iterdir() if p.name.endswith(".toml"))


def load_scene(name_or_path: str | Path) -> Scene:
    """A scene from a TOML file, or a built-in scene by name (see ``builtin_scene_names()``)."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        return scene_from_dict(read_toml(path), source=str(path), base=path.parent)
    if str(name_or_path) in builtin_scene_names():
        res = resources.files("imaging.sim.scenes") / f"{name_or_path}.toml"
        with resources.as_file(res) as p:
            return scene_from_dict(read_toml(p), source=f"built-in scene {name_or_path}", base=p.parent)
    raise ConfigError(
        "<scene>", f"{name_or_path!r} is neither a file nor a built-in scene (built-in: {', '.join(builtin_scene_names())})"
    )


#: Fastest a scene's robot drives, m/s (a limit on what is simulated, not on robots).
MAX_SPEED_MPS = 20.0
#: The largest seed numpy's generators take (non-negative, 64 bits).
MAX_SEED = 2**63 - 1


def _number(value: Any, field: str, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False) -> float:
    """``value`` as a finite float in [lo, hi] (or (lo, hi] with ``lo_open``); ConfigError naming the field
    and the range otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(field, f"expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or value > hi or value < lo or (lo_open and value == lo):
        bounds = "" if math.isinf(lo) and math.isinf(hi) else f" in {'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise ConfigError(field, f"must be a finite number{bounds}, got {value!r}")
    return value


def _flag(value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(field, f"expected true or false, got {value!r}")
    return value


def _seed(value: Any, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
        raise ConfigError(field, f"expected an integer seed from 0 to {MAX_SEED}, got {value!r}")
    return value


def _trajectory_from_table(t: dict[str, Any], start_time_ns: int) -> Trajectory:
    t = dict(t)
    kind = t.pop("kind", "straight")
    start = t.pop("start_m", (0.0, 0.0, 0.0))
    if not isinstance(start, (list, tuple)):
        raise ConfigError("trajectory.start_m", "expected [x, y, z]")
    common = {
        "start_m": tuple(_number(v, "trajectory.start_m") for v in start),
        "heading_deg": _number(t.pop("heading_deg", 0.0), "trajectory.heading_deg"),
        "speed_mps": _number(t.pop("speed_mps", 0.4), "trajectory.speed_mps", 0.0, MAX_SPEED_MPS),
        "t0_ns": start_time_ns,
    }
    profile = {}
    if "accel_mps2" in t:
        profile["accel_mps2"] = _number(t.pop("accel_mps2"), "trajectory.accel_mps2", 0.0, 100.0, lo_open=True)
    if "start_delay_s" in t:
        profile["start_delay_s"] = _number(t.pop("start_delay_s"), "trajectory.start_delay_s", 0.0, MAX_DURATION_S)
    if "stops" in t:
        profile["stops"] = [tuple(st) for st in t.pop("stops")]
    if len(common["start_m"]) != 3:
        raise ConfigError("trajectory.start_m", "expected [x, y, z]")
    if kind == "straight" and profile:
        raise ConfigError("trajectory.kind", "a speed profile (accel_mps2, stops) needs kind = \"path\"")
    if kind == "straight":
        traj: Trajectory = StraightLine(**common)
    elif kind == "path":
        segments = t.pop("segments", None)
        if not segments:
            raise ConfigError("trajectory.segments", "a path needs segments, e.g. [[\"straight\", 2.0], [\"arc\", 1.0, 90.0]]")
        traj = PathWithTurns(segments=[tuple(s) for s in segments], **common, **profile)
    else:
        raise ConfigError("trajectory.kind", f"unknown kind {kind!r} (straight, path)")
    if t:
        raise ConfigError(f"trajectory.{sorted(t)[0]}", "unknown setting")
    return traj


def _positive_or_none(value, field: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0:
        raise ConfigError(field, f"expected a positive number, got {value!r}")
    return float(value)


#: Most scatterers a [[clutter]] box or a [room] may hold (each is simulated on every chirp).
MAX_SCATTERERS = 100_000
#: Longest scene, s: the raw ADC of four radars is 55 MB/s.
MAX_DURATION_S = 24 * 3600.0


def _clutter_targets(box: dict[str, Any], prefix: str) -> list[PointTarget]:
    """``[[clutter]]``: ``count`` point scatterers of ``amplitude`` placed at random (``seed``) in the box
    ``box_m = [[x0, x1], [y0, y1], [z0, z1]]`` (furniture, cables, the odd screw: what a room has)."""
    try:
        count = int(box.pop("count"))
        lo_hi = np.asarray(box.pop("box_m"), float)
        amplitude = _number(box.pop("amplitude", 0.5), f"{prefix}.amplitude", 0.0, 1e6)
        rng = np.random.default_rng(_seed(box.pop("seed", 0), f"{prefix}.seed"))
    except ConfigError:
        raise
    except KeyError as exc:
        raise ConfigError(f"{prefix}.{exc.args[0]}", "is required") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(prefix, str(exc)) from None
    if lo_hi.shape != (3, 2) or np.any(lo_hi[:, 1] < lo_hi[:, 0]):
        raise ConfigError(f"{prefix}.box_m", "expected [[x0, x1], [y0, y1], [z0, z1]] with x0 <= x1 and so on")
    if not 0 <= count <= MAX_SCATTERERS:
        raise ConfigError(f"{prefix}.count", f"must be 0 to {MAX_SCATTERERS}, got {count}")
    if not np.all(np.isfinite(lo_hi)):
        raise ConfigError(f"{prefix}.box_m", "must be finite")
    if box:
        raise ConfigError(f"{prefix}.{sorted(box)[0]}", "unknown setting")
    points = rng.uniform(lo_hi[:, 0], lo_hi[:, 1], (count, 3))
    return [PointTarget(tuple(p), amplitude=amplitude) for p in points]


def _bounded_count(value: Any, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SCATTERERS:
        raise ConfigError(field, f"expected a count from 0 to {MAX_SCATTERERS}, got {value!r}")
    return value


#: A [room]'s walls carry a scatterer every ``spacing_m`` along and every 0.4 m up (``room_scatterers``).
ROOM_ROW_SPACING_M = 0.4


def _room_settings(room: dict[str, Any]) -> dict[str, Any]:
    """``[room]``'s settings checked, its scatterer count against MAX_SCATTERERS before any is made (a spacing of
    a micrometre would otherwise build billions of points)."""
    size = room.pop("size_m", (12.0, 8.0))
    centre = room.pop("centre_m", (0.0, 0.0))
    if not isinstance(size, (list, tuple)) or len(size) != 2:
        raise ConfigError("room.size_m", "expected [x, y] in metres")
    if not isinstance(centre, (list, tuple)) or len(centre) != 2:
        raise ConfigError("room.centre_m", "expected [x, y] in metres")
    size = tuple(_number(v, "room.size_m", 0.0, 1000.0, lo_open=True) for v in size)
    centre = tuple(_number(v, "room.centre_m", -1e6, 1e6) for v in centre)
    # The lowest row of wall scatterers is at 0.1 m: a room no higher has no walls.
    height = _number(room.pop("height_m", 2.5), "room.height_m", 0.1, 100.0, lo_open=True)
    spacing = _number(room.pop("spacing_m", 0.3), "room.spacing_m", 0.0, 1000.0, lo_open=True)
    rows = max(0, math.ceil((height - 0.1) / ROOM_ROW_SPACING_M))
    n = 2 * rows * (size[0] / spacing + size[1] / spacing + 2)
    if n > MAX_SCATTERERS:
        smallest = rows * 2 * (size[0] + size[1]) / (MAX_SCATTERERS - 4 * rows)
        raise ConfigError("room.spacing_m", f"{spacing:g} m puts about {n:.3g} scatterers on the walls, more than the "
                                            f"limit of {MAX_SCATTERERS}; at least {smallest:.3g} m for this room")
    return {"size_m": size, "centre_m": centre, "height_m": height, "spacing_m": spacing,
            "clutter": _bounded_count(room.pop("clutter", 80), "room.clutter"),
            "rng": np.random.default_rng(_seed(room.pop("seed", 0), "room.seed"))}


def scene_from_dict(table: dict[str, Any], source: str | None = None, base: Path | None = None) -> Scene:
    """Build and validate a Scene from a parsed TOML table."""
    try:
        table = dict(table)
        name = str(table.pop("name", "scene"))
        rig_spec = table.pop("rig", "default")
        if isinstance(rig_spec, str) and rig_spec != "default":
            rig = load_rig((base or Path(".")) / rig_spec)
        elif rig_spec == "default":
            rig = default_rig()
        else:
            raise ConfigError("rig", "expected \"default\" or the path of a rig TOML file")
        start_time_ns = table.pop("start_time_ns", DEFAULT_START_TIME_NS)
        if not isinstance(start_time_ns, int) or start_time_ns < 0:
            raise ConfigError("start_time_ns", f"expected a non-negative integer, got {start_time_ns!r}")
        trajectory = _trajectory_from_table(table.pop("trajectory", {}), start_time_ns)
        radars = table.pop("radars", rig.radar_names)
        for i, r in enumerate(radars):
            if r not in rig.radar_names:
                raise ConfigError(f"radars[{i}]", f"no radar {r!r} in the rig (radars: {', '.join(rig.radar_names)})")
        targets = []
        for i, tt in enumerate(table.pop("target", [])):
            tt = dict(tt)
            kind = tt.pop("kind", "point")
            if kind not in TARGET_KINDS:
                raise ConfigError(f"target[{i}].kind", f"unknown kind {kind!r} ({', '.join(TARGET_KINDS)})")
            targets.append(from_dict(TARGET_KINDS[kind], tt, prefix=f"target[{i}]"))
        for i, box in enumerate(table.pop("clutter", [])):
            targets += _clutter_targets(dict(box), f"clutter[{i}]")
        vibration = None
        if "vibration" in table:
            vibration = from_dict(Vibration, table.pop("vibration"), prefix="vibration")
        imu = _flag(table.pop("imu", False), "imu")
        imu_errors = from_dict(ImuErrors, table.pop("imu_errors"), prefix="imu_errors") if "imu_errors" in table else None
        detection_model = None
        if "detections" in table:
            detection_model = from_dict(DetectionModel, table.pop("detections"), prefix="detections")
        static_points = None
        if "room" in table:
            room = dict(table.pop("room"))
            try:
                static_points = room_scatterers(**_room_settings(room))
            except ConfigError:
                raise
            except (TypeError, ValueError, ArithmeticError) as exc:
                raise ConfigError("room", str(exc)) from None
            if room:
                raise ConfigError(f"room.{sorted(room)[0]}", "unknown setting")
        people = [from_dict(Person, p, prefix=f"person[{i}]") for i, p in enumerate(table.pop("person", []))]
        duration_s = table.pop("duration_s", 5.0)
        if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)):
            raise ConfigError("duration_s", f"expected a number of seconds, got {duration_s!r}")
        duration_s = float(duration_s)
        if not 0 < duration_s <= MAX_DURATION_S:
            raise ConfigError("duration_s", f"must be positive and at most {MAX_DURATION_S:g} s, got {duration_s}")
        snr = table.pop("snr_db", None)
        if snr is not None:
            snr = _number(snr, "snr_db", -200.0, 400.0)
        scene = Scene(
            name=name,
            description=str(table.pop("description", "")),
            rig=rig,
            trajectory=trajectory,
            targets=targets,
            duration_s=duration_s,
            radars=list(radars),
            snr_db=None if snr is None else float(snr),
            vibration=vibration,
            intra_chirp_motion=_flag(table.pop("intra_chirp_motion", True), "intra_chirp_motion"),
            adc_counts_per_unit=_positive_or_none(table.pop("adc_counts_per_unit", None), "adc_counts_per_unit"),
            seed=_seed(table.pop("seed", 0), "seed"),
            start_time_ns=start_time_ns,
            truth_rate_hz=_number(table.pop("truth_rate_hz", 1000.0), "truth_rate_hz"),
            imu=imu,
            imu_errors=imu_errors,
            detection_model=detection_model,
            static_points_m=static_points,
            people=people,
        )
        if detection_model is not None and static_points is None and not targets:
            raise ConfigError("detections", "a detection-level scene needs a [room] or point targets to detect")
        if table:
            raise ConfigError(sorted(table)[0], "unknown setting")
        if not (0 < scene.truth_rate_hz <= 100_000):
            raise ConfigError("truth_rate_hz", f"must be in (0, 100000] Hz, got {scene.truth_rate_hz}")
        return scene
    except ConfigError as exc:
        if source and exc.source is None:
            raise ConfigError(exc.field, str(exc).split(": ", 1)[-1], source=source) from None
        raise
    except (TypeError, ValueError, ArithmeticError) as exc:  # a value of the wrong kind the checks above missed
        raise ConfigError("scene", f"invalid settings ({exc})", source=source) from None


def frame_times_ns(scene: Scene, radar: str) -> np.ndarray:
    """Frame start times of one radar over the scene's duration."""
    wf = scene.rig.radar(radar).waveform
    n = int(np.floor(scene.duration_s / wf.frame_interval_s + 1e-9))
    return scene.start_time_ns + np.round(np.arange(n) * wf.frame_interval_s * 1e9).astype(np.int64)
