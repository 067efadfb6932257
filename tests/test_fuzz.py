"""Bad input never gives a traceback: fuzzed option values, rig and scene TOML, and damaged recordings.

Each example goes through the same code a user's command does (``acquisition.cli.main``, the option
checks of ``record``/``run``/``replay`` before anything starts, the TOML loaders, the recording reader).
What may come out: a result, or a one-line error (``SarbotError`` -> exit 2, or argparse's usage error,
exit 2). Anything else escaping is a traceback the user would see, and fails the example.
"""

from __future__ import annotations

import contextlib
import io
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from conftest import SHARED_DATA

from acquisition import cli
from acquisition.cli.daemon import check_replay, record_setup, run_workers
from acquisition.cli.options import check_duration, join_negative_values
from imaging.core.errors import SarbotError

ROOT = Path(__file__).resolve().parents[1]
RIG = ROOT / "imaging" / "rigs" / "default.toml"
SCENE = ROOT / "imaging" / "sim" / "scenes" / "demo_room.toml"
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])

#: Values a user (or a script gone wrong) might type, and the edges hypothesis would take long to find.
EDGES = ["", " ", "-1", "0", "0.0", "-0", "nan", "NaN", "inf", "-inf", "1e999", "1e-999", "1e308", ":", "::", "=",
         "a=b", "x=1:2", "1:0", "0:0", "1:2:3", "-1:1", "1,2", "1,2,3", ",", "0x", "0x100", "2G", "-2G", "0G", "1e99G",
         "99999999999999999999", "65536", "left_front=", "left_front=0", "left_front=70000", "left_front=h:1:2",
         "left_front=127.0.0.1:-5", "left_front=999.1.1.1:4098", "left_front=4098,format=NOPE", "left_front=4098,id=x",
         "left_front=4098,source=notanaddress", "nobody=4098", "all", "none", "\x00", "é", "../../etc/passwd"]
VALUES = st.one_of(st.sampled_from(EDGES), st.text(max_size=24), st.floats().map(repr), st.integers().map(str))


def run_cli(argv: list[str]) -> tuple[int, str]:
    """``sarbot ARGV`` in this process: (exit code, stderr). An exception escaping is a test failure."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = cli.main(argv)
        except SystemExit as exc:  # argparse: usage errors exit 2
            code = exc.code
    return code, err.getvalue()


def check_setup(argv: list[str], tmp_path: Path) -> tuple[int, str]:
    """Everything ``record``/``run``/``replay`` check before they start a process or open a port."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            args = cli.build_parser().parse_args(join_negative_values(argv))
            if args.command in ("record", "run"):
                setup = record_setup(args)
                check_duration(args.duration)
                if args.command == "run":
                    run_workers(setup, args, tmp_path, "fuzz")
            else:
                check_replay(args)
            return 0, ""
        except SystemExit as exc:
            return exc.code, err.getvalue()
        except SarbotError as exc:
            return 2, str(exc)


def assert_clean(code, err, argv):
    assert code in (0, 2), (code, argv, err)
    assert "Traceback" not in err, (argv, err)
    if code == 2:
        assert err.strip(), argv  # said why


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory):
    """A short simulated pass of one radar (``left_front``) with its truth, so ``image`` runs through."""
    from conftest import point_pass

    from imaging.sim.simulator import simulate_recording

    path = tmp_path_factory.mktemp("fuzz") / "small.h5"
    simulate_recording(point_pass(1.0, duration_s=0.25), path)
    return path


OPTIONS_RECORD = ["--radar", "--dca1000", "--imu-port", "--radar-imu", "--can", "--can-arg", "--can-trigger-id", "--duration",
                  "--split-size", "--split-time", "--min-free", "--health-endpoint"]
OPTIONS_RUN = ["--view", "--map-aperture", "--map-pixel", "--map-range", "--map-height", "--map-presum", "--max-speed",
               "--map-radars", "--rio-radars", "--map-threads", "--map-algorithm", "--map-ffbp-block",
               "--map-max-thinning"]
OPTIONS_REPLAY = ["--radar", "--radar-imu-link", "--speed", "--start-delay", "--laps", "--can-trigger-id"]


