"""SRF1 reassembly: in order, reordered, duplicated, dropped, truncated, malformed, restarted; fuzzed; version 2's
CRC, overlapping chunks that disagree, and counter jumps."""

import random
import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.radar.srf1 import HEADER, MAX_PAYLOAD, FrameAssembler, encode_frame, parse

SHAPE = (16, 4, 64, 2)  # a small frame: chirps, rx, samples, I/Q
FRAME_BYTES = int(np.prod(SHAPE)) * 2


def frames(n, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(-2000, 2000, SHAPE, dtype=np.int16) for _ in range(n)]


def datagrams(iqs, start=100, version=1):
    """Version 1 (no CRC) by default: the reassembly tests below cut and garble datagrams, which version 2's
    CRC would simply reject (tested on its own at the end)."""
    return [encode_frame(7, start + k, 1_000_000_000 + k * 52_000_000, iq, version=version) for k, iq in enumerate(iqs)]


def test_datagrams_fit_the_mtu_and_parse_back():
    dgs = encode_frame(3, 42, 123, frames(1)[0])
    assert all(len(d) + 28 <= 1500 for d in dgs)
    assert len(dgs) == -(-FRAME_BYTES // MAX_PAYLOAD)
    h, payload = parse(dgs[1])
    assert (h.radar_id, h.frame_counter, h.frame_time_ns, h.frame_bytes, h.offset) == (3, 42, 123, FRAME_BYTES, MAX_PAYLOAD)
    assert h.ptp_locked


def test_a_restamped_datagram_parses_with_its_new_counter_and_time():
    """A player re-sending encoded frames changes counter and time in place; version 2's CRC is made again
    (a player that patched only the fields had every datagram dropped as a CRC error)."""
    from drivers.radar.srf1 import restamp

    for version in (1, 2):
        d = bytearray(encode_frame(3, 42, 123, frames(1)[0], version=version)[1])
        restamp(d, 2**32 + 7, 999)
        h, payload = parse(bytes(d))
        assert (h.version, h.radar_id, h.frame_counter, h.frame_time_ns, h.offset) == (version, 3, 7, 999, MAX_PAYLOAD)
        assert bytes(payload) == frames(1)[0].tobytes()[MAX_PAYLOAD:2 * MAX_PAYLOAD]


def test_in_order_and_reordered_frames_are_identical():
    iqs = frames(5)
    for shuffle in (False, True):
        asm = FrameAssembler(FRAME_BYTES, radar_id=7)
        out = []
        rng = random.Random(3)
        for dgs in datagrams(iqs):
            dgs = list(dgs)
            if shuffle:
                rng.shuffle(dgs)
            for d in dgs:
                out += asm.feed(d)
        out += asm.flush()
        assert [f.frame_counter for f in out] == [100, 101, 102, 103, 104]
        assert all(f.valid for f in out)
        for f, iq in zip(out, iqs):
            np.testing.assert_array_equal(f.iq(SHAPE), iq)
        assert (asm.counters.reordered > 0) == shuffle
        assert asm.counters.frames_complete == 5 and asm.counters.bytes_lost == 0


def test_loss_duplicates_truncation_and_garbage_are_counted_and_nothing_intact_is_lost():
    iqs = frames(6)
    all_dgs = datagrams(iqs)
    stream = []
    for k, dgs in enumerate(all_dgs):
        for j, d in enumerate(dgs):
            if k == 1 and j == 2:
                continue  # dropped
            if k == 2 and j == 1:
                stream.append(d[: len(d) - 6])  # truncated mid-sample
                continue
            stream.append(d)
            if k == 3 and j == 0:
                stream.append(d)  # duplicated
        if k == 4:
            stream += [b"junk", b"SRF2" + bytes(40), bytes(HEADER.size - 1)]
    asm = FrameAssembler(FRAME_BYTES, radar_id=7)
    out = [f for d in stream for f in asm.feed(d)] + asm.flush()
    by = {f.frame_counter: f for f in out}
    assert sorted(by) == [100, 101, 102, 103, 104, 105]
    assert not by[101].valid and not by[102].valid
    for k in (100, 103, 104, 105):
        assert by[k].valid
        np.testing.assert_array_equal(by[k].iq(SHAPE), iqs[k - 100])
    # The lost chunk is zero-filled; everything received intact is in place.
    lost = by[101].iq(SHAPE).reshape(-1)
    sent = iqs[1].reshape(-1)
    lo = 2 * MAX_PAYLOAD // 2
    hi = min(3 * MAX_PAYLOAD // 2, sent.size)
    assert np.all(lost[lo:hi] == 0)
    np.testing.assert_array_equal(lost[:lo], sent[:lo])
    np.testing.assert_array_equal(lost[hi:], sent[hi:])
    c = asm.counters
    # Truncated: the cut datagram and two too short to hold a header; malformed: the wrong magic.
    assert c.duplicates == 1 and c.truncated == 3 and c.malformed == 1 and c.frames_incomplete == 2
    assert c.bytes_lost == MAX_PAYLOAD + 6 + 2  # a whole chunk, and the truncated one's cut (rounded to a sample)


def test_a_whole_frame_lost_and_a_restart():
    iqs = frames(4)
    dgs = datagrams(iqs)
    asm = FrameAssembler(FRAME_BYTES)
    out = []
    for k in (0, 2, 3):  # frame 101 never arrives
        for d in dgs[k]:
            out += asm.feed(d)
    restart = encode_frame(7, 5, 0, iqs[0])  # the radar rebooted: its counter starts again
    for d in restart:
        out += asm.feed(d)
    out += asm.flush()
    counters = [f.frame_counter for f in out]
    assert counters == [100, 101, 102, 103, 5]
    assert not out[1].valid and out[1].bytes_missing == FRAME_BYTES
    assert asm.counters.frames_skipped == 1 and asm.counters.resyncs == 1
    np.testing.assert_array_equal(out[-1].iq(SHAPE), iqs[0])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=120), max_size=20), st.randoms())
