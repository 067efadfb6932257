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
