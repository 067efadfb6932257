"""Recorder: bus messages into HDF5, bus gaps into /events, and a killed recorder's file stays readable."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import zmq

from acquisition.bus import BusPublisher
from acquisition.messages import Event, ImuBatch, RadarFrameMessage, Trigger
from acquisition.recorder import Recorder
from drivers.radar.stream import RadarFrame
from imaging.core.rig import rig_from_dict
from imaging.io.recording import Recording

RIG = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 8, "sample_rate_hz": 200e3,
                                                     "frame_interval_s": 0.01}}}})
SHAPE = (8, 4, 36, 2)


def test_frames_imu_and_gaps_are_recorded(tmp_path):
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    rec = Recorder(tmp_path / "r.h5", RIG, pub.endpoint, context=ctx)
    time.sleep(0.2)
    rng = np.random.default_rng(0)
    iqs = [rng.integers(-500, 500, SHAPE, dtype=np.int16) for _ in range(10)]
    for k, iq in enumerate(iqs):
        if k == 6:
            pub._seq["radar/left"] += 1  # a message lost between driver and recorder
            continue
        pub.send(RadarFrameMessage("left", RadarFrame(k, 1000 + k, 5000 + k, k != 3, 0, iq)))
    t = np.arange(5, dtype=np.int64)
    pub.send(ImuBatch(t, np.ones((5, 3)), np.full((5, 3), 9.8), t.astype(np.uint32), t + 7))
    pub.send(Trigger(999, "sync_box"))
    pub.send(Event(1234, "radar.left", "warning", "3 datagrams lost in frame 3"))
    while rec.step(timeout_ms=300):
        pass
    rec.close()
    pub.close()
    ctx.term()
    with Recording(tmp_path / "r.h5") as r:
        adc = r.file["radar/left/adc"][()]
        assert adc.shape == (9, *SHAPE) and adc.dtype == np.int16
        kept = [k for k in range(10) if k != 6]
        np.testing.assert_array_equal(adc, np.stack([iqs[k] for k in kept]))
        np.testing.assert_array_equal(r.valid("left"), [k != 3 for k in kept])
        assert r.imu()["time_ns"].size == 5 and r.triggers().tolist() == [999]
        messages = [m.decode() for m in r.file["events/message"][()]]
        assert "radar/left: 1 message(s) lost on the bus" in messages
        assert "3 datagrams lost in frame 3" in messages


def test_recorder_killed_with_sigkill_leaves_its_flushed_data(tmp_path):
    path = tmp_path / "killed.h5"
    code = f"""
import time, numpy as np, zmq, sys
sys.path.insert(0, {str(os.getcwd())!r})
from acquisition.bus import BusPublisher
from acquisition.messages import RadarFrameMessage
from acquisition.recorder import Recorder
from drivers.radar.stream import RadarFrame
from tests.test_recorder import RIG, SHAPE
ctx = zmq.Context()
pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
rec = Recorder({str(path)!r}, RIG, pub.endpoint, flush_interval_s=0.05, context=ctx)
time.sleep(0.2)
k = 0
while True:
    pub.send(RadarFrameMessage("left", RadarFrame(k, k, k, True, 0, np.full(SHAPE, k % 1000, np.int16))))
    k += 1
    rec.step(timeout_ms=10)
    if k == 40:
        print("ready", flush=True)
