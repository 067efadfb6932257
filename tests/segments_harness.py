"""What the batched-assembly tests of both wire formats share (tests/test_srf1_segments.py,
tests/test_dca1000_segments.py): a stream of datagrams cut into batches as UDP GRO cuts it, or anywhere, and
the comparison of an assembler fed one datagram at a time with one fed the same batches whole."""

from __future__ import annotations

import random


def gro_batches(rnd: random.Random, stream: list[bytes], most: int) -> list[tuple[bytes, int]]:
    """``stream`` cut into batches as GRO makes them: consecutive datagrams of one size, at most ``most``
    (each batch's own limit drawn from 1 to ``most``), a shorter datagram ending its batch. (buffer,
    segment_bytes) each."""
    out = []
    i = 0
    while i < len(stream):
        size, limit = len(stream[i]), rnd.randint(1, most)
        j = i + 1
        while j < len(stream) and j - i < limit and len(stream[j]) <= size:
            j += 1
            if len(stream[j - 1]) < size:
                break
        out.append((b"".join(stream[i:j]), max(size, 1)))
        i = j
    return out


def batches_cut_anywhere(rnd: random.Random, stream: list[bytes], largest_segment: int) -> list[tuple[bytes, int]]:
    """``stream`` in runs of 1 to 64 datagrams, each run's segment size its first datagram's or drawn from 1 to
    ``largest_segment`` regardless of the datagrams' lengths (the run's bytes re-cut at it)."""
    cut = []
    i = 0
    while i < len(stream):
        j = min(len(stream), i + rnd.randint(1, 64))
        size = rnd.choice((len(stream[i]), rnd.randint(1, largest_segment)))
        cut.append((b"".join(stream[i:j]), size))
        i = j
    return cut


def one_by_one_and_batched(single, batched, cut: list[tuple[bytes, int]], record, state, flush_every: int = 0,
                           first_ns: int = 5_000, step_ns: int = 7, fill: bytes = b"\xa5",
                           expire_after_ns: int | None = None):
    """Feed the batches' datagrams one at a time (each with its batch's time, ``first_ns`` + ``step_ns`` a
    batch) to the assembler ``single`` and the batches whole to ``batched``, through a buffer overwritten with
    ``fill`` after each call, as the receiver's is. After every batch the frames that came out of each
    (``record`` of each frame) and the assemblers' ``state`` must be the same. With ``expire_after_ns``, both
    ``expire`` that long after each batch; a ``flush`` every ``flush_every`` batches (0: at the end only).
    Returns the frames' records and ``single``'s counters."""
    a, b = [], []
    buffer = bytearray(max((len(data) for data, _ in cut), default=0))
    for k, (data, size) in enumerate(cut):
        recv_ns = first_ns + step_ns * k
        got_a = [f for o in range(0, len(data), size) for f in single.feed(data[o:o + size], recv_ns)]
        buffer[:len(data)] = data
        got_b = batched.feed_segments(memoryview(buffer)[:len(data)], size, recv_ns)
        buffer[:] = fill * len(buffer)  # the receiver's next batch: nothing kept may point here
        if expire_after_ns is not None:
            got_a += single.expire(recv_ns + expire_after_ns)
            got_b += batched.expire(recv_ns + expire_after_ns)
        if flush_every and k % flush_every == flush_every - 1:
            got_a += single.flush()
            got_b += batched.flush()
        a += [record(f) for f in got_a]
        b += [record(f) for f in got_b]
        assert b == a and state(batched) == state(single), f"after batch {k}"
    a += [record(f) for f in single.flush()]
    b += [record(f) for f in batched.flush()]
    assert b == a and state(batched) == state(single)
    return a, single.counters
