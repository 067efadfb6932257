"""One interface over the radar wire formats: datagrams in, frames of int16 I/Q out.

A radar driver does not care whether its radar speaks SRF1 (PTP-stamped chunks with frame counters) or
streams raw DCA1000 bytes: it feeds datagrams to a ``RadarStream`` and publishes the ``RadarFrame`` objects
that come out, in order, each marked valid or not. ``counters`` say what went wrong on the wire.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .dca1000 import Dca1000Assembler, complex_1x_to_iq
from .srf1 import FrameAssembler
from .ti_cfg import TiRadarConfig

WIRE_FORMATS = ("SRF1", "DCA1000")

#: Counters that describe trouble (the others count normal traffic).
TROUBLE_COUNTERS = ("malformed", "truncated", "duplicates", "reordered", "wrong_radar", "sequence_gaps",
                    "frames_incomplete", "frames_skipped", "bytes_lost", "resyncs")


@dataclasses.dataclass
class RadarFrame:
    """A frame as the drivers publish it: ``iq`` int16 [chirps, rx, samples, 2], zero where bytes were lost."""

    frame_counter: int
    frame_time_ns: int
    receive_ns: int
    valid: bool
    bytes_missing: int
    iq: np.ndarray
    ptp_locked: bool = False


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
        return self._frames(self._asm.feed(datagram, receive_ns))

    def flush(self) -> list[RadarFrame]:
        return self._frames(self._asm.flush())


class Dca1000Stream:
    """DCA1000 raw byte stream to frames, laid out by the TI ``.cfg``.

    The DCA1000 sends no time stamps and no frame counter: the counter is the frame's index in the stream
    and its time the kernel receive time of its first datagram (put on the PTP base by the host clock).
    """

    wire_format = "DCA1000"

    def __init__(self, cfg: TiRadarConfig):
        if not cfg.complex_output:
            raise ValueError("only complex ADC output (adcCfg/adcbufCfg complex 1x) is supported for DCA1000 streams")
        self.cfg = cfg
        self._asm = Dca1000Assembler(cfg.frame_bytes)
        self.counters = self._asm.counters

    def _frames(self, frames) -> list[RadarFrame]:
        c = self.cfg
        return [RadarFrame(f.index, f.first_receive_ns, f.first_receive_ns, f.valid, f.bytes_missing,
                           complex_1x_to_iq(f.data, c.chirps_per_frame, c.n_rx, c.adc_samples)) for f in frames]

    def feed(self, datagram: bytes, receive_ns: int) -> list[RadarFrame]:
        return self._frames(self._asm.feed(datagram, receive_ns))

    def flush(self) -> list[RadarFrame]:
        return self._frames(self._asm.flush())


def trouble(counters) -> dict[str, int]:
    """The trouble counters of a stream as a dict (for events and health)."""
    return {k: v for k, v in vars(counters).items() if k in TROUBLE_COUNTERS}
