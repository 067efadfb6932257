"""A rig's radar clock offset (``[radar.NAME.calibration] time_offset_s``, what ``sarbot calibrate`` writes) is
used wherever a radar's stamps meet the IMU's time: the recording keeps it, antennas are placed with it, the
odometry takes scans at it, ``sarbot image`` and ``sarbot rio`` take a calibrated rig with ``--rig``."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from imaging.core.geometry import antenna_track
from imaging.core.rig import CalibrationPrior, default_rig
from imaging.core.trajectory import StraightLine
from imaging.io.recording import Recording, RecordingWriter
from rio.calibration import rig_of_recording, write_rig_toml
from rio.odometry import RadarScan, shift_by_known_offsets

SARBOT = [sys.executable, "-m", "acquisition.cli"]
OFFSET_S = 0.02  # radar stamp minus IMU time: the radar's clock 20 ms ahead


def sarbot(*args):
    return subprocess.run([*SARBOT, *map(str, args)], capture_output=True, text=True, timeout=300)


def late_rig(rig, name="left_front", offset_s=OFFSET_S):
    radars = [dataclasses.replace(r, calibration=CalibrationPrior(time_offset_s=offset_s, time_offset_sigma_s=1e-4))
              if r.name == name else r for r in rig.radars]
    return dataclasses.replace(rig, radars=tuple(radars))


def test_the_recording_keeps_a_radars_clock_offset_and_its_uncertainties(tmp_path):
    rig = late_rig(default_rig())
    rig = dataclasses.replace(rig, radars=tuple(
        dataclasses.replace(r, calibration=dataclasses.replace(r.calibration, rotation_sigma_deg=(0.1, 0.2, 0.3)))
        if r.calibration else r for r in rig.radars))
    RecordingWriter(tmp_path / "r.h5", rig.radars, rig.imu).close()
    with Recording(tmp_path / "r.h5") as rec:
        assert rec.radar("left_front").calibration == rig.radar("left_front").calibration
        assert rec.radar("right_front").calibration is None
    with h5py.File(tmp_path / "r.h5") as f:
        assert f["radar/left_front"].attrs["time_offset_s"] == OFFSET_S
        assert "time_offset_s" not in f["radar/right_front"].attrs


def test_antennas_are_placed_where_the_body_was_when_the_radar_measured():
    rig = default_rig()
    radar = rig.radar("left_front")
    traj = StraightLine(speed_mps=0.5)
    t = np.array([1_000_000_000, 1_500_000_000], np.int64)
    on_time = antenna_track(radar, traj, t, np.zeros(2, int))
    late = antenna_track(late_rig(rig).radar("left_front"), traj, t, np.zeros(2, int))
    # stamped t, measured at t - 20 ms: 10 mm further back along the track
    np.testing.assert_allclose(late.tx_m - on_time.tx_m, [[-0.01, 0, 0]] * 2, atol=1e-9)
    np.testing.assert_array_equal(late.time_ns, t)  # the stamps stay the radar's


def test_the_odometry_takes_each_scan_at_the_imu_time_it_stands_for():
    mount = default_rig().radar("left_front").mount
    scans = [RadarScan(t, name, mount, np.zeros((1, 3)), np.zeros(1))
             for t, name in ((100_000_000, "left_front"), (110_000_000, "right_front"), (115_000_000, "left_front"))]
    priors = {"left_front": CalibrationPrior(time_offset_s=OFFSET_S), "right_front": None}
    shifted = shift_by_known_offsets(scans, priors)
    assert [(s.radar, s.time_ns) for s in shifted] == [("left_front", 80_000_000), ("left_front", 95_000_000),
                                                       ("right_front", 110_000_000)]  # in time order again
    assert shift_by_known_offsets(scans, {}) is scans


@pytest.fixture(scope="module")
def pass_and_rigs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rig_offset")
    path = folder / "point.h5"
    res = sarbot("simulate", "point_target", "-o", path)
    assert res.returncode == 0, res.stderr
    with Recording(path) as rec:
        rig = rig_of_recording(rec)
    late = write_rig_toml(late_rig(rig), folder / "late.toml")
    other = write_rig_toml(dataclasses.replace(rig, radars=tuple(
        dataclasses.replace(r, name="elsewhere") for r in rig.radars)), folder / "other.toml")
    return path, late, other


def _peak_x_m(path):
    res = sarbot("analyze", path)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)["peak_m"][0]


def test_sarbot_image_places_the_antennas_by_a_rig_file_s_clock_offset(pass_and_rigs, tmp_path):
    """The point target's pass (0.4 m/s) imaged with a rig whose radar runs 20 ms ahead: every antenna 8 mm
    further back along the track than the stamps say, so the target moves 8 mm back with them."""
    path, late, _ = pass_and_rigs
    grid = ["--grid", "-0.03:0.03:0.0005,1.97:2.03:0.002", "--radar", "left_front", "--frames", "10:28"]
    assert sarbot("image", path, "-o", tmp_path / "as_recorded.h5", *grid).returncode == 0
    res = sarbot("image", path, "-o", tmp_path / "late.h5", "--rig", late, *grid)
    assert res.returncode == 0, res.stderr
    shift = _peak_x_m(tmp_path / "late.h5") - _peak_x_m(tmp_path / "as_recorded.h5")
    assert shift == pytest.approx(-0.4 * OFFSET_S, abs=0.001)
    with h5py.File(tmp_path / "late.h5") as f:
        assert f.attrs["rig"] == str(late)


def test_a_rig_file_without_the_recordings_radar_is_refused_by_name(pass_and_rigs, tmp_path):
    path, _, other = pass_and_rigs
    for command in (["image", path, "-o", tmp_path / "x.h5", "--rig", other, "--grid", "-0.1:0.1:0.01,1.9:2.1:0.01"],
                    ["rio", path, "-o", tmp_path / "t.h5", "--rig", other]):
        res = sarbot(*command)
        assert res.returncode == 2 and "Traceback" not in res.stderr
        assert f"--rig {other}: has no radar 'left_front'" in res.stderr
        assert not (tmp_path / "x.h5").exists() and not (tmp_path / "t.h5").exists()
