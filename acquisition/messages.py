"""What travels on the bus: one typed message per topic.

Every message turns into ``to_parts()`` = (topic, sensor time, arrays, header fields) for
``BusPublisher.send`` and comes back with ``from_message`` (or ``decode``, which picks the class by topic).
The header keys live here and nowhere else, so a producer and its consumers cannot drift apart.

Topics: ``radar/<name>`` (RadarFrameMessage), ``imu`` (ImuBatch), ``radar_imu/<name>`` (RadarImuBatch: an
IMU on that radar's own mount; not ``imu/<name>``, which a subscription to ``imu`` would take for the
robot's IMU, ZeroMQ topics being prefixes), ``can`` (CanBatch), ``trigger``
(Trigger), ``event`` (Event), ``pose`` (PoseBatch), ``pose/end`` (PoseEnd), ``map/tile`` (MapTile),
``map/status`` (MapStatus), ``worker/state`` (WorkerState), ``health`` (Health).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import numpy as np

from drivers.radar.stream import RadarFrame

from .bus import Message
from .ptp import PtpStatus, ReceiveDelayStats


@dataclasses.dataclass
class Parts:
    """A message as the publisher sends it."""

    topic: str
    sensor_time_ns: int
    arrays: list[np.ndarray]
    fields: dict[str, Any]


class BusMessage:
    """Base of the typed messages: a topic, and the way to and from parts."""

    TOPIC: ClassVar[str]

    def to_parts(self) -> Parts:
        raise NotImplementedError

    @classmethod
    def from_message(cls, msg: Message):
        raise NotImplementedError


def _fields_of(cls, header: dict) -> dict:
    """The header entries that are fields of the dataclass ``cls`` (the bus adds its own: seq, times, arrays)."""
    return {f.name: header[f.name] for f in dataclasses.fields(cls) if f.name in header}


@dataclasses.dataclass
class RadarFrameMessage(BusMessage):
    """A reassembled radar frame (``iq`` int16 [chirps, rx, samples, 2])."""

    TOPIC: ClassVar[str] = "radar/"
    radar: str
    frame: RadarFrame

    @staticmethod
    def topic_of(radar: str) -> str:
        return f"radar/{radar}"

    def to_parts(self) -> Parts:
        f = self.frame
        return Parts(self.topic_of(self.radar), f.frame_time_ns, [f.iq],
                     {"frame_counter": f.frame_counter, "frame_time_ns": f.frame_time_ns, "receive_ns": f.receive_ns,
                      "valid": f.valid, "bytes_missing": f.bytes_missing, "ptp_locked": f.ptp_locked,
                      "nic_receive_ns": f.nic_receive_ns})

    @classmethod
    def from_message(cls, msg: Message) -> "RadarFrameMessage":
        h = msg.header
        return cls(msg.topic.split("/", 1)[1],
                   RadarFrame(int(h["frame_counter"]), int(h["frame_time_ns"]), int(h["receive_ns"]), bool(h["valid"]),
                              int(h.get("bytes_missing", 0)), msg.arrays[0], bool(h.get("ptp_locked", False)),
                              int(h.get("nic_receive_ns", 0))))


@dataclasses.dataclass
class PointCloudMessage(BusMessage):
    """A radar scan's detections, as the odometry made them: ``xyz_m`` [N, 3] in the radar's frame, radial
    ``doppler_mps`` [N], at the scan's measurement time."""

    TOPIC: ClassVar[str] = "points/"
    radar: str
    time_ns: int
    xyz_m: np.ndarray
    doppler_mps: np.ndarray

    def to_parts(self) -> Parts:
        return Parts(f"{self.TOPIC}{self.radar}", int(self.time_ns),
                     [np.asarray(self.xyz_m, np.float32), np.asarray(self.doppler_mps, np.float32)], {})

    @classmethod
    def from_message(cls, msg: Message) -> "PointCloudMessage":
        return cls(msg.topic.split("/", 1)[1], int(msg.sensor_time_ns), msg.arrays[0], msg.arrays[1])


