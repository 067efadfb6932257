"""UDP GRO over real loopback sockets: a segmented send (``UdpSender``) reaches a ``UdpReceiver`` as batches
(``receive_segments``), a plain send as batches of one, and the driver loop publishes from batches exactly the
frames that feeding the datagrams one by one gives."""

import socket
import threading
import time

import numpy as np
import pytest

from drivers.radar.registry import PackedDatagrams
from drivers.radar.stream import feed_segments
from drivers.radar.udp import UdpReceiver, UdpSender


def _gro_receiver(**kwargs) -> UdpReceiver:
    rx = UdpReceiver("127.0.0.1", 0, coalesce_s=0, **kwargs)
    if not rx.gro:  # Linux before 5.0: nothing to test here (the fallback is every other test's receiver)
        rx.close()
        pytest.skip("this kernel refuses UDP_GRO")
    _stamps_on()
    return rx


def _stamps_on() -> None:
    """Let receive stamps take effect: the first socket on the machine to ask for them switches the kernel's
    stamping on a moment later (a deferred static key), and datagrams before that come unstamped."""
    time.sleep(0.05)


def _numbered(count: int, size: int, last: int) -> list[bytes]:
    """``count`` datagrams of ``size`` bytes (the last ``last`` bytes), each filled with its own number."""
    return [bytes([k % 251]) * (last if k == count - 1 else size) for k in range(count)]


def _batches(rx: UdpReceiver, want_bytes: int, timeout_s: float = 5.0) -> list[tuple[bytes, int, int, int]]:
    """Every batch until ``want_bytes`` bytes came (copied: the receiver's buffer is reused)."""
    out, got, deadline = [], 0, time.monotonic() + timeout_s
    while got < want_bytes and time.monotonic() < deadline:
        if (b := rx.receive_segments()) is not None:
            out.append((bytes(b[0]), b[1], b[2], b[3]))
            got += len(b[0])
    return out


def test_a_segmented_send_arrives_in_batches_with_every_datagram_in_order_and_the_kernel_stamp():
    rx = _gro_receiver()
    tx = UdpSender()
    assert tx.segmented
    datagrams = _numbered(150, 1000, 700)  # 64 + 64 + 22 a send, the last one short
    before = time.time_ns()
    tx.send(PackedDatagrams(np.frombuffer(b"".join(datagrams), np.uint8), 1000), rx.address)
    batches = _batches(rx, sum(map(len, datagrams)))
    after = time.time_ns()
    rx.close(), tx.close()
    assert len(batches) == 3  # one receive a send, not 150
    assert [len(b) for b, *_ in batches] == [64_000, 64_000, 21_700]
    assert all(size == 1000 for _, size, _, _ in batches)
    got = [b[o:o + size] for b, size, _, _ in batches for o in range(0, len(b), size)]
    assert got == datagrams  # every datagram, in order, the short last one whole
    assert all(before <= t_ns <= after for _, _, t_ns, _ in batches)
    assert all(drops == 0 for *_, drops in batches)


def test_plain_datagrams_arrive_as_batches_of_one_and_receive_still_gives_datagrams_one_by_one():
    rx = _gro_receiver()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plain = [bytes([k]) * (100 + 37 * k) for k in range(10)]
    for d in plain:
        tx.sendto(d, rx.address)
    batches = _batches(rx, sum(map(len, plain)))
    assert [b for b, *_ in batches] == plain and [size for _, size, _, _ in batches] == [len(d) for d in plain]
    sender = UdpSender()  # a GRO socket behind the old receive(): the batch handed out a datagram at a time
    datagrams = _numbered(70, 500, 123)
    sender.send(PackedDatagrams(np.frombuffer(b"".join(datagrams), np.uint8), 500), rx.address)
    one_by_one, stamps = [], set()
    deadline = time.monotonic() + 5
    while len(one_by_one) < len(datagrams) and time.monotonic() < deadline:
        if (got := rx.receive()) is not None:
            one_by_one.append(got[0])
            stamps.add(got[1])
    rx.close(), tx.close(), sender.close()
    assert one_by_one == datagrams
    assert len(stamps) == 2  # 64 datagrams with one stamp, then 6 with the next send's


def test_feed_segments_feeds_each_datagram_of_a_batch_or_hands_the_batch_to_the_streams_own_method():
    class Collecting:
        def __init__(self):
            self.fed = []

        def feed(self, datagram, receive_ns):
            self.fed.append((datagram, receive_ns))
            return [len(self.fed)] if len(self.fed) % 3 == 0 else []

    stream = Collecting()
    batch = memoryview(b"".join(_numbered(7, 10, 4)))
    assert feed_segments(stream, batch, 10, 55) == [3, 6]
    assert stream.fed == [(d, 55) for d in _numbered(7, 10, 4)]
    assert feed_segments(stream, memoryview(b""), 0, 56) == [] and stream.fed[-1] == (b"", 56)
    with pytest.raises(ValueError, match="segment_bytes"):
        feed_segments(stream, batch, 0, 57)

    class Batching(Collecting):
        def feed_segments(self, buffer, segment_bytes, receive_ns):
            self.fed.append((bytes(buffer), segment_bytes, receive_ns))
            return ["batch"]

    own = Batching()
    assert feed_segments(own, batch, 10, 58) == ["batch"] and own.fed == [(bytes(batch), 10, 58)]


class _Collect:
    """The driver loop's publisher, keeping what it is given."""

    def __init__(self):
        self.sent = []

    def send(self, message):
        self.sent.append(message)


