"""The IMU driver on a real pseudo-terminal fed by the Xbus emulator."""

import time

import numpy as np
import pytest

from drivers.emulators import XbusPty
from drivers.imu import ImuClock, ImuDriver

T_TRIGGER = 1_700_000_000_000_000_000


def run(emulator, n_expected, timeout_s=20.0):
    driver = ImuDriver(emulator.port, trigger_time_ns=T_TRIGGER)
    emulator.start()
    got = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n_expected and time.monotonic() < deadline:
        got += driver.read()
    emulator.close()
    driver.close()
    return got, driver


def test_samples_come_through_the_pty_unchanged_and_on_the_ptp_time_base():
    rng = np.random.default_rng(0)
    n = 800
    gyro, accel = rng.normal(0, 0.1, (n, 3)), rng.normal([0, 0, 9.81], 0.2, (n, 3))
    emu = XbusPty(gyro, accel, rate_hz=400.0, trigger_index=5)
    got, driver = run(emu, n - 5)
    assert len(got) == n - 5  # samples before the trigger have no PTP time and are dropped
    assert driver.dropped_before_trigger == 5
    np.testing.assert_allclose([s.gyro_radps for s in got], gyro[5:], rtol=1e-6, atol=1e-7)  # float32 on the wire
    np.testing.assert_allclose([s.accel_mps2 for s in got], accel[5:], rtol=1e-6)
    times = np.array([s.time_ns for s in got])
    assert times[0] == T_TRIGGER and got[0].sync_in
    np.testing.assert_array_equal(np.diff(times), 2_500_000)  # 25 ticks of 100 us at 400 Hz
    assert [s.counter for s in got] == list(range(5, n))
    assert driver.parser.counters.counter_gaps == 0


def test_line_noise_and_corrupted_packets_lose_only_themselves():
    rng = np.random.default_rng(1)
    n = 300
    gyro, accel = rng.normal(0, 0.1, (n, 3)), rng.normal([0, 0, 9.81], 0.2, (n, 3))
    noise = lambda k: bytes(rng.integers(0, 256, 7, dtype=np.uint8)) + b"\xfa\xff\x36" if k % 50 == 25 else b""  # noqa: E731
    emu = XbusPty(gyro, accel, rate_hz=400.0, noise=noise)
    got, driver = run(emu, n, timeout_s=10.0)
    # A partial header right before a packet can swallow that packet (its checksum then fails); all others arrive.
    counters = [s.counter for s in got]
    assert len(got) >= n - 6
    missing = set(range(n)) - set(counters)
    assert all(k % 50 == 25 for k in missing)
    assert driver.parser.counters.bytes_skipped > 0


def test_tick_counter_wraps_and_drift_is_estimated():
    clock = ImuClock(trigger_time_ns=0)
    ticks = [clock.unwrap(t & 0xFFFFFFFF) for t in range(2**32 - 50, 2**32 + 50)]
    assert ticks == list(range(2**32 - 50, 2**32 + 50))
    clock.trigger_ticks = ticks[0]
    assert clock.time_ns(ticks[-1]) == 99 * 100_000
    # Host clock 30 ppm fast against the IMU clock.
    for k in range(200):
        clock.observe(k * 100, int(k * 100 * 100_000 * (1 + 30e-6)))
    assert clock.drift_ppm() == pytest.approx(30.0, abs=0.5)


def test_packets_without_a_counter_are_recorded_with_the_no_counter_mark():
    """An Xsens configured without the packet counter: the production driver loop publishes its samples
    (with NO_COUNTER) instead of crashing on a counter of -1."""
    import threading

    import zmq

    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.driver_loops import imu_driver_loop
    from acquisition.messages import ImuBatch
    from drivers.imu import NO_COUNTER

    n = 200
    emu = XbusPty(np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)), rate_hz=400.0, start_counter=None)
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber(pub.endpoint, topics=[ImuBatch.TOPIC], context=ctx)
    stop = threading.Event()
    loop = threading.Thread(target=imu_driver_loop, args=(emu.port, pub, stop, T_TRIGGER))
    loop.start()
    time.sleep(0.3)
    emu.start()
    batches = []
    deadline = time.monotonic() + 10
    while sum(len(b) for b in batches) < n and time.monotonic() < deadline:
        m = sub.receive(timeout_ms=100)
        if m is not None:
            batches.append(ImuBatch.from_message(m))
    stop.set()
    loop.join(5)
    emu.close()
    pub.close(), sub.close(), ctx.term()
    assert not loop.is_alive()
    counters = np.concatenate([b.counter for b in batches])
    assert counters.size == n and counters.dtype == np.uint32
    assert np.all(counters == NO_COUNTER)
    np.testing.assert_array_equal(np.diff(np.concatenate([b.time_ns for b in batches])), 2_500_000)