@dataclasses.dataclass
class ImuBatch(BusMessage):
    """Timed IMU samples: PTP times [N] int64, gyro [N, 3] rad/s, specific force [N, 3] m/s^2, the IMU's
    counters [N] uint32 and host receive times [N] int64; the IMU clock's drift against the host, ppm."""

    TOPIC: ClassVar[str] = "imu"
    time_ns: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray
    counter: np.ndarray
    host_time_ns: np.ndarray
    clock_drift_ppm: float | None = None

    def __len__(self) -> int:
        return int(np.asarray(self.time_ns).size)

    @classmethod
    def from_samples(cls, samples, clock_drift_ppm: float | None = None) -> "ImuBatch":
        """A batch from ``drivers.imu.ImuSample`` objects."""
        return cls(np.array([s.time_ns for s in samples], np.int64), np.array([s.gyro_radps for s in samples]),
                   np.array([s.accel_mps2 for s in samples]), np.array([s.counter for s in samples], np.uint32),
                   np.array([s.host_time_ns for s in samples], np.int64), clock_drift_ppm)

    def to_parts(self) -> Parts:
        return Parts(self.TOPIC, int(self.time_ns[0]) if len(self) else 0,
                     [np.asarray(self.time_ns, np.int64), np.asarray(self.gyro_radps), np.asarray(self.accel_mps2),
                      np.asarray(self.counter, np.uint32), np.asarray(self.host_time_ns, np.int64)],
                     {"clock_drift_ppm": self.clock_drift_ppm})

    @classmethod
    def from_message(cls, msg: Message) -> "ImuBatch":
        return cls(*msg.arrays, clock_drift_ppm=msg.header.get("clock_drift_ppm"))


@dataclasses.dataclass
class RadarImuBatch(BusMessage):
    """Samples of the IMU on a radar's own mount (axes: the radar's), as an ImuBatch; recorded in
    ``/radar/<name>/imu``."""

    TOPIC: ClassVar[str] = "radar_imu/"
    radar: str
    batch: ImuBatch

    def __len__(self) -> int:
        return len(self.batch)

    @classmethod
    def topic_of(cls, radar: str) -> str:
        return f"{cls.TOPIC}{radar}"

    def to_parts(self) -> Parts:
        return dataclasses.replace(self.batch.to_parts(), topic=self.topic_of(self.radar))

    @classmethod
    def from_message(cls, msg: Message) -> "RadarImuBatch":
        return cls(msg.topic[len(cls.TOPIC):], ImuBatch.from_message(msg))


class ArrayBatch(BusMessage):
    """A batch whose every field is an array of one length, the first ``time_ns``: sent as arrays only."""

    def __len__(self) -> int:
        return int(np.asarray(self.time_ns).size)

    def to_parts(self) -> Parts:
        arrays = [getattr(self, f.name) for f in dataclasses.fields(self)]
        return Parts(self.TOPIC, int(arrays[0][0]) if len(self) else 0, arrays, {})

    @classmethod
    def from_message(cls, msg: Message):
        return cls(*msg.arrays)


class HeaderMessage(BusMessage):
    """A message of header fields only: every dataclass field travels in the header, ``time_ns`` as the
    message's sensor time."""

    def to_parts(self) -> Parts:
        fields = dataclasses.asdict(self)
        return Parts(self.TOPIC, int(fields.pop("time_ns")), [], fields)

    @classmethod
    def from_message(cls, msg: Message):
        return cls(**_fields_of(cls, msg.header), time_ns=int(msg.sensor_time_ns))


@dataclasses.dataclass
class CanBatch(ArrayBatch):
    """CAN frames as /can stores them: time_ns [K], arbitration_id [K], dlc [K], data [K, 64]."""

    TOPIC: ClassVar[str] = "can"
    time_ns: np.ndarray
    arbitration_id: np.ndarray
    dlc: np.ndarray
    data: np.ndarray


@dataclasses.dataclass
class Trigger(HeaderMessage):
    """The hardware trigger that ties a run's sensors together: its PTP time and who saw it."""

    TOPIC: ClassVar[str] = "trigger"
    time_ns: int
    source: str


@dataclasses.dataclass
class Event(HeaderMessage):
    """Something for /events: packet loss, checksum errors, resyncs, restarts.

    ``condition`` names a state that lasts (``"receive_buffer"``: a socket got less buffer than asked): health
    then repeats the message for the rest of the run, where other events are said once."""

    TOPIC: ClassVar[str] = "event"
    time_ns: int
    source: str
    level: str
    message: str
    condition: str = ""


@dataclasses.dataclass
class LoggedEvent(Event):
    """An event as the daemon wrote it to /events -- a driver's, a worker's, a loss on the bus or the
    supervisor's own (a restart, a device's answer) -- published again on the health endpoint, so a viewer
    has every event in one stream, each once."""

    TOPIC: ClassVar[str] = "log"


