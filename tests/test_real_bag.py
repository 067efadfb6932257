"""The real ROS1 recording (TI IWR6843AOP point clouds, ADIS16448 IMU, hardware trigger): what can be
asserted without ground truth."""

import subprocess
import sys

import numpy as np
import pytest
from conftest import SHARED_DATA

from imaging.io.recording import Recording
from rio.ego_velocity import EgoStatus
from rio.odometry import RioOptions, imu_from_recording, run_rio, scans_from_recording

BAG = SHARED_DATA / "ti_mmwave_rospkg_demo"


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    out = tmp_path_factory.mktemp("bag") / "demo.h5"
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "import-bag", str(BAG / "ti_mmwave_rospkg_demo.bag"),
                          "--calib", str(BAG / "calib_ti_mmwave_rospkg_dataset.yaml"), "-o", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "scans 412" in res.stdout and "imu_samples 8270" in res.stdout
    return out


def test_import_keeps_every_message_on_one_clock(imported):
    with Recording(imported) as rec:
        imu = rec.imu()
        trig = rec.triggers()
        det = rec.detections("radar")
        frames = rec.frame_time_ns("radar")
        mount = rec.radar("radar").mount
    assert imu["time_ns"].size == 8270 and trig.size == 413 and frames.size == 412
    assert np.all(np.diff(imu["time_ns"]) > 0)
    assert 200 < imu["rate_hz"] < 210
    # Each scan starts at a trigger; its detections are stamped mid-frame (18.5 ms frames).
    assert np.all(np.isin(frames, trig))
    scan_time = det["time_ns"][np.searchsorted(det["scan"], np.arange(frames.size))]
    np.testing.assert_array_equal(scan_time - frames, 9_250_000)
    # Triggers and IMU share the sensor clock: they overlap in time.
    assert imu["time_ns"][0] < trig[0] < imu["time_ns"][-1]
    assert 19 <= np.bincount(det["scan"]).min() and np.bincount(det["scan"]).max() <= 87
    np.testing.assert_allclose(mount.translation_m, [0.03, 0.03, -0.06])
    # The radar looks front-right (the trigger topic is "radar_right"), tilted down by about 9 deg.
    boresight = mount.boresight_body
    assert boresight[0] > 0.5 and boresight[1] < -0.5 and -0.26 < boresight[2] < 0


def test_a_plausible_hand_held_trajectory(imported):
    """No ground truth: the radar agrees with the IMU, speeds are walking speeds, the rig ends at rest."""
    from rio.ekf import EkfConfig

    with Recording(imported) as rec:
        imu = imu_from_recording(rec)
        scans = scans_from_recording(rec)
    # Hand-held, Doppler quantised in 0.12 m/s steps: a wider velocity floor than a wheeled robot needs.
    res = run_rio(imu, scans, RioOptions(static_init_s=1.0, ekf=EkfConfig(radar_velocity_sigma_floor_mps=0.1)))
    accepted, refused = res.stats.get("radar_updates", 0), res.stats.get("radar_rejected_by_gate", 0)
    assert accepted > 0.95 * (accepted + refused)
    speed = np.linalg.norm(res.trajectory.velocity_mps, axis=1)
    assert speed.max() < 2.0 and speed[-10:].max() < 0.1
    p = res.trajectory.position_m
    length = np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))
    assert 15.0 < length < 45.0  # about 40 s of walking with pauses
    assert np.ptp(p[:, 2]) < 2.5  # carried at hand height, not flying off


def test_static_start_and_end_are_recognised(imported):
    with Recording(imported) as rec:
        imu = imu_from_recording(rec)
        scans = scans_from_recording(rec)
    res = run_rio(imu, scans, RioOptions(static_init_s=1.0))
    assert np.all(np.isfinite(res.trajectory.position_m))
    # Initial attitude from gravity: the rig rests tilted by the mean specific force's direction.
    f = imu.accel_mps2[imu.time_ns < imu.time_ns[0] + 1_000_000_000].mean(axis=0)
    roll, pitch = res.trajectory.sample(res.trajectory.time_ns[:1]).rotation.as_euler("xyz")[0, :2]
    assert roll == pytest.approx(np.arctan2(f[1], f[2]), abs=0.01)
    assert pitch == pytest.approx(np.arctan2(-f[0], np.hypot(f[1], f[2])), abs=0.01)
    status = [s for _, _, s in res.scan_status]
    n = len(status)
    # The radar's own verdict (whether or not the IMU then agreed to a zero-velocity update).
    zv = np.array([s.startswith(EgoStatus.ZERO_VELOCITY.value) for s in status])
    # Standing at the start (about 4 s) and set down for the last half second (the IMU still shakes before).
    assert zv[: n // 10].mean() > 0.8 and zv[-4:].all()
    assert zv[n // 3: 2 * n // 3].mean() < 0.3  # carried around in between


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_the_same_drive_as_a_ros2_bag_imports_the_same(imported, tmp_path, storage):
    """The ROS 1 bag converted to ROS 2 (rosbags' converter, MCAP or sqlite3 storage): import-bag reads it
    through the same AnyReader path, and the recording holds the same samples."""
    from rosbags.convert import convert
    from rosbags.typesys import Stores, get_typestore

    ros2 = tmp_path / f"drive_{storage}"
    convert([BAG / "ti_mmwave_rospkg_demo.bag"], ros2, dst_storage=storage, dst_version=8, compress=None,
            compress_mode="file", default_typestore=get_typestore(Stores.ROS1_NOETIC),
            typestore=get_typestore(Stores.ROS2_HUMBLE), exclude_topics=[], include_topics=[], exclude_msgtypes=[],
            include_msgtypes=[])
    out = tmp_path / "from_ros2.h5"
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "import-bag", str(ros2),
                          "--calib", str(BAG / "calib_ti_mmwave_rospkg_dataset.yaml"), "-o", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    with Recording(imported) as a, Recording(out) as b:
        for key in ("time_ns", "gyro_radps", "accel_mps2"):
            np.testing.assert_array_equal(a.imu()[key], b.imu()[key])
        (name,) = a.radar_names
        da, db = a.detections(name), b.detections(name)
        for key in ("time_ns", "scan", "xyz_m", "doppler_mps"):
            np.testing.assert_array_equal(da[key], db[key])
        np.testing.assert_array_equal(a.triggers(), b.triggers())


def test_standstill_speed_below_a_centimetre_per_second_at_both_ends(imported):
    """The rig stands still for the first seconds and again once set down for the last half second: the
    odometry's speed there stays below 0.01 m/s (zero-velocity updates to the IMU's noise once the radar and
    the IMU's mean rate and specific force agree it stands; 0.02 m/s before left it crawling to zero)."""
    with Recording(imported) as rec:
        imu = imu_from_recording(rec)
        scans = scans_from_recording(rec)
    res = run_rio(imu, scans, RioOptions(static_init_s=1.0))
    t = (res.trajectory.time_ns - imu.time_ns[0]) * 1e-9
    speed = np.linalg.norm(res.trajectory.velocity_mps, axis=1)
    start, end = t < 4.0, t > t[-1] - 0.4
    assert start.sum() > 250 and end.sum() > 35
    assert speed[start].max() < 0.01, f"{speed[start].max():.4f} m/s at the start"
    assert speed[end].max() < 0.01, f"{speed[end].max():.4f} m/s at the end"
    # and the radar's verdict agrees these are standstills
    zv = [s for tt, _, s in res.scan_status if (tt - imu.time_ns[0]) * 1e-9 > t[-1] - 0.4]
    assert zv and all(s == EgoStatus.ZERO_VELOCITY.value for s in zv)