@FUZZ
@given(command=st.sampled_from(["record", "run"]), option=st.sampled_from(OPTIONS_RECORD + OPTIONS_RUN), value=VALUES)
def test_record_and_run_options(tmp_path, command, option, value):
    if option in OPTIONS_RUN and command == "record":
        command = "run"
    argv = [command, "--config", str(RIG), "-o", str(tmp_path), "--radar", "left_front=4098", option, value]
    code, err = check_setup(argv, tmp_path)
    assert_clean(code, err, argv)


@FUZZ
@given(option=st.sampled_from(OPTIONS_REPLAY), value=VALUES)
def test_replay_options(tmp_path, small_recording, option, value):
    argv = ["replay", str(small_recording), "--radar", "left_front=127.0.0.1:4098", option, value]
    code, err = check_setup(argv, tmp_path)
    assert_clean(code, err, argv)


def test_image_runs_with_the_fuzzed_commands_defaults(tmp_path, small_recording):
    """The base command of the fuzz below images (so the fuzz reaches the option it varies)."""
    code, err = run_cli(["image", str(small_recording), "-o", str(tmp_path / "i.h5"), "--grid", IMAGE_GRID])
    assert code == 0, err
    assert (tmp_path / "i.h5").exists()


IMAGE_GRID = "-0.3:0.3:0.05,1.7:2.3:0.05"


@FUZZ
@given(option=st.sampled_from(["--grid", "--frames", "--tx", "--rx", "--mode", "--window", "--oversample", "--radar",
                               "--trajectory", "--aperture", "--algorithm", "--aperture-window"]), value=VALUES)
def test_image_options(tmp_path, small_recording, option, value):
    out = tmp_path / f"image_{abs(hash((option, value)))}.h5"
    argv = ["image", str(small_recording), "-o", str(out), "--grid", IMAGE_GRID, option, value]
    code, err = run_cli(argv)
    assert_clean(code, err, argv)


@FUZZ
@given(option=st.sampled_from(["--at", "--radius", "--vibration", "--half-length"]), value=VALUES)
def test_analyze_options(tmp_path, option, value):
    code, err = run_cli(["analyze", str(tmp_path / "missing.h5"), option, value])
    assert_clean(code, err, [option, value])
    assert code == 2


# -- rig and scene TOML -------------------------------------------------------------------------------------
TOML_VALUES = st.one_of(
    st.sampled_from(["0", "-1", "1e300", "-1e300", "nan", "inf", "-inf", "true", "\"\"", "\"x\"", "[]", "[0]",
                     "[1, 2]", "[[1, 2], [3]]", "{}", "{a = 1}", "[\"straight\", -1]", "[[\"arc\", 0.0, 0.0]]",
                     "1979-05-27", "0.0", "1e-300", "999999999999"]),
    st.integers(min_value=-10**12, max_value=10**12).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\"\\\n\r"), max_size=12)
    .map(lambda s: f'"{s}"'))


def mutate_toml(text: str, data) -> str:
    """Replace one value, drop one line, or add a line of junk (a syntax error must be a clean error too)."""
    lines = text.splitlines()
    assignments = [i for i, line in enumerate(lines) if re.match(r"\s*[A-Za-z_]+\s*=\s*[^\[]", line)
                   and not line.strip().startswith('"""')]
    how = data.draw(st.sampled_from(["value", "value", "value", "drop", "junk"]))
    i = data.draw(st.sampled_from(assignments))
    if how == "value":
        key = lines[i].split("=", 1)[0]
        lines[i] = f"{key}= {data.draw(TOML_VALUES)}"
    elif how == "drop":
        del lines[i]
    else:
        lines.insert(i, data.draw(st.text(max_size=20)))
    return "\n".join(lines) + "\n"


def _without_multiline_strings(text: str) -> str:
    return re.sub(r'"""(.|\n)*?"""', '"(description)"', text)


