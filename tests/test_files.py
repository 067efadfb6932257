"""Recording, trajectory and image files: round trips, schema checks, crash-safety of SWMR writes."""

from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import pytest

from imaging.core.errors import FileFormatError
from imaging.core.rig import default_rig
from imaging.core.trajectory import PathWithTurns, SampledTrajectory, StraightLine
from imaging.io.image_file import SarImage, read_image, write_image
from imaging.io.recording import Recording, RecordingWriter
from imaging.io.trajectory_file import read_trajectory, write_trajectory, write_tum


def test_recording_round_trip_complex_and_int16(tmp_path):
    rig = default_rig()
    radar = rig.radar("right_rear")
    wf = radar.waveform
    rng = np.random.default_rng(0)
    shape = (3, wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp)
    iq = rng.integers(-2000, 2000, size=shape + (2,), dtype=np.int16)
    for dtype in ("complex64", "int16"):
        path = tmp_path / f"{dtype}.h5"
        with RecordingWriter(path, [radar], imu=rig.imu, truth=True, adc_dtype=dtype, wire_format="SRF1") as w:
            data = iq if dtype == "int16" else (iq[..., 0] + 1j * iq[..., 1]).astype(np.complex64)
            w.append_frames("right_rear", data, [10, 20, 30], [7, 8, 9], [11, 21, 31], [1, 0, 1])
            w.append_event(15, "radar.right_rear", "warning", "frame 8: 3 datagrams lost")
            w.append_truth(StraightLine().sample(np.array([0, 10, 20])))
        with Recording(path) as rec:
            assert rec.radar_names == ["right_rear"]
            back = rec.radar("right_rear")
            assert back.waveform == wf
            np.testing.assert_allclose(back.mount.rotation_xyzw, radar.mount.rotation_xyzw)
            np.testing.assert_allclose(back.array.tx_positions_m, radar.array.tx_positions_m)
            np.testing.assert_array_equal(rec.adc("right_rear"), (iq[..., 0] + 1j * iq[..., 1]).astype(np.complex64))
            np.testing.assert_array_equal(rec.valid("right_rear"), [True, False, True])
            np.testing.assert_array_equal(rec.frame_time_ns("right_rear"), [10, 20, 30])
            assert rec.file["events/message"][0].decode() == "frame 8: 3 datagrams lost"
            assert rec.file["radar/right_rear"].attrs["wire_format"] == "SRF1"
            assert rec.truth().source == "truth"


def test_recording_refuses_to_overwrite(tmp_path):
    path = tmp_path / "r.h5"
    RecordingWriter(path, default_rig().radars).close()
    with pytest.raises(FileFormatError, match="exists already"):
        RecordingWriter(path, default_rig().radars)


def test_recording_schema_errors(tmp_path):
    with pytest.raises(FileFormatError, match="no such file"):
        Recording(tmp_path / "none.h5")
    p = tmp_path / "v2.h5"
    with h5py.File(p, "w") as f:
        f.attrs["schema"] = "sarbot.recording"
        f.attrs["schema_version"] = 2
    with pytest.raises(FileFormatError, match="version 2 is not supported"):
        Recording(p)


