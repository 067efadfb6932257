"""The ZeroMQ bus over real sockets: order, zero-copy arrays, sequence checking, counted drops."""

import time

import numpy as np
import pytest
import zmq

from acquisition.bus import BusPublisher, BusSubscriber


@pytest.fixture
def pair():
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber(pub.endpoint, topics=["radar/", "imu"], context=ctx)
    time.sleep(0.2)  # let the subscription reach the publisher (slow-joiner)
    yield pub, sub
    pub.close()
    sub.close()
    ctx.term()


def test_messages_arrive_in_order_with_their_arrays(pair):
    pub, sub = pair
    frames = [np.arange(24, dtype=np.int16).reshape(2, 3, 4) + k for k in range(200)]
    for k, f in enumerate(frames):
        pub.publish("radar/left_front", 1_000 + k, [f, np.array([k], np.uint32)], valid=True)
        if k % 20 == 0:
            pub.publish("imu", k, [np.full(3, 9.81)])
    pub.publish("other", 0)  # not subscribed
    got = []
    while (m := sub.receive(timeout_ms=500)) is not None:
        got.append(m)
    radar = [m for m in got if m.topic == "radar/left_front"]
    assert [m.seq for m in radar] == list(range(200))
    for m, f in zip(radar, frames):
        np.testing.assert_array_equal(m.arrays[0], f)
        assert m.arrays[0].dtype == np.int16 and m.header["valid"] is True
        assert m.sensor_time_ns == 1_000 + m.seq and m.host_time_ns > 0
    assert all(m.topic != "other" for m in got)
    assert sub.stats["radar/left_front"].missed == 0 and sub.stats["imu"].received == 10
    # Zero-copy: the array is a view on the received ZeroMQ frame, not a copy.
    assert not radar[0].arrays[0].flags.owndata


def test_an_empty_array_crosses_the_bus(pair):
    """A scan with no detection is a message with [0, 3] and [0] arrays (it crashed the odometry worker's
    publish: a memoryview of an empty array cannot be cast)."""
    pub, sub = pair
    pub.publish("radar/left_front", 7, [np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.ones(2)])
    m = sub.receive(timeout_ms=1000)
    assert m is not None and [a.shape for a in m.arrays] == [(0, 3), (0,), (2,)]
    assert m.arrays[0].dtype == np.float32 and m.arrays[2].tolist() == [1.0, 1.0]


def test_a_gap_in_the_sequence_is_counted(pair):
    pub, sub = pair
    for k in range(10):
        if k in (3, 4, 7):
            pub._seq["radar/x"] += 1  # as if the message had been dropped on the way
            continue
        pub.publish("radar/x", k)
    while sub.receive(timeout_ms=300) is not None:
        pass
    st = sub.stats["radar/x"]
    assert st.received == 7 and st.missed == 3 and st.gaps == 2


def test_a_slow_subscriber_loses_messages_but_counts_every_one():
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx, high_water_mark=50)
    sub = BusSubscriber(pub.endpoint, context=ctx, high_water_mark=50)
    time.sleep(0.2)
    big = np.zeros(100_000, np.uint8)
    n = 3000
    for k in range(n):
        pub.publish("radar/flood", k, [big])
    received, last_seen = 0, -1
    while (m := sub.receive(timeout_ms=500)) is not None:
        received += 1
        last_seen = m.seq
    st = sub.stats["radar/flood"]
    assert received < n  # the queues overflowed
    assert st.received + st.missed == last_seen + 1  # every message up to the last one seen is accounted for
    assert st.missed > 0 and st.gaps > 0
    pub.close()
    sub.close()
    ctx.term()


def test_a_short_queue_for_one_endpoint_stays_short_beside_a_long_one():
    """A worker's radar frames get a 50-frame queue, its IMU the default 10,000, in one subscriber. ZeroMQ
    applies a socket's last ZMQ_RCVHWM to all its connections: on one socket the frames' queue became
    10,000 long (7 GB of frames) and a slow worker's memory grew without bound, nothing dropped. Flooded
    while it reads nothing, the subscriber now holds about the two 50-frame queues (plus what the kernel's
    socket buffers hold), and counts the rest as lost."""
    ctx = zmq.Context()
    frames = BusPublisher("tcp://127.0.0.1:0", context=ctx, high_water_mark=50)
    imu = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber([frames.endpoint, imu.endpoint], context=ctx, high_water_marks={frames.endpoint: 50})
    time.sleep(0.3)
    big = np.zeros(200_000, np.uint8)
    n = 1000
    for k in range(n):
        frames.publish("radar/flood", k, [big])
        imu.publish("imu", k, [np.zeros(3)])
        time.sleep(0.0002)  # the flood over 0.2 s or more: ZeroMQ's I/O threads keep up with it
    time.sleep(0.5)
    received = 0
    while (m := sub.receive(timeout_ms=500)) is not None:
        received += m.topic == "radar/flood"
    frames.publish("radar/flood", n, [big])  # one more, after the gap: the loss shows in its sequence number
    while (m := sub.receive(timeout_ms=500)) is not None:
        received += m.topic == "radar/flood"
    st = sub.stats["radar/flood"]
    assert received < 300, received  # 50 + 50 + the kernel's buffers; it was all 1000
    assert st.received == received and st.received + st.missed == n + 1
    assert sub.stats["imu"].received == n and sub.stats["imu"].missed == 0  # the long queue is still long
    for p in (frames, imu):
        p.close()
    sub.close()
    ctx.term()


def test_several_publishers_of_one_topic_are_not_gaps():
    """Every driver publishes "event": their sequence numbers are each their own, not one topic's."""
    ctx = zmq.Context()
    pubs = [BusPublisher("tcp://127.0.0.1:0", context=ctx) for _ in range(3)]
    sub = BusSubscriber([p.endpoint for p in pubs], topics=["event"], context=ctx)
    time.sleep(0.3)
    for k in range(20):
        for p in pubs[: 1 + k % 3]:
            p.publish("event", k)
    pubs[1]._seq["event"] += 2  # and one publisher really loses two
    pubs[1].publish("event", 99)
    while sub.receive(timeout_ms=300) is not None:
        pass
    st = sub.stats["event"]
    assert st.received == 20 + 13 + 6 + 1 and st.missed == 2 and st.gaps == 1
    for p in pubs:
        p.close()
    sub.close()
    ctx.term()


def test_the_health_line_tells_a_drifting_imu_clock_from_one_at_another_rate():
    """A crystal drifts tens of ppm; a replay at 0.5x (the demo) makes the IMU's clock run at half the host's,
    which the line says as a rate rather than as +1,000,000 ppm of drift."""
    from acquisition.messages import ClockState, Health

    def line(drift_ppm):
        clock = ClockState({"left": True}, True, drift_ppm)
        return Health({"left": 19.2}, 400.0, 0, 0, 0, {"left": 0}, 0, None, {}, clock).line()

    assert "IMU clock drift +12.3 ppm" in line(12.3) and "IMU clock drift -850.0 ppm" in line(-850.0)
    assert "IMU clock drift unknown" in line(None)
    assert "IMU clock drift unknown" in line(float("nan"))  # a recording's "not known" (was "clock at nanx")
    assert "IMU clock at 0.50x host time (a replay at that speed?)" in line(1e6)  # replayed at 0.5x
    assert "IMU clock at 2.00x host time" in line(-5e5)  # at 2x
    assert "ppm" not in line(1e6)
