"""SRF1, the PTP-stamped frame protocol of the reference radar: encoding and frame reassembly.

One UDP datagram per chunk, little-endian::

    magic "SRF1" | u8 version | u8 flags (bit0: PTP locked) | u16 radar_id | u32 frame_counter
    | u64 frame_time_ns | u32 frame_bytes | u32 offset | [u32 crc32c, version 2] | payload

The payload is int16 I,Q interleaved, ordered ``[chirp][rx][sample]``; ``offset`` is the chunk's byte offset
within the frame. Version 2 adds a CRC32C (Castagnoli) over the 28 header bytes before it and the
payload, so a flipped bit is caught; version 1 (no CRC) stays readable. The assembler puts chunks in place
by offset, so reordering is harmless; bytes already received are never overwritten, and a chunk that
contradicts them (other bytes, another frame time) makes the frame invalid. Duplicates, gaps, truncated,
malformed and corrupt datagrams are counted; a frame touched by loss is zero-filled and marked invalid,
never passed on as if complete; a jump in the frame counter (a restart, a forged or corrupt counter)
larger than ``resync_jump`` resynchronises instead of filling the gap with placeholder frames.

A datagram of a frame already passed on (a late duplicate or a chunk delayed on the way) is counted as
``late_datagrams`` and dropped: it never touches a frame, and no counter is passed on twice. A sender
that restarted with a smaller counter is told from that by its frame time (newer than any seen) or by a
counter more than ``late_horizon`` behind. Counters are compared modulo 2^32, so the wrap from 2^32 - 1
to 0 is the next frame, not a restart. See docs/wire/srf1.md.
"""

from __future__ import annotations

import dataclasses
import functools
import struct
import typing

import crc32c
import numpy as np

from imaging.core.waveform import Waveform

from .registry import PackedDatagrams, WireFormat
from .stream import RadarFrame

MAGIC = b"SRF1"
VERSION = 2
VERSIONS = (1, 2)
HEADER = struct.Struct("<4sBBHIQII")  # the fields of both versions
CRC = struct.Struct("<I")  # version 2: after the fields
HEADER_V2 = struct.Struct("<4sBBHIQIII")  # version 2's fields and its CRC, unpacked in one call
FLAG_PTP_LOCKED = 0x01
_OFFSET_AT = struct.calcsize("<4sBBHIQI")  # where the header's ``offset`` field starts
#: Payload bytes per datagram so that IP (20) + UDP (8) + SRF1 header (v2) fit a 1500-byte MTU, multiple of 4.
MAX_PAYLOAD = (1500 - 20 - 8 - HEADER.size - CRC.size) // 4 * 4


def header_size(version: int) -> int:
    return HEADER.size + (CRC.size if version >= 2 else 0)


def _crc(fields, payload) -> int:
    """Version 2's CRC32C: over the header's fields (the bytes before the CRC), then the payload."""
    return crc32c.crc32c(payload, crc32c.crc32c(fields))


class Srf1Error(ValueError):
    """A datagram that is not SRF1 or contradicts itself."""


class Srf1CrcError(Srf1Error):
    """A version 2 datagram whose CRC32C does not match: bits changed on the way."""


class Srf1Header(typing.NamedTuple):
    """One datagram's header (a named tuple: one is made per datagram, 10,000 a second per radar)."""

    version: int
    flags: int
    radar_id: int
    frame_counter: int
    frame_time_ns: int
    frame_bytes: int
    offset: int

    @property
    def ptp_locked(self) -> bool:
        return bool(self.flags & FLAG_PTP_LOCKED)


def encode_frame(radar_id: int, frame_counter: int, frame_time_ns: int, iq: np.ndarray, ptp_locked: bool = True,
                 payload_bytes: int = MAX_PAYLOAD, version: int = VERSION) -> list[bytes]:
    """Datagrams of one frame; ``iq`` int16 [chirps, rx, samples, 2] (or any int16 array in wire order)."""
    return encode_frame_packed(radar_id, frame_counter, frame_time_ns, iq, ptp_locked, payload_bytes, version).split()


