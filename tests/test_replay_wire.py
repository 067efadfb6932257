"""Replay's cheap sending (packed SRF1 encoding, UDP segmentation, raw chunk reads on later laps) puts on the
wire byte for byte the datagrams the encoder of before sent one by one, lap after lap, in order."""

import errno
import socket
import threading

import h5py
import numpy as np
import pytest

from acquisition.replay import replay_radar
from acquisition.replay_frames import LapFrames
from drivers.radar.registry import PackedDatagrams
from drivers.radar.srf1 import PackedEncoder, encode_frame, encode_frame_packed
from drivers.radar.udp import UdpSender
from imaging.core.errors import SarbotError
from imaging.core.rig import rig_from_dict
from imaging.io.recording import Recording, RecordingWriter
from reference_srf1 import encode_frame as encode_frame_before

RIG = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 32}}}})
N_FRAMES = 5
T0_NS = 1_700_000_000_000_000_000
INTERVAL_NS = 52_000_000


@pytest.fixture
def recording(tmp_path):
    """Radar "left" with noise-like int16 frames (89,600 bytes: 63 datagrams, more than one segmented send)."""
    radar = RIG.radar("left")
    wf = radar.waveform
    iq = np.random.default_rng(3).integers(-2048, 2048, (N_FRAMES, wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2),
                                           dtype=np.int16)
    times = T0_NS + np.arange(N_FRAMES, dtype=np.int64) * INTERVAL_NS
    path = tmp_path / "frames.h5"
    with RecordingWriter(path, [radar], adc_dtype="int16", truth=False) as w:
        w.append_frames("left", iq, times, 2**32 - 8 + np.arange(N_FRAMES), times)  # the counter wraps in lap 1
    return path, iq


@pytest.mark.parametrize("shape", [(32, 4, 175, 2), (360,), (361,), (1,), (0,)])
@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("payload_bytes", [1440, 1000, 4])
def test_the_packed_encoder_makes_the_datagrams_of_before_byte_for_byte(shape, version, payload_bytes):
    iq = np.random.default_rng(7).integers(-32768, 32767, shape, dtype=np.int16, endpoint=True)
    for locked in (True, False):
        before = encode_frame_before(9, 2**32 + 11, 1_234_567_890_123, iq, locked, payload_bytes, version)
        packed = encode_frame_packed(9, 2**32 + 11, 1_234_567_890_123, iq, locked, payload_bytes, version)
        assert packed.count == len(before)
        assert packed.data.tobytes() == b"".join(before)
        assert packed.split() == before
        assert encode_frame(9, 2**32 + 11, 1_234_567_890_123, iq, locked, payload_bytes, version) == before


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("payload_bytes", [1440, 1000])
def test_frames_sent_again_get_their_crcs_updated_to_the_datagrams_of_before(version, payload_bytes):
    """The encoder that keeps a frame's CRCs updates them for each new counter and time (wrapping, and the
    whole u64 time), and encodes afresh a frame whose bytes changed under the same key."""
    rng = np.random.default_rng(11)
    frames = [rng.integers(-2048, 2048, (32, 4, 175, 2), dtype=np.int16) for _ in range(3)]
    encoder = PackedEncoder(5, True, payload_bytes, version)
    for lap in range(4):
        for k, iq in enumerate(frames):
            if lap == 2 and k == 1:
                iq = iq.copy()
                iq[7, 2, 100, 0] += 1  # one sample other: the kept CRCs would be wrong for it
            counter, t_ns = 2**32 - 4 + 3 * lap + k, [0, 2**64 - 3, T0_NS, 123][lap] + k
            got = encoder(counter, t_ns, iq, frame_key=k)
            assert got.data.tobytes() == b"".join(encode_frame_before(5, counter, t_ns, iq, True, payload_bytes, version))


