"""TI DCA1000EVM raw ADC capture: the UDP data stream and its layout.

Data datagrams (UDP port 4098): ``u32 LE sequence | 48-bit LE byte count | int16 LE samples``. The byte
count is the stream offset of the datagram's first sample, so datagrams are placed by it: packets are not
aligned to frames, and a lost datagram leaves a gap of exactly its size, which is zero-filled; every frame
it touches is marked invalid. Frames are ``TiRadarConfig.frame_bytes`` long, back to back.

Sample layout of the xWR18xx in complex 1x mode (``ti_capture`` layout ``lvds2``): per chirp, per RX,
samples in pairs as four int16 words ``Q0 Q1 I0 I1`` with ``adcbufCfg``'s SampleSwap set (TI's default;
this reproduces the reference values of the mmwave-capture-std test capture), ``I0 I1 Q0 Q1`` without.
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np

from imaging.core.errors import ConfigError
from imaging.core.samples import iq_to_complex
from imaging.core.waveform import Waveform

from .registry import WireFormat
from .stream import RadarFrame, feed_in_runs
from .ti_capture import capture_to_iq, iq_to_capture
from .ti_cfg import TiRadarConfig, load_ti_cfg

DATA_PORT = 4098
CONFIG_PORT = 4096
HEADER_BYTES = 10
#: The fewest datagrams ``Dca1000Assembler.feed_segments`` takes as one run; fewer go through ``feed``, whose
#: ``have`` checks cost ~20 us a datagram (benchmarks/stream_segments.py: batches of 3 already pay, of 2 not).
_MIN_RUN = 3


class Dca1000Error(ValueError):
    pass


def parse_data_packet(payload: bytes) -> tuple[int, int, memoryview]:
    """(sequence, byte count, samples) of one data datagram."""
    if len(payload) < HEADER_BYTES:
        raise Dca1000Error(f"datagram of {len(payload)} bytes is shorter than the {HEADER_BYTES}-byte header")
    seq = struct.unpack_from("<I", payload)[0]
    byte_count = int.from_bytes(payload[4:10], "little")
    return seq, byte_count, memoryview(payload)[HEADER_BYTES:]


def encode_data_packets(stream: bytes, start_seq: int = 1, start_byte: int = 0, payload_bytes: int = 1456) -> list[bytes]:
    """Datagrams carrying ``stream`` the way the DCA1000 sends it (for emulation and tests)."""
    out = []
    for k, off in enumerate(range(0, len(stream), payload_bytes)):
        head = struct.pack("<I", start_seq + k) + (start_byte + off).to_bytes(6, "little")
        out.append(head + stream[off:off + payload_bytes])
    return out


def decode_complex_1x(frame: bytes | np.ndarray, chirps: int, n_rx: int, samples: int) -> np.ndarray:
    """complex64 [chirps, n_rx, samples] from the xWR18xx complex-1x byte layout (Q0 Q1 I0 I1 words)."""
    return iq_to_complex(complex_1x_to_iq(frame, chirps, n_rx, samples))


@dataclasses.dataclass
class Dca1000Counters:
    datagrams: int = 0
    malformed: int = 0
    duplicates: int = 0
    reordered: int = 0
    sequence_gaps: int = 0
    bytes_lost: int = 0
    frames_complete: int = 0
    frames_incomplete: int = 0
    resyncs: int = 0
    frames_skipped: int = 0  # whole frames jumped over by a resync (never emitted)


@dataclasses.dataclass
class RawFrame:
    index: int  # frame number counted from the start of the stream
    data: bytearray
    valid: bool
    bytes_missing: int
    first_receive_ns: int


class Dca1000Assembler:
    """Cut the DCA1000 byte stream into frames by byte count, whatever the datagram boundaries."""

    def __init__(self, frame_bytes: int, window_bytes: int | None = None, max_gap_frames: int = 64):
        """A datagram more than ``max_gap_frames`` frames ahead of the stream is a jump (a restarted
        capture, a corrupt byte count): pending frames are emitted and the stream resynchronises there."""
        self.max_gap_frames = max_gap_frames
        self.frame_bytes = frame_bytes
        self.window = window_bytes or 2 * frame_bytes  # how far the stream may run ahead of a frame
        self.counters = Dca1000Counters()
        self._frames: dict[int, tuple[bytearray, np.ndarray, int]] = {}
        self._next_emit = 0
        self._max_end = 0
        self._last_seq: int | None = None

    def feed(self, payload: bytes, recv_ns: int = 0) -> list[RawFrame]:
        c = self.counters
        c.datagrams += 1
        try:
            seq, start, data = parse_data_packet(payload)
        except Dca1000Error:
            c.malformed += 1
            return []
        if len(data) % 2:
            c.malformed += 1
            data = data[:-1]
        if self._last_seq is not None:
            if seq == self._last_seq:
                c.duplicates += 1
                return []
            if seq < self._last_seq:
                c.reordered += 1
            elif seq > self._last_seq + 1:
                c.sequence_gaps += 1
        self._last_seq = max(seq, self._last_seq or 0)
        end = start + len(data)
        out: list[RawFrame] = []
        first_frame = start // self.frame_bytes
        if first_frame - max(self._next_emit, self._max_end // self.frame_bytes) > self.max_gap_frames:
            c.resyncs += 1
            out += self.flush()
            c.frames_skipped += max(first_frame - self._next_emit, 0)
            self._frames.clear()
            self._next_emit = first_frame
            self._max_end = start
        if end <= self._next_emit * self.frame_bytes:
            c.duplicates += 1  # belongs to frames already emitted
            return out
        pos = start
        while pos < end:
            k = pos // self.frame_bytes
            lo = pos - k * self.frame_bytes
            n = min(end - pos, self.frame_bytes - lo)
            if k >= self._next_emit:
                buf, have, first = self._frames.get(k) or (bytearray(self.frame_bytes), np.zeros(self.frame_bytes, bool), recv_ns)
                seg = slice(lo, lo + n)
                if have[seg].all():
                    c.duplicates += 1
                else:
                    buf[seg] = data[pos - start:pos - start + n]
                    have[seg] = True
                self._frames[k] = (buf, have, first)
            pos += n
        self._max_end = max(self._max_end, end)
        return out + self._emit()

    def feed_segments(self, buffer, segment_bytes: int, recv_ns: int = 0) -> list[RawFrame]:
        """``feed`` of every datagram of a batch received in one go (UDP GRO), with the same result: the same
        frames, bytes and counters as feeding them one by one in order.

        Runs of datagrams that carry on the stream where it stands (``_contiguous_run``) are taken at once;
        any other datagram goes through ``feed``, after which the next run is tried.

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
        list[RawFrame]
            The frames the batch completes or gives up, in order.
        """
        return feed_in_runs(buffer, segment_bytes, recv_ns, self.feed, self._contiguous_run, _MIN_RUN)

    def _contiguous_run(self, view: memoryview, segment_bytes: int, first: int, available: int,
                        recv_ns: int) -> tuple[int, list[RawFrame]]:
        """How many of the ``available`` full-size datagrams from the ``first``-th on carry on the stream
        where it stands, each as ``feed`` would take it, taken at once; and the frames that go. Stops
        before the first that does not (``feed`` takes that one).

        A datagram is taken if its sequence number is the next and its byte count the stream's end so far
        (``_max_end``): no gap, duplicate, reordering or jump, and its bytes new (nothing at or past
        ``_max_end`` has been received). Its frames are filled one copy and one ``have`` mark a frame, and
        frames are passed on once, after the run: what goes after each datagram goes after the last, in
        the same order, as nothing the run does can hold a frame back."""
        if self._last_seq is None:  # no stream to carry on yet: ``feed`` takes the next
            return 0, []
        size = segment_bytes - HEADER_BYTES
        start = self._max_end
        if size <= 0 or size % 2 or start < self._next_emit * self.frame_bytes:
            return 0, []
        at = first * segment_bytes
        steps = np.arange(available, dtype=np.int64)
        counts = start + size * steps
        same = ((np.ndarray(available, "<u4", view, at, (segment_bytes,)) == self._last_seq + 1 + steps)
                & (np.ndarray(available, "<u4", view, at + 4, (segment_bytes,)) == counts & 0xFFFFFFFF)
                & (np.ndarray(available, "<u2", view, at + 8, (segment_bytes,)) == counts >> 32))
        take = available if same.all() else int(np.argmin(same))
        if not take:
            return 0, []
        rows = np.ndarray((take, size), np.uint8, view, at + HEADER_BYTES, (segment_bytes, 1))
        end = start + take * size
        pos = start
        while pos < end:
            k = pos // self.frame_bytes
            lo = pos - k * self.frame_bytes
            n = min(end - pos, self.frame_bytes - lo)
            buf, have, first_ns = self._frames.get(k) or (bytearray(self.frame_bytes), np.zeros(self.frame_bytes, bool),
                                                          recv_ns)
            _copy_rows(rows, pos - start, np.frombuffer(buf, np.uint8)[lo:lo + n])
            have[lo:lo + n] = True
            self._frames[k] = (buf, have, first_ns)
            pos += n
        self.counters.datagrams += take
        self._last_seq += take
        self._max_end = end
        return take, self._emit()

    def _emit(self) -> list[RawFrame]:
        out = []
        while True:
            k = self._next_emit
            entry = self._frames.get(k)
            frame_end = (k + 1) * self.frame_bytes
            complete = entry is not None and entry[1].all()
            if not (complete or self._max_end - frame_end >= self.window):
                break
            out.append(self._pop_next())
        return out

    def _pop_next(self) -> RawFrame:
        """Emit the next frame in order (zero-filled where bytes are missing) and count it."""
        k = self._next_emit
        buf, have, first = self._frames.pop(k, (bytearray(self.frame_bytes), np.zeros(self.frame_bytes, bool), 0))
        missing = int(self.frame_bytes - have.sum())
        if missing:
            self.counters.frames_incomplete += 1
            self.counters.bytes_lost += missing
        else:
            self.counters.frames_complete += 1
        self._next_emit += 1
        return RawFrame(k, buf, missing == 0, missing, first)

    def flush(self) -> list[RawFrame]:
        """Emit everything pending in order (end of capture, or before a resync): frames with holes
        zero-filled and invalid, frames never seen between them empty and invalid."""
        out = []
        while self._frames:
            out.append(self._pop_next())
        return out


def _copy_rows(rows: np.ndarray, start: int, out: np.ndarray) -> None:
    """``out`` (u8, contiguous) gets ``out.size`` bytes of ``rows`` (u8 [n, size], one datagram's payload a
    row) read as one stream from byte ``start`` on: a partial row, whole rows in one strided copy, a partial
    row."""
    size = rows.shape[1]
    row, col = divmod(start, size)
    done = 0
    if col:
        done = min(size - col, out.size)
        out[:done] = rows[row, col:col + done]
        row += 1
    whole = (out.size - done) // size
    if whole:
        out[done:done + whole * size].reshape(whole, size)[...] = rows[row:row + whole]
        done += whole * size
        row += whole
    if done < out.size:
        out[done:] = rows[row, :out.size - done]


def complex_1x_to_iq(frame: bytes | np.ndarray, chirps: int, n_rx: int, samples: int, iq_swap: bool = True) -> np.ndarray:
    """int16 [chirps, n_rx, samples, 2] (I, Q) from the complex-1x byte layout, without going through floats."""
    words = np.frombuffer(bytes(frame), dtype="<i2")
    if words.size != 2 * chirps * n_rx * samples:
        raise Dca1000Error(f"{words.size // 2} complex samples do not fill [{chirps}, {n_rx}, {samples}]")
    return capture_to_iq(words, "lvds2", chirps, n_rx, samples, iq_swap)[0]


def iq_to_complex_1x(iq: np.ndarray, iq_swap: bool = True) -> bytes:
    """The inverse of :func:`complex_1x_to_iq`: int16 [..., samples, 2] (even sample count) to wire bytes."""
    iq = np.asarray(iq, np.int16)
    return iq_to_capture(iq.reshape(-1, 1, 1, iq.shape[-2], 2), "lvds2", iq_swap).tobytes()


class Dca1000Stream:
    """DCA1000 raw byte stream to frames, laid out by the TI ``.cfg``.

    The DCA1000 sends no time stamps and no frame counter: the counter is the frame's index in the stream
    and its time the receipt of its first datagram -- the kernel's stamp here (put on the PTP base by the host
    clock), the network card's where the driver takes hardware stamps (``times_by_receipt``: the driver loop
    replaces it, ``drivers.radar.timestamping.CardFrameTimes``).
    """

    wire_format = "DCA1000"
    times_by_receipt = True

    def __init__(self, cfg: TiRadarConfig):
        if not cfg.complex_output:
            raise ValueError("only complex ADC output (adcCfg/adcbufCfg complex 1x) is supported for DCA1000 streams")
        self.cfg = cfg
        self._asm = Dca1000Assembler(cfg.frame_bytes)
        self.counters = self._asm.counters

    def _frames(self, frames) -> list[RadarFrame]:
        c = self.cfg
        return [RadarFrame(f.index, f.first_receive_ns, f.first_receive_ns, f.valid, f.bytes_missing,
                           complex_1x_to_iq(f.data, c.chirps_per_frame, c.n_rx, c.adc_samples, c.iq_swap)) for f in frames]

    def feed(self, datagram: bytes, receive_ns: int) -> list[RadarFrame]:
        return self._frames(self._asm.feed(datagram, receive_ns))

    def feed_segments(self, buffer, segment_bytes: int, receive_ns: int) -> list[RadarFrame]:
        """``feed`` of every datagram of a batch (``Dca1000Assembler.feed_segments``): the datagrams back to
        back in ``buffer``, each ``segment_bytes`` long but the last, all received at ``receive_ns``."""
        return self._frames(self._asm.feed_segments(buffer, segment_bytes, receive_ns))

    def flush(self) -> list[RadarFrame]:
        return self._frames(self._asm.flush())


class Dca1000Encoder:
    """Frames to the DCA1000's byte stream: sequence numbers and byte counts run on across frames."""

    def __init__(self, iq_swap: bool = True):
        self.sequence = 1
        self.stream_bytes = 0
        self.iq_swap = iq_swap  # TI's default; a recording does not keep its radar's adcbufCfg

    def __call__(self, frame_counter: int, frame_time_ns: int, iq: np.ndarray) -> list[bytes]:
        wire = iq_to_complex_1x(iq, self.iq_swap)
        datagrams = encode_data_packets(wire, start_seq=self.sequence, start_byte=self.stream_bytes)
        self.sequence += len(datagrams)
        self.stream_bytes += len(wire)
        return datagrams


