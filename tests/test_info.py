"""`sarbot info`: the numbers it reports are the file's, for recordings, trajectories and images."""

import json
import subprocess
import sys

import numpy as np
from test_round_trip import RIG

from imaging.core.trajectory import SampledTrajectory
from imaging.io.recording import RecordingWriter
from imaging.io.trajectory_file import write_trajectory

CLI = [sys.executable, "-m", "acquisition.cli"]


def sarbot(*args, cwd=None):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120, cwd=cwd)


def make_recording(path):
    """20 frames of the rig's radar at its frame interval, frame 7 invalid and counters 12-13 missing; 400 Hz
    IMU with two samples missing by counter; two events; no truth."""
    radar = RIG.radar("left")
    wf = radar.waveform
    counters = np.r_[0:12, 14:22]
    t = 1_700_000_000_000_000_000 + counters * int(round(wf.frame_interval_s * 1e9))
    iq = np.zeros((counters.size, wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2), np.int16)
    valid = np.ones(counters.size, np.uint8)
    valid[7] = 0
    n = 400
    imu_counter = np.r_[0:100, 102:n + 2].astype(np.uint32)
    t_imu = t[0] + imu_counter.astype(np.int64) * 2_500_000
    with RecordingWriter(path, [radar], imu=RIG.imu, adc_dtype="int16", truth=False) as w:
        w.append_frames("left", iq, t, counters, t, valid)
        w.append_imu(t_imu, np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), imu_counter, t_imu)
        w.append_trigger(t[0], "sync_box")
        w.append_event(int(t[3]), "radar.left", "warning", "kernel dropped 3 datagram(s)")
        w.append_event(int(t[9]), "bus", "error", "radar/left: 1 message(s) lost on the bus")
        w.set_imu_clock_drift_ppm(12.5)
    return wf


def test_info_on_a_recording_says_what_is_in_it(tmp_path):
    path = tmp_path / "rec.h5"
    wf = make_recording(path)
    res = sarbot("info", str(path), "--json")
    assert res.returncode == 0, res.stderr
    d = json.loads(res.stdout)
    left = d["radars"]["left"]
    assert (left["frames"], left["invalid_frames"], left["counter_gaps"]) == (20, 1, 2)
    assert abs(left["frame_rate_hz"] - 1 / wf.frame_interval_s) < 1e-6
    assert left["waveform"]["chirps_per_frame"] == wf.chirps_per_frame
    assert d["imu"]["samples"] == 400 and d["imu"]["counter_gaps"] == 2 and d["imu"]["clock_drift_ppm"] == 12.5
    assert abs(d["imu"]["rate_hz"] - 400.0) < 1e-6
    assert d["events"]["by_level"] == {"warning": 1, "error": 1} and d["triggers"] == 1 and d["truth"] is False
    text = sarbot("info", str(path))
    assert text.returncode == 0
    assert "radar left: 20 frames" in text.stdout and "1 invalid, 2 missing by counter" in text.stdout
    assert "clock drift +12.5 ppm" in text.stdout
    # No truth to export: a one-line error.
    tum = sarbot("info", str(path), "--tum", str(tmp_path / "t.txt"))
    assert tum.returncode == 2 and "has no /truth" in tum.stderr


def test_info_on_a_trajectory_and_its_tum_export(tmp_path):
    t = 1_700_000_000_000_000_000 + np.arange(101, dtype=np.int64) * 10_000_000  # 1 s at 100 Hz
    x = np.linspace(0.0, 0.5, 101)
    pos = np.column_stack([x, np.zeros(101), np.zeros(101)])
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (101, 1))
    traj = SampledTrajectory(t, pos, quat, np.tile([0.5, 0.0, 0.0], (101, 1)), source="rio")
    path = write_trajectory(tmp_path / "traj.h5", traj)
    res = sarbot("info", str(path), "--json", "--tum", str(tmp_path / "traj.txt"))
    assert res.returncode == 0, res.stderr
    d = json.loads(res.stdout)
    assert d["poses"] == 101 and abs(d["rate_hz"] - 100.0) < 1e-9 and abs(d["path_length_m"] - 0.5) < 1e-9
    assert d["stop_cut_short"] == 0  # written whole (docs/formats/trajectory.md)
    rows = np.loadtxt(tmp_path / "traj.txt")
    assert rows.shape == (101, 8)
    np.testing.assert_allclose(rows[:, 1], x, atol=1e-9)
    np.testing.assert_allclose(rows[:, 0] - rows[0, 0], np.arange(101) * 0.01, atol=1e-6)
    again = sarbot("info", str(path), "--tum", str(tmp_path / "traj.txt"))
    assert again.returncode == 2 and "exists already" in again.stderr  # never overwritten unasked


def test_info_on_files_that_are_not_sarbots(tmp_path):
    import h5py

    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["schema"] = "someone.else"
    (tmp_path / "text.h5").write_text("not hdf5")
    for path, message in ((other, "not a sarbot file"), (tmp_path / "text.h5", "not a readable HDF5 file"),
                          (tmp_path / "missing.h5", "no such file")):
        res = sarbot("info", str(path))
        assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr


