"""CAN through python-can: the sync box's trigger frame and the robot base's frames, recorded raw.

Any python-can interface works (``socketcan`` on the robot, ``udp_multicast`` or ``virtual`` for emulation
and tests). Frames are kept as they arrive: arbitration id, length and data, with the kernel receive time
moved onto the PTP (TAI) time base by the TAI-UTC offset. The sync box's trigger frame (``trigger_id``)
carries the PTP time of the trigger edge as a little-endian u64 in its first 8 bytes; a shorter trigger
frame is dated by its receive time.
"""

from __future__ import annotations

import dataclasses
import struct

import can
import numpy as np

from imaging.core.constants import CAN_TRIGGER_ID, TAI_MINUS_UTC_NS
from imaging.core.errors import ConfigError

#: Maximum CAN FD payload, the width of /can/data.
MAX_DATA = 64
DEFAULT_TRIGGER_ID = CAN_TRIGGER_ID


@dataclasses.dataclass(frozen=True)
class CanConfig:
    """Where the CAN bus is and which frame is the trigger.

    ``interface`` and ``channel`` are python-can's (``socketcan``/``can0``, ``udp_multicast``/a group
    address, ``virtual``/any name); ``options`` go to ``can.Bus`` as keyword arguments.
    """

    interface: str
    channel: str | None = None
    trigger_id: int | None = DEFAULT_TRIGGER_ID
    options: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.interface not in can.VALID_INTERFACES:
            raise ConfigError("can.interface", f"{self.interface!r} is not a python-can interface "
                              f"(known: {', '.join(sorted(can.VALID_INTERFACES))})")
        if self.trigger_id is not None and not 0 <= self.trigger_id < 1 << 29:
            raise ConfigError("can.trigger_id", f"{self.trigger_id} is not a CAN arbitration id")

    def open(self) -> can.BusABC:
        kwargs = dict(self.options)
        if self.channel is not None:
            kwargs["channel"] = self.channel
        return can.Bus(interface=self.interface, **kwargs)


@dataclasses.dataclass
class CanCounters:
    frames: int = 0
    error_frames: int = 0
    triggers: int = 0


@dataclasses.dataclass
class CanFrames:
    """A batch of frames as /can stores them: time_ns [K], arbitration_id [K], dlc [K], data [K, 64]."""

    time_ns: np.ndarray
    arbitration_id: np.ndarray
    dlc: np.ndarray
    data: np.ndarray

    def __len__(self) -> int:
        return int(self.time_ns.size)


def frames_from_messages(messages: list[can.Message], tai_offset_ns: int = TAI_MINUS_UTC_NS) -> CanFrames:
    k = len(messages)
    data = np.zeros((k, MAX_DATA), np.uint8)
    for i, m in enumerate(messages):
        data[i, :len(m.data)] = np.frombuffer(bytes(m.data), np.uint8)
    return CanFrames(np.array([round(m.timestamp * 1e9) + tai_offset_ns for m in messages], np.int64),
                     np.array([m.arbitration_id for m in messages], np.uint32),
                     np.array([len(m.data) for m in messages], np.uint8), data)


def trigger_time_ns(arbitration_payload: bytes, receive_time_ns: int) -> int:
    """PTP time of a trigger frame: its u64 payload if it has 8 bytes, else its receive time."""
    if len(arbitration_payload) >= 8:
        return struct.unpack_from("<Q", arbitration_payload)[0]
    return receive_time_ns


def message_from_row(arbitration_id: int, dlc: int, data: np.ndarray) -> can.Message:
    """A stored /can row back into a frame (CAN FD when longer than 8 bytes)."""
    ident, dlc = int(arbitration_id), int(dlc)
    return can.Message(arbitration_id=ident, data=bytes(data[:dlc]), is_extended_id=ident > 0x7FF, is_fd=dlc > 8)


class CanDriver:
    """Read frames from a python-can bus; a batch per call, error frames counted and left out."""

    def __init__(self, bus: can.BusABC, trigger_id: int | None = DEFAULT_TRIGGER_ID,
                 tai_offset_ns: int = TAI_MINUS_UTC_NS):
        self.bus = bus
        self.trigger_id = trigger_id
        self.tai_offset_ns = tai_offset_ns
        self.counters = CanCounters()

    def read(self, timeout_s: float = 0.1, max_frames: int = 1000) -> tuple[CanFrames, list[int]]:
        """Frames received within ``timeout_s`` (all that are waiting, up to ``max_frames``) and the PTP
        times of the trigger frames among them."""
        messages = []
        msg = self.bus.recv(timeout_s)
        while msg is not None:
            if msg.is_error_frame:
                self.counters.error_frames += 1
            else:
                messages.append(msg)
            if len(messages) >= max_frames:
                break
            msg = self.bus.recv(0.0)
        frames = frames_from_messages(messages, self.tai_offset_ns)
        self.counters.frames += len(frames)
        triggers = [trigger_time_ns(bytes(m.data), int(t)) for m, t in zip(messages, frames.time_ns)
                    if self.trigger_id is not None and m.arbitration_id == self.trigger_id]
        self.counters.triggers += len(triggers)
        return frames, triggers

    def close(self) -> None:
        self.bus.shutdown()