def test_killed_writer_leaves_a_readable_file(tmp_path):
    # A writer SIGKILLed after flushing 5 frames: the file opens and holds those 5 frames.
    path = tmp_path / "killed.h5"
    code = f"""
import os, signal, numpy as np
from imaging.io.recording import RecordingWriter
from imaging.core.rig import default_rig
r = default_rig().radar("left_front"); wf = r.waveform
w = RecordingWriter({str(path)!r}, [r])
adc = np.ones((1, wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp), np.complex64)
for k in range(5):
    w.append_frames("left_front", adc * k, [k], [k], [k])
w.flush()
w.append_frames("left_front", adc * 99, [99], [99], [99])  # not flushed
os.kill(os.getpid(), signal.SIGKILL)
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True)
    assert res.returncode == -9
    with Recording(path) as rec:
        n = rec.n_frames("left_front")
        assert n >= 5
        np.testing.assert_array_equal(rec.frame_time_ns("left_front")[:5], np.arange(5))
        assert rec.adc("left_front", slice(4, 5))[0, 0, 0, 0] == 4


def test_trajectory_file_round_trip_and_tum(tmp_path):
    truth = PathWithTurns(segments=[("straight", 1.0), ("arc", 0.5, 90.0)], speed_mps=0.5, t0_ns=1_700_000_000_000_000_000)
    times = truth.t0_ns + np.arange(0, 4_000_000_000, 10_000_000)
    traj = SampledTrajectory.from_trajectory(truth, times, source="truth")
    write_trajectory(tmp_path / "t.h5", traj)
    back = read_trajectory(tmp_path / "t.h5")
    np.testing.assert_array_equal(back.time_ns, traj.time_ns)
    np.testing.assert_allclose(back.position_m, traj.position_m)
    assert back.source == "truth"
    write_tum(tmp_path / "t.txt", traj)
    first = (tmp_path / "t.txt").read_text().splitlines()[0].split()
    assert first[0] == "1700000000.000000000" and len(first) == 8
    with pytest.raises(FileFormatError, match="not a sarbot trajectory"):
        write_image(tmp_path / "i.h5", SarImage(np.zeros((2, 2)), np.arange(2.0), np.arange(2.0), None, {"wavelength_m": 1.0}))
        read_trajectory(tmp_path / "i.h5")


def test_trajectory_writer_gathers_appends_and_writes_them_all(tmp_path):
    """Poses appended a few at a time (as the live odometry does) reach the file in order: a chunk's worth
    without a flush, the rest at a flush and at close; an empty append is harmless."""
    from imaging.io.trajectory_file import WRITE_EVERY_POSES, TrajectoryWriter

    truth = StraightLine(speed_mps=0.4, t0_ns=1_700_000_000_000_000_000)
    n = WRITE_EVERY_POSES + 1000
    traj = SampledTrajectory.from_trajectory(truth, truth.t0_ns + np.arange(n, dtype=np.int64) * 2_500_000)
    cov = np.arange(n * 6, dtype=float).reshape(n, 6)
    path = tmp_path / "rio.h5"
    with TrajectoryWriter(path, "rio", covariance_width=6) as w:
        written = lambda: w._f["trajectory/time_ns"].shape[0]  # noqa: E731
        edges = list(range(0, n, 7)) + [n]
        for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            w.append(traj.time_ns[a:b], traj.position_m[a:b], traj.orientation_xyzw[a:b], traj.velocity_mps[a:b], cov[a:b])
            if i == 10:
                assert written() == 0  # gathered
                w.flush()
                assert written() == b
        assert WRITE_EVERY_POSES <= written() < n  # a chunk's worth went without a flush; the rest waits
        w.append(traj.time_ns[:0], traj.position_m[:0], traj.orientation_xyzw[:0], traj.velocity_mps[:0], cov[:0])
    back = read_trajectory(path)
    np.testing.assert_array_equal(back.time_ns, traj.time_ns)
    np.testing.assert_array_equal(back.position_m, traj.position_m)
    np.testing.assert_array_equal(back.orientation_xyzw, traj.orientation_xyzw)
    np.testing.assert_array_equal(back.velocity_mps, traj.velocity_mps)
    with h5py.File(path) as f:
        np.testing.assert_array_equal(f["trajectory/covariance_diag"][()], cov)


def test_the_trajectory_file_says_whether_the_stop_cut_it_short_and_old_files_read_as_not_known(tmp_path):
    """``stop_cut_short``: 1 from a writer closed hurried, 0 from one closed whole (and from write_trajectory);
    a file without it (older, or whose writer never closed it) reads as None, and so does one left by an
    error: neither says where its poses end."""
    from imaging.io.trajectory_file import TrajectoryWriter

    truth = StraightLine(speed_mps=0.4, t0_ns=1_700_000_000_000_000_000)
    traj = SampledTrajectory.from_trajectory(truth, truth.t0_ns + np.arange(20, dtype=np.int64) * 10_000_000)
    poses = (traj.time_ns, traj.position_m, traj.orientation_xyzw, traj.velocity_mps)
    for cut_short in (True, False):
        w = TrajectoryWriter(tmp_path / f"{cut_short}.h5", "rio")
        w.append(*poses)
        w.close(stop_cut_short=cut_short)
        back = read_trajectory(tmp_path / f"{cut_short}.h5")
        assert back.stop_cut_short == int(cut_short) and back.time_ns.size == 20
        with h5py.File(tmp_path / f"{cut_short}.h5") as f:
            assert f.attrs["stop_cut_short"] == int(cut_short)
    assert read_trajectory(write_trajectory(tmp_path / "offline.h5", traj)).stop_cut_short == 0
    # A hurried trajectory written again still says so.
    again = read_trajectory(write_trajectory(tmp_path / "again.h5", read_trajectory(tmp_path / "True.h5")))
    assert again.stop_cut_short == 1
    # An old file: version 1 without the attribute.
    with h5py.File(tmp_path / "False.h5", "a") as f:
        del f.attrs["stop_cut_short"]
    old = read_trajectory(tmp_path / "False.h5")
    assert old.stop_cut_short is None and old.time_ns.size == 20
    with pytest.raises(RuntimeError, match="boom"), TrajectoryWriter(tmp_path / "error.h5", "rio") as w:
        w.append(*poses)
        raise RuntimeError("boom")
    assert read_trajectory(tmp_path / "error.h5").stop_cut_short is None


def test_sampled_trajectory_interpolates_a_turn():
    truth = PathWithTurns(segments=[("straight", 0.5), ("arc", 0.5, 180.0), ("straight", 0.5)], speed_mps=0.5)
    times = np.arange(0, 5_000_000_000, 1_000_000)
    sampled = SampledTrajectory.from_trajectory(truth, times)
    query = np.array([123_456_789, 1_777_777_777, 3_000_000_001])
    a, b = truth.sample(query), sampled.sample(query)
    np.testing.assert_allclose(b.position_m, a.position_m, atol=1e-6)
    np.testing.assert_allclose(b.angular_velocity_body_radps, a.angular_velocity_body_radps, atol=1e-3)
    np.testing.assert_allclose(np.abs(np.sum(b.orientation_xyzw * a.orientation_xyzw, axis=1)), 1.0, atol=1e-9)
    # The path's geometry: after a half circle of radius 0.5 the robot is 1 m to the left, heading back.
    end = truth.sample(np.array([10_000_000_000]))
    np.testing.assert_allclose(end.position_m[0], [0.0, 1.0, 0.0], atol=1e-12)
    assert end.velocity_mps[0] == pytest.approx([0, 0, 0])


def test_image_file_round_trip(tmp_path):
    img = SarImage((np.arange(6) * (1 + 1j)).reshape(2, 3), np.arange(3.0), np.arange(2.0), np.array([0.3]),
                   {"radar": "a", "frames": "0:4", "trajectory_source": "truth", "method": "tdbp-linear", "wavelength_m": 0.0038})
    write_image(tmp_path / "i.h5", img)
    back = read_image(tmp_path / "i.h5")
    np.testing.assert_array_equal(back.image, img.image)
    assert back.attrs["method"] == "tdbp-linear" and back.wavelength_m == 0.0038


def test_systemd_units_verify(tmp_path):
    """The units pass `systemd-analyze verify` (where systemd is installed) with the real executable."""
    import shutil
    from pathlib import Path

    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed")
    units = Path(__file__).resolve().parents[1] / "systemd"
    exe = Path(sys.executable).with_name("sarbot")
    for unit in units.iterdir():
        text = unit.read_text().replace("/opt/sarbot/.venv/bin/sarbot", str(exe))
        text = text.replace("User=sarbot", "User=root").replace("Group=sarbot", "Group=root")
        (tmp_path / unit.name).write_text(text)
    res = subprocess.run([analyze, "verify", *(str(p) for p in sorted(tmp_path.iterdir()))], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


@pytest.mark.parametrize("damage", ["cut-5%", "cut-50%", "cut-90%", "metadata-bits", "not-hdf5"])
def test_a_damaged_recording_is_a_one_line_error_not_a_hang(tmp_path, damage):
    """A recording cut short (a full disk, a copy that stopped) or with flipped metadata bits: one line
    naming the file and exit code 2, from the first command that reads it. SWMR read mode used to retry
    damaged metadata for 30 s to 10 minutes; the subprocess timeout guards against that."""
    import random

    from test_round_trip import make_source

    whole = tmp_path / "whole.h5"
    make_source(whole, n_frames=20)
    data = bytearray(whole.read_bytes())
    if damage.startswith("cut"):
        data = data[: len(data) * int(damage[4:-1]) // 100]
    elif damage == "metadata-bits":
        rng = random.Random(0)
        for _ in range(20):
            data[rng.randrange(4096)] ^= 0xFF  # the superblock and root group live in the first pages
    else:
        data = bytearray(b"this is not a recording\n" * 100)
    bad = tmp_path / "bad.h5"
    bad.write_bytes(bytes(data))
    for cmd in (["image", str(bad), "-o", str(tmp_path / "img.h5"), "--grid=-0.2:0.2:0.01,1.9:2.1:0.01"],
                ["replay", str(bad), "--radar", "left=127.0.0.1:9", "--speed", "0"]):
        res = subprocess.run([sys.executable, "-m", "acquisition.cli", *cmd], capture_output=True, text=True, timeout=30)
        assert res.returncode == 2, (cmd[0], res.stderr[-2000:])
        assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr, res.stderr
        assert str(bad) in res.stderr


def _flip_byte_in_chunk(path, dataset: str, chunk: int = 0) -> None:
    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(chunk)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        byte = fh.read(1)[0]
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes([byte ^ 0x01]))


def test_every_dataset_the_writers_chunk_carries_a_checksum_and_a_flipped_byte_is_a_clear_error(tmp_path):
    """Recording (simulator and importers write through RecordingWriter), trajectory and image files: every
    dataset of numbers has HDF5's Fletcher-32 checksum per chunk (variable-length strings take no filter);
    a byte changed in a trajectory's positions or an image's pixels is a FileFormatError naming file and
    dataset, not h5py's OSError or silently other numbers."""
    from acquisition.verify import verify_file

    rig = default_rig()
    with RecordingWriter(tmp_path / "r.h5", rig.radars, imu=rig.imu, truth=True, detections=[rig.radars[0].name]) as w:
        w.append_event(1, "test", "info", "x")
    with h5py.File(tmp_path / "r.h5", "r") as f:
        datasets = []
        f.visititems(lambda name, obj: datasets.append(obj) if isinstance(obj, h5py.Dataset) else None)
        numbers = [d.name for d in datasets if h5py.check_vlen_dtype(d.dtype) is None]
        assert len(numbers) == 40 and [d.name for d in datasets if d.name in numbers and not d.fletcher32] == []
        assert sorted(d.name for d in datasets if not d.fletcher32) == [
            "/events/level", "/events/message", "/events/source", "/trigger/source"]

    truth = PathWithTurns(segments=[("straight", 1.0)], speed_mps=0.5, t0_ns=1_700_000_000_000_000_000)
    traj = SampledTrajectory.from_trajectory(truth, truth.t0_ns + np.arange(0, 2_000_000_000, 10_000_000), source="truth")
    write_trajectory(tmp_path / "t.h5", traj)
    _flip_byte_in_chunk(tmp_path / "t.h5", "trajectory/position_m")
    with pytest.raises(FileFormatError, match=f"{tmp_path / 't.h5'}: /trajectory/position_m: damaged data"):
        read_trajectory(tmp_path / "t.h5")
    assert [f.dataset for f in verify_file(tmp_path / "t.h5")] == ["/trajectory/position_m"]

    img = SarImage(np.ones((40, 30), np.complex64), np.arange(30.0), np.arange(40.0), None, {"wavelength_m": 0.0038})
    write_image(tmp_path / "i.h5", img)
    assert verify_file(tmp_path / "i.h5") == []
    _flip_byte_in_chunk(tmp_path / "i.h5", "image")
    with pytest.raises(FileFormatError, match=f"{tmp_path / 'i.h5'}: /image: damaged data"):
        read_image(tmp_path / "i.h5")
    assert [f.dataset for f in verify_file(tmp_path / "i.h5")] == ["/image"]