@dataclasses.dataclass
class PoseBatch(ArrayBatch):
    """Odometry poses: times [N] int64, positions [N, 3] m, orientations [N, 4] xyzw, velocities [N, 3] m/s."""

    TOPIC: ClassVar[str] = "pose"
    time_ns: np.ndarray
    position_m: np.ndarray
    orientation_xyzw: np.ndarray
    velocity_mps: np.ndarray


@dataclasses.dataclass
class PoseEnd(HeaderMessage):
    """The odometry has sent its last pose."""

    TOPIC: ClassVar[str] = "pose/end"
    time_ns: int


@dataclasses.dataclass
class MapTile(BusMessage):
    """One strip-map tile: ``key`` (ix, iy) in tiles of ``tile_px`` pixels of ``pixel_m``; ``image`` complex64."""

    TOPIC: ClassVar[str] = "map/tile"
    key: tuple[int, int]
    pixel_m: float
    tile_px: int
    image: np.ndarray

    def to_parts(self) -> Parts:
        return Parts(self.TOPIC, 0, [np.asarray(self.image, np.complex64)],
                     {"key": [int(k) for k in self.key], "pixel_m": float(self.pixel_m), "tile_px": int(self.tile_px)})

    @classmethod
    def from_message(cls, msg: Message) -> "MapTile":
        h = msg.header
        return cls(tuple(h["key"]), float(h["pixel_m"]), int(h["tile_px"]), msg.arrays[0])


@dataclasses.dataclass
class MapVelocityError(HeaderMessage):
    """The trajectory's velocity error (truth minus trajectory) along one world direction, read off tiles the
    strip map refocused together (``rio.map_feedback.LookVelocityMeasurement``): for the odometry."""

    TOPIC: ClassVar[str] = "map/velocity_error"
    time_ns: int  # centre of the tiles' time span (the trajectory's time base)
    span_s: float
    direction_x: float  # unit direction, world frame
    direction_y: float
    direction_z: float
    velocity_error_mps: float
    sigma_mps: float
    radars: str  # comma-separated
    tiles: int

    @classmethod
    def of(cls, m) -> "MapVelocityError":
        return cls(int(m.time_ns), float(m.span_s), *(float(x) for x in m.direction), float(m.velocity_error_mps),
                   float(m.sigma_mps), ",".join(m.radars), int(m.tiles))

    def measurement(self):
        from rio.map_feedback import LookVelocityMeasurement

        return LookVelocityMeasurement(int(self.time_ns), float(self.span_s),
                                       np.array([self.direction_x, self.direction_y, self.direction_z]),
                                       float(self.velocity_error_mps), float(self.sigma_mps),
                                       tuple(r for r in self.radars.split(",") if r), int(self.tiles))


@dataclasses.dataclass
class MapStatus(HeaderMessage):
    """The live strip map's state."""

    TOPIC: ClassVar[str] = "map/status"
    frames_imaged: int = 0
    frames_standing_still: int = 0  # no aperture to gain: left out
    frames_skipped_invalid: int = 0
    frames_dropped_behind: int = 0
    frames_lost_on_bus: int = 0  # never received: the worker's queue on the bus was full (sequence gaps)
    frames_beyond_odometry: int = 0  # at the end, frames the odometry's last pose did not reach
    frames_off_map: int = 0  # needed tiles beyond the map's max_tiles (a long drive, an odometry gone astray)
    frames_presummed_more: int = 0  # imaged with more pre-summing than configured, to catch up
    presum_factor: int = 1  # the extra pre-summing of the latest frame (1: as configured)
    frames_batched: int = 0  # imaged together with other queued frames of their radar (the same map, cheaper)
    frames_rx_summed: int = 0  # imaged with each TX's RX channels summed into one profile, to catch up
    frames_thinned: int = 0  # left out to catch up, once pre-summing and RX sums went as far as they go (one in `thinning` kept)
    thinning: int = 1  # of the latest frames: one in that many imaged (1: every frame)
    lag_s: float = 0.0  # frame reception to imaged, the latest frame
    waiting_for_poses_s: float = 0.0  # sensor time the newest frame is ahead of the odometry's newest pose
    max_lag_s: float = 0.0
    busy_s: float = 0.0  # time spent imaging
    tiles: int = 0
    tiles_refocused: int = 0  # finished tiles refocused on their strongest scatterers (--map-refocus)
    tiles_awaiting_refocus: int = 0  # finished tiles not yet refocused (at the end: every tile left as imaged)
    refocus_s: float = 0.0  # time spent refocusing finished tiles
    refocus_max_s: float = 0.0  # the longest refocus of one tile
    refocus_wait_s: float = 0.0  # finished to refocus begun, the latest tiles
    max_refocus_wait_s: float = 0.0
    tiles_without_radar_imu: int = 0  # --map-imu-aided: finished tiles whose frames no radar's own IMU covered
    stop_cut_short: int = 0  # 1: hurried at the stop (SIGTERM after worker_stop_timeout_s): queue dropped, no refocus
    time_ns: int = 0


