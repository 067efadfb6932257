"""Xbus/MTData2 framing and the streaming parser: round trips, noise, cuts, checksums, fuzzing."""

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.xbus import (
    STATUS_SYNC_IN,
    ImuPacket,
    XbusParser,
    checksum,
    decode_mtdata2,
    encode_message,
    encode_mtdata2,
)


def packets(n, start=0):
    return [ImuPacket(counter=(start + k) & 0xFFFF, sample_time_fine=25 * k, accel_mps2=(0.1 * k, -0.2, 9.81),
                      gyro_radps=(0.001, -0.002, 0.003 * k), status=STATUS_SYNC_IN if k == 3 else 0) for k in range(n)]


def same(a: ImuPacket, b: ImuPacket):
    return (a.counter == b.counter and a.sample_time_fine == b.sample_time_fine and a.status == b.status
            and all(abs(x - y) < 1e-5 * max(1, abs(x)) for x, y in zip(a.accel_mps2 + a.gyro_radps, b.accel_mps2 + b.gyro_radps)))


def test_checksum_makes_the_sum_zero():
    msg = encode_message(0x36, bytes(range(20)))
    assert sum(msg[1:]) & 0xFF == 0
    assert msg[0] == 0xFA and msg[1] == 0xFF and msg[3] == 20
    long_msg = encode_message(0x36, bytes(300))
    assert long_msg[3] == 0xFF and long_msg[4:6] == (300).to_bytes(2, "big") and sum(long_msg[1:]) & 0xFF == 0
    assert checksum(b"\xff\x30\x00") == (-0x12F) & 0xFF


def test_round_trip_in_arbitrary_chunks():
    sent = packets(50)
    stream = b"".join(encode_mtdata2(p) for p in sent)
    parser = XbusParser()
    got = []
    rng = random.Random(1)
    i = 0
    while i < len(stream):
        n = rng.randint(1, 17)
        got += parser.feed(stream[i:i + n])
        i += n
    assert len(got) == 50 and all(same(a, b) for a, b in zip(sent, got))
    assert got[3].sync_in and not got[4].sync_in
    assert parser.counters.checksum_errors == 0 and parser.counters.bytes_skipped == 0


def test_noise_wrong_checksums_and_a_cut_lose_only_what_they_touch():
    sent = packets(20)
    msgs = [bytearray(encode_mtdata2(p)) for p in sent]
    msgs[5][10] ^= 0x40  # corrupted: checksum fails
    msgs[9] = msgs[9][:12]  # cut in the middle (the line dropped the rest)
    stream = b"\x00\x13\xfa\x01garbage" + b"".join(bytes(m[:]) if k != 12 else b"\xfa\xff\x36" + bytes(m) for k, m in enumerate(msgs))
    parser = XbusParser()
    got = parser.feed(stream)
    counters = [p.counter for p in got]
    assert 5 not in counters and 9 not in counters
    assert set(range(20)) - {5, 9} == set(counters)
    assert parser.counters.checksum_errors >= 1 and parser.counters.bytes_skipped > 0
    assert parser.counters.counter_gaps == 2 and parser.counters.packets_missed == 2


def test_counter_wraps_without_a_gap():
    parser = XbusParser()
    got = parser.feed(b"".join(encode_mtdata2(p) for p in packets(6, start=65533)))
    assert [p.counter for p in got] == [65533, 65534, 65535, 0, 1, 2]
    assert parser.counters.counter_gaps == 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 399))
def test_fuzz_parser_never_raises_and_keeps_good_messages(noise, cut):
    good = [encode_mtdata2(p) for p in packets(3)]
    stream = noise[:cut] + good[0] + noise[cut:] + good[1] + good[2]
    parser = XbusParser()
    got = parser.feed(stream)
    counters = [p.counter for p in got]
    # Noise may swallow the message it runs into, never the ones after a clean boundary.
    assert 1 in counters and 2 in counters


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_fuzz_decode_mtdata2(data):
    try:
        decode_mtdata2(data)
    except ValueError:
        pass
