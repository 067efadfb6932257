"""SRF1 frames from batches of datagrams received back to back (UDP GRO): ``feed_segments`` gives exactly the
frames, bytes, times and counters of feeding the same datagrams one by one, whatever the trouble on the wire
and wherever the batches are cut; its batched path is really taken; its CRC seeds match CRC32C itself."""

import dataclasses
import random

import crc32c
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.radar.srf1 import HEADER, MAGIC, FrameAssembler, Srf1Stream, encode_frame, parse
from drivers.radar.srf1_datagram import CRC, _crc, payload_seeds
from segments_harness import batches_cut_anywhere, gro_batches
from segments_harness import one_by_one_and_batched as compare

SHAPE = (16, 4, 64, 2)
FRAME_BYTES = int(np.prod(SHAPE)) * 2  # 16,384


def _datagram(version, flags, radar_id, counter, time_ns, offset, payload, frame_bytes=FRAME_BYTES):
    """A datagram with whatever fields it is given, and (version 2) a right CRC for them."""
    fields = HEADER.pack(MAGIC, version, flags, radar_id, counter & 0xFFFFFFFF, time_ns, frame_bytes, offset)
    return fields + (CRC.pack(_crc(fields, payload)) if version >= 2 else b"") + bytes(payload)


def troubled_stream(rnd: random.Random, n_frames: int = 7) -> list[bytes]:
    """Datagrams of ``n_frames`` frames of radar 7 across the counter's wrap, version 2 mostly (a frame in
    version 1 now and then), chunks of 256 bytes (the frame is 64 of them) or 300 (a short last one), with
    rare trouble mixed in: lost, repeated, swapped with the one before, a flipped bit, cut short, another
    radar's, another frame time, other PTP flags, a counter jump, a late duplicate of an earlier frame."""
    rng = np.random.default_rng(rnd.randrange(2**32))
    chunk = rnd.choice((256, 300))
    rate = rnd.choice((0.0, 0.01, 0.05))
    stream: list[bytes] = []
    sent: list[bytes] = []
    for k in range(n_frames):
        iq = rng.integers(-2000, 2000, SHAPE, dtype=np.int16)
        version = 1 if rnd.random() < 0.2 else 2
        counter, time_ns = 2**32 - 3 + k, 1_000_000_000 + k * 52_000_000
        for d in encode_frame(7, counter & 0xFFFFFFFF, time_ns, iq, payload_bytes=chunk, version=version):
            sent.append(d)
            h, payload = parse(d)
            kind = rnd.randrange(11) if rnd.random() < rate else None
            if kind == 0:
                continue  # lost
            if kind == 1:
                stream += [d, d]
            elif kind == 2 and stream:
                stream.insert(-1, d)
            elif kind == 3:
                bad = bytearray(d)
                bad[rnd.randrange(len(bad))] ^= 1 << rnd.randrange(8)
                stream.append(bytes(bad))
            elif kind == 4:
                stream.append(d[:rnd.randrange(1, len(d))])
            elif kind == 5:
                stream += [_datagram(version, h.flags, 8, counter, time_ns, h.offset, payload), d]
            elif kind == 6:
                stream += [_datagram(version, h.flags, 7, counter, time_ns + 1, h.offset, payload), d]
            elif kind == 7:
                stream.append(_datagram(version, h.flags ^ 1, 7, counter, time_ns, h.offset, payload))
            elif kind == 8:
                stream += [_datagram(version, h.flags, 7, counter + 40, time_ns, h.offset, payload), d]
            elif kind == 9 and len(sent) > 200:
                stream += [sent[rnd.randrange(len(sent) - 200)], d]  # a frame already passed on
            else:
                stream.append(d)
    return stream


def frame_record(f):
    return (f.frame_counter, f.frame_time_ns, bytes(f.data), f.valid, f.bytes_missing, f.ptp_locked, f.last_receive_ns)


def state(asm: FrameAssembler):
    """What an assembler holds between datagrams: counters, where it stands, the frames being filled."""
    pending = {k: (p.header, bytes(p.data), None if p.have is None else p.have.tobytes(), p.prefix, p.received,
                   p.last_offset, p.last_recv, p.contradicted) for k, p in asm._partial.items()}
    filling = None if asm._filling is None else asm._filling[:2] + asm._filling[3:]
    return (dataclasses.astuple(asm.counters), asm._next_emit, asm._newest_time_ns, asm._newest_recv_ns, asm._chunk,
            asm._last_real, asm._interval_ns, filling, pending)