@FUZZ
@given(data=st.data())
def test_rig_toml(tmp_path, data):
    from imaging.core.rig import load_rig

    path = tmp_path / "rig.toml"
    path.write_text(mutate_toml(_without_multiline_strings(RIG.read_text()), data))
    try:
        rig = load_rig(path)
    except SarbotError as exc:
        assert str(exc)
        return
    for radar in rig.radars:  # what loaded is usable: the derived quantities are finite
        wf = radar.waveform
        assert np.isfinite(wf.wavelength_m) and wf.samples_per_chirp > 0 and wf.chirps_per_frame > 0


@FUZZ
@given(data=st.data())
def test_scene_toml(tmp_path, data):
    from imaging.sim.scene import load_scene

    path = tmp_path / "scene.toml"
    text = mutate_toml(_without_multiline_strings(SCENE.read_text()), data)
    path.write_text(text)
    try:
        scene = load_scene(str(path))
    except SarbotError as exc:
        assert str(exc)
        return
    assert scene.duration_s > 0 and np.isfinite(scene.duration_s)
    tomllib.loads(text)  # it parsed, so it was TOML


# -- damaged recordings ---------------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_damaged_recording(tmp_path, small_recording, data):
    """Bytes flipped anywhere, or the file cut anywhere: every reader either reads or says which file is
    damaged (a FileFormatError, one line), never another exception and never a hang."""
    from imaging.io.recording import Recording

    raw = bytearray(small_recording.read_bytes())
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    else:
        for _ in range(data.draw(st.integers(1, 16))):
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= data.draw(st.integers(1, 255))
    path = tmp_path / "damaged.h5"
    path.write_bytes(bytes(raw))
    try:
        with Recording(path) as rec:
            for name in rec.radar_names:
                rec.n_frames(name), rec.frame_time_ns(name), rec.frame_counter(name), rec.valid(name)
                rec.adc_iq(name, slice(0, 2)), rec.waveform(name) if hasattr(rec, "waveform") else None
            rec.imu(), rec.events(), rec.triggers(), rec.can(), rec.truth()
    except SarbotError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc).strip()


def test_a_damaged_chunk_index_is_a_clear_error_at_open(tmp_path, small_recording):
    """Each chunked dataset's index (an HDF5 extensible array, 'EAIB' blocks with their own checksums) damaged
    in turn: the recording is refused at open, naming the file, instead of a raw OSError from the first read of
    the data behind it (what hypothesis found with one flipped bit)."""
    from imaging.io.recording import Recording

    raw = small_recording.read_bytes()
    blocks = [m.start() for m in re.finditer(b"EAIB", raw)]
    assert len(blocks) >= 5  # one per appendable dataset: adc, time, counter, valid, imu ...
    for offset in blocks:
        damaged = bytearray(raw)
        damaged[offset] ^= 1
        path = tmp_path / f"index_{offset}.h5"
        path.write_bytes(bytes(damaged))
        with pytest.raises(SarbotError) as info:
            with Recording(path) as rec:
                for name in rec.radar_names:
                    rec.adc_iq(name, slice(0, 2)), rec.frame_time_ns(name), rec.valid(name)
                rec.imu(), rec.events(), rec.triggers(), rec.can(), rec.truth()
        assert str(path) in str(info.value) and "damaged" in str(info.value) and "\n" not in str(info.value)


# -- issue 31: every hostile input it lists ------------------------------------------------------------------
#: A scene that simulates in a moment; ``{top}``, ``{trajectory}`` and ``{extra}`` take the value under test.
SCENE_TOML = """name = "hostile"
duration_s = 0.2
{top}
[trajectory]
kind = "straight"
speed_mps = 0.4
{trajectory}
[[target]]
kind = "point"
position_m = [0.0, 2.0, 0.0]
{extra}
"""
DCA1000_CFG = SHARED_DATA / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg"
#: A rig of one radar; ``{radar}`` is its table header, ``{waveform}`` its waveform table.
RIG_TOML = """[radar.{radar}]
mount_translation_m = [0.0, 0.2, 0.3]
mount_yaw_deg = 90.0
waveform = {{ {waveform} }}
"""