def _send_runs(tx: UdpSender, datagrams: list[bytes], address) -> None:
    """Send ``datagrams`` in order, each run of one size in segmented sends (as replay does)."""
    run: list[bytes] = []
    for d in datagrams + [b""]:
        if run and (len(d) != len(run[0]) or len(run[-1]) != len(run[0])):
            tx.send(PackedDatagrams(np.frombuffer(b"".join(run), np.uint8), len(run[0])), address)
            run = []
        run.append(d)


def _run_loop(rx: UdpReceiver, stream, send) -> tuple[list, list[str]]:
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.messages import Event, RadarFrameMessage

    pub, stop = _Collect(), threading.Event()
    driver = threading.Thread(target=radar_driver_loop, args=(rx, "left", stream, pub, stop),
                              kwargs={"report_every_s": 0.1})
    driver.start()
    send()
    time.sleep(0.5)
    stop.set()
    driver.join(5)
    frames = [m.frame for m in pub.sent if isinstance(m, RadarFrameMessage)]
    return frames, [m.message for m in pub.sent if isinstance(m, Event)]


def test_the_driver_loop_publishes_from_batches_the_frames_that_feeding_datagram_by_datagram_gives():
    """SRF1 frames with a datagram lost, two swapped and one duplicated, sent as replay sends them: the loop
    over a GRO socket publishes the same frames (counters, times, validity, bytes) as a stream fed the same
    datagrams one by one, and the same trouble counters."""
    from drivers.radar.srf1 import Srf1Stream, encode_frame
    from drivers.radar.stream import trouble

    shape = (16, 4, 64, 2)
    rng = np.random.default_rng(3)
    wire = []
    for k in range(8):
        wire.append(encode_frame(7, k, 1_000_000_000 + k * 52_000_000, rng.integers(-3000, 3000, shape, dtype=np.int16)))
    del wire[2][5]  # lost
    wire[4][3], wire[4][4] = wire[4][4], wire[4][3]  # reordered
    wire[6].insert(7, wire[6][6])  # duplicated
    datagrams = [d for frame in wire for d in frame]
    assert len({len(d) for d in datagrams}) > 1  # a frame's last datagram is short: runs of several sizes

    rx, tx = _gro_receiver(), UdpSender()
    batches = []
    receive_segments = rx.receive_segments

    def counting():
        got = receive_segments()
        if got is not None:
            batches.append(len(got[0]) // max(got[1], 1))
        return got

    rx.receive_segments = counting
    frames, events = _run_loop(rx, stream := Srf1Stream(shape[:3], radar_id=7), lambda: _send_runs(tx, datagrams, rx.address))
    rx.close(), tx.close()
    reference = Srf1Stream(shape[:3], radar_id=7)
    want = [f for d in datagrams for f in reference.feed(d, 1)] + reference.flush()
    assert max(batches) > 1 and len(batches) < len(datagrams) / 4  # batches, not a receive per datagram
    assert [(f.frame_counter, f.frame_time_ns, f.valid, f.bytes_missing, f.ptp_locked) for f in frames] == \
        [(f.frame_counter, f.frame_time_ns, f.valid, f.bytes_missing, f.ptp_locked) for f in want]
    assert all(a.iq.tobytes() == b.iq.tobytes() for a, b in zip(frames, want))
    assert not all(f.valid for f in want)  # the loss shows
    assert trouble(stream.counters) == trouble(reference.counters) and trouble(stream.counters)["duplicates"] == 1
    assert all(f.receive_ns > 0 for f in frames)
    assert not any("kernel dropped" in e for e in events)


def test_kernel_drops_of_batches_are_reported_by_the_driver_loop():
    """A receive buffer far too small for a burst of segmented sends: the kernel drops whole batches, and the
    loop says so in an event (with GRO the counter counts receives, each a batch)."""
    from drivers.radar.srf1 import Srf1Stream

    rx, tx = _gro_receiver(rcvbuf_bytes=1 << 16), UdpSender()
    burst = PackedDatagrams(np.zeros(64 * 1000 * 40, np.uint8), 1000)

    tx.send(burst, rx.address)  # before the loop reads: most of the burst cannot fit

    def send():
        time.sleep(0.2)
        tx.sendto(b"x", rx.address)  # a later datagram carries the drop counter

    frames, events = _run_loop(rx, Srf1Stream((16, 4, 64), radar_id=7), send)
    rx.close(), tx.close()
    dropped = [e for e in events if e.startswith("kernel dropped")]
    assert dropped and all("receive(s) (UDP GRO" in e for e in dropped)
    assert rx.kernel_drops >= 30  # of 40 batches of 64 kB, a 64 kB buffer holds one or two


def test_over_loopback_a_socket_without_gro_stamps_a_segmented_sends_datagrams_alike_so_batches_change_no_stamp():
    """What the docs' "exact over loopback" rests on: the kernel stamps a segmented send once, and a socket
    without GRO sees that stamp on every datagram cut from it (64, 64, 22 of a 150-datagram frame), the very
    grouping a GRO socket gets as batches."""
    rx = UdpReceiver("127.0.0.1", 0, coalesce_s=0, gro=False)
    assert not rx.gro
    _stamps_on()
    tx = UdpSender()
    for _ in range(2):
        tx.send(PackedDatagrams(np.zeros(150 * 1000, np.uint8), 1000), rx.address)
        time.sleep(0.01)
    stamps = []
    deadline = time.monotonic() + 5
    while len(stamps) < 300 and time.monotonic() < deadline:
        if (got := rx.receive_segments()) is not None:
            assert got[1] == len(got[0]) == 1000  # no GRO: batches of one
            stamps.append(got[2])
    rx.close(), tx.close()
    runs = [stamps.count(s) for s in dict.fromkeys(stamps)]
    assert runs == [64, 64, 22, 64, 64, 22] and 0 not in stamps