"""
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=os.getcwd())
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with Recording(path) as r:
        n = r.n_frames("left")
        assert n >= 20  # at least what was flushed before the kill
        adc = r.file["radar/left/adc"][:n]
        np.testing.assert_array_equal(adc[:, 0, 0, 0, 0], np.arange(n) % 1000)


def _flip_byte_in_chunk(path, dataset: str, chunk: int) -> int:
    """Flip one byte in the middle of a chunk's stored bytes, found by h5py's get_chunk_info; its file offset."""
    import h5py

    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(chunk)
    where = info.byte_offset + info.size // 2
    with open(path, "r+b") as fh:
        fh.seek(where)
        byte = fh.read(1)[0]
        fh.seek(where)
        fh.write(bytes([byte ^ 0x20]))
    return info.byte_offset


def test_a_flipped_byte_in_a_recorded_frame_or_valid_is_a_read_error_that_verify_names(tmp_path):
    """Every chunk carries HDF5's Fletcher-32 checksum: one byte changed on the disk in a frame's ADC or in
    `valid` of a file the recorder wrote is a clear error naming file and dataset (h5py's OSError was a
    traceback; without the checksum, silently other numbers), and verify_file names dataset and chunk."""
    import pytest

    from acquisition.verify import format_findings, verify_file
    from imaging.core.errors import SarbotError

    path = tmp_path / "r.h5"
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    rec = Recorder(path, RIG, pub.endpoint, context=ctx)
    time.sleep(0.2)
    rng = np.random.default_rng(1)
    iqs = [rng.integers(-500, 500, SHAPE, dtype=np.int16) for _ in range(6)]
    for k, iq in enumerate(iqs):
        pub.send(RadarFrameMessage("left", RadarFrame(k, 1000 + k, 5000 + k, True, 0, iq)))
    t = np.arange(5, dtype=np.int64)
    pub.send(ImuBatch(t, np.ones((5, 3)), np.full((5, 3), 9.8), t.astype(np.uint32), t + 7))
    while rec.step(timeout_ms=300):
        pass
    rec.close(), pub.close(), ctx.term()
    assert verify_file(path) == []
    assert format_findings([], path) == f"{path}: no damage found: every chunk read back, its checksum matched"

    adc_offset = _flip_byte_in_chunk(path, "radar/left/adc", 3)  # frame 3: one frame a chunk
    _flip_byte_in_chunk(path, "radar/left/valid", 0)
    with Recording(path) as r:
        np.testing.assert_array_equal(r.adc_iq("left", slice(0, 3)), np.stack(iqs[:3]))  # the others still read
        with pytest.raises(SarbotError, match=f"{path}: /radar/left/adc: damaged data, a chunk's checksum fails"):
            r.adc_iq("left")
        with pytest.raises(SarbotError, match=f"{path}: /radar/left/valid: damaged data"):
            r.valid("left")
        assert r.imu()["time_ns"].tolist() == t.tolist()
    findings = verify_file(path)
    assert [(f.dataset, f.chunk_index, f.chunk_offset) for f in findings] == [
        ("/radar/left/adc", 3, (3, 0, 0, 0, 0)), ("/radar/left/valid", 0, (0,))]
    assert findings[0].file_offset == adc_offset
    lines = format_findings(findings).splitlines()
    assert len(lines) == 2 and lines[0].startswith(f"{path}: /radar/left/adc chunk 3 (from element [3, 0, 0, 0, 0], "
                                                    f"file byte {adc_offset}): ")


def test_sensor_data_published_before_the_recorder_listened_is_counted_as_lost(tmp_path):
    """A driver's first messages, published before the recorder's subscription reached it, are dropped by
    ZeroMQ; a first sequence number above 0 was not counted as a gap. For the sensor topics it is now (the
    drivers wait for the recorder, so from them it does not happen); a worker's state is not sensor data."""
    from acquisition.messages import WorkerState

    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    for k in range(3):  # nobody listens yet: gone
        pub.send(RadarFrameMessage("left", RadarFrame(k, 1000 + k, 5000 + k, True, 0, np.zeros(SHAPE, np.int16))))
    pub.send(WorkerState("rio", False, 0.0, {}))
    rec = Recorder(tmp_path / "r.h5", RIG, pub.endpoint, context=ctx)
    time.sleep(0.3)
    for k in range(3, 5):
        pub.send(RadarFrameMessage("left", RadarFrame(k, 1000 + k, 5000 + k, True, 0, np.zeros(SHAPE, np.int16))))
    pub.send(WorkerState("rio", True, 0.0, {}))
    while rec.step(timeout_ms=300):
        pass
    assert rec.bus_lost == 3
    rec.close(), pub.close(), ctx.term()
    with Recording(tmp_path / "r.h5") as r:
        assert r.frame_counter("left").tolist() == [3, 4]
        assert [e[3] for e in r.events()] == ["radar/left: 3 message(s) lost on the bus"]


def test_a_driver_publisher_waits_until_the_recorder_listens():
    """The drivers' publishers hear subscriptions (XPUB): the recorder's RECORDER_LISTENING arrives after
    its other topics, so what a driver sends after the wait reaches it from the first message."""
    import threading

    from acquisition.bus import RECORDER_LISTENING

    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx, watch_subscriptions=True)
    stop = threading.Event()
    t0 = time.monotonic()
    assert not pub.wait_for_subscriber(RECORDER_LISTENING, 0.3, stop)  # nobody yet
    assert 0.25 < time.monotonic() - t0 < 1.0
    from acquisition.bus import BusSubscriber

    sub = BusSubscriber(pub.endpoint, topics=[RadarFrameMessage.TOPIC, RECORDER_LISTENING], context=ctx,
                        counted_from_start=(RadarFrameMessage.TOPIC,))
    assert pub.wait_for_subscriber(RECORDER_LISTENING, 5.0, stop)
    pub.send(RadarFrameMessage("left", RadarFrame(0, 1000, 5000, True, 0, np.zeros(SHAPE, np.int16))))
    m = sub.receive(timeout_ms=2000)
    assert m is not None and m.seq == 0 and sub.missed == 0
    stop.set()
    assert not BusPublisher("tcp://127.0.0.1:0", context=ctx, watch_subscriptions=True).wait_for_subscriber(
        RECORDER_LISTENING, 5.0, stop)  # stop set: no waiting
    sub.close(), pub.close(), ctx.destroy(linger=0)


