"""Radar frames over real loopback UDP: SRF1 emulation in, reassembly with kernel timestamps out."""

import socket
import threading
import time

import numpy as np

from drivers.radar.srf1 import FrameAssembler, encode_frame
from drivers.radar.udp import UdpReceiver

SHAPE = (64, 4, 175, 2)
FRAME_BYTES = int(np.prod(SHAPE)) * 2


def test_frames_over_loopback_udp_arrive_whole_with_kernel_timestamps():
    rx = UdpReceiver()
    assert rx.rcvbuf_bytes >= 4 << 20
    rng = np.random.default_rng(0)
    frames = [rng.integers(-2000, 2000, SHAPE, dtype=np.int16) for _ in range(20)]
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send():
        for k, iq in enumerate(frames):
            for d in encode_frame(1, k, 1_700_000_000_000_000_000 + k * 52_000_000, iq):
                tx.sendto(d, rx.address)
            time.sleep(0.002)

    t = threading.Thread(target=send)
    before = time.time_ns()
    t.start()
    asm = FrameAssembler(FRAME_BYTES, radar_id=1)
    out = []
    deadline = time.monotonic() + 10
    while len(out) < len(frames) and time.monotonic() < deadline:
        got = rx.receive()
        if got is None:
            continue
        data, t_ns, drops = got
        out += asm.feed(data, t_ns)
    t.join()
    assert len(out) == 20 and all(f.valid for f in out)
    for f, iq in zip(out, frames):
        np.testing.assert_array_equal(f.iq(SHAPE), iq)
    # Kernel receive time stamps: real, increasing, within the test's own span.
    stamps = [f.last_receive_ns for f in out]
    assert before <= stamps[0] <= time.time_ns() and np.all(np.diff(stamps) > 0)
    assert rx.kernel_drops == 0 and asm.counters.bytes_lost == 0
    rx.close()
    tx.close()


def _stop_and_drain(stop: threading.Event, driver: threading.Thread, sub) -> tuple[list, list[str]]:
    """Let the last datagrams land, stop the driver loop, and take every frame and event it published."""
    from acquisition.messages import Event, RadarFrameMessage

    time.sleep(0.5)
    stop.set()
    driver.join(5)
    frames, events = [], []
    while (m := sub.receive(timeout_ms=300)) is not None:
        if m.topic == Event.TOPIC:
            events.append(Event.from_message(m).message)
        else:
            frames.append(RadarFrameMessage.from_message(m).frame)
    return frames, events