def test_info_on_an_image(tmp_path):
    from imaging.io.image_file import SarImage, write_image

    x, y = np.arange(-0.5, 0.5, 0.01), np.arange(1.5, 2.5, 0.02)
    img = SarImage(np.ones((y.size, x.size), np.complex64), x, y, attrs={"radar": "left_front", "wavelength_m": 0.0039,
                                                                        "n_frames": 30})
    path = write_image(tmp_path / "img.h5", img)
    res = sarbot("info", str(path), "--json")
    assert res.returncode == 0, res.stderr
    d = json.loads(res.stdout)
    assert d["shape"] == [y.size, x.size] and d["pixel_m"] == [0.01, 0.02]  # as a person wrote them
    assert d["attrs"]["radar"] == "left_front" and d["attrs"]["n_frames"] == 30


def test_info_on_a_recording_with_a_damaged_chunk_is_a_one_line_error(tmp_path):
    """A byte flipped on the disk in `valid`: the chunk's checksum fails, and `sarbot info` says which file and
    dataset in one line (exit 2), not h5py's traceback."""
    import h5py

    path = tmp_path / "r.h5"
    make_recording(path)
    with h5py.File(path, "r") as f:
        info = f["radar/left/valid"].id.get_chunk_info(0)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + 3)
        byte = fh.read(1)[0]
        fh.seek(info.byte_offset + 3)
        fh.write(bytes([byte ^ 0x01]))
    res = sarbot("info", str(path))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert f"{path}: /radar/left/valid: damaged data, a chunk's checksum fails" in line


def test_info_verify_says_clean_or_each_damaged_chunk(tmp_path):
    """`info --verify` reads every chunk: a clean file exits 0 with one line; two flipped chunks of two datasets
    are two lines naming each dataset and chunk, exit 2."""
    import h5py

    path = tmp_path / "r.h5"
    make_recording(path)
    clean = sarbot("info", "--verify", str(path))
    assert clean.returncode == 0 and "no damage found" in clean.stdout and not clean.stderr
    with h5py.File(path, "r") as f:
        places = [f[key].id.get_chunk_info(0).byte_offset for key in ("radar/left/valid", "imu/counter")]
    with open(path, "r+b") as fh:
        for offset in places:
            fh.seek(offset + 5)
            byte = fh.read(1)[0]
            fh.seek(offset + 5)
            fh.write(bytes([byte ^ 0x40]))
    res = sarbot("info", "--verify", str(path))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 2
    assert "/radar/left/valid chunk 0" in lines[0] or "/radar/left/valid chunk 0" in lines[1]
    assert any("/imu/counter chunk 0" in line for line in lines)


KILLED_WRITER = """
import os, sys
sys.path.insert(0, {tests!r})
from test_info import make_recording
from imaging.io.recording import RecordingWriter
import test_info
class Kept(RecordingWriter):
    def __exit__(self, *exc):  # flushed, never closed: as a recorder killed after its last flush
        self._f.flush()
        os._exit(9)
test_info.RecordingWriter = Kept
make_recording({path!r})
"""


def test_info_on_a_file_left_by_a_killed_recorder_reads_it_and_says_so(tmp_path):
    """A recorder killed after a flush leaves the SWMR-write flag set: `info` reads it as export and replay do
    (exit 0, its numbers) and says it was not closed cleanly, instead of calling it damaged."""
    from pathlib import Path

    path = tmp_path / "killed.h5"
    code = KILLED_WRITER.format(tests=str(Path(__file__).parent), path=str(path))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 9, done.stderr
    res = sarbot("info", str(path))
    assert res.returncode == 0, res.stderr
    assert "not closed cleanly" in res.stdout and "radar left: 20 frames" in res.stdout
    d = json.loads(sarbot("info", str(path), "--json").stdout)
    assert d["state"] == "not closed cleanly" and d["radars"]["left"]["frames"] == 20
    assert sarbot("info", "--verify", str(path)).returncode == 0


def test_info_on_damaged_metadata_is_one_line(tmp_path):
    """A recording whose radar group lost an attribute (the waveform's) is a one-line error, not a KeyError."""
    import h5py

    path = tmp_path / "r.h5"
    make_recording(path)
    with h5py.File(path, "r+") as f:
        del f["radar/left"].attrs["f0_hz"]
    res = sarbot("info", str(path))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and str(path) in res.stderr


def test_info_tum_never_replaces_the_file_it_reads(tmp_path):
    t = 1_700_000_000_000_000_000 + np.arange(11, dtype=np.int64) * 10_000_000
    traj = SampledTrajectory(t, np.zeros((11, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (11, 1)), np.zeros((11, 3)), source="rio")
    path = write_trajectory(tmp_path / "traj.h5", traj)
    before = path.read_bytes()
    res = sarbot("info", str(path), "--tum", str(path), "--overwrite")
    assert res.returncode == 2 and "a file this command reads" in res.stderr
    assert path.read_bytes() == before