@pytest.fixture(scope="module")
def hostile_files(tmp_path_factory, small_recording):
    """The files the hostile commands read: a recording, a trajectory, an image, a rig that is not UTF-8, a
    regular file (to put an output 'in'), and rigs and scenes with the issue's values."""
    import shutil

    from imaging.core.trajectory import SampledTrajectory
    from imaging.io.image_file import SarImage, write_image
    from imaging.io.trajectory_file import write_trajectory

    d = tmp_path_factory.mktemp("hostile")
    files = {"rec": d / "rec.h5", "dir": d, "file": d / "afile"}
    shutil.copyfile(small_recording, files["rec"])
    files["file"].write_text("a file, not a folder\n")
    t = np.arange(11, dtype=np.int64) * 10_000_000
    files["traj"] = write_trajectory(d / "traj.h5", SampledTrajectory(t, np.zeros((11, 3)), np.tile([0.0, 0, 0, 1], (11, 1)),
                                                                      np.zeros((11, 3)), source="rio"))
    x, y = np.arange(-0.5, 0.5, 0.01), np.arange(1.5, 2.5, 0.02)
    image = np.zeros((y.size, x.size), np.complex64)
    image[25, 50] = 1.0
    files["image"] = write_image(d / "img.h5", SarImage(image, x, y, attrs={"radar": "left_front", "wavelength_m": 0.0039}))
    (d / "latin1.toml").write_bytes(RIG_TOML.format(radar="left_front", waveform="").encode() + b"# caf\xe9\n")
    files["latin1"] = d / "latin1.toml"
    rigs = {"chirps": "chirps_per_frame = 1000000000000", "chirps_float": "chirps_per_frame = 1e12"}
    for name, waveform in rigs.items():
        (d / f"rig_{name}.toml").write_text(RIG_TOML.format(radar="left_front", waveform=waveform))
    (d / "rig_slash.toml").write_text(RIG_TOML.format(radar='"a/b"', waveform=""))
    (d / "rig_ok.toml").write_text(RIG_TOML.format(radar="left_front", waveform=""))
    scenes = {"heading_inf": ("", "heading_deg = inf", ""), "seed_neg": ("seed = -1", "", ""),
              "speed_nan": ("", "speed_mps = nan", ""), "snr_nan": ("snr_db = nan", "", ""),
              "imu_string": ('imu = "false"', "", ""), "spacing": ("", "", "[room]\nspacing_m = 1e-6"),
              "clutter_seed": ("", "", "[[clutter]]\ncount = 3\nbox_m = [[0, 1], [1, 2], [0, 1]]\nseed = -1")}
    for name, (top, trajectory, extra) in scenes.items():
        text = SCENE_TOML.format(top=top, trajectory=trajectory, extra=extra)
        if name == "speed_nan":  # speed_mps given once
            text = text.replace("speed_mps = 0.4\n", "")
        (d / f"scene_{name}.toml").write_text(text)
    damaged = d / "damaged_metadata.h5"
    shutil.copyfile(small_recording, damaged)
    import h5py

    with h5py.File(damaged, "r+") as f:
        del f["radar/left_front"].attrs["f0_hz"]
    files["damaged"] = damaged
    return files