@dataclasses.dataclass
class WorkerState(HeaderMessage):
    """A worker's state, sent every second: whether its kernels are compiled (``warm``, after
    ``warm_up_s``), and its counters (e.g. radar scans skipped because it fell behind)."""

    TOPIC: ClassVar[str] = "worker/state"
    role: str
    warm: bool
    warm_up_s: float
    counters: dict[str, int]
    #: The odometry's online calibration, where it runs one: per radar ``mount_translation_m`` [3],
    #: ``mount_rotation_xyzw`` [4], ``time_offset_s`` and ``sigma`` [7] (docs/formats/trajectory.md's axes).
    calibration: dict[str, dict] = dataclasses.field(default_factory=dict)
    time_ns: int = 0


#: Sensors silent this long are said to be idle in health (a warning; the daemon itself is fine).
IDLE_WARNING_S = 5.0
#: An IMU clock this far off the host's is no crystal's drift (tens of ppm) but a clock at another rate, as a
#: replay at another speed gives (`sarbot demo` replays at 0.5x): the health line says the rate instead.
CLOCK_RATE_NOT_DRIFT_PPM = 10_000.0


def imu_clock_text(drift_ppm: float | None) -> str:
    """An IMU clock against the host's, for a person: "clock drift +12.3 ppm", "clock drift unknown", or its
    rate where it is no drift ("clock at 0.50x host time (a replay at that speed?)")."""
    if drift_ppm is None or not math.isfinite(drift_ppm):  # a file stores "not known" as NaN
        return "clock drift unknown"
    if abs(drift_ppm) < CLOCK_RATE_NOT_DRIFT_PPM:
        return f"clock drift {drift_ppm:+.1f} ppm"
    # drift_ppm is (host clock rate / IMU clock rate - 1) * 1e6
    return f"clock at {1.0 / (1.0 + drift_ppm * 1e-6):.2f}x host time (a replay at that speed?)"


@dataclasses.dataclass
class Latency:
    """From a frame's last datagram (kernel time stamp) to the recorder, ms, over a health interval."""

    p50: float
    p99: float
    max: float


@dataclasses.dataclass
class ClockState:
    """The time bases: PTP lock per radar, whether the trigger was seen, the IMU clock's drift (ppm)."""

    ptp_locked: dict[str, bool]
    trigger_seen: bool
    imu_drift_ppm: float | None


