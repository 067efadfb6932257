"""sarbot's files read by an outsider, with nothing but the repository's docs.

An independent check of the claim that a user can read sarbot's outputs from the docs alone: this module
imports numpy, h5py and the standard library only (never sarbot), makes its files with the ``sarbot``
command line (see docs/cli.md) and reads them with its own reader written from docs/formats/recording.md,
docs/formats/image.md, docs/formats/trajectory.md, docs/conventions.md, docs/signal-model.md,
docs/config/scene.md and docs/config/rig.md. Every expectation below is what those pages say; where they
are silent or disagree with the files, the case says so (an ``xfail`` names the doc gap).
The scenes are written here (geometry known without reading sarbot's built-in ones): the reference
rig's left-front radar passes two point targets; a detection-level drive with an IMU turns by a known arc.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

C_MPS = 299_792_458.0
START_TIME_NS = 1_700_000_000_000_000_000  # docs/config/scene.md: start_time_ns's default

# Two point targets left of a straight pass along world x (docs/config/scene.md). The left-front radar sits
# at body (0.15, 0.20, 0.30) m, so at body x = -0.15 m it is at world (0, 0.2, 0.3): target A is r0 = 2.0 m
# broadside of it, B 2.5 m away and 0.1 m further along, with amplitude 0.7 and a 90 degree phase.
POINT_SCENE = """
name = "spec_points"
duration_s = 1.5
radars = ["left_front"]
trajectory = { kind = "straight", start_m = [-0.45, 0.0, 0.0], heading_deg = 0.0, speed_mps = 0.4 }
target = [{ kind = "point", position_m = [0.0, 2.2, 0.3] },
          { kind = "point", position_m = [0.1, 2.7, 0.3], amplitude = 0.7, phase_deg = 90.0 }]
"""
TARGETS = [  # (position in the world frame, amplitude, phase in degrees), as in POINT_SCENE
    (np.array([0.0, 2.2, 0.3]), 1.0, 0.0),
    (np.array([0.1, 2.7, 0.3]), 0.7, 90.0),
]
GRID = (-0.1, 0.2, 0.001, 2.1, 2.8, 0.008)  # x0, x1, dx, y0, y1, dy (docs/cli.md: x0:x1:dx,y0:y1:dy)

# The same kind of pass as int16 I/Q counts, two frames (docs/config/scene.md: adc_counts_per_unit).
COUNTS_SCENE = POINT_SCENE.replace('name = "spec_points"', 'name = "spec_counts"\nadc_counts_per_unit = 1000.0')
COUNTS_SCENE = COUNTS_SCENE.replace("duration_s = 1.5", "duration_s = 0.11")

# A detection-level drive with the IMU (docs/config/scene.md "Detection-level scenes"): stand 1 s, then
# 0.8 m straight at heading 30 deg, a 60 deg arc of radius 1 m, then straight again.
DRIVE_SCENE = """
name = "spec_drive"
duration_s = 7.0
imu = true
seed = 3
detections = {}
room = { size_m = [10, 8], centre_m = [1.0, 2.0] }
[trajectory]
kind = "path"
start_m = [1.0, 2.0, 0.0]
heading_deg = 30.0
speed_mps = 0.4
accel_mps2 = 0.5
start_delay_s = 1.0
segments = [["straight", 0.8], ["arc", 1.0, 60.0], ["straight", 1.0]]
"""
DRIVE_START_M = np.array([1.0, 2.0, 0.0])
DRIVE_HEADING_DEG = 30.0


def sarbot(*args, cwd):
    """Run the ``sarbot`` command line installed beside this Python; fail with its stderr if it fails."""
    exe = Path(sys.executable).with_name("sarbot")
    assert exe.exists(), f"no sarbot command beside {sys.executable}"
    done = subprocess.run([str(exe), "-q", *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"sarbot {' '.join(args)} exited {done.returncode}: {done.stderr[-2000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Every file of this module, made once by the command line as docs/cli.md shows."""
    work = tmp_path_factory.mktemp("spec")
    for name, text in [("points.toml", POINT_SCENE), ("counts.toml", COUNTS_SCENE), ("drive.toml", DRIVE_SCENE)]:
        (work / name).write_text(text)
    sarbot("simulate", "points.toml", "-o", "points.h5", cwd=work)
    sarbot("simulate", "counts.toml", "-o", "counts.h5", cwd=work)
    sarbot("simulate", "point_target", "-o", "point_target.h5", cwd=work)
    x0, x1, dx, y0, y1, dy = GRID
    sarbot("image", "points.h5", "-o", "image.h5", "--radar", "left_front",
           "--grid", f"{x0}:{x1}:{dx},{y0}:{y1}:{dy}", cwd=work)
    sarbot("simulate", "drive.toml", "-o", "drive.h5", cwd=work)
    sarbot("rio", "drive.h5", "-o", "traj.h5", "--tum", "traj.txt", cwd=work)
    sarbot("info", "drive.h5", "--tum", "truth.txt", cwd=work)
    return work


# --- my own geometry, from docs/conventions.md: quaternions [x, y, z, w], child -> parent --------------------

