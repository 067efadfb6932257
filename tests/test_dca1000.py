"""DCA1000 raw capture: the real IWR1843 capture reassembled, the layout decoded, losses handled."""

import numpy as np
import pytest
from conftest import SHARED_DATA

from drivers.radar.dca1000 import (
    DATA_PORT,
    Dca1000Assembler,
    complex_1x_to_iq,
    decode_complex_1x,
    encode_data_packets,
    iq_to_complex_1x,
    parse_data_packet,
)
from drivers.radar.pcap import read_udp
from drivers.radar.ti_cfg import load_ti_cfg, parse_ti_cfg
from imaging.core.errors import ConfigError

DATA = SHARED_DATA / "dca1000_iwr1843_one_frame"


def test_cfg_gives_the_frame_layout_and_waveform():
    cfg = load_ti_cfg(DATA / "xwr18xx_profile.cfg")
    assert (cfg.n_rx, cfg.n_tx, cfg.adc_samples, cfg.loops) == (4, 2, 256, 16)
    assert cfg.tx_order == (0, 2) and cfg.chirps_per_frame == 32
    assert cfg.frame_bytes == 32 * 4 * 256 * 4
    wf = cfg.waveform()
    assert wf.f0_hz == 77e9 and wf.samples_per_chirp == 256 and wf.slope_hz_per_s == pytest.approx(70e12)
    assert wf.frame_interval_s == pytest.approx(0.1) and wf.chirp_interval_s == pytest.approx(486.14e-6)


def test_bad_cfg_names_the_command():
    with pytest.raises(ConfigError, match="profileCfg"):
        parse_ti_cfg("channelCfg 15 5 0\nframeCfg 0 1 16 0 100 1 0\nchirpCfg 0 0 0 0 0 0 0 1\n")
    with pytest.raises(ConfigError, match=r"chirpCfg \(line 2\).*exactly one TX"):
        parse_ti_cfg("profileCfg 0 77 429 7 57.14 0 0 70 1 256 5209 0 0 30\nchirpCfg 0 0 0 0 0 0 0 3\n"
                     "channelCfg 15 5 0\nframeCfg 0 0 16 0 100 1 0\n")


def test_real_capture_reassembles_sample_for_sample():
    cfg = load_ti_cfg(DATA / "xwr18xx_profile.cfg")
    packets = [d for d in read_udp(DATA / "one_frame.pcap") if d.dst_port == DATA_PORT]
    assert len(packets) == 12
    payload = b"".join(bytes(parse_data_packet(d.payload)[2]) for d in packets)
    asm = Dca1000Assembler(cfg.frame_bytes)
    frames = [f for d in packets for f in asm.feed(d.payload, d.time_ns)] + asm.flush()
    # The capture holds 16384 bytes: the first eighth of the frame its .cfg describes (131072 bytes).
    assert len(payload) == 16384 and len(frames) == 1
    frame = frames[0]
    assert not frame.valid and frame.bytes_missing == cfg.frame_bytes - 16384
    assert bytes(frame.data[:16384]) == payload  # samples equal to the packet payloads
    assert asm.counters.sequence_gaps == 0 and asm.counters.duplicates == 0
    iq = decode_complex_1x(frame.data, cfg.chirps_per_frame, cfg.n_rx, cfg.adc_samples)
    assert iq.shape == (32, 4, 256)
    flat = iq.reshape(-1)
    # Reference values of the same capture in the mmwave-capture-std tests.
    for k, v in {4065: 223 + 120j, 3293: -90 - 615j, 415: -88 + 193j, 1255: 366 - 21j, 2394: 745 - 301j}.items():
        assert flat[k] == v
    assert np.all(flat[4096:] == 0)