def _configure(options: dict[str, str], where: str) -> TiRadarConfig:
    unknown = set(options) - {"cfg"}
    if unknown:
        raise ConfigError(f"{where}.{sorted(unknown)[0]}", "unknown option (DCA1000 takes cfg=FILE)")
    if "cfg" not in options:
        raise ConfigError(f"{where}.cfg", "a DCA1000 radar needs its TI .cfg file (cfg=FILE)")
    cfg = load_ti_cfg(Path(options["cfg"]))
    if not cfg.complex_output:
        raise ConfigError(f"{where}.cfg", f"{options['cfg']}: only complex ADC output (adcCfg complex 1x) is supported")
    return cfg


def _waveform(cfg: TiRadarConfig) -> Waveform:
    return cfg.waveform()


def _open_stream(waveform: Waveform, cfg: TiRadarConfig, radar_id: int | None) -> Dca1000Stream:
    return Dca1000Stream(cfg)


def _open_encoder(radar_id: int) -> Dca1000Encoder:
    return Dca1000Encoder()


def _arm_option(text: str) -> dict:
    """``--dca1000-arm NAME[=HOST[:PORT]][,listen=...][,lanes=...][,delay_us=...]``: sarbot arms the card."""
    from .ti_arming import parse_arm_option

    return parse_arm_option(text)[1]


def _radar_cli_option(text: str) -> dict:
    """``--radar-cli NAME=DEVICE``: sarbot configures and starts the radar over its CLI serial port."""
    name, sep, device = text.partition("=")
    if not (name and sep and device):
        raise ValueError("expected NAME=DEVICE")
    if not Path(device).exists():
        raise ValueError(f"no such device {device}")
    return {"cli_port": device}


def _controls(link, settings: dict) -> list:
    """One ``TiRadarControl`` driving what the options asked for: the card, the radar's CLI, or both."""
    from .ti_arming import TiRadarControl

    return [TiRadarControl(link.name, str(link.options["cfg"]), link.port, **settings)]


WIRE_FORMAT = WireFormat("DCA1000", "TI DCA1000EVM raw ADC stream, laid out by the radar's TI .cfg", _open_stream,
                         _open_encoder, configure=_configure, waveform=_waveform, options=("cfg",),
                         control_options={"--dca1000-arm": _arm_option, "--radar-cli": _radar_cli_option},
                         controls=_controls)