def rotate(q_xyzw, v):
    """Rotate vectors v (..., 3) by unit quaternions [x, y, z, w] (..., 4): child frame into parent frame."""
    q = np.asarray(q_xyzw, float)
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def conjugate(q_xyzw):
    return np.asarray(q_xyzw, float) * np.array([-1.0, -1.0, -1.0, 1.0])


def yaw_rad(q_xyzw):
    """Heading of the body's x axis in the world's x-y plane."""
    forward = rotate(q_xyzw, np.array([1.0, 0.0, 0.0]))
    return np.arctan2(forward[..., 1], forward[..., 0])


def yaw_quaternion(yaw_deg):
    half = math.radians(yaw_deg) / 2.0
    return np.array([0.0, 0.0, math.sin(half), math.cos(half)])


def truth_at(rec, time_ns):
    """The /truth pose (position, orientation) at times time_ns, linearly interpolated."""
    t = rec["truth/time_ns"][:]
    position = np.stack([np.interp(time_ns, t, rec["truth/position_m"][:, i]) for i in range(3)], axis=-1)
    orientation = np.stack([np.interp(time_ns, t, rec["truth/orientation_xyzw"][:, i]) for i in range(4)], -1)
    return position, orientation / np.linalg.norm(orientation, axis=-1, keepdims=True)


def antenna_world_m(rec, radar, time_ns, antenna_sensor_m):
    """docs/conventions.md: p_b = mount_translation + R(mount_rotation) p_s, then the body pose into the world."""
    attrs = rec[f"radar/{radar}"].attrs
    body_p, body_q = truth_at(rec, time_ns)
    in_body = attrs["mount_translation_m"] + rotate(attrs["mount_rotation_xyzw"], antenna_sensor_m)
    return body_p + rotate(body_q, in_body)


# --- the recording file: docs/formats/recording.md ----------------------------------------------------------

def test_recording_root_and_radar_attributes_are_the_documented_ones(files):
    with h5py.File(files / "points.h5", "r") as rec:
        assert rec.attrs["schema"] == "sarbot.recording" and int(rec.attrs["schema_version"]) == 1
        assert isinstance(rec.attrs["software_version"], str) and rec.attrs["software_version"]
        assert rec.attrs["created_utc"][:2] == "20" and "T" in rec.attrs["created_utc"]  # ISO 8601
        assert list(rec["radar"]) == ["left_front"]  # the scene's `radars`
        a = rec["radar/left_front"].attrs
        # The reference radar (docs/signal-model.md's table; the default rig's left_front starts at 76.0 GHz).
        expected = dict(f0_hz=76.0e9, bandwidth_hz=4.0e9, chirp_duration_s=180e-6, chirp_interval_s=200e-6,
                        frame_interval_s=52e-3, sample_rate_hz=977e3)
        for key, value in expected.items():
            assert a[key] == pytest.approx(value, rel=1e-12), key
        assert int(a["chirps_per_frame"]) == 256 and int(a["n_tx"]) == 4 and int(a["n_rx"]) == 4
        # The rig's mount (docs/config/rig.md): (0.15, 0.20, 0.30) m, yaw 90 deg = looking left.
        np.testing.assert_allclose(a["mount_translation_m"], [0.15, 0.20, 0.30], atol=1e-12)
        np.testing.assert_allclose(a["mount_rotation_xyzw"], yaw_quaternion(90.0), atol=1e-12)
        np.testing.assert_allclose(rotate(a["mount_rotation_xyzw"], np.array([1.0, 0, 0])), [0, 1, 0], atol=1e-12)
        # The default array: RX j at y = j lambda0 / 2, TX i at y = Nr i lambda0 / 2 (docs/signal-model.md).
        half_wavelength_m = C_MPS / 76.0e9 / 2.0
        assert a["tx_positions_m"].shape == (4, 3) and a["rx_positions_m"].shape == (4, 3)
        np.testing.assert_allclose(a["rx_positions_m"][:, 1], np.arange(4) * half_wavelength_m, rtol=1e-9)
        np.testing.assert_allclose(a["tx_positions_m"][:, 1], 4 * np.arange(4) * half_wavelength_m, rtol=1e-9)
        np.testing.assert_allclose(a["tx_positions_m"][:, [0, 2]], 0.0)
        # TDM: chirp k is sent by TX k mod n_tx, stored as int32 [chirps_per_frame].
        assert a["tdm_tx_order"].dtype == np.int32
        np.testing.assert_array_equal(a["tdm_tx_order"], np.arange(256) % 4)
        assert a["wire_format"] == "simulated"
        assert "receive_stamp" not in a  # "absent in simulations"


