"""DCA1000 frames from batches of datagrams received back to back (UDP GRO): ``feed_segments`` gives exactly
the frames, bytes, times and counters of feeding the same datagrams one by one, whatever the trouble on the
wire and wherever the batches are cut; its batched path is really taken; its strided copy matches numpy's
plain reshape."""

import dataclasses
import random
import struct

import numpy as np
import pytest
from conftest import SHARED_DATA
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.radar.dca1000 import Dca1000Assembler, Dca1000Stream, _copy_rows, encode_data_packets
from drivers.radar.ti_cfg import load_ti_cfg
from segments_harness import batches_cut_anywhere, gro_batches
from segments_harness import one_by_one_and_batched as compare

FRAME_BYTES = 4 * 4 * 64 * 4  # 4,096: frames are not a whole number of datagrams


def troubled_stream(rnd: random.Random, n_bytes: int = 9 * FRAME_BYTES) -> list[bytes]:
    """A capture's datagrams (``payload_bytes`` 1456 or 1000, the last one shorter) with rare trouble:
    lost, repeated, swapped with the one before, cut short (an odd length too), a header and nothing
    more, a sequence number or byte count jumped far ahead, the capture restarted from 0, one resent
    long after."""
    rng = np.random.default_rng(rnd.randrange(2**32))
    stream = rng.integers(-3000, 3000, n_bytes // 2, dtype=np.int16).tobytes()
    sent = encode_data_packets(stream, payload_bytes=rnd.choice((1456, 1000)))
    if rnd.random() < 0.3:  # sequence numbers that wrap from 2^32 - 1 to 0 (the card's u32 runs over)
        sent = [struct.pack("<I", (2**32 - 20 + k) & 0xFFFFFFFF) + d[4:] for k, d in enumerate(sent)]
    rate = rnd.choice((0.0, 0.02, 0.08))
    out: list[bytes] = []
    for i, d in enumerate(sent):
        kind = rnd.randrange(9) if rnd.random() < rate else None
        if kind == 0:
            continue
        if kind == 1:
            out += [d, d]
        elif kind == 2 and out:
            out.insert(-1, d)
        elif kind == 3:
            out.append(d[:rnd.randrange(1, len(d))])
        elif kind == 4:
            out += [d[:10], d]
        elif kind == 5:
            seq, count = struct.unpack_from("<I", d)[0], int.from_bytes(d[4:10], "little")
            out += [struct.pack("<I", (seq + 5) & 0xFFFFFFFF) + count.to_bytes(6, "little") + d[10:], d]
        elif kind == 6:
            count = int.from_bytes(d[4:10], "little") + 100 * FRAME_BYTES
            out += [d[:4] + count.to_bytes(6, "little") + d[10:]]
        elif kind == 7:
            out += encode_data_packets(stream[:3000], payload_bytes=1000)  # a restarted capture's start
        elif kind == 8 and i > 20:
            out += [sent[rnd.randrange(i - 20)], d]
        else:
            out.append(d)
    return out


def state(asm: Dca1000Assembler):
    """What an assembler holds between datagrams: counters, where the stream stands, the frames pending."""
    pending = {k: (bytes(buf), have.tobytes(), first) for k, (buf, have, first) in asm._frames.items()}
    return dataclasses.astuple(asm.counters), asm._next_emit, asm._max_end, asm._last_seq, pending


def record(f):
    return f.index, bytes(f.data), f.valid, f.bytes_missing, f.first_receive_ns


def one_by_one_and_batched(cut: list[tuple[bytes, int]], flush_every: int = 0):
    """``segments_harness.one_by_one_and_batched`` for two DCA1000 assemblers."""
    single, batched = Dca1000Assembler(FRAME_BYTES), Dca1000Assembler(FRAME_BYTES)
    return compare(single, batched, cut, record, state, flush_every, 9_000, 3, b"\x5a")


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from((1, 2, 8, 64)))
def test_batches_give_exactly_the_frames_and_counters_of_one_datagram_at_a_time(seed, most):
    rnd = random.Random(seed)
    stream = troubled_stream(rnd)
    frames, counters = one_by_one_and_batched(gro_batches(rnd, stream, most), rnd.choice((0, 0, 7)))
    assert counters.datagrams == len(stream) and frames


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_batches_cut_anywhere_even_against_gro_give_the_same_frames(seed):
    rnd = random.Random(seed)
    stream = troubled_stream(rnd, 5 * FRAME_BYTES)
    cut = batches_cut_anywhere(rnd, stream, 1500)
    frames, counters = one_by_one_and_batched(cut)
    assert counters.datagrams == sum(-(-len(data) // size) for data, size in cut)


def test_a_clean_capture_in_batches_of_64_comes_out_whole_and_takes_the_batched_path():
    calls = []

    class Counting(Dca1000Assembler):
        def feed(self, payload, recv_ns=0):
            calls.append(len(payload))
            return super().feed(payload, recv_ns)

    rng = np.random.default_rng(1)
    stream = rng.integers(-3000, 3000, 20 * FRAME_BYTES // 2, dtype=np.int16).tobytes()
    dgs = encode_data_packets(stream, payload_bytes=1000)  # 82 datagrams, frames cut mid-datagram
    asm = Counting(FRAME_BYTES)
    out = []
    for k in range(0, len(dgs), 64):  # the last datagram is the only short one
        out += asm.feed_segments(b"".join(dgs[k:k + 64]), len(dgs[0]), 100 + k)
    out += asm.flush()
    assert [f.index for f in out] == list(range(20)) and all(f.valid for f in out)
    assert b"".join(bytes(f.data) for f in out) == stream
    assert asm.counters.datagrams == len(dgs) and asm.counters.frames_complete == 20
    assert len(calls) == 2  # the first datagram (nothing to carry on from) and the short last one


def test_the_strided_copy_reads_the_rows_as_one_stream():
    rng = np.random.default_rng(2)
    packed = rng.integers(0, 256, (9, 30), dtype=np.uint8)
    rows = packed[:, 4:]  # 26 payload bytes a row, strided as in a batch
    flat = rows.reshape(-1)
    for start in (0, 1, 25, 26, 27, 60):
        for n in (1, 5, 26, 27, 52, 100, flat.size - start):
            if start + n <= flat.size:
                out = np.zeros(n, np.uint8)
                _copy_rows(rows, start, out)
                np.testing.assert_array_equal(out, flat[start:start + n])


def test_the_stream_s_batches_give_its_frames():
    cfg = load_ti_cfg(SHARED_DATA / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg")  # 131,072-byte frames
    rng = np.random.default_rng(3)
    wire = rng.integers(-3000, 3000, cfg.frame_bytes // 2, dtype=np.int16).tobytes()
    dgs = encode_data_packets(wire)
    stream = Dca1000Stream(cfg)
    out = stream.feed_segments(memoryview(b"".join(dgs[:-1])), len(dgs[0]), 10) + stream.feed_segments(
        memoryview(dgs[-1]), len(dgs[-1]), 11)
    assert len(out) == 1 and out[0].valid and out[0].frame_time_ns == 10
    reference = Dca1000Stream(cfg)
    want = [f for d in dgs for f in reference.feed(d, 10)]
    np.testing.assert_array_equal(out[0].iq, want[0].iq)
    with pytest.raises(ValueError, match="segment_bytes"):
        stream.feed_segments(memoryview(dgs[0]), -1, 12)
