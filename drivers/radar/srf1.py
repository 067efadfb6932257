"""SRF1, the PTP-stamped frame protocol of the reference radar: frame reassembly. The datagrams themselves
(layout, encoder, parser) are ``drivers.radar.srf1_datagram``'s, importable from here too.

The assembler puts chunks in place by offset, so reordering is harmless; bytes already received are never
overwritten, and a chunk that contradicts them (other bytes, another frame time) makes the frame invalid.
Duplicates, gaps, truncated, malformed and corrupt datagrams are counted; a frame touched by loss is
zero-filled and marked invalid, never passed on as if complete; a jump in the frame counter (a restart, a
forged or corrupt counter) larger than ``resync_jump`` resynchronises instead of filling the gap with
placeholder frames.

A datagram of a frame already passed on (a late duplicate or a chunk delayed on the way) is counted as
``late_datagrams`` and dropped: it never touches a frame, and no counter is passed on twice. A sender
that restarted with a smaller counter is told from that by its frame time (newer than any seen) or by a
counter more than ``late_horizon`` behind. Counters are compared modulo 2^32, so the wrap from 2^32 - 1
to 0 is the next frame, not a restart. See docs/wire/srf1.md.
"""

from __future__ import annotations

import dataclasses
import functools

import crc32c
import numpy as np

from imaging.core.waveform import Waveform

from .registry import PackedDatagrams, WireFormat  # noqa: F401 - PackedDatagrams re-exported
from .srf1_datagram import (  # noqa: F401 - the datagram's names, re-exported: they were this module's
    CRC,
    FLAG_PTP_LOCKED,
    HEADER,
    HEADER_V2,
    MAGIC,
    MAX_PAYLOAD,
    VERSION,
    VERSIONS,
    PackedEncoder,
    Srf1CrcError,
    Srf1Error,
    Srf1Header,
    _crc,
    encode_frame,
    encode_frame_packed,
    chunk_header_words,
    header_words,
    header_size,
    parse,
    payload_seeds,
    restamp,
)
from .stream import RadarFrame, feed_in_runs

#: The fewest datagrams ``FrameAssembler.feed_segments`` takes as one run; fewer go through ``feed``. A run
#: costs ~20 us of numpy calls besides ~1 us a datagram, ``feed``'s in-order path ~4 us a datagram
#: (benchmarks/stream_segments.py, loaded: runs of 8 were 0.63-1.06x feed's CPU, of 4 1.5x more, of 16 1.7x
#: less).
_MIN_RUN = 12

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
        # Once a batch of its datagrams comes (``FrameAssembler._in_order_run``): (chunk size, the headers its
        # chunks must have as u32 words [chunks, 7], their CRC32C seeds or None (version 1), ``data`` as numpy).
        self.runs: tuple | None = None


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

    def feed_segments(self, buffer, segment_bytes: int, recv_ns: int = 0) -> list[Frame]:
        """``feed`` of every datagram of a batch received in one go (UDP GRO), with the same result: the same
        frames, bytes and counters as feeding them one by one in order.

        Runs of the frame being filled in order (``_in_order``'s datagrams) are taken at once by
        ``_in_order_run``; any other datagram (a frame's first or last, a gap, a bad CRC, ...) goes through
        ``feed``, after which the next run is tried.

        Parameters
        ----------
        buffer : bytes-like
            The datagrams back to back, each ``segment_bytes`` long but the last (1 to ``segment_bytes``
            bytes). Not kept: the receiver reuses it.
        segment_bytes : int
            Bytes of every datagram but the last (> 0).
        recv_ns : int
            The batch's receive time (host clock, ns), every datagram's.

        Returns
        -------
        list[Frame]
            The frames the batch completes or gives up, in order.
        """
        return feed_in_runs(buffer, segment_bytes, recv_ns, self.feed, self._in_order_run, _MIN_RUN)

    def _in_order_run(self, view: memoryview, segment_bytes: int, first: int, available: int,
                      recv_ns: int) -> tuple[int, list[Frame]]:
        """How many of the ``available`` full-size datagrams from the ``first``-th on are the next chunks
        of the frame being filled in order, each as ``feed`` would take it, taken at once; and the frames
        that go. Stops before the first that is not (``feed`` takes that one).

        A datagram is taken if its header is the frame's (magic, version, flags, radar, counter, time,
        frame size) with the next offset in order, its payload as long as the sender's chunks and inside
        the frame, and (version 2) its CRC32C right: stricter than ``_in_order`` (the flags too), so every
        datagram taken is one ``feed`` takes the same way. What the frame's chunks must hold is made once
        a frame (``_Partial.runs``); per batch the headers are compared as one array, the CRC32C is one call
        a datagram, and the payloads go into the frame in one strided copy."""
        if self._filling is None:  # no frame being filled in order: ``feed`` takes the next
            return 0, []
        wire_counter, n, part, time_ns, radar_id = self._filling
        head = part.header
        size = segment_bytes - header_size(head.version)
        if part.have is not None or size != self._chunk or segment_bytes < HEADER_V2.size or part.prefix % size:
            return 0, []
        runs = part.runs
        if runs is None or runs[0] != size:
            fields = HEADER.pack(MAGIC, head.version, head.flags, radar_id, wire_counter, time_ns, self.frame_bytes, 0)
            expected = chunk_header_words(fields, size, self.frame_bytes // size)  # the chunks inside the frame
            seeds = payload_seeds(fields, expected[:, 6]).tolist() if head.version >= 2 else None
            runs = part.runs = (size, expected, seeds, np.frombuffer(part.data, np.uint8))
        _, expected, seeds, data = runs
        j = part.prefix // size
        count = min(available, len(expected) - j)
        if count <= 0:
            return 0, []
        words = header_words(view, segment_bytes, first, count)
        same = words[:, :7] == expected[j:j + count]
        take = count if same.all() else int(np.argmin(same.all(axis=1)))
        if take and seeds is not None:
            payloads = np.ndarray((take, size), np.uint8, view, first * segment_bytes + segment_bytes - size,
                                  (segment_bytes, 1))
            wrong = np.fromiter(map(crc32c.crc32c, payloads, seeds[j:j + take]), np.uint32, take) != words[:take, 7]
            if wrong.any():
                take = int(np.argmax(wrong))
        if not take:
            return 0, []
        lo, hi = part.prefix, part.prefix + take * size
        data[lo:hi].reshape(take, size)[...] = np.ndarray((take, size), np.uint8, view,
                                                          first * segment_bytes + segment_bytes - size, (segment_bytes, 1))
        self.counters.datagrams += take
        self._newest_recv_ns = max(self._newest_recv_ns, recv_ns)
        part.received += hi - lo
        part.prefix, part.last_offset, part.last_recv = hi, hi - size, recv_ns
        if part.received >= self.frame_bytes:  # its last byte: it and any complete ones behind it go
            if seeds is not None:  # as ``_in_order`` leaves it; ``_feed`` (version 1) leaves it to ``_finish``
                self._filling = None
            return take, self._emit_ready(newest=n)
        return take, []

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

    def feed_segments(self, buffer, segment_bytes: int, receive_ns: int) -> list[RadarFrame]:
        """``feed`` of every datagram of a batch (``FrameAssembler.feed_segments``): the datagrams back to back
        in ``buffer``, each ``segment_bytes`` long but the last, all received at ``receive_ns``."""
        frames = self._asm.feed_segments(buffer, segment_bytes, receive_ns)
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