def test_frames_are_written_at_the_flush_all_of_them_in_order_with_their_clock_marks(tmp_path):
    """The recorder keeps a radar's frames until its flush and writes them there in one append per column:
    after each flush the file (read as a SWMR reader reads it) holds every frame stored before, in order,
    with its times, counter, valid flag, PTP lock and card stamp; a frame of the wrong shape is refused
    when it is stored, not at the flush."""
    import h5py
    import pytest

    from acquisition.bus import Message

    rec = Recorder(tmp_path / "r.h5", RIG, ["tcp://127.0.0.1:9"])
    rng = np.random.default_rng(1)
    iqs = [rng.integers(-500, 500, SHAPE, dtype=np.int16) for _ in range(7)]

    def store(k, iq):
        frame = RadarFrame(100 + k, 5_000 + k, 9_000 + k, k != 2, 0 if k != 2 else 64, iq, k != 4, 77 * k)
        p = RadarFrameMessage("left", frame).to_parts()
        rec._store(Message(p.topic, k, p.sensor_time_ns, 0, {"seq": k, "pub": "t", **p.fields}, p.arrays))

    for k in range(4):
        store(k, iqs[k])
    rec.flush()
    with h5py.File(tmp_path / "r.h5", "r", swmr=True) as f:
        assert f["radar/left/adc"].shape[0] == 4
    for k in range(4, 7):
        store(k, iqs[k])
    with pytest.raises(ValueError, match="adc shape"):
        store(7, np.zeros((8, 4, 35, 2), np.int16))
    rec.close()
    with Recording(tmp_path / "r.h5") as r:
        np.testing.assert_array_equal(r.file["radar/left/adc"][()], np.stack(iqs))
        np.testing.assert_array_equal(r.frame_counter("left"), 100 + np.arange(7))
        np.testing.assert_array_equal(r.file["radar/left/frame_time_ns"][()], 5_000 + np.arange(7))
        np.testing.assert_array_equal(r.file["radar/left/host_time_ns"][()], 9_000 + np.arange(7))
        np.testing.assert_array_equal(r.valid("left"), [1, 1, 0, 1, 1, 1, 1])
        np.testing.assert_array_equal(r.file["radar/left/ptp_locked"][()], [1, 1, 1, 1, 0, 1, 1])
        np.testing.assert_array_equal(r.file["radar/left/nic_time_ns"][()], 77 * np.arange(7))
    assert rec.frames == {"left": 7} and rec.invalid_frames == {"left": 1}


def test_frames_written_as_whole_chunks_are_the_chunks_hdf5_would_store(tmp_path):
    """The writer hands HDF5 each frame as its stored chunk (data and Fletcher-32 checksum): the file holds,
    chunk for chunk, what HDF5's own filter stores for the same frames, given as a list or stacked, int16 or
    complex; a frame of another shape is refused naming both shapes; a byte changed on the disk still fails
    HDF5's check when read."""
    import h5py
    import pytest

    from imaging.io.recording import RecordingWriter

    rng = np.random.default_rng(5)
    iqs = [rng.integers(-32768, 32767, SHAPE, dtype=np.int16) for _ in range(5)]
    with RecordingWriter(tmp_path / "w.h5", RIG.radars, adc_dtype="int16") as w:
        w.append_frames("left", iqs[:2], [1, 2], [1, 2], [11, 12])
        w.append_frames("left", np.stack(iqs[2:]), [3, 4, 5], [3, 4, 5], [13, 14, 15])
        with pytest.raises(ValueError, match=r"\(8, 4, 35, 2\).* do not fit \(8, 4, 36, 2\)"):
            w.append_frames("left", [np.zeros((8, 4, 35, 2), np.int16)], [6], [6], [16])
    cx = [(rng.normal(size=SHAPE[:3]) + 1j * rng.normal(size=SHAPE[:3])).astype(np.complex64) for _ in range(2)]
    with RecordingWriter(tmp_path / "c.h5", RIG.radars) as w:
        w.append_frames("left", cx, [1, 2], [1, 2], [11, 12])
    with h5py.File(tmp_path / "usual.h5", "w") as f:  # HDF5 filtering the same frames itself
        f.create_dataset("i", data=np.stack(iqs), chunks=(1, *SHAPE), fletcher32=True)
        f.create_dataset("c", data=np.stack(cx), chunks=(1, *SHAPE[:3]), fletcher32=True)
    with h5py.File(tmp_path / "w.h5", "r") as fw, h5py.File(tmp_path / "c.h5", "r") as fc, \
            h5py.File(tmp_path / "usual.h5", "r") as fu:
        for ours, usual, n in ((fw["radar/left/adc"], fu["i"], 5), (fc["radar/left/adc"], fu["c"], 2)):
            assert ours.shape[0] == n and ours.fletcher32 and ours.chunks == usual.chunks
            zeros = (0,) * (ours.ndim - 1)
            for k in range(n):
                assert ours.id.read_direct_chunk((k, *zeros)) == usual.id.read_direct_chunk((k, *zeros))
        np.testing.assert_array_equal(fw["radar/left/adc"][...], np.stack(iqs))
        np.testing.assert_array_equal(fw["radar/left/frame_counter"][...], [1, 2, 3, 4, 5])
        offset = fw["radar/left/adc"].id.get_chunk_info(3).byte_offset
    with open(tmp_path / "w.h5", "r+b") as fh:  # one byte of frame 3 flipped on the disk
        fh.seek(offset + 100)
        byte = fh.read(1)
        fh.seek(offset + 100)
        fh.write(bytes([byte[0] ^ 0x10]))
    with h5py.File(tmp_path / "w.h5", "r") as fw:
        np.testing.assert_array_equal(fw["radar/left/adc"][2], iqs[2])
        with pytest.raises(OSError):
            fw["radar/left/adc"][3]