def one_by_one_and_batched(cut: list[tuple[bytes, int]], flush_every: int = 0, radar_id=7):
    """``segments_harness.one_by_one_and_batched`` for two SRF1 assemblers, ``expire`` after each batch."""
    single, batched = FrameAssembler(FRAME_BYTES, radar_id=radar_id), FrameAssembler(FRAME_BYTES, radar_id=radar_id)
    return compare(single, batched, cut, frame_record, state, flush_every, 5_000, 7, b"\xa5", 100_000_000)


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from((1, 2, 8, 64)))
def test_batches_give_exactly_the_frames_and_counters_of_one_datagram_at_a_time(seed, most):
    rnd = random.Random(seed)
    stream = troubled_stream(rnd)
    frames, counters = one_by_one_and_batched(gro_batches(rnd, stream, most), rnd.choice((0, 0, 9)))
    assert counters.datagrams == len(stream) and frames


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_batches_cut_anywhere_even_against_gro_give_the_same_frames(seed):
    """Batches cut at random sizes regardless of the datagrams' lengths: a segment size that is not every
    datagram's (the buffer re-cut at it) is still fed as those segments would be one by one."""
    rnd = random.Random(seed)
    stream = troubled_stream(rnd, 5)
    cut = batches_cut_anywhere(rnd, stream, 400)
    _, counters = one_by_one_and_batched(cut)
    assert counters.datagrams == sum(-(-len(data) // size) for data, size in cut)


def test_clean_frames_in_gro_batches_come_out_whole_and_take_the_batched_path():
    """Clean version 2 frames in GRO batches: every frame whole and valid, and ``feed`` called for two
    datagrams a frame (its first and its short last), the rest taken in one run."""
    calls = []

    class Counting(FrameAssembler):
        def feed(self, datagram, recv_ns=0):
            calls.append(len(datagram))
            return super().feed(datagram, recv_ns)

    rng = np.random.default_rng(1)
    iqs = [rng.integers(-2000, 2000, SHAPE, dtype=np.int16) for _ in range(4)]
    stream = [d for k, iq in enumerate(iqs) for d in encode_frame(7, 9 + k, 1_000 + k, iq, payload_bytes=300)]
    asm = Counting(FRAME_BYTES, radar_id=7)
    out = []
    for k in range(0, len(stream), 55):  # GRO's batches: a frame's 55 datagrams, its short last one ending it
        out += asm.feed_segments(b"".join(stream[k:k + 55]), len(stream[k]), 1)
    assert [f.frame_counter for f in out] == [9, 10, 11, 12]
    assert all(f.valid and bytes(f.data) == iq.tobytes() for f, iq in zip(out, iqs))
    assert asm.counters.datagrams == len(stream) == 4 * 55 and asm.counters.frames_complete == 4
    assert len(calls) == 4 * 2  # each frame's first (a new frame) and its short last one


def test_a_frame_ending_inside_a_run_goes_at_once():
    """Chunks that divide the frame (64 of 256 bytes): the run that takes the last one passes the frame on."""
    rng = np.random.default_rng(2)
    iqs = [rng.integers(-2000, 2000, SHAPE, dtype=np.int16) for _ in range(2)]
    stream = [d for k, iq in enumerate(iqs) for d in encode_frame(7, k, 1_000 + k, iq, payload_bytes=256)]
    asm = FrameAssembler(FRAME_BYTES, radar_id=7)
    first = asm.feed_segments(b"".join(stream[:70]), len(stream[0]), 1)  # frame 0 whole and 6 of frame 1
    assert [f.frame_counter for f in first] == [0] and bytes(first[0].data) == iqs[0].tobytes()
    rest = asm.feed_segments(b"".join(stream[70:]), len(stream[0]), 2)
    assert [(f.frame_counter, f.last_receive_ns) for f in rest] == [(1, 2)] and bytes(rest[0].data) == iqs[1].tobytes()


def test_the_stream_s_batches_give_its_frames():
    rng = np.random.default_rng(3)
    iq = rng.integers(-2000, 2000, SHAPE, dtype=np.int16)
    dgs = encode_frame(7, 1, 2_000, iq)
    stream = Srf1Stream(SHAPE[:3], radar_id=7)
    out = stream.feed_segments(memoryview(b"".join(dgs[:-1])), len(dgs[0]), 10) + stream.feed_segments(
        memoryview(dgs[-1]), len(dgs[-1]), 11)
    assert len(out) == 1 and out[0].valid and out[0].receive_ns == 11 and out[0].frame_time_ns == 2_000
    np.testing.assert_array_equal(out[0].iq, iq)
    assert stream.feed_segments(memoryview(b""), 1472, 12) == []
    with pytest.raises(ValueError, match="segment_bytes"):
        stream.feed_segments(memoryview(dgs[0]), 0, 13)


def test_payload_seeds_are_crc32c_of_the_header_with_each_offset():
    rnd = random.Random(4)
    for _ in range(20):
        fields = HEADER.pack(MAGIC, 2, rnd.randrange(256), rnd.randrange(2**16), rnd.randrange(2**32),
                             rnd.randrange(2**64), rnd.randrange(2**32), 0)
        offsets = np.array([rnd.randrange(2**32) for _ in range(16)] + [0, 2**32 - 1], np.uint32)
        want = [crc32c.crc32c(fields[:-4] + int(o).to_bytes(4, "little")) for o in offsets]
        assert payload_seeds(fields, offsets).tolist() == want