def test_wire_faults_through_a_proxy_never_give_a_wrong_valid_frame():
    """SRF1 v2 through a real UDP proxy that drops, duplicates, reorders, truncates and flips bits, with
    datagrams of another radar mixed in, and a spoofer on another address sending the radar's counters:
    through the production driver loop, every frame marked valid is bit for bit the one sent."""
    import random
    import socket
    import threading
    import time

    import zmq

    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.messages import Event, RadarFrameMessage
    from drivers.radar.srf1 import Srf1Stream

    shape = (16, 4, 64, 2)
    rng = np.random.default_rng(11)
    sent = {100 + k: rng.integers(-3000, 3000, shape, dtype=np.int16) for k in range(60)}
    rx = UdpReceiver("127.0.0.1", 0, accept_from="127.0.0.1")
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber(pub.endpoint, topics=[RadarFrameMessage.TOPIC, Event.TOPIC], context=ctx)
    stop = threading.Event()
    driver = threading.Thread(target=radar_driver_loop, args=(rx, "left", Srf1Stream(shape[:3], radar_id=7), pub, stop))
    driver.start()
    time.sleep(0.3)
    faults = random.Random(5)
    proxy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    proxy.bind(("127.0.0.1", 0))
    spoofer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    spoofer.bind(("127.0.0.2", 0))
    held = None
    counts = dict.fromkeys(("drop", "dup", "reorder", "truncate", "flip", "other_radar", "spoof", "late"), 0)
    encoded = {}
    for counter, iq in sent.items():
        encoded[counter] = encode_frame(7, counter, 1_000_000_000 + counter, iq)
        for d in encoded[counter]:
            r = faults.random()
            out = [d]
            if r < 0.01 and counter - 10 in encoded:  # a datagram of a frame 6-10 back, resent late
                counts["late"] += 1
                old = encoded[counter - faults.randrange(6, 11)]
                out = [d, old[faults.randrange(len(old))]]
            elif r < 0.03:
                counts["drop"] += 1
                out = []
            elif r < 0.06:
                counts["dup"] += 1
                out = [d, d]
            elif r < 0.09 and held is None:
                counts["reorder"] += 1
                held, out = d, []
            elif r < 0.11:
                counts["truncate"] += 1
                out = [d[: faults.randrange(10, len(d))]]
            elif r < 0.14:
                counts["flip"] += 1
                b = bytearray(d)
                b[faults.randrange(len(b))] ^= 1 << faults.randrange(8)
                out = [bytes(b)]
            elif r < 0.16:
                counts["other_radar"] += 1
                out = [d, encode_frame(9, counter, 0, np.zeros(shape, np.int16))[0]]
            elif r < 0.18:
                counts["spoof"] += 1
                spoofer.sendto(encode_frame(7, counter, 1_000_000_000 + counter, np.zeros(shape, np.int16))[0], rx.address)
            for x in out:
                proxy.sendto(x, rx.address)
            if held is not None and out:
                proxy.sendto(held, rx.address)
                held = None
        time.sleep(0.002)
    frames, events = _stop_and_drain(stop, driver, sub)
    rx.close(), proxy.close(), spoofer.close(), pub.close(), sub.close(), ctx.term()
    assert all(n > 0 for n in counts.values()), counts
    assert len({f.frame_counter for f in frames}) == len(frames)  # no counter passed on twice
    valid = [f for f in frames if f.valid]
    # About 14 % of datagrams are hit and a frame is six datagrams: some 40 % of frames come through whole.
    assert len(valid) > 12 and len(frames) - len(valid) > 12
    for f in valid:
        np.testing.assert_array_equal(f.iq, sent[f.frame_counter])
        assert f.frame_time_ns == 1_000_000_000 + f.frame_counter
    text = " ".join(events)
    assert "crc_errors +" in text and "wrong_radar +" in text and "foreign_source +" in text


def test_late_duplicates_through_a_proxy_lose_nothing_and_write_no_counter_twice():
    """One datagram of frame k resent while frame k+6..k+10 arrives, through a real UDP proxy and the
    production driver loop: every frame comes through once, whole and valid; the late datagrams are counted
    in the events, and no bytes are reported lost (the assembler used to resync on them: the frame being
    assembled came out as two invalid partial rows and the counters in between were written twice)."""
    import threading

    import zmq

    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.messages import Event, RadarFrameMessage
    from drivers.radar.srf1 import Srf1Stream

    shape = (16, 4, 64, 2)
    rng = np.random.default_rng(12)
    first = 2**32 - 20  # the counter wraps on the way
    sent = {(first + k) & 0xFFFFFFFF: rng.integers(-3000, 3000, shape, dtype=np.int16) for k in range(40)}
    rx = UdpReceiver("127.0.0.1", 0)
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber(pub.endpoint, topics=[RadarFrameMessage.TOPIC, Event.TOPIC], context=ctx)
    stop = threading.Event()
    driver = threading.Thread(target=radar_driver_loop, args=(rx, "left", Srf1Stream(shape[:3], radar_id=7), pub, stop),
                              kwargs={"report_every_s": 0.2})
    driver.start()
    time.sleep(0.3)
    proxy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    encoded, late = [], 0
    for k, (counter, iq) in enumerate(sent.items()):
        encoded.append(encode_frame(7, counter, 1_000_000_000 + k * 52_000_000, iq))
        for j, d in enumerate(encoded[-1]):
            proxy.sendto(d, rx.address)
            if j == 2 and k >= 10 and k % 3 == 0:
                back = encoded[k - (6 + k % 5)]
                proxy.sendto(back[k % len(back)], rx.address)
                late += 1
        time.sleep(0.003)
    frames, events = _stop_and_drain(stop, driver, sub)
    rx.close(), proxy.close(), pub.close(), sub.close(), ctx.term()
    assert late == 10
    assert [f.frame_counter for f in frames] == list(sent)  # each once, in order, across the wrap
    assert all(f.valid for f in frames)
    for f in frames:
        np.testing.assert_array_equal(f.iq, sent[f.frame_counter])
    text = " ".join(events)
    assert sum(int(n) for e in events for n in _rises(e, "late_datagrams")) == late
    assert "bytes_lost" not in text and "resyncs" not in text and "frames_incomplete" not in text


