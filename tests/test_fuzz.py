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