def _hostile_cases() -> list[tuple[str, str]]:
    """(label, command) of every case issue 31 lists; paths as {rec}, {dir}, ... of ``hostile_files``."""
    rig = str(RIG)
    rec = ["record", "--config", rig, "-o", "{dir}/out", "--duration", "1"]
    run = ["run", "--config", rig, "-o", "{dir}/out", "--radar", "left_front=4098", "--imu-port", "{dir}/no_imu", "--duration", "1"]
    cases = {f"health endpoint {e!r}": [*rec, "--radar", "left_front=4098", "--health-endpoint", e]
             for e in ("foo", "tcp://", "tcp://127.0.0.1:99999", "ipc://", "tcp://:5", "tcp://192.0.2.1:5000", "udp://x:1")}
    cases.update({
        "config a folder": ["record", "--config", "{dir}", "-o", "{dir}/out", "--radar", "left_front=4098"],
        "rig not UTF-8": ["record", "--config", "{latin1}", "-o", "{dir}/out", "--radar", "left_front=4098"],
        "rig chirps 10^12": ["record", "--config", "{dir}/rig_chirps.toml", "-o", "{dir}/out", "--radar", "left_front=4098"],
        "rig chirps 1e12": ["record", "--config", "{dir}/rig_chirps_float.toml", "-o", "{dir}/out", "--radar", "left_front=4098"],
        "rig radar a/b": ["record", "--config", "{dir}/rig_slash.toml", "-o", "{dir}/out", "--radar", "a/b=4098"],
        "radar named twice": [*rec, "--radar", "left_front=4098", "--radar", "left_front=4099"],
        "radar on an address not this host's": [*rec, "--radar", "left_front=192.0.2.1:4098"],
        "dca1000 on an address not this host's": [*rec, "--dca1000", f"left_front=192.0.2.1:4098:{DCA1000_CFG}"],
        "image -o in a file": ["image", "{rec}", "-o", "{file}/i.h5", "--grid", IMAGE_GRID],
        "image -o in /proc": ["image", "{rec}", "-o", "/proc/sarbot_i.h5", "--grid", IMAGE_GRID],
        "simulate -o in a file": ["simulate", "paper_pass_0.4", "-o", "{file}/s.h5"],
        "simulate -o in /proc": ["simulate", "{dir}/scene_ok.toml", "-o", "/proc/sarbot_s.h5"],
        "export -o in a file": ["export", "{rec}", "-o", "{file}/e.mcap"],
        "export -o in /proc": ["export", "{rec}", "-o", "/proc/sarbot_e.mcap"],
        "rio -o in a file": ["rio", "{rec}", "-o", "{file}/t.h5"],
        "info --tum in a file": ["info", "{traj}", "--tum", "{file}/t.txt"],
        "info --tum in /proc": ["info", "{traj}", "--tum", "/proc/sarbot_t.txt"],
        "rio --static-init nan": ["rio", "{rec}", "-o", "{dir}/t1.h5", "--static-init", "nan"],
        "rio --velocity-floor nan": ["rio", "{rec}", "-o", "{dir}/t2.h5", "--velocity-floor", "nan"],
        "replay --start-delay 1e12": ["replay", "{rec}", "--radar", "left_front=127.0.0.1:4098", "--start-delay", "1e12"],
        "info on damaged metadata": ["info", "{damaged}"],
        "run --max-speed nan": [*run, "--max-speed", "nan"],
        "run --max-speed -1": [*run, "--max-speed", "-1"],
        "run --map-height nan": [*run, "--map-height", "nan"],
        "run --map-pixel inf": [*run, "--map-pixel", "inf"],
        "run --map-pixel 1e-9": [*run, "--map-pixel", "1e-9"],
        "analyze --radius -1": ["analyze", "{image}", "--radius", "-1"],
        "analyze --radius nan": ["analyze", "{image}", "--radius", "nan"],
        "install-unit --config not a rig": ["install-unit", "--root", "{dir}/stage", "--config", "{file}", "--no-deps"],
        # Nothing overwritten unasked; the input itself never.
        "rio -o the recording": ["rio", "{rec}", "-o", "{rec}"],
        "rio -o the recording --overwrite": ["rio", "{rec}", "-o", "{rec}", "--overwrite"],
        "rio --tum the recording": ["rio", "{rec}", "-o", "{dir}/t3.h5", "--tum", "{rec}"],
        "rio -o an existing file": ["rio", "{rec}", "-o", "{file}"],
        "info --tum the file read": ["info", "{traj}", "--tum", "{traj}", "--overwrite"],
        "info --tum an existing file": ["info", "{traj}", "--tum", "{file}"],
        "export -o the recording": ["export", "{rec}", "-o", "{rec}", "--overwrite"],
        "export -o an existing file": ["export", "{rec}", "-o", "{file}"],
        "simulate -o an existing file": ["simulate", "{dir}/scene_ok.toml", "-o", "{file}"],
        "simulate -o its scene": ["simulate", "{dir}/scene_ok.toml", "-o", "{dir}/scene_ok.toml", "--overwrite"],
        "import-ti -o an existing file": ["import-ti", "{file}", "--cfg", "{file}", "-o", "{rec}"],
        "import-ti -o its capture": ["import-ti", "{file}", "--cfg", "{dir}/x.cfg", "-o", "{file}", "--overwrite"],
        "import-bag -o an existing file": ["import-bag", "{file}", "--calib", "{file}", "-o", "{rec}"],
        "batch writing over its recording": ["batch", "{rec}", "-o", "{dir}", "--grid", IMAGE_GRID],
        "batch -o a file": ["batch", "{rec}", "-o", "{file}", "--grid", IMAGE_GRID],
        "import-ti -o in a file": ["import-ti", "{dir}/x.cfg", "--cfg", "{dir}/x.cfg", "-o", "{file}/r.h5"],
        "replay radar named twice": ["replay", "{rec}", "--radar", "left_front=127.0.0.1:4098",
                                     "--radar", "left_front=127.0.0.1:4099"],
    })
    cases.update({f"scene {name}": ["simulate", f"{{dir}}/scene_{name}.toml", "-o", f"{{dir}}/sim_{name}.h5"]
                  for name in ("heading_inf", "seed_neg", "speed_nan", "snr_nan", "imu_string", "spacing", "clutter_seed")})
    return sorted(cases.items())