def encode_frame_packed(radar_id: int, frame_counter: int, frame_time_ns: int, iq: np.ndarray, ptp_locked: bool = True,
                        payload_bytes: int = MAX_PAYLOAD, version: int = VERSION) -> PackedDatagrams:
    """``encode_frame``'s datagrams back to back in one buffer (``PackedDatagrams``), built with whole-array
    copies: one header packed and copied to every datagram with its offset patched in, the payload copied
    in one strided step. What is left per datagram is its CRC32C (version 2). A ``PackedEncoder`` of its own,
    so the buffer is the caller's."""
    return PackedEncoder(radar_id, ptp_locked, payload_bytes, version)(frame_counter, frame_time_ns, iq)


class PackedEncoder:
    """Replay's SRF1 encoder: ``encode_frame_packed``'s datagrams, into one buffer kept from call to call (a
    frame's datagrams hold until the next call), and for a frame sent before without a CRC32C computed per
    datagram.

    A looped replay sends the same frames lap after lap with another counter and time. CRC32C is linear: the
    CRC of (header', payload) is that of (header, payload) xor one term that depends only on header xor
    header' and the payload's length. So the first time a frame is sent (``frame_key``: which frame it is)
    its datagrams' CRCs are kept (4 bytes a datagram); when it comes again, with the same bytes (its CRC32C
    over the whole frame, one pass, says so), they are updated by that term, one per frame, instead of
    computed again over every datagram's header and payload: the per-datagram Python work that cost more
    than the copies and the sending. A frame with other bytes under a known key is encoded afresh."""

    def __init__(self, radar_id: int, ptp_locked: bool = True, payload_bytes: int = MAX_PAYLOAD, version: int = VERSION):
        self.radar_id, self.ptp_locked, self.payload_bytes, self.version = radar_id, ptp_locked, payload_bytes, version
        self._buffer = np.empty(0, np.uint8)
        self._known: dict = {}  # frame_key -> (the frame's CRC32C, its header at offset 0, its datagrams' CRCs)
        self._zeros_crc: dict[int, int] = {}  # CRC32C of as many zero bytes as a header and a payload of a length

    def __call__(self, frame_counter: int, frame_time_ns: int, iq: np.ndarray, frame_key=None) -> PackedDatagrams:
        data = _wire_bytes(iq)
        size = _packed_size(data.size, self.payload_bytes, header_size(self.version))
        if self._buffer.size != size:
            self._buffer = np.empty(size, np.uint8)
        out = self._buffer
        head = _header(self.radar_id, frame_counter, frame_time_ns, data.size, self.ptp_locked, self.version)
        _lay_out(out, data, head, self.payload_bytes, self.version)
        if self.version >= 2:
            column = _crc_column(out, self.payload_bytes, self.version)
            frame_crc = crc32c.crc32c(data) if frame_key is not None else None
            known = self._known.get(frame_key)
            if known is not None and known[0] == frame_crc:
                column[:] = known[2] ^ self._crc_change(known[1], head, data.size)
            else:
                column[:] = _datagram_crcs(out, head, self.payload_bytes)
                if frame_key is not None:
                    self._known[frame_key] = (frame_crc, head, column.copy())
        return PackedDatagrams(out, header_size(self.version) + self.payload_bytes)

    def _crc_change(self, head_before: bytes, head: bytes, frame_bytes: int) -> np.ndarray:
        """What turns each datagram's CRC under ``head_before`` into its CRC under ``head`` (headers at offset
        0; the offsets are the same in both): crc(d xor 0..0) for d = the headers' difference followed by as
        many zeros as the datagram's payload, that is crc(d) xor crc(zeros), per payload length."""
        delta = bytes(a ^ b for a, b in zip(head_before, head))
        n_full, rest = divmod(frame_bytes, self.payload_bytes)
        change = np.empty(n_full + (rest > 0), "<u4")
        for rows, length in ((slice(0, n_full), self.payload_bytes), (slice(n_full, None), rest)):
            if length:
                zeros = self._zeros_crc.get(length)
                if zeros is None:
                    zeros = self._zeros_crc[length] = crc32c.crc32c(bytes(HEADER.size + length))
                change[rows] = crc32c.crc32c(bytes(length), crc32c.crc32c(delta)) ^ zeros
        return change


def _wire_bytes(iq: np.ndarray) -> np.ndarray:
    """The frame's bytes as they go on the wire (int16 little-endian), uint8, without a copy where it can."""
    return np.ascontiguousarray(iq, dtype="<i2").reshape(-1).view(np.uint8)