def _rises(event: str, counter: str) -> list[str]:
    """The rises of ``counter`` in an event's text ("late_datagrams +2, duplicates +1")."""
    return [part.split("+")[1] for part in event.split(", ") if part.startswith(counter + " +")]


SENDER = """
import socket, sys, time
port, n = int(sys.argv[1]), int(sys.argv[2])
tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
payload = bytes(1400)
t0 = time.perf_counter()
for k in range(n):  # one datagram every 100 us, as a radar's burst arrives on the wire
    while time.perf_counter() < t0 + k * 1e-4:
        pass
    tx.sendto(payload, ("127.0.0.1", port))
"""


def _wakeups_to_receive(coalesce_s: float, n: int = 2000) -> tuple[int, int]:
    """(datagrams received, times the receiving thread slept) for ``n`` datagrams paced by another process."""
    import subprocess
    import sys

    rx = UdpReceiver(coalesce_s=coalesce_s)
    status = f"/proc/self/task/{threading.get_native_id()}/status"

    def switches() -> int:
        with open(status) as f:
            return next(int(line.split()[1]) for line in f if line.startswith("voluntary_ctxt_switches"))

    sender = subprocess.Popen([sys.executable, "-c", SENDER, str(rx.address[1]), str(n)])
    got, before = 0, switches()
    deadline = time.monotonic() + 30
    while got < n and time.monotonic() < deadline:
        got += rx.receive() is not None
    slept = switches() - before
    sender.wait(10)
    rx.close()
    return got, slept


def test_an_empty_socket_is_left_to_fill_so_a_burst_costs_few_wake_ups():
    """Datagrams 100 us apart: a receiver faster than that slept after almost every one (the four-radar
    soak's drivers woke 5,600 times a second each). Left for 2 ms when empty, it takes them some 20 at a
    time, and loses none."""
    got, slept = _wakeups_to_receive(coalesce_s=0.002)
    assert got == 2000
    assert slept < 2000 / 5, slept


def test_a_receive_buffer_smaller_than_asked_is_said_once_in_the_log_events_and_every_health(tmp_path, caplog):
    """The kernel caps SO_RCVBUF at net.core.rmem_max (even SO_RCVBUFFORCE at 1 GB): a socket granted less
    than its driver asked overflowed in bursts while nothing said why. getsockopt's value (twice the grant on
    Linux) is checked; the shortfall goes to the log, once to /events, and into every health report."""
    import logging
    import threading

    import zmq

    from acquisition.bus import BusPublisher
    from acquisition.daemon import HealthMonitor
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.recorder import Recorder
    from drivers.radar.srf1 import Srf1Stream
    from imaging.core.rig import rig_from_dict
    from imaging.io.recording import Recording

    asked = 2**31 - 1  # more than any kernel grants
    with caplog.at_level(logging.WARNING, logger="sarbot.drivers.radar.udp"):
        rx = UdpReceiver(rcvbuf_bytes=asked)
    assert rx.rcvbuf_short is not None and "of 2147.5 MB asked" in rx.rcvbuf_short
    assert [r.getMessage() for r in caplog.records] == [rx.rcvbuf_short]
    assert UdpReceiver(rcvbuf_bytes=1 << 16).rcvbuf_short is None  # 64 kB is granted anywhere

    rig = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 16, "sample_rate_hz": 200e3}}}})
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    rec = Recorder(tmp_path / "r.h5", rig, pub.endpoint, context=ctx)
    time.sleep(0.3)
    stop = threading.Event()
    driver = threading.Thread(target=radar_driver_loop, args=(rx, "left", Srf1Stream((16, 4, 64)), pub, stop))
    driver.start()
    monitor = HealthMonitor(rec, {})
    deadline = time.monotonic() + 5
    while not rec.conditions and time.monotonic() < deadline:
        rec.step(timeout_ms=100)
    lines = [monitor.sample(0).line() for _ in range(2)]
    stop.set()
    driver.join(5)
    rec.close(), rx.close(), pub.close(), ctx.term()
    assert all(f"radar.left: {rx.rcvbuf_short}" in line for line in lines)
    with Recording(tmp_path / "r.h5") as r:
        assert [e[3] for e in r.events()] == [rx.rcvbuf_short]