HOSTILE = _hostile_cases()


@pytest.mark.parametrize("case", HOSTILE, ids=[label for label, _ in HOSTILE])
def test_every_hostile_input_of_issue_31_is_one_line_and_exit_2_within_10_s(hostile_files, case):
    """Each case the issue lists under "Commands and files": no traceback, no exit 0, no hang (10 s), and the
    files the command reads unchanged."""
    import time

    label, template = case
    files = {k: str(v) for k, v in hostile_files.items()}
    (hostile_files["dir"] / "scene_ok.toml").write_text(SCENE_TOML.format(top="", trajectory="", extra=""))
    (hostile_files["dir"] / "x.cfg").write_text("sensorStop\n")
    argv = [part.format(**files) for part in template]
    before = {k: Path(v).read_bytes() for k, v in files.items() if Path(v).is_file()}
    t0 = time.monotonic()
    code, err = run_cli(argv)
    elapsed = time.monotonic() - t0
    assert code == 2, (label, code, err)
    said = [line for line in err.splitlines() if not line.startswith(("INFO ", "WARNING "))]  # progress, log lines
    assert "Traceback" not in err and len(said) == 1 and said[0].startswith("sarbot: error: "), (label, err)
    assert elapsed < 10.0, (label, elapsed)
    assert {k: Path(v).read_bytes() for k, v in files.items() if Path(v).is_file()} == before, label


#: Values the issue found hostile, for any numeric or boolean field.
HOSTILE_VALUES = ["nan", "inf", "-inf", "-1", "1e-6", "1e-9", "1e12", "1000000000000", '"false"', '"1"', "0"]
SCENE_FIELDS = {"top": ["seed", "snr_db", "imu", "duration_s", "truth_rate_hz", "intra_chirp_motion", "adc_counts_per_unit"],
                "trajectory": ["heading_deg", "speed_mps"],
                "room": ["spacing_m", "height_m", "clutter", "seed"]}


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(section=st.sampled_from(sorted(SCENE_FIELDS)), data=st.data(), value=st.sampled_from(HOSTILE_VALUES))
def test_scene_fields_with_hostile_values_load_in_time_or_are_refused_naming_the_field(tmp_path, section, data, value):
    """Any of the issue's values in any scene field: refused naming the field, or a scene that is sane (finite
    duration, speed and SNR, booleans that are booleans, a bounded number of scatterers), within 10 s."""
    import time

    from imaging.sim.scene import MAX_SCATTERERS, load_scene

    field = data.draw(st.sampled_from(SCENE_FIELDS[section]))
    line = f"{field} = {value}"
    top, trajectory, extra = (line, "", "") if section == "top" else ("", line, "") if section == "trajectory" else (
        "", "", f"[room]\n{line}")
    text = SCENE_TOML.format(top=top, trajectory=trajectory, extra=extra)
    if section == "trajectory" and field == "speed_mps":
        text = text.replace("speed_mps = 0.4\n", "", 1)
    if field == "duration_s":
        text = text.replace("duration_s = 0.2\n", "", 1)
    path = tmp_path / "scene.toml"
    path.write_text(text)
    t0 = time.monotonic()
    try:
        scene = load_scene(str(path))
    except SarbotError as exc:
        assert field in str(exc) and "\n" not in str(exc)
    else:
        assert np.isfinite(scene.duration_s) and scene.duration_s > 0
        assert isinstance(scene.imu, bool) and isinstance(scene.intra_chirp_motion, bool)
        assert scene.snr_db is None or np.isfinite(scene.snr_db)
        assert 0 <= scene.seed and np.isfinite(scene.trajectory.speed_mps)
        assert scene.static_points_m is None or len(scene.static_points_m) <= MAX_SCATTERERS + 10_000
    assert time.monotonic() - t0 < 10.0