@dataclasses.dataclass
class Health(HeaderMessage):
    """The daemon's health over its last interval (also logged and sent to systemd as STATUS)."""

    TOPIC: ClassVar[str] = "health"
    frames_per_s: dict[str, float]
    imu_hz: float
    can_frames: int
    bus_lost: int
    wire_events: int
    invalid_frames: dict[str, int]
    restarts: int
    latency_ms: Latency | None
    endpoints: dict[str, str]
    clock: ClockState
    workers: dict[str, WorkerState] = dataclasses.field(default_factory=dict)
    sensors_idle_s: float = 0.0  # since the last radar frame, IMU sample or CAN frame
    conditions: dict[str, str] = dataclasses.field(default_factory=dict)  # lasting ones, by source: what is wrong
    imu_samples_lost: int = 0  # across IMU driver restarts, so far
    #: The host's PTP state from linuxptp (acquisition.ptp.PtpStatus); None where no ptp4l is watched.
    ptp: PtpStatus | None = None
    #: Per radar: host receive time minus frame end over the recent frames (acquisition.ptp.ReceiveDelayStats).
    receive_delay: dict[str, ReceiveDelayStats] = dataclasses.field(default_factory=dict)
    #: Per radar: frames recorded while its clock said it was not PTP-locked (marked in /radar/NAME/ptp_locked).
    unlocked_frames: dict[str, int] = dataclasses.field(default_factory=dict)
    #: Per radar: which receive stamps time its frames, "hardware" (the network card's PTP hardware clock, which
    #: the receive delay is then measured with) or "software" (the kernel's, CLOCK_REALTIME).
    receive_stamp: dict[str, str] = dataclasses.field(default_factory=dict)
    #: Per radar with hardware stamps: frames whose last datagram the card left unstamped (host stamp only;
    #: left out of the receive delay, 0 in /radar/NAME/nic_time_ns).
    nic_unstamped: dict[str, int] = dataclasses.field(default_factory=dict)
    time_ns: int = 0

    @property
    def warm(self) -> bool:
        """Every worker has compiled its kernels (True without workers)."""
        return all(w.warm for w in self.workers.values())

    @classmethod
    def from_message(cls, msg: Message) -> "Health":
        fields = _fields_of(cls, msg.header)
        fields["latency_ms"] = Latency(**fields["latency_ms"]) if fields.get("latency_ms") else None
        fields["clock"] = ClockState(**fields["clock"])
        fields["workers"] = {role: WorkerState(**w) for role, w in fields.get("workers", {}).items()}
        fields["ptp"] = PtpStatus(**fields["ptp"]) if fields.get("ptp") else None
        fields["receive_delay"] = {n: ReceiveDelayStats(**d) for n, d in fields.get("receive_delay", {}).items()}
        return cls(**fields, time_ns=int(msg.sensor_time_ns))

    def line(self) -> str:
        """One line for the log and systemd's STATUS."""
        parts = [f"sensors idle for {self.sensors_idle_s:.0f} s"] if self.sensors_idle_s >= IDLE_WARNING_S else []
        parts += [f"{n} {r:.1f} frames/s" for n, r in self.frames_per_s.items()]
        parts.append(f"IMU {self.imu_hz:.0f} Hz")
        parts.append(f"IMU {imu_clock_text(self.clock.imu_drift_ppm)}")
        locks = self.clock.ptp_locked
        unlocked = [n for n, ok in locks.items() if not ok]
        if locks:
            parts.append("PTP unlocked: " + ", ".join(unlocked) if unlocked else "PTP locked")
        if self.ptp is not None:
            parts.append(self.ptp.line())
        parts += [f"{n} receive-frame end {d.median_ms:.1f} ms (p99 {d.p99_ms:.1f})" for n, d in self.receive_delay.items()]
        for source in sorted(set(self.receive_stamp.values())):
            parts.append(f"{source} receive stamps: " + ", ".join(n for n, s in self.receive_stamp.items() if s == source))
        parts += [f"{n} {k} frames without a hardware stamp" for n, k in self.nic_unstamped.items() if k]
        parts += [f"{n} {k} frames unlocked" for n, k in self.unlocked_frames.items() if k]
        if self.latency_ms:
            parts.append(f"latency p50 {self.latency_ms.p50:.1f} ms, p99 {self.latency_ms.p99:.1f} ms")
        parts.append(f"invalid frames {sum(self.invalid_frames.values())}, wire events {self.wire_events}, "
                     f"bus lost {self.bus_lost}, restarts {self.restarts}")
        if self.imu_samples_lost:
            parts.append(f"IMU samples lost {self.imu_samples_lost}")
        parts += [f"{source}: {text}" for source, text in self.conditions.items()]
        cold = [role for role, w in self.workers.items() if not w.warm]
        if self.workers:
            parts.append(f"warming up: {', '.join(cold)}" if cold else "workers warm")
        for role, w in self.workers.items():
            parts += [f"{role} {name} {n}" for name, n in w.counters.items() if n]
            parts += [f"{role} {name} time offset {c['time_offset_s'] * 1e3:+.1f} ms +- {c['sigma'][6] * 1e3:.1f}, "
                      f"lever arm +- {max(c['sigma'][3:5]) * 1e3:.1f} mm" for name, c in w.calibration.items()]
        return ", ".join(parts)


_BY_TOPIC: dict[str, type[BusMessage]] = {cls.TOPIC: cls for cls in (
    ImuBatch, CanBatch, Trigger, Event, LoggedEvent, PoseBatch, PoseEnd, MapTile, MapVelocityError, MapStatus, WorkerState, Health)}


def decode(msg: Message) -> BusMessage:
    """The typed message a bus message carries (by its topic); KeyError for a topic sarbot does not know."""
    if msg.topic.startswith(RadarFrameMessage.TOPIC):
        return RadarFrameMessage.from_message(msg)
    if msg.topic.startswith(PointCloudMessage.TOPIC):
        return PointCloudMessage.from_message(msg)
    if msg.topic.startswith(RadarImuBatch.TOPIC):
        return RadarImuBatch.from_message(msg)
    return _BY_TOPIC[msg.topic].from_message(msg)