def _header(radar_id: int, frame_counter: int, frame_time_ns: int, frame_bytes: int, ptp_locked: bool,
            version: int) -> bytes:
    """The 28 header bytes before the CRC, at offset 0."""
    return HEADER.pack(MAGIC, version, FLAG_PTP_LOCKED if ptp_locked else 0, radar_id, frame_counter & 0xFFFFFFFF,
                       frame_time_ns, frame_bytes, 0)


def _packed_size(frame_bytes: int, payload_bytes: int, head_size: int) -> int:
    n_full, rest = divmod(frame_bytes, payload_bytes)
    return n_full * (head_size + payload_bytes) + (head_size + rest if rest else 0)


def _lay_out(out: np.ndarray, data: np.ndarray, head: bytes, payload_bytes: int, version: int) -> None:
    """Headers (``head`` with each datagram's offset) and payloads into ``out``, by whole-array copies; the
    CRC field is left as it was."""
    head_size = header_size(version)
    stride = head_size + payload_bytes
    n_full, rest = divmod(data.size, payload_bytes)
    full = out[:n_full * stride].reshape(n_full, stride)
    head_bytes = np.frombuffer(head, np.uint8)
    full[:, :HEADER.size] = head_bytes
    full[:, _OFFSET_AT:HEADER.size] = (np.arange(n_full, dtype="<u4") * payload_bytes).view(np.uint8).reshape(n_full, 4)
    full[:, head_size:] = data[:n_full * payload_bytes].reshape(n_full, payload_bytes)
    if rest:
        last = out[n_full * stride:]
        last[:HEADER.size] = head_bytes
        last[_OFFSET_AT:HEADER.size] = np.array([n_full * payload_bytes], "<u4").view(np.uint8)
        last[head_size:] = data[n_full * payload_bytes:]


