"""Xsens Xbus / MTData2 over serial: message framing, checksum, streaming parser with resynchronisation.

A message is ``FA FF MID LEN data CS`` (``LEN == 0xFF``: a 16-bit big-endian length follows). The checksum
byte makes the sum of every byte after the preamble ``FA`` zero modulo 256. MTData2 (MID 0x36) data is a
sequence of items ``XDI (u16 BE) | size (u8) | payload``, big-endian throughout. The items sarbot uses:
packet counter, fine sample time (10 kHz ticks), acceleration, rate of turn and the status word, whose bit
21 marks a SyncIn trigger edge.
"""

from __future__ import annotations

import dataclasses
import struct

PREAMBLE = 0xFA
BUS_ID = 0xFF
MID_MTDATA2 = 0x36

XDI_PACKET_COUNTER = 0x1020
XDI_SAMPLE_TIME_FINE = 0x1060
XDI_ACCELERATION = 0x4020
XDI_RATE_OF_TURN = 0x8020
XDI_STATUS_WORD = 0xE020
STATUS_SYNC_IN = 1 << 21
SAMPLE_TIME_FINE_HZ = 10_000
MAX_PAYLOAD = 2048  # longer "messages" are noise that happens to contain FA FF


class XbusError(ValueError):
    """A malformed message (bad checksum, bad length, unknown layout)."""


def checksum(body: bytes) -> int:
    """The checksum byte for ``body`` = BID MID LEN... data (everything after the preamble but the checksum)."""
    return (-sum(body)) & 0xFF


def encode_message(mid: int, data: bytes) -> bytes:
    """One Xbus message."""
    if len(data) < 0xFF:
        body = bytes([BUS_ID, mid, len(data)]) + data
    else:
        body = bytes([BUS_ID, mid, 0xFF]) + struct.pack(">H", len(data)) + data
    return bytes([PREAMBLE]) + body + bytes([checksum(body)])


@dataclasses.dataclass
class ImuPacket:
    """One decoded MTData2 sample (SI units, sensor frame)."""

    counter: int | None = None
    sample_time_fine: int | None = None
    accel_mps2: tuple[float, float, float] | None = None
    gyro_radps: tuple[float, float, float] | None = None
    status: int | None = None

    @property
    def sync_in(self) -> bool:
        return self.status is not None and bool(self.status & STATUS_SYNC_IN)


def encode_mtdata2(packet: ImuPacket) -> bytes:
    """MTData2 message carrying the fields of ``packet`` that are set."""
    items = b""
    if packet.counter is not None:
        items += struct.pack(">HBH", XDI_PACKET_COUNTER, 2, packet.counter & 0xFFFF)
    if packet.sample_time_fine is not None:
        items += struct.pack(">HBI", XDI_SAMPLE_TIME_FINE, 4, packet.sample_time_fine & 0xFFFFFFFF)
    if packet.accel_mps2 is not None:
        items += struct.pack(">HB3f", XDI_ACCELERATION, 12, *packet.accel_mps2)
    if packet.gyro_radps is not None:
        items += struct.pack(">HB3f", XDI_RATE_OF_TURN, 12, *packet.gyro_radps)
    if packet.status is not None:
        items += struct.pack(">HBI", XDI_STATUS_WORD, 4, packet.status)
    return encode_message(MID_MTDATA2, items)


def decode_mtdata2(data: bytes) -> ImuPacket:
    """Items of an MTData2 payload; unknown items are skipped, truncated ones are an error."""
    out = ImuPacket()
    i = 0
    while i < len(data):
        if i + 3 > len(data):
            raise XbusError(f"MTData2 item header cut at byte {i} of {len(data)}")
        xdi, size = struct.unpack_from(">HB", data, i)
        i += 3
        if i + size > len(data):
            raise XbusError(f"MTData2 item 0x{xdi:04X} needs {size} bytes, {len(data) - i} left")
        payload = data[i:i + size]
        i += size
        kind = xdi & 0xFFF0  # low bits select coordinate system / number format; float32 only here
        if kind == XDI_PACKET_COUNTER and size == 2:
            out.counter = struct.unpack(">H", payload)[0]
        elif kind == XDI_SAMPLE_TIME_FINE and size == 4:
            out.sample_time_fine = struct.unpack(">I", payload)[0]
        elif kind == XDI_ACCELERATION and size == 12:
            out.accel_mps2 = struct.unpack(">3f", payload)
        elif kind == XDI_RATE_OF_TURN and size == 12:
            out.gyro_radps = struct.unpack(">3f", payload)
        elif kind == XDI_STATUS_WORD and size == 4:
            out.status = struct.unpack(">I", payload)[0]
    return out


@dataclasses.dataclass
class XbusCounters:
    messages: int = 0
    checksum_errors: int = 0
    length_errors: int = 0
    decode_errors: int = 0
    bytes_skipped: int = 0
    resyncs: int = 0
    counter_gaps: int = 0
    packets_missed: int = 0


class XbusParser:
    """Streaming parser: feed any chunks of bytes, get complete MTData2 packets.

    Byte-level resynchronisation: anything before a preamble is skipped and counted; a message whose
    checksum fails costs one byte (the search restarts after its preamble), so a packet cut in the middle
    by noise loses only that packet. Packet-counter gaps are counted (the counter wraps at 2^16).
    """

    def __init__(self):
        self.buffer = bytearray()
        self.counters = XbusCounters()
        self._last_counter: int | None = None
        self._in_sync = True

    def feed(self, chunk: bytes) -> list[ImuPacket]:
        self.buffer.extend(chunk)
        out: list[ImuPacket] = []
        buf = self.buffer
        c = self.counters
        while True:
            start = buf.find(bytes([PREAMBLE, BUS_ID]))
            if start < 0:
                # Keep a trailing FA: it may be the first byte of the next message.
                keep = 1 if buf and buf[-1] == PREAMBLE else 0
                skipped = len(buf) - keep
                if skipped:
                    self._skip(skipped)
                break
            if start:
                self._skip(start)
                continue
            if len(buf) < 4:
                break
            mid, length = buf[2], buf[3]
            header = 4
            if length == 0xFF:
                if len(buf) < 6:
                    break
                length = struct.unpack_from(">H", buf, 4)[0]
                header = 6
            if length > MAX_PAYLOAD:
                c.length_errors += 1
                self._skip(1)
                continue
            total = header + length + 1
            if len(buf) < total:
                break
            if sum(buf[1:total]) & 0xFF:
                c.checksum_errors += 1
                self._skip(1)
                continue
            data = bytes(buf[header:header + length])
            del buf[:total]
            self._in_sync = True
            c.messages += 1
            if mid != MID_MTDATA2:
                continue
            try:
                packet = decode_mtdata2(data)
            except XbusError:
                c.decode_errors += 1
                continue
            self._check_counter(packet)
            out.append(packet)
        return out

    def _skip(self, n: int) -> None:
        del self.buffer[:n]
        self.counters.bytes_skipped += n
        if self._in_sync:
            self.counters.resyncs += 1
            self._in_sync = False

    def _check_counter(self, packet: ImuPacket) -> None:
        if packet.counter is None:
            return
        if self._last_counter is not None:
            missed = (packet.counter - self._last_counter - 1) & 0xFFFF
            if missed:
                self.counters.counter_gaps += 1
                self.counters.packets_missed += missed
        self._last_counter = packet.counter