def test_fuzz_assembler_never_raises(junk, rnd):
    asm = FrameAssembler(FRAME_BYTES)
    dgs = [d for group in datagrams(frames(2)) for d in group] + junk
    rnd.shuffle(dgs)
    for d in dgs:
        for f in asm.feed(d):
            assert len(f.data) == FRAME_BYTES
    asm.flush()


def _flip(datagram: bytes, bit: int) -> bytes:
    b = bytearray(datagram)
    b[bit // 8] ^= 1 << (bit % 8)
    return bytes(b)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_version_2_a_flipped_bit_anywhere_never_makes_a_valid_frame(data):
    """One bit flipped in any datagram, header or payload: the datagram is dropped (CRC error), its frame
    comes out invalid, and every frame marked valid is bit for bit what was sent."""
    iqs = frames(3, seed=1)
    dgs = datagrams(iqs, version=2)
    k = data.draw(st.integers(0, 2), label="frame")
    j = data.draw(st.integers(0, len(dgs[k]) - 1), label="datagram")
    bit = data.draw(st.integers(0, 8 * len(dgs[k][j]) - 1), label="bit")
    dgs[k][j] = _flip(dgs[k][j], bit)
    asm = FrameAssembler(FRAME_BYTES)
    out = [f for group in dgs for d in group for f in asm.feed(d)] + asm.flush()
    valid = {f.frame_counter: f for f in out if f.valid}
    for i, iq in enumerate(iqs):
        if 100 + i in valid:
            np.testing.assert_array_equal(valid[100 + i].iq(SHAPE), iq)
    assert 100 + k not in valid
    assert asm.counters.crc_errors + asm.counters.malformed + asm.counters.wrong_radar >= 1


def test_overlapping_chunks_never_overwrite_and_a_contradiction_invalidates_the_frame():
    iq = frames(1, seed=2)[0]
    data = iq.tobytes()
    half = FRAME_BYTES // 2
    head = encode_frame(7, 100, 5, iq, payload_bytes=half)  # two chunks
    forged = encode_frame(7, 100, 5, np.frombuffer(bytes(FRAME_BYTES), "<i2"), payload_bytes=half)[0]  # zeros, chunk 0
    asm = FrameAssembler(FRAME_BYTES)
    out = asm.feed(head[0]) + asm.feed(forged) + asm.feed(head[1]) + asm.flush()
    assert len(out) == 1 and not out[0].valid
    assert bytes(out[0].data) == data  # the first bytes received stayed
    assert asm.counters.contradictions == 1
    # The same bytes again are a harmless duplicate; another frame time for the same counter is not.
    asm = FrameAssembler(FRAME_BYTES)
    out = asm.feed(head[0]) + asm.feed(head[0]) + asm.feed(head[1])
    assert len(out) == 1 and out[0].valid and asm.counters.contradictions == 0
    asm = FrameAssembler(FRAME_BYTES)
    other_time = encode_frame(7, 100, 6, iq, payload_bytes=half)[1]
    out = asm.feed(head[0]) + asm.feed(other_time) + asm.flush()
    assert len(out) == 1 and not out[0].valid and asm.counters.contradictions == 1


def test_a_placeholder_is_timed_between_its_neighbours_and_keeps_their_lock():
    """A lost frame's times come from the frames around it (frame times stay in order), its PTP lock from the
    frame before; also for a loss right before a counter jump, which the resync once swallowed."""
    iqs = frames(5)
    dgs = datagrams(iqs)
    asm = FrameAssembler(FRAME_BYTES)
    out = []
    for k in (0, 1, 3):  # 102 lost; only one frame (103) comes before the counter jumps
        for d in dgs[k]:
            out += asm.feed(d, recv_ns=5_000_000_000 + k * 52_000_000)
    for d in encode_frame(7, 100 + 60, 1_000_000_000 + 60 * 52_000_000, iqs[4], version=1):
        out += asm.feed(d, recv_ns=5_000_000_000 + 60 * 52_000_000)  # a jump of 57: a resync
    out += asm.flush()
    assert [f.frame_counter for f in out] == [100, 101, 102, 103, 160]
    lost = out[2]
    assert not lost.valid and lost.bytes_missing == FRAME_BYTES and lost.ptp_locked
    assert lost.frame_time_ns == 1_000_000_000 + 2 * 52_000_000
    assert lost.last_receive_ns == 5_000_000_000 + 2 * 52_000_000
    assert asm.counters.frames_skipped == 1 and asm.counters.resyncs == 1


def test_frames_behind_an_incomplete_one_go_once_the_radar_is_quiet():
    """The radar's last frames: one incomplete, one complete behind it. Nothing newer will come to end the
    wait, so once the socket has been quiet for quiet_s both are passed on, in order."""
    iqs = frames(3)
    dgs = datagrams(iqs)
    asm = FrameAssembler(FRAME_BYTES, quiet_s=0.25)
    out = []
    for k, group in enumerate(dgs):
        for d in (group[:-1] if k == 1 else group):  # frame 101 loses its last datagram
            out += asm.feed(d, recv_ns=1_000_000_000 + k * 52_000_000)
    assert [f.frame_counter for f in out] == [100]  # 102 is complete but waits behind 101
    last_ns = 1_000_000_000 + 2 * 52_000_000
    assert asm.expire(last_ns + 200_000_000) == []  # not quiet long enough
    late = asm.expire(last_ns + 300_000_000)
    assert [(f.frame_counter, f.valid) for f in late] == [(101, False), (102, True)]
    np.testing.assert_array_equal(late[1].iq(SHAPE), iqs[2])
    assert asm.expire(last_ns + 900_000_000) == [] and asm.flush() == []


def test_a_counter_jump_is_a_resync_not_hundreds_of_placeholder_frames():
    """A forged or corrupt frame counter 900 ahead (one version-1 datagram): at most a handful of frames come
    out for it, not 900 zero-filled ones (650 MB of a reference radar's frames)."""
    iqs = frames(6, seed=3)
    dgs = datagrams(iqs)
    forged = encode_frame(7, 100 + 3 + 900, 0, iqs[0], version=1)[0]
    asm = FrameAssembler(FRAME_BYTES)
    out = []
    for k, group in enumerate(dgs):
        for d in group:
            out += asm.feed(d)
        if k == 2:
            out += asm.feed(forged)
    out += asm.flush()
    assert len(out) <= len(iqs) + 2
    assert asm.counters.resyncs >= 1
    valid = {f.frame_counter: f for f in out if f.valid}
    assert set(valid) == {100, 101, 102, 103, 104, 105}
    for k, iq in enumerate(iqs):
        np.testing.assert_array_equal(valid[100 + k].iq(SHAPE), iq)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_chunks_in_any_order_size_and_content_match_a_byte_by_byte_model(data):
    """The assembler keeps no byte map while chunks come in order (its fast path). Against a model that
    keeps one from the start: chunks of any size and offset, in any order, repeated, some with other
    bytes or another frame time, give the same bytes, validity and loss."""
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    size = 4 * data.draw(st.integers(1, 64))
    truth = rng.integers(0, 256, size, dtype=np.uint8)
    bounds = sorted({0, size, *[4 * k for k in data.draw(st.lists(st.integers(1, size // 4), max_size=8))]})
    chunks = [(lo, hi, 5, truth[lo:hi]) for lo, hi in zip(bounds[:-1], bounds[1:])]
    for _ in range(data.draw(st.integers(0, 3))):  # resent, forged or mistimed chunks
        lo, hi, _, _ = chunks[data.draw(st.integers(0, len(chunks) - 1))]
        kind = data.draw(st.sampled_from(["again", "other_bytes", "other_time"]))
        payload = truth[lo:hi] if kind != "other_bytes" else (truth[lo:hi] ^ 0xFF)
        chunks.insert(data.draw(st.integers(0, len(chunks))), (lo, hi, 6 if kind == "other_time" else 5, payload))
    chunks = [c for c in chunks if not data.draw(st.booleans())] if data.draw(st.booleans()) else chunks  # loss

    have, got, contradicted = np.zeros(size, bool), np.zeros(size, np.uint8), False
    for lo, hi, t, payload in chunks:
        if have.all():
            break  # a complete frame is passed on at once: what comes after is a late duplicate
        had = have[lo:hi]
        contradicted |= t != chunks[0][2] or bool(np.any(got[lo:hi][had] != payload[had]))
        got[lo:hi][~had] = payload[~had]
        have[lo:hi] = True

    asm = FrameAssembler(size)
    head = struct.Struct("<4sBBHIQII")
    out = []
    for lo, hi, t, payload in chunks:
        out += asm.feed(head.pack(b"SRF1", 1, 1, 7, 100, t, size, lo) + payload.tobytes())
    out += asm.flush()
    if not chunks:
        assert out == []
        return
    assert len(out) == 1
    frame = out[0]
    assert bytes(frame.data) == got.tobytes()
    assert frame.bytes_missing == size - int(have.sum())
    assert frame.valid == (bool(have.all()) and not contradicted)


def test_a_late_duplicate_of_a_finished_frame_is_dropped_and_touches_nothing():
    """One datagram of frame k sent again while frame k+6..k+10 is arriving (a resend or a route that held it
    up): it was taken for a restart, so the frames being assembled came out as invalid partial rows and the
    counters in between were passed on a second time. Now it is counted and dropped; nothing else changes."""
    iqs = frames(24, seed=4)
    dgs = datagrams(iqs)
    asm = FrameAssembler(FRAME_BYTES, radar_id=7)
    out = []
    late = 0
    for k, group in enumerate(dgs):
        for j, d in enumerate(group):
            out += asm.feed(d)
            if j == 1 and k >= 10:  # mid-frame: a datagram of a frame 6 to 10 back comes again
                back = 6 + k % 5
                out += asm.feed(dgs[k - back][k % len(dgs[k - back])])
                late += 1
    out += asm.flush()
    assert [f.frame_counter for f in out] == list(range(100, 124))  # each once, in order
    assert all(f.valid for f in out)
    for f, iq in zip(out, iqs):
        np.testing.assert_array_equal(f.iq(SHAPE), iq)
    c = asm.counters
    assert c.late_datagrams == late == 14
    assert c.resyncs == 0 and c.bytes_lost == 0 and c.frames_incomplete == 0 and c.frames_skipped == 0


def test_the_counter_wraps_from_2_32_minus_1_to_0_without_a_resync():
    iqs = frames(8, seed=5)
    start = 2**32 - 4
    dgs = [encode_frame(7, start + k, 1_000_000_000 + k * 52_000_000, iq, version=1) for k, iq in enumerate(iqs)]
    asm = FrameAssembler(FRAME_BYTES)
    out = []
    for k, group in enumerate(dgs):
        for d in group:
            out += asm.feed(d)
        if k == 7:  # frame 2^32 - 2 again, 6 frames back across the wrap: late, not a restart
            out += asm.feed(dgs[1][0])
    out += asm.flush()
    assert [f.frame_counter for f in out] == [2**32 - 4, 2**32 - 3, 2**32 - 2, 2**32 - 1, 0, 1, 2, 3]
    assert all(f.valid for f in out)
    for f, iq in zip(out, iqs):
        np.testing.assert_array_equal(f.iq(SHAPE), iq)
    assert asm.counters.resyncs == 0 and asm.counters.late_datagrams == 1 and asm.counters.frames_skipped == 0


def test_a_sender_restarted_a_few_frames_back_is_told_from_a_late_datagram_by_its_newer_time():
    """A radar restarted (counter back to 0, its PTP clock going on): counters 0.. behind the next frame due
    but with frame times newer than any seen are its new frames, not late datagrams."""
    iqs = frames(6, seed=6)
    asm = FrameAssembler(FRAME_BYTES)
    out = []
    for k in range(4):
        for d in encode_frame(7, k, 1_000_000_000 + k * 52_000_000, iqs[k], version=1):
            out += asm.feed(d)
    for k in range(2):
        for d in encode_frame(7, k, 2_000_000_000 + k * 52_000_000, iqs[4 + k], version=1):
            out += asm.feed(d)
    out += asm.flush()
    assert [f.frame_counter for f in out] == [0, 1, 2, 3, 0, 1]
    assert all(f.valid for f in out) and asm.counters.resyncs == 1 and asm.counters.late_datagrams == 0
    np.testing.assert_array_equal(out[-1].iq(SHAPE), iqs[5])


class _GeneralPathOnly(FrameAssembler):
    """The assembler with its in-order path turned off: every datagram takes ``_feed``'s every check."""

    def _in_order(self, datagram, recv_ns):
        return None


def _v2_datagram(radar_id, counter, time_ns, offset, payload, frame_bytes=FRAME_BYTES):
    """A version 2 datagram with a right CRC, whatever its fields say (an overrun, a short chunk, ...)."""
    from drivers.radar.srf1 import CRC, MAGIC, _crc

    fields = HEADER.pack(MAGIC, 2, 1, radar_id, counter, time_ns, frame_bytes, offset)
    return fields + CRC.pack(_crc(fields, payload)) + bytes(payload)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_in_order_path_takes_every_datagram_as_the_general_path_does(seed):
    """The assembler's in-order path (``_in_order``, the cheap one almost every datagram takes) skips checks
    only where the frame it fills makes them moot: fed the same version 2 datagrams, in order with random
    trouble mixed in (lost, repeated, swapped, corrupted, another radar's, another frame time, a short or
    overrunning chunk with a right CRC, a counter jump, another frame size), it and the general path alone give the same frames,
    byte for byte, and the same counters."""
    rnd = random.Random(seed)
    iqs = frames(8, seed % 1000)
    stream = []
    for k, iq in enumerate(iqs):
        counter, time_ns = 2**32 - 4 + k, 1_000_000_000 + k * 52_000_000  # across the counter's wrap
        for d in encode_frame(7, counter & 0xFFFFFFFF, time_ns, iq, payload_bytes=300, version=2):
            h, payload = parse(d)
            last = h.offset + 300 > FRAME_BYTES
            # Rare trouble, so most frames are still being filled in order when it comes (the first
            # datagram out of order sends the rest of its frame down the general path).
            kind = rnd.randrange(10) if rnd.random() < 0.03 else ("overrun" if last and rnd.random() < 0.3 else None)
            if kind == 0:
                continue  # lost
            if kind == 1:
                stream += [d, d]
            elif kind == 2 and stream:
                stream.insert(-1, d)  # swapped with the one before
            elif kind == 3:
                bad = bytearray(d)
                bad[rnd.randrange(len(bad))] ^= 1 << rnd.randrange(8)
                stream += [bytes(bad), d]
            elif kind == 4:
                stream += [_v2_datagram(8, h.frame_counter, h.frame_time_ns, h.offset, payload), d]
            elif kind == 5:
                stream += [_v2_datagram(7, h.frame_counter, h.frame_time_ns + 1, h.offset, payload), d]
            elif kind == 6:
                stream += [_v2_datagram(7, h.frame_counter, h.frame_time_ns, h.offset, payload[:len(payload) // 2]), d]
            elif kind in (7, "overrun"):
                # as long as the sender's chunks: at the frame's last offset, one that overruns the frame
                stream += [_v2_datagram(7, h.frame_counter, h.frame_time_ns, h.offset,
                                        bytes(payload) + bytes(300 - len(payload))), d]
            elif kind == 8:
                stream += [_v2_datagram(7, (h.frame_counter + 40) & 0xFFFFFFFF, h.frame_time_ns, h.offset, payload), d]
            elif kind == 9:
                stream += [_v2_datagram(7, h.frame_counter, h.frame_time_ns, h.offset, payload, FRAME_BYTES + 4), d]
            else:
                stream.append(d)
    results = []
    for asm in (FrameAssembler(FRAME_BYTES, radar_id=7), _GeneralPathOnly(FRAME_BYTES, radar_id=7)):
        out = []
        for i, d in enumerate(stream):
            out += asm.feed(d, 1000 + i)
        out += asm.flush()
        results.append(([(f.frame_counter, f.frame_time_ns, bytes(f.data), f.valid, f.bytes_missing, f.last_receive_ns)
                         for f in out], asm.counters))
    assert results[0] == results[1]
    assert results[0][1].datagrams == len(stream)


def test_the_in_order_path_is_taken_and_gives_the_frames_sent():
    """Clean version 2 frames: every frame out whole and valid, and all but each frame's first datagram
    taken by the in-order path (counted by the general path's calls)."""
    calls = []

    class Counting(FrameAssembler):
        def _feed(self, datagram, recv_ns):
            calls.append(1)
            return super()._feed(datagram, recv_ns)

    iqs = frames(3)
    asm = Counting(FRAME_BYTES, radar_id=7)
    out = []
    n = 0
    for k, iq in enumerate(iqs):
        for d in encode_frame(7, 5 + k, 1_000 + k, iq, version=2):
            out += asm.feed(d, 1)
            n += 1
    assert [f.frame_counter for f in out] == [5, 6, 7]
    assert all(f.valid and bytes(f.data) == iq.tobytes() for f, iq in zip(out, iqs))
    assert len(calls) == 3 and n > 3 * 3
    assert asm.counters.datagrams == n and asm.counters.frames_complete == 3