def test_loss_and_reorder_in_a_continuous_stream():
    frame_bytes = 4 * 4 * 64 * 4
    rng = np.random.default_rng(0)
    stream = rng.integers(-3000, 3000, frame_bytes * 3 // 2, dtype=np.int16).tobytes()  # three frames
    dgs = encode_data_packets(stream, payload_bytes=1000)
    dgs[4], dgs[5] = dgs[5], dgs[4]  # reordered
    del dgs[9]  # lost: bytes 9000..9999 fall in frame 2 (frames are 4096 bytes)
    dgs.insert(2, dgs[1])  # duplicated
    asm = Dca1000Assembler(frame_bytes)
    frames = [f for d in dgs for f in asm.feed(d)] + asm.flush()
    assert [f.index for f in frames] == [0, 1, 2]
    assert [f.valid for f in frames] == [True, True, False]
    assert frames[2].bytes_missing == 1000
    for f in frames[:2]:
        assert bytes(f.data) == stream[f.index * frame_bytes:(f.index + 1) * frame_bytes]
    got = bytes(frames[2].data)
    want = stream[2 * frame_bytes:3 * frame_bytes]
    lo, hi = 9000 - 2 * frame_bytes, 10000 - 2 * frame_bytes
    assert got[:lo] == want[:lo] and got[hi:] == want[hi:] and got[lo:hi] == bytes(1000)
    c = asm.counters
    assert c.duplicates == 1 and c.reordered == 1 and c.sequence_gaps >= 1 and c.bytes_lost == 1000


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=64), max_size=30))
def test_fuzz_assembler_never_raises(payloads):
    asm = Dca1000Assembler(256)
    for p in payloads:
        for f in asm.feed(p):
            assert len(f.data) == 256
    for f in asm.flush():
        assert len(f.data) == 256


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=300))
def test_fuzz_cfg_parser_fails_cleanly(text):
    try:
        parse_ti_cfg(text)
    except ConfigError:
        pass


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 4), st.integers(1, 4), st.integers(1, 8), st.integers(0, 2**31))
def test_complex_1x_layout_round_trips_and_matches_the_float_decoder(chirps, n_rx, pairs, seed):
    samples = 2 * pairs
    iq = np.random.default_rng(seed).integers(-32768, 32767, (chirps, n_rx, samples, 2), dtype=np.int16)
    wire = iq_to_complex_1x(iq)
    np.testing.assert_array_equal(complex_1x_to_iq(wire, chirps, n_rx, samples), iq)
    np.testing.assert_array_equal(decode_complex_1x(wire, chirps, n_rx, samples), iq[..., 0] + 1j * iq[..., 1].astype(np.float32))


def test_real_capture_replayed_on_loopback_through_the_driver():
    """The pcap's datagrams sent on loopback UDP, received by the radar driver loop with kernel time stamps,
    come out on the bus as one frame shaped by the .cfg whose samples equal the packet payloads."""
    import threading

    import zmq

    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.messages import Event, RadarFrameMessage
    from acquisition.replay import replay_pcap
    from drivers.radar.dca1000 import Dca1000Stream
    from drivers.radar.udp import UdpReceiver

    cfg = load_ti_cfg(DATA / "xwr18xx_profile.cfg")
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber(pub.endpoint, topics=["radar/", "event"], context=ctx)
    rx = UdpReceiver()
    stop = threading.Event()
    stream = Dca1000Stream(cfg)
    t = threading.Thread(target=radar_driver_loop, args=(rx, "iwr1843", stream, pub, stop))
    t.start()
    import time

    time.sleep(0.3)
    sent = replay_pcap(DATA / "one_frame.pcap", rx.address, DATA_PORT, speed=1.0)
    time.sleep(0.3)
    stop.set()
    t.join(5)
    messages = []
    while (m := sub.receive(timeout_ms=500)) is not None:
        messages.append(m)
    rx.close()
    pub.close()
    sub.close()
    ctx.term()
    frames = [RadarFrameMessage.from_message(m).frame for m in messages if m.topic == RadarFrameMessage.topic_of("iwr1843")]
    assert sent == 12 and stream.counters.datagrams == 12 and stream.counters.sequence_gaps == 0
    assert len(frames) == 1
    iq = frames[0].iq
    assert iq.shape == (cfg.chirps_per_frame, cfg.n_rx, cfg.adc_samples, 2) == (32, 4, 256, 2)
    payload = b"".join(bytes(parse_data_packet(d.payload)[2]) for d in read_udp(DATA / "one_frame.pcap") if d.dst_port == DATA_PORT)
    flat = iq.reshape(-1, 2)
    np.testing.assert_array_equal(flat[:4096], complex_1x_to_iq(payload, 1, 1, 4096).reshape(-1, 2))
    assert flat[4065].tolist() == [223, 120] and not np.any(flat[4096:])
    # The capture holds an eighth of the frame: it is passed on, zero-filled and marked invalid, and said so.
    assert frames[0].valid is False and frames[0].bytes_missing == cfg.frame_bytes - 16384
    assert frames[0].receive_ns > 1.6e18  # a kernel time stamp, not a placeholder
    assert any("bytes_lost +114688" in Event.from_message(m).message for m in messages if m.topic == Event.TOPIC)