def test_recording_datasets_have_the_documented_types_shapes_and_times(files):
    with h5py.File(files / "points.h5", "r") as rec:
        g = rec["radar/left_front"]
        n_samples = math.floor(977e3 * 180e-6)  # docs/signal-model.md: floor(fs Tc) = 175
        n_frames = g["frame_time_ns"].shape[0]
        assert n_frames == math.floor(1.5 / 52e-3)  # every whole frame of the 1.5 s scene
        assert g["adc"].dtype == np.complex64  # a simulation without adc_counts_per_unit
        assert g["adc"].shape == (n_frames, 256, 4, n_samples)
        for name, dtype in [("frame_time_ns", np.int64), ("frame_counter", np.uint32),
                            ("host_time_ns", np.int64), ("valid", np.uint8)]:
            assert g[name].dtype == dtype and g[name].shape == (n_frames,), name
        frame_time_ns = g["frame_time_ns"][:]
        assert frame_time_ns[0] == START_TIME_NS
        np.testing.assert_array_equal(np.diff(frame_time_ns), 52_000_000)
        np.testing.assert_array_equal(np.diff(g["frame_counter"][:].astype(np.int64)), 1)
        assert g["valid"][:].all()
        # Host time is UTC (CLOCK_REALTIME), sensor time TAI (docs/conventions.md: 37 s apart); a frame is
        # received after its last chirp and before the next frame starts.
        receive_delay_s = (g["host_time_ns"][:] - frame_time_ns) * 1e-9 + 37.0
        assert np.all(receive_delay_s >= 256 * 200e-6 - 1e-9) and np.all(receive_delay_s <= 52e-3 + 1e-3)
        # /truth: at truth_rate_hz (1000 by default) over the scene's duration; the first pose is start_m.
        t = rec["truth/time_ns"][:]
        assert t.dtype == np.int64 and t[0] == START_TIME_NS
        np.testing.assert_array_equal(np.diff(t), 1_000_000)
        assert (t[-1] - t[0]) * 1e-9 == pytest.approx(1.5, abs=2e-3)
        for name, width in [("position_m", 3), ("orientation_xyzw", 4), ("velocity_mps", 3)]:
            assert rec[f"truth/{name}"].dtype == np.float64 and rec[f"truth/{name}"].shape == (len(t), width)
        np.testing.assert_allclose(rec["truth/position_m"][0], [-0.45, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(rec["truth/velocity_mps"][:], np.tile([0.4, 0, 0], (len(t), 1)), atol=1e-9)
        assert rec["trigger/time_ns"][:].tolist() == [START_TIME_NS]  # the first chirp of the run
        # Every numeric dataset: chunked, appendable along its first axis, Fletcher-32.
        numeric = []
        rec.visititems(lambda name, obj: numeric.append(obj)
                       if isinstance(obj, h5py.Dataset) and obj.dtype.kind in "iufc" else None)
        assert len(numeric) >= 10
        for ds in numeric:
            assert ds.chunks is not None and ds.maxshape[0] is None and ds.fletcher32, ds.name
    # A reader can follow the file as it is written: it opens as SWMR.
    with h5py.File(files / "points.h5", "r", libver="latest", swmr=True) as rec:
        assert rec["radar/left_front/adc"].shape[0] == n_frames


def test_trigger_source_is_the_documented_simulation_value(files):
    """docs/formats/recording.md: a simulation's trigger is `radar_first_chirp`, at the scene's start (this
    case xfailed until the page listed it: the first draft named only the hardware sources)."""
    with h5py.File(files / "points.h5", "r") as rec:
        sources = [s.decode() if isinstance(s, bytes) else s for s in rec["trigger/source"][:]]
        assert rec["trigger/time_ns"][0] == START_TIME_NS
    assert sources == ["radar_first_chirp"]


# --- the signal model: docs/signal-model.md ----------------------------------------------------------------

def range_profile(samples, oversample=16):
    """Hann window and zero-padded FFT along fast time; bin k is two-way range k c fs / (Nfft slope)."""
    n = len(samples)
    return np.fft.fft(samples * np.hanning(n), oversample * n)


def two_way_range_m(rec, frame, chirp, rx, target_m, sample_time_s=0.0):
    """|p_tx - p| + |p_rx - p| at the chirp's start (frame_time + chirp * Tr) plus sample_time_s."""
    g = rec["radar/left_front"]
    a = g.attrs
    t_ns = g["frame_time_ns"][frame] + np.round((chirp * a["chirp_interval_s"] + sample_time_s) * 1e9)
    tx = antenna_world_m(rec, "left_front", t_ns, a["tx_positions_m"][a["tdm_tx_order"][chirp]])
    rx_m = antenna_world_m(rec, "left_front", t_ns, a["rx_positions_m"][rx])
    return np.linalg.norm(tx - target_m, axis=-1) + np.linalg.norm(rx_m - target_m, axis=-1)


def adc_complex(g, frame, chirp, rx):
    """complex64, or int16 I/Q pairs with I first (docs/formats/recording.md)."""
    raw = g["adc"][frame, chirp, rx]
    return raw[..., 0] + 1j * raw[..., 1] if raw.dtype == np.int16 else raw.astype(complex)


CASES = [(0, 0, 0), (14, 1, 3), (14, 6, 1), (27, 255, 2)]  # (frame, chirp, rx): every TX, early and late


@pytest.mark.parametrize("frame, chirp, rx", CASES)
def test_raw_frames_range_compress_to_the_targets_ranges(files, frame, chirp, rx):
    with h5py.File(files / "points.h5", "r") as rec:
        a = rec["radar/left_front"].attrs
        slope = a["bandwidth_hz"] / a["chirp_duration_s"]
        fs = a["sample_rate_hz"]
        samples = adc_complex(rec["radar/left_front"], frame, chirp, rx)
        profile = np.abs(range_profile(samples)) ** 2
        n_fft = len(profile)
        bin_m = C_MPS * fs / (n_fft * slope)
        # A positive beat frequency: far more power in the first half of the FFT than in the second.
        assert 10 * np.log10(profile[1:n_fft // 2].sum() / profile[n_fft // 2 + 1:].sum()) > 20.0
        found = []
        for target_m, _, _ in TARGETS:
            expected = two_way_range_m(rec, frame, chirp, rx, target_m)
            k = int(round(expected / bin_m))
            window = slice(k - 8, k + 9)  # +-8 bins of 4.7 mm: within the Hann main lobe (about 16 bins)
            found.append((expected, (window.start + np.argmax(profile[window])) * bin_m))
        if frame == 14:  # mid-pass, broadside of A at r0 = 2.0 m: two-way 4.0 m (docs/conventions.md)
            assert found[0][0] == pytest.approx(4.0, abs=0.002)
        for expected, measured in found:
            assert measured == pytest.approx(expected, abs=bin_m), (expected, measured)
        assert np.argmax(profile) * bin_m == pytest.approx(found[0][0], abs=bin_m)  # A is the strongest


@pytest.mark.parametrize("frame, chirp, rx", CASES)
def test_raw_samples_match_the_documented_beat_signal(files, frame, chirp, rx):
    """s = A exp(+j 2 pi / c (f0 + slope n / fs) r(t + n / fs)): a matched filter gives A and the phase."""
    with h5py.File(files / "points.h5", "r") as rec:
        a = rec["radar/left_front"].attrs
        f0, fs, slope = a["f0_hz"], a["sample_rate_hz"], a["bandwidth_hz"] / a["chirp_duration_s"]
        samples = adc_complex(rec["radar/left_front"], frame, chirp, rx)
        n = np.arange(len(samples))
        for target_m, amplitude, phase_deg in TARGETS:
            r = two_way_range_m(rec, frame, chirp, rx, target_m, sample_time_s=n / fs)  # intra-chirp motion
            model = np.exp(1j * 2 * np.pi / C_MPS * (f0 + slope * n / fs) * r)
            estimate = np.vdot(model, samples) / len(n)
            assert abs(estimate) == pytest.approx(amplitude, rel=0.05)
            assert np.degrees(np.angle(estimate * np.exp(-1j * np.radians(phase_deg)))) == pytest.approx(0, abs=6)


def test_int16_counts_are_iq_pairs_with_i_first(files):
    with h5py.File(files / "counts.h5", "r") as rec:
        g = rec["radar/left_front"]
        assert g["adc"].dtype == np.int16 and g["adc"].shape == (2, 256, 4, 175, 2)
        a = g.attrs
        f0, fs, slope = a["f0_hz"], a["sample_rate_hz"], a["bandwidth_hz"] / a["chirp_duration_s"]
        samples = adc_complex(g, 1, 5, 2)
        n = np.arange(len(samples))
        target_m, _, _ = TARGETS[0]
        r = two_way_range_m(rec, 1, 5, 2, target_m, sample_time_s=n / fs)
        estimate = np.vdot(np.exp(1j * 2 * np.pi / C_MPS * (f0 + slope * n / fs) * r), samples) / len(n)
        assert abs(estimate) == pytest.approx(1000.0, rel=0.05)  # adc_counts_per_unit x amplitude 1
        assert np.degrees(np.angle(estimate)) == pytest.approx(0, abs=6)


def test_built_in_point_target_is_at_r0_2_m_broadside_as_described(files):
    """docs/config/scene.md: 'one point target at r0 = 2 m broadside to the left-front radar, 0.4 m/s'."""
    with h5py.File(files / "point_target.h5", "r") as rec:
        g = rec["radar/left_front"]
        a = g.attrs
        bin_m = C_MPS * a["sample_rate_hz"] / (16 * 175 * a["bandwidth_hz"] / a["chirp_duration_s"])
        two_way_m = np.array([np.argmax(np.abs(range_profile(adc_complex(g, k, 0, 0)))) * bin_m
                              for k in range(g["adc"].shape[0])])
        speed = np.linalg.norm(rec["truth/velocity_mps"][:], axis=1)
    assert two_way_m.min() / 2 == pytest.approx(2.0, abs=bin_m)  # closest (broadside) range of TX 0 / RX 0
    assert 0 < np.argmin(two_way_m) < len(two_way_m) - 1  # passed during the recording
    np.testing.assert_allclose(speed, 0.4, atol=1e-9)


# --- the image file: docs/formats/image.md -----------------------------------------------------------------

def half_power_width(axis, power):
    """Width at -3.0 dB (docs/conventions.md) around the maximum, by linear interpolation."""
    level = power.max() * 10 ** -0.3
    k = int(np.argmax(power))
    lo, hi = k - int(np.argmax(power[k::-1] < level)), k + int(np.argmax(power[k:] < level))
    left = np.interp(level, power[lo:lo + 2], axis[lo:lo + 2])
    right = np.interp(level, power[hi - 1:hi + 1][::-1], axis[hi - 1:hi + 1][::-1])
    return right - left


def test_image_file_has_the_documented_datasets_and_attributes(files):
    x0, x1, dx, y0, y1, dy = GRID
    with h5py.File(files / "image.h5", "r") as f:
        assert f.attrs["schema"] == "sarbot.image" and int(f.attrs["schema_version"]) == 1
        x, y, z = f["x_m"][:], f["y_m"][:], f["z_m"][:]
        assert f["x_m"].dtype == f["y_m"].dtype == f["z_m"].dtype == np.float64
        assert f["image"].dtype == np.complex64 and f["image"].shape == (len(y), len(x))  # [ny, nx]
        for axis, start, stop, step in [(x, x0, x1, dx), (y, y0, y1, dy)]:
            assert axis[0] == pytest.approx(start) and np.allclose(np.diff(axis), step)
            assert stop - step < axis[-1] <= stop + step / 2  # the grid's end (inclusive or not: not documented)
        np.testing.assert_allclose(z, [0.3])  # default height: the radar's (docs/cli.md "Grids")
        assert all(f[k].fletcher32 for k in ("image", "x_m", "y_m", "z_m"))
        a = dict(f.attrs)
    assert (files / "image.png").exists()  # "a PNG goes beside it"
    assert a["radar"] == "left_front" and a["frames"] == "0:28" and int(a["n_frames"]) == 28
    assert a["trajectory_source"] == "truth"
    assert a["method"] in {f"{alg}-{mode}" for alg in ("tdbp", "ffbp") for mode in ("nearest", "linear", "exact")}
    assert a["window"] == "hann" and a["aperture_window"] == "rectangular" and int(a["oversample"]) >= 1
    assert int(a["n_profiles"]) == 28 * 256 * 4  # chirp x RX per frame
    step_hz = 4.0e9 / 180e-6 / 977e3
    assert a["bandwidth_hz"] == pytest.approx(175 * step_hz, rel=1e-9)  # sampled bandwidth, 3.980 GHz
    # "at the chirp's centre frequency": f0 + B/2 = 78 GHz (the file's exact definition: see the report).
    assert a["centre_frequency_hz"] == pytest.approx(78.0e9, rel=1e-3)
    assert a["wavelength_m"] == pytest.approx(C_MPS / a["centre_frequency_hz"], rel=1e-9)
    frames_span_s = 27 * 52e-3 + 256 * 200e-6
    assert a["aperture_length_m"] == pytest.approx(0.4 * frames_span_s, rel=0.05)
    assert a["speed_mps"] == pytest.approx(0.4, rel=1e-6)
    np.testing.assert_allclose(a["look_direction"], [0, 1, 0], atol=1e-9)  # left of a pass along world x
    # The radar's track: y = 0.2, z = 0.3, x from -0.3 to -0.3 + 0.4 * frames_span_s.
    np.testing.assert_allclose(a["aperture_centre_m"], [-0.3 + 0.2 * frames_span_s, 0.2, 0.3], atol=0.02)
    assert Path(a["source_file"]).name == "points.h5"


def test_image_peaks_sit_at_the_targets_with_the_documented_widths(files):
    with h5py.File(files / "image.h5", "r") as f:
        power = np.abs(f["image"][:]).astype(float) ** 2
        x, y = f["x_m"][:], f["y_m"][:]
        wavelength_m, aperture_m = f.attrs["wavelength_m"], f.attrs["aperture_length_m"]
        bandwidth_hz = f.attrs["bandwidth_hz"]
    range_width_m = 1.4381 * C_MPS / (2 * bandwidth_hz)  # docs/signal-model.md: 5.42 cm
    assert range_width_m == pytest.approx(0.0542, abs=2e-4)
    peaks = []
    masked = power.copy()
    for target_m, amplitude, _ in TARGETS:
        r0 = target_m[1] - 0.2  # from the radar's track at y = 0.2 m
        cross_width_m = 0.88448 * wavelength_m * r0 / (2 * aperture_m)
        iy, ix = np.unravel_index(np.argmax(masked), masked.shape)
        # Within a resolution cell of the target's documented coordinates (plus half a pixel of the grid).
        assert abs(x[ix] - target_m[0]) <= cross_width_m / 2 + GRID[2] / 2, (x[ix], target_m)
        assert abs(y[iy] - target_m[1]) <= range_width_m / 2 + GRID[5] / 2, (y[iy], target_m)
        assert half_power_width(x, power[iy]) == pytest.approx(cross_width_m, rel=0.15)
        assert half_power_width(y, power[:, ix]) == pytest.approx(range_width_m, rel=0.15)
        peaks.append(np.sqrt(power[iy, ix]))
        masked[np.ix_(np.abs(y - y[iy]) < 0.2, np.abs(x - x[ix]) < 0.05)] = 0.0
    assert peaks[1] / peaks[0] == pytest.approx(0.7, rel=0.1)  # amplitudes 1.0 and 0.7, coherently summed


# --- the trajectory file and the drive: docs/formats/trajectory.md, docs/conventions.md ----------------------

def read_tum(path):
    rows = np.loadtxt(path)
    assert rows.ndim == 2 and rows.shape[1] == 8  # t tx ty tz qx qy qz qw
    return rows


def test_truth_follows_the_scenes_motion(files):
    with h5py.File(files / "drive.h5", "r") as rec:
        t_s = (rec["truth/time_ns"][:] - START_TIME_NS) * 1e-9
        p, q, v = rec["truth/position_m"][:], rec["truth/orientation_xyzw"][:], rec["truth/velocity_mps"][:]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    standing = t_s < 1.0 - 1e-3  # start_delay_s
    np.testing.assert_allclose(p[standing], np.tile(DRIVE_START_M, (standing.sum(), 1)), atol=1e-9)
    np.testing.assert_allclose(q[standing], np.tile(yaw_quaternion(DRIVE_HEADING_DEG), (standing.sum(), 1)),
                               atol=1e-9)  # heading 30 deg from world x: [0, 0, sin 15, cos 15]
    speed = np.linalg.norm(v, axis=1)
    assert speed.max() == pytest.approx(0.4, abs=1e-6)
    assert np.max(np.abs(np.gradient(speed, t_s))) <= 0.5 + 0.01  # accel_mps2 (see the xfail below)
    # Body x is forward: the velocity points along the orientation's x axis; on the first straight, the
    # heading; on the arc, speed / yaw rate is its radius; after it the heading has turned by 60 deg.
    moving = speed > 0.05
    heading = np.arctan2(v[moving, 1], v[moving, 0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (heading - yaw_rad(q[moving])))), 0, atol=np.radians(0.5))
    distance = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    first_straight = (distance > 0.01) & (distance < 0.79)
    direction = (p[first_straight] - DRIVE_START_M) / distance[first_straight, None]
    np.testing.assert_allclose(direction[:, :2], np.tile([math.cos(math.radians(30)), 0.5],
                                                         (first_straight.sum(), 1)), atol=1e-6)
    yaw = np.unwrap(yaw_rad(q))
    on_arc = (distance > 0.85) & (distance < 0.8 + math.radians(60) - 0.05)
    np.testing.assert_allclose(speed[on_arc] / np.abs(np.gradient(yaw, t_s)[on_arc]), 1.0, rtol=0.02)
    assert distance[-1] > 0.8 + math.radians(60) + 0.1  # the arc is done by the end
    assert abs(np.degrees(yaw[-1] - yaw[0])) == pytest.approx(60.0, abs=0.5)  # the sign: see the report


def test_truth_accelerates_on_the_documented_ramp(files):
    """docs/config/scene.md: a raised-cosine speed ramp peaking at accel_mps2, pi v / (2 a) long (this case
    xfailed against the first draft, which said "accelerate at this rate")."""
    with h5py.File(files / "drive.h5", "r") as rec:
        t_s = (rec["truth/time_ns"][:] - START_TIME_NS) * 1e-9
        speed = np.linalg.norm(rec["truth/velocity_mps"][:], axis=1)
    ramp_s = math.pi * 0.4 / (2 * 0.5)  # speed_mps, accel_mps2
    up = (t_s > 1.0) & (t_s < 1.0 + ramp_s)  # after start_delay_s
    np.testing.assert_allclose(speed[up], 0.2 * (1 - np.cos(math.pi * (t_s[up] - 1.0) / ramp_s)), atol=2e-3)
    assert np.max(np.gradient(speed, t_s)[up]) == pytest.approx(0.5, abs=0.01)


def test_imu_and_detections_follow_the_documented_frames(files):
    with h5py.File(files / "drive.h5", "r") as rec:
        imu = rec["imu"]
        assert imu.attrs["rate_hz"] == pytest.approx(400.0)
        t = imu["time_ns"][:]
        assert imu["gyro_radps"].dtype == np.float64 and imu["gyro_radps"].shape == (len(t), 3)
        assert imu["accel_mps2"].dtype == np.float64 and imu["counter"].dtype == np.uint32
        np.testing.assert_array_equal(np.diff(t), 2_500_000)
        still = (t - START_TIME_NS) * 1e-9 < 0.95
        # Specific force of a level IMU at rest, z up: +g along z.
        np.testing.assert_allclose(imu["accel_mps2"][still].mean(axis=0), [0, 0, 9.81], atol=0.02)
        truth_t = rec["truth/time_ns"][:]
        yaw_rate = np.gradient(np.unwrap(yaw_rad(rec["truth/orientation_xyzw"][:])), truth_t * 1e-9)
        turning = np.abs(np.interp(t, truth_t, yaw_rate)) > 0.3
        np.testing.assert_allclose(imu["gyro_radps"][turning, 2], np.interp(t[turning], truth_t, yaw_rate),
                                   atol=0.01)
        for radar in rec["radar"]:
            g = rec[f"radar/{radar}"]
            assert g["adc"].shape[0] == 0  # a detection-level simulation: an empty adc
            d = g["detections"]
            for name, dtype, width in [("time_ns", np.int64, None), ("scan", np.uint32, None),
                                       ("xyz_m", np.float32, 3), ("doppler_mps", np.float32, None),
                                       ("snr_db", np.float32, None)]:
                assert d[name].dtype == dtype and d[name].shape[1:] == ((width,) if width else ()), name
            det_t = d["time_ns"][:]
            frame_t = g["frame_time_ns"][:]
            k = np.searchsorted(frame_t, det_t, side="right") - 1
            assert np.all(k >= 0) and np.all(det_t - frame_t[k] <= 256 * 200e-6 * 1e9)  # within the frame
            # Doppler: range rate, positive receding; for a still room it is -(v_sensor . unit(xyz)).
            xyz = d["xyz_m"][:].astype(float)
            body_p, body_q = truth_at(rec, det_t)
            velocity = np.stack([np.interp(det_t, truth_t, rec["truth/velocity_mps"][:, i]) for i in range(3)], 1)
            omega = np.zeros_like(velocity)
            omega[:, 2] = np.interp(det_t, truth_t, yaw_rate)
            mount_t, mount_q = g.attrs["mount_translation_m"], g.attrs["mount_rotation_xyzw"]
            radar_v_world = velocity + np.cross(omega, rotate(body_q, mount_t))
            radar_v_sensor = rotate(conjugate(mount_q), rotate(conjugate(body_q), radar_v_world))
            predicted = -np.sum(radar_v_sensor * xyz / np.linalg.norm(xyz, axis=1, keepdims=True), axis=1)
            moving = np.linalg.norm(radar_v_sensor, axis=1) > 0.2
            assert np.mean(np.abs(d["doppler_mps"][:][moving] - predicted[moving]) < 0.06) > 0.9, radar
            # Positions in the sensor frame: mounted and posed, most land on the room's walls.
            world = body_p + rotate(body_q, mount_t + rotate(mount_q, xyz))
            on_wall = (np.abs(np.abs(world[:, 0] - 1.0) - 5.0) < 0.1) | (np.abs(np.abs(world[:, 1] - 2.0) - 4.0) < 0.1)
            assert on_wall.mean() > 0.5, radar


def test_imu_can_and_events_groups_are_the_documented_ones(files):
    with h5py.File(files / "drive.h5", "r") as rec:
        a = rec["imu"].attrs  # the reference rig's IMU (docs/config/rig.md defaults)
        expected = dict(rate_hz=400.0, gyro_noise_density_radps_per_sqrt_hz=1e-4,
                        accel_noise_density_mps2_per_sqrt_hz=1e-3, gyro_bias_random_walk_radps2_per_sqrt_hz=1e-5,
                        accel_bias_random_walk_mps3_per_sqrt_hz=1e-4)
        for key, value in expected.items():
            assert a[key] == pytest.approx(value, rel=1e-12), key
        np.testing.assert_allclose(a["mount_translation_m"], [0, 0, 0])
        np.testing.assert_allclose(a["mount_rotation_xyzw"], [0, 0, 0, 1])
        assert "clock_drift_ppm" in a  # NaN until a driver knows it
        counter = rec["imu/counter"][:].astype(np.int64)
        np.testing.assert_array_equal(np.diff(counter), 1)
        assert rec["imu/host_time_ns"].dtype == np.int64 and rec["imu/host_time_ns"].shape == counter.shape
        # /events: strings and int64 times, one row each.
        lengths = {len(rec[f"events/{k}"]) for k in ("time_ns", "source", "level", "message")}
        assert len(lengths) == 1 and rec["events/time_ns"].dtype == np.int64
        # /can (docs/wire/can.md): the trigger frame 0x100 carries the trigger's PTP time, u64 LE;
        # 0x201 the wheel speeds, int32 LE mm/s, left then right.
        can = rec["can"]
        ids, dlc, data, t = can["arbitration_id"][:], can["dlc"][:], can["data"][:], can["time_ns"][:]
        assert ids.dtype == np.uint32 and dlc.dtype == np.uint8 and data.dtype == np.uint8 and t.dtype == np.int64
        assert data.shape == (len(ids), 64) and np.all(data[np.arange(64)[None, :] >= dlc[:, None]] == 0)
        trigger = data[ids == 0x100]
        assert len(trigger) == 1
        assert int.from_bytes(bytes(trigger[0, :8]), "little") == int(rec["trigger/time_ns"][0])
        wheels = data[ids == 0x201][:, :8].copy().view("<i4") * 1e-3  # [K, 2] m/s
        wheel_t = t[ids == 0x201]
        assert len(wheels) > 100
        truth_t = rec["truth/time_ns"][:]
        speed = np.interp(wheel_t, truth_t, np.linalg.norm(rec["truth/velocity_mps"][:], axis=1))
        yaw_rate = np.interp(wheel_t, truth_t, np.gradient(np.unwrap(yaw_rad(rec["truth/orientation_xyzw"][:])),
                                                           truth_t * 1e-9))
        straight = np.abs(yaw_rate) < 1e-3
        np.testing.assert_allclose(wheels[straight], np.stack([speed[straight]] * 2, axis=1), atol=0.01)
        turning = np.abs(yaw_rate) > 0.3
        assert turning.sum() > 10
        np.testing.assert_array_equal(np.sign(wheels[turning, 1] - wheels[turning, 0]), np.sign(yaw_rate[turning]))


def test_a_flipped_byte_is_a_read_error_never_good_data(files, tmp_path):
    """docs/formats/recording.md: every numeric dataset carries Fletcher-32, so a flipped byte is a read error."""
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes((files / "counts.h5").read_bytes())
    with h5py.File(damaged, "r") as rec:
        chunk = rec["radar/left_front/frame_time_ns"].id.get_chunk_info(0)
    raw = bytearray(damaged.read_bytes())
    raw[chunk.byte_offset + 2] ^= 0x10  # a byte of the first frame's time
    damaged.write_bytes(bytes(raw))
    with h5py.File(damaged, "r") as rec:
        with pytest.raises(OSError):
            rec["radar/left_front/frame_time_ns"][:]
    exe = Path(sys.executable).with_name("sarbot")  # info --verify: one line per damaged chunk, exit 2
    done = subprocess.run([str(exe), "info", "--verify", str(damaged)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "/radar/left_front/frame_time_ns" in done.stdout + done.stderr


def test_info_tum_of_truth_is_the_truth_in_tum_order(files):
    tum = read_tum(files / "truth.txt")
    with h5py.File(files / "drive.h5", "r") as rec:
        np.testing.assert_allclose(tum[:, 0], rec["truth/time_ns"][:] * 1e-9, atol=1e-6, rtol=0)
        np.testing.assert_allclose(tum[:, 1:4], rec["truth/position_m"][:], atol=2e-9)
        np.testing.assert_allclose(tum[:, 4:], rec["truth/orientation_xyzw"][:], atol=2e-9)


def test_trajectory_file_has_the_documented_layout_and_matches_the_tum_text(files):
    with h5py.File(files / "traj.h5", "r") as f:
        assert f.attrs["schema"] == "sarbot.trajectory" and int(f.attrs["schema_version"]) == 1
        assert f.attrs["source"] == "rio"
        tr = f["trajectory"]
        n = tr["time_ns"].shape[0]
        assert n > 100 and tr["time_ns"].dtype == np.int64
        for name, width in [("position_m", 3), ("orientation_xyzw", 4), ("velocity_mps", 3), ("covariance_diag", 15)]:
            assert tr[name].dtype == np.float64 and tr[name].shape == (n, width), name
            assert tr[name].fletcher32, name
        t = tr["time_ns"][:]
        assert np.all(np.diff(t) > 0)
        assert np.all(tr["covariance_diag"][:] > 0)
        pose = np.concatenate([tr["position_m"][:], tr["orientation_xyzw"][:]], axis=1)
    tum = read_tum(files / "traj.txt")
    assert len(tum) == n
    np.testing.assert_allclose(tum[:, 0], t * 1e-9, atol=1e-6, rtol=0)
    np.testing.assert_allclose(tum[:, 1:], pose, atol=2e-9)


def test_trajectory_poses_are_the_body_in_the_start_pose_world_frame(files):
    """docs/conventions.md: world = local level, z up, origin the start pose; orientation body -> world."""
    with h5py.File(files / "traj.h5", "r") as f:
        t = f["trajectory/time_ns"][:]
        p, q, v = (f[f"trajectory/{k}"][:] for k in ("position_m", "orientation_xyzw", "velocity_mps"))
    with h5py.File(files / "drive.h5", "r") as rec:
        truth_p, truth_q = truth_at(rec, t)
        truth_v = np.stack([np.interp(t, rec["truth/time_ns"][:], rec["truth/velocity_mps"][:, i])
                            for i in range(3)], axis=1)
        start_p, start_q = truth_at(rec, rec["truth/time_ns"][:1])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    to_start = conjugate(start_q[0])
    np.testing.assert_allclose(p, rotate(to_start, truth_p - start_p[0]), atol=0.05)
    np.testing.assert_allclose(v, rotate(to_start, truth_v), atol=0.05)
    yaw_error = np.degrees(np.angle(np.exp(1j * (yaw_rad(q) - (yaw_rad(truth_q) - yaw_rad(start_q[0]))))))
    assert np.max(np.abs(yaw_error)) < 1.0
    assert np.degrees(np.unwrap(yaw_rad(q))[-1] - yaw_rad(q[0])) == pytest.approx(
        np.degrees(np.unwrap(yaw_rad(truth_q))[-1] - yaw_rad(truth_q[0])), abs=1.0)
    speed = np.linalg.norm(v, axis=1)
    moving = speed > 0.2  # body x forward
    heading_error = np.angle(np.exp(1j * (np.arctan2(v[moving, 1], v[moving, 0]) - yaw_rad(q[moving]))))
    assert np.max(np.abs(np.degrees(heading_error))) < 3.0


def test_truth_tum_and_trajectory_tum_agree_once_their_first_poses_are_aligned(files):
    """docs/formats/trajectory.md: /truth is in the scene's frame, the odometry in its start pose's, so the
    comparison aligns the first poses (evo's --align_origin). Unaligned they differ by start_m and heading_deg
    (this case xfailed against the first draft, which compared them as they are)."""
    truth, traj = read_tum(files / "truth.txt"), read_tum(files / "traj.txt")
    position = np.stack([np.interp(traj[:, 0], truth[:, 0], truth[:, i]) for i in (1, 2, 3)], axis=1)
    unaligned_m = np.sqrt(np.mean(np.sum((position - traj[:, 1:4]) ** 2, axis=1)))
    assert unaligned_m > 0.5  # start_m is 2.2 m from the origin
    first = np.argmin(np.abs(truth[:, 0] - traj[0, 0]))
    to_origin = conjugate(truth[first, 4:8])
    aligned = rotate(to_origin, position - truth[first, 1:4])
    assert np.sqrt(np.mean(np.sum((aligned - traj[:, 1:4]) ** 2, axis=1))) < 0.05


def test_info_json_names_the_kind_of_each_file(files):
    for name, kind in [("points.h5", "recording"), ("image.h5", "image"), ("traj.h5", "trajectory")]:
        assert json.loads(sarbot("info", name, "--json", cwd=files))["kind"] == kind