RIG_FIELDS = ["chirps_per_frame", "n_tx", "n_rx", "f0_hz", "bandwidth_hz", "chirp_duration_s", "chirp_interval_s",
              "frame_interval_s", "sample_rate_hz"]


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(field=st.sampled_from(RIG_FIELDS), value=st.sampled_from(HOSTILE_VALUES))
def test_rig_waveform_fields_with_hostile_values_are_refused_or_bounded(tmp_path, field, value):
    """Any of the issue's values in any waveform field: refused naming the field, or a waveform whose frame is
    within the limits (so no recorder, simulator or driver allocates without end)."""
    from imaging.core.rig import load_rig
    from imaging.core.waveform import MAX_SAMPLES_PER_FRAME

    path = tmp_path / "rig.toml"
    path.write_text(RIG_TOML.format(radar="left_front", waveform=f"{field} = {value}"))
    try:
        rig = load_rig(path)
    except SarbotError as exc:
        assert "\n" not in str(exc) and ("waveform" in str(exc) or "radar" in str(exc))
        return
    wf = rig.radar("left_front").waveform
    assert wf.chirps_per_frame * wf.n_rx * wf.samples_per_chirp <= MAX_SAMPLES_PER_FRAME
    assert np.isfinite(wf.frame_interval_s) and np.isfinite(wf.wavelength_m)


# -- a flipped byte in a recording's data --------------------------------------------------------------------
@pytest.fixture(scope="module")
def recorded_chunks(small_recording):
    """Every chunk of every checksummed dataset of the small recording: (dataset, byte offset, size)."""
    import h5py

    chunks, unfiltered = [], []
    with h5py.File(small_recording, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and obj.chunks is not None:
                if not obj.fletcher32:
                    unfiltered.append(name)
                    return
                for i in range(obj.id.get_num_chunks()):
                    info = obj.id.get_chunk_info(i)
                    chunks.append((f"/{name}", int(info.byte_offset), int(info.size)))
        f.visititems(visit)
    # Only variable-length strings go without a checksum (HDF5 filters none of them).
    assert all(name.startswith(("events/", "trigger/source")) for name in unfiltered), unfiltered
    return chunks


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_flipped_byte_anywhere_in_a_recordings_data_is_found(tmp_path, small_recording, recorded_chunks, data):
    """One byte changed anywhere in any chunk of data (frames, valid flags, times, IMU, truth, CAN, event
    times): `info --verify` names that dataset, and reading it is an error, never good-looking data."""
    from acquisition.verify import verify_file
    from imaging.io.recording import Recording

    dataset, offset, size = data.draw(st.sampled_from(recorded_chunks))
    at = offset + data.draw(st.integers(0, size - 1))
    raw = bytearray(small_recording.read_bytes())
    raw[at] ^= data.draw(st.integers(1, 255))
    path = tmp_path / "flipped.h5"
    path.write_bytes(bytes(raw))
    findings = verify_file(path)
    assert any(f.dataset == dataset for f in findings), (dataset, at, findings)
    code, err = run_cli(["info", "--verify", str(path)])
    assert code == 2 and dataset in err and "Traceback" not in err
    with pytest.raises((SarbotError, OSError)):
        with Recording(path) as rec:
            rec.file[dataset][()]
