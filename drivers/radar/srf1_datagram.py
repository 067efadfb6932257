"""SRF1 datagrams, the PTP-stamped frame protocol of the reference radar: their layout, making them and reading
them. The frames they carry are put back together by ``drivers.radar.srf1``.

One UDP datagram per chunk, little-endian::

    magic "SRF1" | u8 version | u8 flags (bit0: PTP locked) | u16 radar_id | u32 frame_counter
    | u64 frame_time_ns | u32 frame_bytes | u32 offset | [u32 crc32c, version 2] | payload

The payload is int16 I,Q interleaved, ordered ``[chirp][rx][sample]``; ``offset`` is the chunk's byte offset
within the frame. Version 2 adds a CRC32C (Castagnoli) over the 28 header bytes before it and the
payload, so a flipped bit is caught; version 1 (no CRC) stays readable. See docs/wire/srf1.md.
"""

from __future__ import annotations

import struct
import typing

import crc32c
import numpy as np

from .registry import PackedDatagrams

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



# Batches of datagrams received back to back (UDP GRO): their headers read and their CRCs checked at once.

def header_words(buffer, segment_bytes: int, first: int, count: int) -> np.ndarray:
    """u32 [count, 8] over ``buffer`` (no copy): the first 32 bytes of ``count`` datagrams of ``segment_bytes``
    bytes each, packed back to back, from the ``first``-th on. Words 0-6 are the header up to ``offset``
    (magic; version, flags and radar_id; counter; frame time low and high; frame_bytes; offset), word 7 version
    2's CRC (a version 1 datagram's first payload bytes). ``segment_bytes`` must be at least 32."""
    return np.ndarray((count, 8), "<u4", buffer, first * segment_bytes, (segment_bytes, 4))


def chunk_header_words(fields: bytes, chunk_bytes: int, n_chunks: int) -> np.ndarray:
    """u32 [n_chunks, 7]: words 0-6 of ``header_words`` for chunks 0 .. n_chunks - 1 of ``chunk_bytes`` each
    of the frame whose header ``fields`` (the 28 bytes, any offset) are: what a frame's datagrams in order
    must hold."""
    words = np.tile(np.frombuffer(fields, "<u4"), (n_chunks, 1))
    words[:, 6] = np.arange(n_chunks, dtype=np.uint32) * chunk_bytes
    return words


def _offset_tables() -> np.ndarray:
    """u32 [4, 256]: M(d) for 4 bytes ``d`` that are zero but byte k, ``table[k, byte]``. CRC32C carried on
    from a running value ``v`` over 4 bytes ``d`` is crc32c(0000, v) xor M(d) with M linear and the same for
    every ``v`` (``d`` is xored into the state, which then goes through four linear steps), so M(d) is the
    xor of ``table[k, d_k]`` over k."""
    zeros = crc32c.crc32c(bytes(4))
    return np.array([[crc32c.crc32c(bytes(k) + bytes([b]) + bytes(3 - k)) ^ zeros for b in range(256)]
                     for k in range(4)], np.uint32)


_OFFSET_TABLES = _offset_tables()


def payload_seeds(fields: bytes, offsets: np.ndarray) -> np.ndarray:
    """CRC32C of each header ``fields`` (the 28 bytes before the CRC) with its ``offset`` set to each of
    ``offsets`` (u32), without a call per offset: the running CRC32C its payload is to be checked from
    (``crc32c(payload, seed)`` is then version 2's CRC). The offset is the last of the 28 bytes, so every seed
    is the CRC of the 24 bytes before it carried on over the 4 offset bytes."""
    carried = crc32c.crc32c(bytes(4), crc32c.crc32c(fields[:_OFFSET_AT]))
    o = offsets.astype(np.uint32)
    t = _OFFSET_TABLES
    return carried ^ t[0][o & 0xFF] ^ t[1][(o >> 8) & 0xFF] ^ t[2][(o >> 16) & 0xFF] ^ t[3][o >> 24]