def received_datagrams(run_sender) -> list[bytes]:
    """Every datagram that arrives at a fresh loopback socket while ``run_sender(address)`` runs, in order."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.5)
    got: list[bytes] = []

    def drain():
        while True:
            try:
                got.append(rx.recv(65536))
            except socket.timeout:
                return

    thread = threading.Thread(target=drain)
    thread.start()
    run_sender(rx.getsockname())
    thread.join()
    rx.close()
    return got


def test_three_laps_on_the_wire_are_the_encoder_of_befores_datagrams(recording):
    path, iq = recording
    lap_ns = N_FRAMES * INTERVAL_NS
    with Recording(path) as rec:
        got = received_datagrams(lambda address: replay_radar(rec, "left", address, speed=None, radar_id=4, laps=3,
                                                              lap_ns=lap_ns))
    want = [d for lap in range(3) for k in range(N_FRAMES)
            for d in encode_frame_before(4, (2**32 - 8 + k + lap * N_FRAMES) & 0xFFFFFFFF,
                                         T0_NS + k * INTERVAL_NS + lap * lap_ns, iq[k])]
    assert len(want) == 3 * N_FRAMES * 63
    assert got == want


class RefusingSocket:
    """A socket whose kernel refuses UDP segmentation (EINVAL), as an old kernel does."""

    def __init__(self, sock):
        self.sock = sock
        self.refused = 0

    def sendmsg(self, *args):
        self.refused += 1
        raise OSError(errno.EINVAL, "Invalid argument")

    def sendto(self, *args):
        return self.sock.sendto(*args)

    def close(self):
        self.sock.close()


@pytest.mark.parametrize("kernel", ["segments", "refuses", "not asked"])
def test_the_sender_sends_the_same_datagrams_whether_the_kernel_segments_or_not(kernel):
    iq = np.random.default_rng(5).integers(-2048, 2048, (32, 4, 175, 2), dtype=np.int16)
    packed = encode_frame_packed(1, 77, T0_NS, iq)
    sender = UdpSender(segmented=kernel != "not asked")
    if kernel == "refuses":
        sender.sock = RefusingSocket(sender.sock)
    got = received_datagrams(lambda address: [sender.send(packed, address) for _ in range(2)])
    sender.close()
    assert got == 2 * encode_frame_before(1, 77, T0_NS, iq)
    # the kernel's refusal is asked once, then every datagram goes by its own sendto
    assert sender.segmented is (kernel == "segments")
    assert kernel != "refuses" or sender.sock.refused == 1


def test_datagrams_of_one_size_and_a_short_last_one_split_and_count():
    packed = PackedDatagrams(np.arange(10, dtype=np.uint8), 4)
    assert packed.count == 3
    assert packed.split() == [bytes([0, 1, 2, 3]), bytes([4, 5, 6, 7]), bytes([8, 9])]
    sender = UdpSender()
    empty = encode_frame_packed(1, 0, 0, np.zeros(0, np.int16))
    assert received_datagrams(lambda address: sender.send(empty, address)) == []  # an empty frame: no datagram
    sender.close()


def test_later_laps_read_the_chunks_raw_and_stop_on_a_frame_changed_since_the_first(recording, tmp_path):
    path, iq = recording
    with Recording(path) as rec:
        frames = LapFrames(rec, "left", laps=2)
        assert frames.raw_reads
        for k in range(N_FRAMES):
            np.testing.assert_array_equal(frames.read(0, k), iq[k])
        for k in range(N_FRAMES):
            np.testing.assert_array_equal(frames.read(1, k), iq[k])
        assert not LapFrames(rec, "left", laps=1).raw_reads  # one lap: HDF5's checked read only
    with h5py.File(path, "r+") as f:  # a frame rewritten between the laps (Fletcher-32 made anew)
        f["radar/left/adc"][2] = iq[2] // 2
    with Recording(path) as rec:
        frames._ds = rec.file["radar/left/adc"]  # the same reader, its first lap's CRCs kept, on the changed file
        np.testing.assert_array_equal(frames.read(1, 1), iq[1])
        with pytest.raises(SarbotError, match="frame 2 changed on disk"):
            frames.read(1, 2)