def _udp_port_bound(port: int) -> bool:
    """Whether a socket is bound to UDP ``port`` on this machine (the kernel's table)."""
    with open("/proc/net/udp") as f:
        return any(int(line.split()[1].split(":")[1], 16) == port for line in f.readlines()[1:])


def test_a_radar_already_streaming_when_recording_starts_loses_nothing_that_arrived_after_the_bind(tmp_path):
    """`record` started while the radar streams (a frame every 5 ms): the driver binds its port, then the
    recorder's subscription takes a moment to reach the driver's publisher, and ZeroMQ dropped what was
    published meanwhile (0-3 frames at the reference rate), counted nowhere. Now the driver waits for the
    recorder and its socket keeps the datagrams: every frame sent after the port was bound is in the file,
    whole, and the counters run without a gap from the first frame recorded."""
    import threading

    from acquisition.daemon import Setup, record
    from acquisition.processes import free_port
    from drivers.radar.link import RadarLink
    from imaging.core.rig import rig_from_dict
    from imaging.io.recording import Recording

    rig = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 8, "sample_rate_hz": 200e3,
                                                         "frame_interval_s": 0.01}}}})
    wf = rig.radar("left").waveform
    shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)
    port = free_port(socket.SOCK_DGRAM)
    done = threading.Event()
    bound_before: dict[int, bool] = {}  # frame counter -> the port was bound before its first datagram left

    def radar():
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        k = 0
        while not done.is_set():
            bound_before[k] = _udp_port_bound(port)
            iq = np.full(shape, k % 3000, np.int16)
            for d in encode_frame(1, k, 1_700_000_000_000_000_000 + k * 10_000_000, iq):
                tx.sendto(d, ("127.0.0.1", port))
            k += 1
            time.sleep(0.005)
        tx.close()

    sender = threading.Thread(target=radar)
    sender.start()
    try:
        (path,) = record(Setup(rig, [RadarLink("left", port)], flush_interval_s=0.2), tmp_path, duration_s=4.0,
                         path=tmp_path / "r.h5")
    finally:
        done.set()
        sender.join(5)
    after_bind = [k for k, bound in bound_before.items() if bound]
    with Recording(path) as rec:
        counters = rec.frame_counter("left").astype(np.int64)
        valid = rec.valid("left")
        events = rec.events()
        first_frames = rec.adc_iq("left", slice(0, 3))
    assert len(after_bind) > 100 and counters.size > 100
    # Every frame sent once the port was bound is there (the last few may still have been on the way).
    missing = sorted(set(after_bind[:-20]) - set(counters.tolist()))
    assert missing == [], f"{len(missing)} frames sent after the bind not recorded: {missing[:10]}"
    assert np.all(np.diff(counters) == 1) and valid[1:-1].all()  # the ends may be frames cut by start and stop
    assert counters[0] <= after_bind[0]  # the first frame after the bind, or one caught mid-frame before it
    np.testing.assert_array_equal(first_frames[1:, 0, 0, 0, 0], (counters[1:3] % 3000))
    assert not [e for e in events if "on the bus" in e[3]], events  # (a frame cut by start or stop is wire loss)