def test_rows_of_a_dataset_not_one_chunk_each_are_stacked_and_appended():
    """``append_rows`` on a column whose chunks hold several rows (no whole-chunk write possible) appends
    them the usual way; a row of another shape is refused."""
    import h5py
    import pytest

    from imaging.io.columns import Column

    with h5py.File("rows.h5", "w", driver="core", backing_store=False) as f:
        col = Column(f.create_dataset("x", (0, 3), np.int32, maxshape=(None, 3), chunks=(4, 3), fletcher32=True))
        assert not col.row_per_chunk
        col.append_rows([np.arange(3), np.arange(3, 6)])
        col.append_rows([])
        np.testing.assert_array_equal(f["x"][...], [[0, 1, 2], [3, 4, 5]])
        assert col.rows == 2
        with pytest.raises(ValueError, match=r"row of shape \(2,\) does not fit \(3,\)"):
            col.append_rows([np.arange(2)])
        one = Column(f.create_dataset("y", (0, 3), np.int32, maxshape=(None, 3), chunks=(1, 3), fletcher32=True))
        plain = Column(f.create_dataset("z", (0, 3), np.int32, maxshape=(None, 3), chunks=(1, 3)))
        assert one.row_per_chunk and not plain.row_per_chunk


def test_a_closed_writer_lets_go_of_its_chunk_buffers_without_the_garbage_collector(tmp_path):
    """Each part of a split recording has its own writer: closing one frees its columns' chunk buffers at
    once, not whenever the garbage collector next runs (each part kept 2.9 MB of four radars' until then)."""
    import gc
    import weakref

    from imaging.io.recording import RecordingWriter

    w = RecordingWriter(tmp_path / "w.h5", RIG.radars, adc_dtype="int16")
    w.append_frames("left", [np.ones(SHAPE, np.int16)], [1], [1], [1])
    buffer = weakref.ref(w._columns["radar/left/adc"]._chunk)
    gc.disable()
    try:
        w.close()
        del w
        assert buffer() is None
    finally:
        gc.enable()


def test_imu_batches_are_written_at_the_flush_in_order(tmp_path):
    """The IMU's batches wait for the flush, as the frames do, and are then written in one append per column:
    after a flush the file (as a SWMR reader sees it) holds every sample stored before, in order; an empty
    batch adds nothing."""
    import h5py

    from acquisition.bus import Message

    rec = Recorder(tmp_path / "r.h5", RIG, ["tcp://127.0.0.1:9"])
    rng = np.random.default_rng(3)
    batches = []
    for k, n in enumerate([20, 21, 0, 19]):
        t = 1_000 * k + np.arange(n, dtype=np.int64)
        b = ImuBatch(t, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), (t % 65536).astype(np.uint32), t + 5, 2.0)
        batches.append(b)
        p = b.to_parts()
        rec._store(Message(p.topic, k, p.sensor_time_ns, 0, {"seq": k, "pub": "t", **p.fields}, p.arrays))
        if k == 1:
            rec.flush()
            with h5py.File(tmp_path / "r.h5", "r", swmr=True) as f:
                np.testing.assert_array_equal(f["imu/time_ns"][()], np.concatenate([batches[0].time_ns, batches[1].time_ns]))
    rec.close()
    with Recording(tmp_path / "r.h5") as r:
        imu = r.imu()
        for key in ("time_ns", "gyro_radps", "accel_mps2", "counter", "host_time_ns"):
            np.testing.assert_array_equal(imu[key], np.concatenate([getattr(b, key) for b in batches]))
    assert rec.imu_samples == 60