def _crc_column(out: np.ndarray, payload_bytes: int, version: int) -> np.ndarray:
    """The CRC fields of the datagrams packed in ``out`` (version 2), as a little-endian u32 array view."""
    stride = header_size(version) + payload_bytes
    count = -(-out.size // stride)
    return np.lib.stride_tricks.as_strided(out[HEADER.size:], (count, CRC.size), (stride, 1)).view("<u4")[:, 0]


def _datagram_crcs(out: np.ndarray, head: bytes, payload_bytes: int) -> np.ndarray:
    """Every datagram's CRC32C (over its header's fields, then its payload), one at a time."""
    head_size = header_size(2)
    stride = head_size + payload_bytes
    view = memoryview(out)
    crc = crc32c.crc32c
    return np.array([crc(view[o + head_size:o + stride], crc(view[o:o + HEADER.size])) for o in range(0, out.size, stride)],
                    np.uint32)


def restamp(datagram: bytearray, frame_counter: int, frame_time_ns: int) -> None:
    """Give an encoded datagram another frame counter and time, in place, and (version 2) its CRC anew: for
    a player that sends the same frames again and again."""
    magic, version, flags, radar_id, _, _, frame_bytes, offset = HEADER.unpack_from(datagram)
    HEADER.pack_into(datagram, 0, magic, version, flags, radar_id, frame_counter & 0xFFFFFFFF, frame_time_ns,
                     frame_bytes, offset)
    if version >= 2:
        view = memoryview(datagram)
        CRC.pack_into(datagram, HEADER.size, _crc(view[:HEADER.size], view[header_size(version):]))


def parse(datagram: bytes) -> tuple[Srf1Header, memoryview]:
    """Header and payload of one datagram; Srf1Error names what is wrong."""
    if len(datagram) < HEADER.size:
        raise Srf1Error(f"datagram of {len(datagram)} bytes is shorter than the {HEADER.size}-byte header")
    magic, version, flags, radar_id, counter, t_ns, frame_bytes, offset = HEADER.unpack_from(datagram)
    if magic != MAGIC:
        raise Srf1Error(f"magic {magic!r} is not {MAGIC!r}")
    if version not in VERSIONS:
        raise Srf1Error(f"version {version} is not supported")
    size = header_size(version)
    if len(datagram) < size:
        raise Srf1Error(f"datagram of {len(datagram)} bytes is shorter than the {size}-byte version {version} header")
    payload = memoryview(datagram)[size:]
    if version >= 2:
        (want,) = CRC.unpack_from(datagram, HEADER.size)
        got = _crc(memoryview(datagram)[:HEADER.size], payload)
        if got != want:
            raise Srf1CrcError(f"CRC32C 0x{got:08x} is not the datagram's 0x{want:08x}")
    if offset + len(payload) > frame_bytes:
        raise Srf1Error(f"chunk at offset {offset} with {len(payload)} bytes overruns the {frame_bytes}-byte frame")
    return Srf1Header(version, flags, radar_id, counter, t_ns, frame_bytes, offset), payload


@dataclasses.dataclass
class Srf1Counters:
    datagrams: int = 0
    malformed: int = 0
    truncated: int = 0
    duplicates: int = 0
    reordered: int = 0
    wrong_radar: int = 0
    frames_complete: int = 0
    frames_incomplete: int = 0
    frames_skipped: int = 0  # frame counters never seen at all
    late_datagrams: int = 0  # datagrams of frames already passed on: dropped
    bytes_lost: int = 0
    resyncs: int = 0
    crc_errors: int = 0  # version 2 datagrams whose CRC32C failed: dropped
    contradictions: int = 0  # chunks whose bytes or frame time disagree with what the frame already holds


@dataclasses.dataclass
class Frame:
    """A reassembled frame: ``data`` the frame's bytes (zero where lost), ``valid`` False if any were lost."""

    frame_counter: int
    frame_time_ns: int
    data: bytearray
    valid: bool
    bytes_missing: int
    ptp_locked: bool
    last_receive_ns: int

    def iq(self, shape: tuple[int, ...]) -> np.ndarray:
        """The frame as int16 with ``shape`` (e.g. [chirps, rx, samples, 2])."""
        return np.frombuffer(bytes(self.data), dtype="<i2").reshape(shape)


class _Partial:
    """A frame being assembled. While its chunks come in order (almost always), what is here is just
    ``data[:prefix]`` and no map of received bytes is kept; the first chunk out of order builds ``have``."""

    def __init__(self, header: Srf1Header, recv_ns: int):
        self.header = header
        self.data = bytearray(header.frame_bytes)
        self.have: np.ndarray | None = None
        self.prefix = 0
        self.received = 0
        self.last_offset = -1
        self.last_recv = recv_ns
        self.contradicted = False  # a chunk disagreed with bytes already received, or with the frame time


class FrameAssembler:
    """Reassemble one radar's frames from SRF1 datagrams.

    Frames are emitted in counter order: complete ones as soon as their last byte arrives; incomplete
    ones when a frame ``window`` counters newer arrives (the rest is lost), or when the radar has sent
    nothing for ``quiet_s`` (``expire``), zero-filled and invalid. A frame of which nothing came is a
    placeholder: zero, invalid, its frame and receive times interpolated between its neighbours' on the
    counter grid (so frame times stay monotonic), and the PTP lock of the frame before it (its clock said
    nothing).

    Parameters
    ----------
    frame_bytes : int
        Expected frame size (from the waveform); datagrams that disagree count as malformed.
    radar_id : int, optional
        Datagrams of other radars are counted and ignored.
    """

    def __init__(self, frame_bytes: int, radar_id: int | None = None, window: int = 2, resync_jump: int = 16,
                 late_horizon: int = 64, quiet_s: float = 0.25):
        """A counter more than ``resync_jump`` ahead is a restart (or a corrupt counter): a resync, not that
        many placeholder frames. Up to ``resync_jump`` frames lost in a row are recorded as invalid
        placeholders, so the file shows the loss where it happened. A counter of a frame already emitted,
        up to ``late_horizon`` behind, is a late datagram (dropped) unless its frame time is newer than
        every frame time seen (the sender restarted); further behind it is a restart."""
        self.frame_bytes = frame_bytes
        self.radar_id = radar_id
        self.window = window
        self.resync_jump = resync_jump
        self.late_horizon = late_horizon
        self.counters = Srf1Counters()
        # Keyed by the counter unwrapped (it goes on past 2^32); frames carry it modulo 2^32 again.
        self._partial: dict[int, _Partial] = {}
        self._next_emit: int | None = None
        self._newest_time_ns: int | None = None  # the newest frame time of any datagram taken
        self._chunk = 0  # the largest payload seen: the sender's chunk size
        self.quiet_ns = int(quiet_s * 1e9)
        self._newest_recv_ns = 0  # the latest receive time of any datagram taken
        # The last frame passed on that a datagram came for: (counter, frame time, receive time, PTP lock),
        # and the frame interval seen between neighbours: what a placeholder's times are made from.
        self._last_real: tuple[int, int, int, bool] | None = None
        self._interval_ns = 0
        # (wire counter, unwrapped counter, frame, frame time, radar id) of the frame the last datagram went
        # on filling in order (``_in_order``), or None; ``_finish`` clears it.
        self._filling: tuple[int, int, _Partial, int, int] | None = None

    def _unwrap(self, counter: int) -> int:
        """The wire's u32 counter as the nearest integer to the next frame due (so 0 follows 2^32 - 1)."""
        if self._next_emit is None:
            return counter
        delta = ((counter - self._next_emit + 2**31) & 0xFFFFFFFF) - 2**31
        return self._next_emit + delta

    def _is_restart(self, n: int, frame_time_ns: int) -> bool:
        """For a counter behind the next frame due: did the sender start again (True), or is this a late
        datagram of a frame already passed on (False)?"""
        behind = self._next_emit - n
        if behind > self.late_horizon:
            return True
        # The frames just passed on (within ``window``) take a chunk with another time as a late one too: it
        # can no longer change them, and a sender that starts again at the counter it just sent is not likely.
        return behind > self.window and self._newest_time_ns is not None and frame_time_ns > self._newest_time_ns

    def feed(self, datagram: bytes, recv_ns: int = 0) -> list[Frame]:
        """The frames this datagram completes (or passes on as incomplete), in counter order."""
        if self._filling is not None:
            done = self._in_order(datagram, recv_ns)
            if done is not None:
                return done
        return self._feed(datagram, recv_ns)

    def _in_order(self, datagram, recv_ns: int) -> list[Frame] | None:
        """The next chunk of the frame being filled in order, with only the checks it needs; None for any
        other datagram, which ``_feed`` takes (and counts) with every check.

        Almost every datagram is this one (all of a reference frame's 498 but its first). Its frame is
        pending, so its counter is neither late nor a jump, its frame time not newer than any seen, and a
        chunk as long as the sender's is not truncated: the header's fields, the CRC and the offset are left
        to check. ``_feed`` took 2x the CPU for it (benchmarks/driver_cpu_per_frame.py)."""
        if len(datagram) < HEADER_V2.size:
            return None
        magic, version, _, radar_id, counter, time_ns, frame_bytes, offset, want = HEADER_V2.unpack_from(datagram)
        wire_counter, n, part, part_time_ns, part_radar_id = self._filling
        if (counter != wire_counter or offset != part.prefix or time_ns != part_time_ns or radar_id != part_radar_id
                or part.have is not None or version != 2 or magic != MAGIC or frame_bytes != self.frame_bytes):
            return None
        view = memoryview(datagram)
        payload = view[HEADER_V2.size:]
        size = len(payload)
        hi = offset + size
        if hi > frame_bytes or (size != self._chunk and not (hi == frame_bytes and size % 4 == 0 and size < self._chunk)):
            return None
        if crc32c.crc32c(payload, crc32c.crc32c(view[:HEADER.size])) != want:
            return None  # ``_feed`` counts it
        self.counters.datagrams += 1
        self._newest_recv_ns = max(self._newest_recv_ns, recv_ns)
        part.data[offset:hi] = payload
        part.received += size
        part.prefix, part.last_offset, part.last_recv = hi, offset, recv_ns
        if part.received >= frame_bytes:  # the frame's last byte: it and any complete ones behind it go
            self._filling = None
            return self._emit_ready(newest=n)
        return []

    def _feed(self, datagram: bytes, recv_ns: int) -> list[Frame]:
        """``feed`` with every check: any datagram."""
        self._filling = None
        c = self.counters
        c.datagrams += 1
        if len(datagram) < HEADER.size:
            c.truncated += 1
            return []
        try:
            header, payload = parse(datagram)
        except Srf1CrcError:
            c.crc_errors += 1
            return []
        except Srf1Error:
            c.malformed += 1
            return []
        if header.frame_bytes != self.frame_bytes:
            c.malformed += 1
            return []
        if self.radar_id is not None and header.radar_id != self.radar_id:
            c.wrong_radar += 1
            return []
        # A datagram cut short: a partial I/Q sample at its end, or shorter than the sender's chunks without
        # ending the frame. Its whole samples are kept; what is missing counts as lost.
        if len(payload) % 4:
            c.truncated += 1
            payload = payload[: len(payload) // 4 * 4]
        elif header.offset + len(payload) != header.frame_bytes and len(payload) < self._chunk:
            c.truncated += 1
        self._chunk = max(self._chunk, len(payload))
        n = self._unwrap(header.frame_counter)
        out: list[Frame] = []
        if self._next_emit is None:
            self._next_emit = n
        elif n < self._next_emit and not self._is_restart(n, header.frame_time_ns):
            # A frame already passed on: a late duplicate or a chunk held up on the way. Resynchronising on
            # it (as before) turned the frames being assembled into invalid partial ones and wrote the
            # counters in between a second time.
            c.late_datagrams += 1
            return out
        elif n - self._next_emit > self.resync_jump or n < self._next_emit:
            # The sender restarted or jumped: flush what is pending as incomplete and start again here.
            c.resyncs += 1
            out += self._flush_all()
            self._next_emit = n = header.frame_counter
            self._newest_time_ns = None
            self._last_real = None  # no placeholder is timed across a restart
        if self._newest_time_ns is None or header.frame_time_ns > self._newest_time_ns:
            self._newest_time_ns = header.frame_time_ns
        self._newest_recv_ns = max(self._newest_recv_ns, recv_ns)
        part = self._partial.get(n)
        if part is None:
            part = self._partial[n] = _Partial(header, recv_ns)
        lo, hi = header.offset, header.offset + len(payload)
        if part.have is None:
            if lo == part.prefix and header.frame_time_ns == part.header.frame_time_ns:
                # The next chunk in order: nothing here to overlap or contradict; a slice copy is all.
                part.data[lo:hi] = payload
                part.received += hi - lo
                part.prefix = hi
                part.last_offset = lo
                part.last_recv = recv_ns
                # Set before the frames go: ``_finish`` clears it if this one goes with them.
                self._filling = (header.frame_counter, n, part, part.header.frame_time_ns, header.radar_id)
                out += self._emit_ready(newest=n)
                return out
            part.have = np.zeros(self.frame_bytes, bool)
            part.have[:part.prefix] = True
        had = part.have[lo:hi]
        overlap = had.any()
        if header.frame_time_ns != part.header.frame_time_ns or (
                overlap and not np.array_equal(np.frombuffer(part.data, np.uint8)[lo:hi][had],
                                               np.frombuffer(payload, np.uint8)[had])):
            # The bytes already here stay; the frame can no longer be trusted to be what the radar sent.
            c.contradictions += 1
            part.contradicted = True
        if overlap and had.all():
            c.duplicates += 1
            return out
        if lo < part.last_offset:
            c.reordered += 1
        part.last_offset = max(part.last_offset, lo)
        if overlap:  # rare: a resent or overlapping chunk; only the bytes not yet here are taken
            fresh = ~had
            part.received += int(np.count_nonzero(fresh))
            np.frombuffer(part.data, np.uint8)[lo:hi][fresh] = np.frombuffer(payload, np.uint8)[fresh]
        else:  # the usual case, kept as cheap as a slice copy
            part.received += hi - lo
            part.data[lo:hi] = payload
        part.have[lo:hi] = True
        part.last_recv = recv_ns
        out += self._emit_ready(newest=n)
        return out

    def _emit_ready(self, newest: int) -> list[Frame]:
        out = []
        while self._next_emit is not None:
            k = self._next_emit
            part = self._partial.get(k)
            complete = part is not None and part.received >= self.frame_bytes
            if complete or newest - k >= self.window:
                out.append(self._finish(k))
                self._next_emit = k + 1
            else:
                break
        return out

    def _finish(self, k: int) -> Frame:
        c = self.counters
        if self._filling is not None and self._filling[1] == k:
            self._filling = None
        part = self._partial.pop(k, None)
        if part is None:
            c.frames_skipped += 1
            c.bytes_lost += self.frame_bytes
            time_ns, recv_ns, locked = self._placeholder_times(k)
            return Frame(k & 0xFFFFFFFF, time_ns, bytearray(self.frame_bytes), False, self.frame_bytes, locked, recv_ns)
        missing = self.frame_bytes - part.received
        if missing:
            c.frames_incomplete += 1
            c.bytes_lost += missing
        elif not part.contradicted:
            c.frames_complete += 1
        valid = missing == 0 and not part.contradicted
        if self._last_real is not None and self._last_real[0] == k - 1:
            self._interval_ns = part.header.frame_time_ns - self._last_real[1]
        self._last_real = (k, part.header.frame_time_ns, part.last_recv, part.header.ptp_locked)
        return Frame(k & 0xFFFFFFFF, part.header.frame_time_ns, part.data, valid, missing, part.header.ptp_locked, part.last_recv)

    def _placeholder_times(self, k: int) -> tuple[int, int, bool]:
        """Frame time, receive time and PTP lock for counter ``k``, of which no datagram came: on the line
        through the frames before and after it, or one frame interval from the nearest one (0, 0 with
        neither)."""
        before = self._last_real
        j = min((j for j in self._partial if j > k), default=None)
        after = None if j is None else (j, self._partial[j].header.frame_time_ns, self._partial[j].last_recv)
        locked = before[3] if before is not None else (j is not None and self._partial[j].header.ptp_locked)
        if before is not None and after is not None:
            w = (k - before[0]) / (after[0] - before[0])
            return (before[1] + round(w * (after[1] - before[1])), before[2] + round(w * (after[2] - before[2])),
                    locked)
        if self._interval_ns <= 0 or (before is None and after is None):
            return 0, 0, locked
        near, steps = (before, k - before[0]) if before is not None else (after, k - after[0])
        return near[1] + steps * self._interval_ns, near[2] + steps * self._interval_ns, locked

    def _flush_all(self) -> list[Frame]:
        """Everything pending, in counter order, with a placeholder for each counter between that never came."""
        out = []
        if self._partial:
            first = min(self._partial) if self._next_emit is None else min(self._next_emit, min(self._partial))
            for k in range(first, max(self._partial) + 1):
                out.append(self._finish(k))
            self._next_emit = k + 1
        return out

    def expire(self, now_ns: int) -> list[Frame]:
        """Pass on what is pending once the radar has sent nothing for ``quiet_s`` (host clock ``now_ns``,
        the receive stamps' clock): frames it left incomplete cannot be completed any more, and complete
        ones behind them would otherwise wait for its next datagram (the end of a run, seconds later)."""
        if not self._partial or not self._newest_recv_ns or now_ns - self._newest_recv_ns < self.quiet_ns:
            return []
        return self._flush_all()

    def flush(self) -> list[Frame]:
        """Emit everything still pending (end of stream)."""
        out = self._flush_all()
        self._next_emit = None
        return out


class Srf1Stream:
    """SRF1 datagrams to frames; frame time and counter come from the datagrams."""

    wire_format = "SRF1"

    def __init__(self, shape: tuple[int, int, int], radar_id: int | None = None):
        self.shape = (*shape, 2)
        self._asm = FrameAssembler(int(np.prod(self.shape)) * 2, radar_id=radar_id)
        self.counters = self._asm.counters

    def _frames(self, frames) -> list[RadarFrame]:
        return [RadarFrame(f.frame_counter, f.frame_time_ns, f.last_receive_ns, f.valid, f.bytes_missing,
                           np.frombuffer(f.data, dtype="<i2").reshape(self.shape), f.ptp_locked) for f in frames]

    def feed(self, datagram: bytes, receive_ns: int) -> list[RadarFrame]:
        frames = self._asm.feed(datagram, receive_ns)
        return self._frames(frames) if frames else frames

    def flush(self) -> list[RadarFrame]:
        return self._frames(self._asm.flush())

    def expire(self, now_ns: int) -> list[RadarFrame]:
        return self._frames(self._asm.expire(now_ns))


def _open_stream(waveform: Waveform, settings, radar_id: int | None) -> Srf1Stream:
    return Srf1Stream((waveform.chirps_per_frame, waveform.n_rx, waveform.samples_per_chirp), radar_id)


def _open_encoder(radar_id: int):
    return functools.partial(encode_frame, radar_id)


WIRE_FORMAT = WireFormat("SRF1", "PTP-stamped frame chunks (the reference radar)", _open_stream, _open_encoder,
                         open_packed_encoder=PackedEncoder)
