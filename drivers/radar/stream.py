"""What every radar wire format delivers: datagrams in, frames of int16 I/Q out, trouble counted.

A radar driver does not care whether its radar speaks SRF1 (PTP-stamped chunks with frame counters) or
streams raw DCA1000 bytes: it feeds datagrams to a ``RadarStream`` and publishes the ``RadarFrame`` objects
that come out, in order, each marked valid or not. ``counters`` say what went wrong on the wire.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np

#: Counters that describe trouble (the others count normal traffic).
TROUBLE_COUNTERS = ("malformed", "truncated", "duplicates", "reordered", "wrong_radar", "sequence_gaps",
                    "frames_incomplete", "frames_skipped", "late_datagrams", "bytes_lost", "resyncs", "crc_errors", "contradictions",
                    "foreign_source")


@dataclasses.dataclass
class RadarFrame:
    """A frame as the drivers publish it: ``iq`` int16 [chirps, rx, samples, 2], zero where bytes were lost.
    ``receive_ns`` is the kernel's (host clock) receive stamp of its last datagram, ``nic_receive_ns`` the
    network card's (its PTP hardware clock) of the same datagram where hardware stamps are in use (else 0)."""

    frame_counter: int
    frame_time_ns: int
    receive_ns: int
    valid: bool
    bytes_missing: int
    iq: np.ndarray
    ptp_locked: bool = False
    nic_receive_ns: int = 0


class RadarStream(Protocol):
    """Reassembles one radar's frames from its datagrams.

    ``feed`` takes one datagram with its kernel receive time (ns) and returns the frames it completes, in
    order; ``flush`` returns what is still pending at the end of the stream (incomplete frames marked
    invalid). ``counters`` is a dataclass of integer counters; those named in ``TROUBLE_COUNTERS`` are
    reported as events.

    A stream that holds frames back for datagrams still to come may also have ``expire(now_ns)``: called
    while the socket is quiet, with the host clock, it returns what it will wait for no longer.
    """

    wire_format: str
    counters: Any

    def feed(self, datagram: bytes, receive_ns: int) -> list[RadarFrame]: ...

    def flush(self) -> list[RadarFrame]: ...


def feed_segments(stream: RadarStream, buffer: memoryview, segment_bytes: int, receive_ns: int) -> list[RadarFrame]:
    """Feed ``stream`` one batch of datagrams received together (UDP GRO: ``UdpReceiver.receive_segments``)
    and return the frames they complete, in order.

    Parameters
    ----------
    stream : RadarStream
        The radar's stream. One that has its own ``feed_segments(buffer, segment_bytes, receive_ns) ->
        list[RadarFrame]`` gets the whole batch in one call; that method must return exactly what feeding
        each segment through ``feed`` in order would (same frames, same counters). Otherwise each segment
        goes through ``feed`` as ``bytes``. A stream's own method is called only with a non-empty ``buffer``
        and ``segment_bytes > 0`` (an empty datagram goes through ``feed``).
    buffer : memoryview
        The batch: datagrams of ``segment_bytes`` bytes each, back to back, the last possibly shorter
        (1 to ``segment_bytes`` bytes). It is the receiver's own buffer, overwritten by its next receive:
        neither this function nor the stream may keep the view (copy what must outlive the call).
    segment_bytes : int
        The size of every datagram in the batch but the last (bytes, > 0). A plain datagram is a batch of
        one: ``segment_bytes == len(buffer)``.
    receive_ns : int
        The kernel's receive stamp of the batch (host clock, ns): every datagram of the batch gets it (the
        kernel stamps a batch once, at its first datagram).

    Returns
    -------
    list[RadarFrame]
        The frames the batch completed, in order (usually none: a frame spans hundreds of datagrams).
    """
    if not len(buffer):  # an empty datagram: the stream counts it as it always did
        return stream.feed(b"", receive_ns)
    if segment_bytes <= 0:
        raise ValueError(f"segment_bytes must be positive, got {segment_bytes}")
    own = getattr(stream, "feed_segments", None)
    if own is not None:
        return own(buffer, segment_bytes, receive_ns)
    frames: list[RadarFrame] = []
    for offset in range(0, len(buffer), segment_bytes):
        if done := stream.feed(bytes(buffer[offset:offset + segment_bytes]), receive_ns):
            frames += done
    return frames


def feed_in_runs(buffer, segment_bytes: int, receive_ns: int, feed, take_run, min_run: int) -> list:
    """The loop of a stream's own ``feed_segments``: runs of datagrams taken at once, the rest one by one.

    Parameters
    ----------
    buffer : bytes-like
        The batch: datagrams of ``segment_bytes`` bytes back to back, the last possibly shorter. Not kept.
    segment_bytes : int
        Bytes of every datagram but the last (> 0).
    receive_ns : int
        The batch's receive stamp (host clock, ns), every datagram's.
    feed : callable
        The stream's (or assembler's) ``feed(datagram, receive_ns) -> list``; given a view of one datagram (it
        copies what it keeps).
    take_run : callable
        ``take_run(view, segment_bytes, first, available, receive_ns) -> (taken, frames)``: how many of the
        ``available`` full-size datagrams from the ``first``-th on it took at once (0: none, ``feed`` takes the
        next), and the frames that went. It must leave the stream exactly as ``feed`` of each would.
    min_run : int
        Fewest full-size datagrams left for ``take_run`` to be tried (shorter runs cost more than they save).

    Returns
    -------
    list
        The frames the batch completed, in order.
    """
    if segment_bytes <= 0:
        raise ValueError(f"segment_bytes must be positive, got {segment_bytes}")
    view = memoryview(buffer).cast("B")
    full = len(view) // segment_bytes  # datagrams of the full size
    count = -(-len(view) // segment_bytes)
    out: list = []
    i = 0
    while i < count:
        if full - i >= min_run:
            taken, done = take_run(view, segment_bytes, i, full - i, receive_ns)
            out += done
            if taken:
                i += taken
                continue
        out += feed(view[i * segment_bytes:(i + 1) * segment_bytes], receive_ns)
        i += 1
    return out


def trouble(counters) -> dict[str, int]:
    """The trouble counters of a stream as a dict (for events and health)."""
    return {k: v for k, v in vars(counters).items() if k in TROUBLE_COUNTERS}
