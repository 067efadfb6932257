"""The sarbot command line, run as a real process: the happy path and every user mistake."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

SARBOT = [sys.executable, "-m", "acquisition.cli"]


def sarbot(*args, cwd=None):
    return subprocess.run([*SARBOT, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "point.h5"
    res = sarbot("simulate", "point_target", "-o", path)
    assert res.returncode == 0, res.stderr
    assert "wrote" in res.stdout and "38 frames of left_front" in res.stdout
    return path


def test_simulate_image_analyze(recording, tmp_path):
    out = tmp_path / "img.h5"
    res = sarbot("image", recording, "-o", out, "--radar", "left_front", "--frames", "10:28",
                 "--grid", "-0.1:0.1:0.002,1.85:2.15:0.004", "--tx", "0", "--rx", "0")
    assert res.returncode == 0, res.stderr
    assert out.exists() and out.with_suffix(".png").stat().st_size > 10_000
    with h5py.File(out) as f:
        assert f.attrs["schema"] == "sarbot.image" and f.attrs["schema_version"] == 1
        assert f["image"].shape == (76, 101) and f["image"].dtype == np.complex64
        assert f.attrs["frames"] == "10:28" and f.attrs["trajectory_source"] == "truth"
        assert f.attrs["radar"] == "left_front" and f.attrs["method"] == "tdbp-linear"
        # default plane height: the radar's height (0.3 m above the body origin)
        assert f["z_m"][0] == pytest.approx(0.3)
    res = sarbot("analyze", out)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["peak_m"][0] == pytest.approx(0.0, abs=0.002) and report["peak_m"][1] == pytest.approx(2.0, abs=0.004)
    assert report["range"]["ratio_to_theory"] == pytest.approx(1.0, abs=0.05)
    assert report["cross_range"]["ratio_to_theory"] == pytest.approx(1.0, abs=0.05)


def test_image_imports_autofocus_only_when_asked(recording, tmp_path):
    """``sarbot image`` without --autofocus does not import imaging.autofocus (scipy.optimize: 0.6 s of a
    whole process); with it, it does."""
    code = ("import sys; from acquisition.cli import main; code = main(sys.argv[1:]); "
            "print('imported' if 'imaging.autofocus' in sys.modules else 'not imported'); sys.exit(code)")
    args = [recording, "-o", tmp_path / "a.h5", "--frames", "10:20", "--grid", "-0.05:0.05:0.005,1.9:2.1:0.005",
            "--tx", "0", "--rx", "0"]
    res = subprocess.run([sys.executable, "-c", code, "image", *map(str, args)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("not imported")
    args[2] = tmp_path / "b.h5"
    res = subprocess.run([sys.executable, "-c", code, "image", *map(str, args), "--autofocus", "pga"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("imported") and "not imported" not in res.stdout


def test_image_start_up_is_not_gone_through_by_the_garbage_collector(recording, tmp_path):
    """The ~120,000 objects of ``sarbot image``'s imports and numba's set-up are made with the cyclic
    collector paused and then frozen: no full collection goes through them (before, three did during
    the start and one at exit, each through 50,000-112,000 objects)."""
    code = ("import gc, sys; sizes = []; "
            "gc.callbacks.append(lambda phase, info: sizes.append(len(gc.get_objects(2))) "
            "if phase == 'start' and info['generation'] == 2 else None); "
            "from acquisition.cli import main; code = main(sys.argv[1:]); gc.collect(); "
            "print('frozen', gc.get_freeze_count(), 'full collections through', sizes); sys.exit(code)")
    args = [recording, "-o", tmp_path / "a.h5", "--frames", "10:20", "--grid", "-0.05:0.05:0.005,1.9:2.1:0.005"]
    res = subprocess.run([sys.executable, "-c", code, "image", *map(str, args)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    words = res.stdout.splitlines()[-1].split(" ", 2)
    assert words[0] == "frozen" and int(words[1]) > 50_000
    sizes = json.loads(words[2].removeprefix("full collections through "))
    assert sizes and max(sizes) < 20_000  # the last: the test's own gc.collect()


def test_image_loads_its_cached_kernels_without_numbas_registries_nor_scipy_fft(recording, tmp_path):
    """``sarbot image`` with its kernels in numba's cache loads them without numba's typing and lowering
    registries (its implementations of Python and numpy, and scipy.linalg for BLAS: 0.2 s of CPU), and
    range-compresses with scipy's FFT without importing scipy.fft (0.2 s more, imaging/pocketfft.py); the
    image is the same bit for bit as the library's, formed in this process the usual way."""
    from imaging.image_formation import ImagingOptions, image_recording
    from imaging.io.recording import Recording

    code = ("import sys; from acquisition.cli import main; code = main(sys.argv[1:]); "
            "print(sorted(m for m in ('numba.np.arraymath', 'scipy.linalg', 'scipy.fft') if m in sys.modules)); sys.exit(code)")
    grid = "-0.05:0.05:0.005,1.9:2.1:0.005"
    for name in ("first.h5", "cached.h5"):  # the first run fills numba's cache if it is empty (and compiles)
        args = [recording, "-o", tmp_path / name, "--frames", "10:20", "--grid", grid]
        res = subprocess.run([sys.executable, "-c", code, "image", *map(str, args)], capture_output=True, text=True,
                             timeout=300)
        assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("[]")
    with Recording(recording) as rec:
        expected = image_recording(rec, None, grid, frames=slice(10, 20), options=ImagingOptions()).image
    for name in ("first.h5", "cached.h5"):
        with h5py.File(tmp_path / name) as f:
            np.testing.assert_array_equal(f["image"][()], expected.astype(np.complex64))  # as the file stores it


def test_image_imports_neither_matplotlib_nor_scipy_rotations(recording, tmp_path):
    """``sarbot image`` writes its PNG (the image's pixels) without matplotlib, places its antennas without
    scipy's Rotation (half a second of a whole process between them) and does not let numba search every
    installed distribution for extensions; ``--png-figure`` draws matplotlib's figure, axes and colour bar,
    990 pixels wide."""
    from PIL import Image

    code = ("import sys, importlib.metadata as md; scans = []; md.entry_points = lambda *a, **k: scans.append(1); "
            "from acquisition.cli import main; code = main(sys.argv[1:]); "
            "print(sorted(m for m in ('matplotlib', 'scipy.spatial') if m in sys.modules) + scans); sys.exit(code)")
    args = [recording, "-o", tmp_path / "a.h5", "--frames", "10:20", "--grid", "-0.05:0.05:0.005,1.9:2.1:0.005"]
    res = subprocess.run([sys.executable, "-c", code, "image", *map(str, args)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("[]")
    with Image.open(tmp_path / "a.png") as png:
        assert png.size == (21 * 13, 41 * 13)  # 13 x 13 screen pixels per grid point: 512 or more on the longer side
        assert png.text["Title"].startswith("left_front frames 10:20")
    args[2] = tmp_path / "b.h5"
    res = subprocess.run([sys.executable, "-c", code, "image", *map(str, args), "--png-figure"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "'matplotlib'" in res.stdout.splitlines()[-1]
    with Image.open(tmp_path / "b.png") as png:
        assert png.size[0] == 990
    with h5py.File(tmp_path / "a.h5") as a, h5py.File(tmp_path / "b.h5") as b:
        np.testing.assert_array_equal(a["image"][()], b["image"][()])


#: A process that ran a command and ends by acquisition.cli.end_process (argv[1]: "closed" if the command said it
#: left nothing to close, "thread" if a thread still runs then).
END_PROCESS = """
import atexit, sys, threading
from acquisition import cli
atexit.register(lambda: print("exit handler ran"))
print("buffered", end="")  # stdout is a pipe here: block-buffered, not yet written
if "closed" in sys.argv[1:]:
    cli.nothing_left_to_close()
if "thread" in sys.argv[1:]:
    stop = threading.Event()
    threading.Thread(target=stop.wait, args=(0.5,)).start()
code = cli.end_process(3)
print(f" end_process returned {code}", end="")
sys.exit(code)
"""


@pytest.mark.parametrize("state, stdout", [
    (["closed"], "bufferedexit handler ran\n"),  # at once: handlers, streams flushed, nothing after
    ([], "buffered end_process returned 3exit handler ran\n"),  # the usual end
    (["closed", "thread"], "buffered end_process returned 3exit handler ran\n"),  # a thread runs: the usual end
])
def test_a_command_that_closed_everything_ends_its_process_at_once(state, stdout):
    res = subprocess.run([sys.executable, "-c", END_PROCESS, *state], capture_output=True, text=True, timeout=60)
    assert res.returncode == 3, res.stderr
    assert res.stdout == stdout


def test_image_ends_its_process_at_once_with_its_output_written(recording, tmp_path):
    """``sarbot image`` ends without the interpreter's teardown: exit code 0, its line printed, both files
    whole (the image the same as the library's, as test_simulate_image_analyze checks), the -v stage line
    logged."""
    res = sarbot("-v", "image", recording, "-o", tmp_path / "a.h5", "--grid", "-0.1:0.1:0.01,1.9:2.1:0.01",
                 "--frames", "0:4")
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"wrote {tmp_path / 'a.h5'} and {tmp_path / 'a.png'}"
    assert "stage seconds: " in res.stderr
    with h5py.File(tmp_path / "a.h5") as f:
        assert f["image"].shape == (21, 21) and np.isfinite(f["image"][()]).all()
    assert (tmp_path / "a.png").read_bytes()[-8:] == b"IEND\xaeB`\x82"  # the PNG's last chunk, flushed


def test_image_with_ffbp_equals_the_direct_image(recording, tmp_path):
    """``--algorithm ffbp``: the same image as the direct kernel within -40 dB (all channels, the whole
    pass), the plan's error figures in the file; a volume grid is a one-line error."""
    grid = "-0.4:0.4:0.002,1.8:2.2:0.004"
    images = {}
    for algorithm in ("direct", "ffbp"):
        out = tmp_path / f"{algorithm}.h5"
        res = sarbot("image", recording, "-o", out, "--radar", "left_front", "--grid", grid, "--algorithm", algorithm)
        assert res.returncode == 0, res.stderr
        with h5py.File(out) as f:
            images[algorithm] = f["image"][()].astype(complex)
            attrs = dict(f.attrs)
    assert attrs["method"] == "ffbp-linear" and attrs["ffbp_levels"] >= 3
    err = 20 * np.log10(np.linalg.norm(images["ffbp"] - images["direct"]) / np.linalg.norm(images["direct"]))
    assert err < -40.0 and err < attrs["ffbp_error_bound_db"]
    assert abs(err - attrs["ffbp_error_estimate_db"]) < 8.0
    res = sarbot("image", recording, "-o", tmp_path / "v.h5", "--grid", "-0.1:0.1:0.01,1.9:2.1:0.01,0:0.6:0.1", "--algorithm", "ffbp")
    assert_user_error(res, "horizontal plane", "volume")


def test_analyze_several_images_fits_integration_gain(tmp_path):
    scene = tmp_path / "noisy.toml"
    scene.write_text(
        'duration_s = 2.0\nradars = ["left_front"]\nsnr_db = -10.0\n'
        '[trajectory]\nstart_m = [-0.55, -0.2, 0.0]\nspeed_mps = 0.4\n'
        '[[target]]\nkind = "point"\nposition_m = [0.0, 2.0, 0.3]\n'
    )
    rec = tmp_path / "noisy.h5"
    assert sarbot("simulate", scene, "-o", rec).returncode == 0
    paths = []
    for n in (4, 8, 16):
        p = tmp_path / f"img{n}.h5"
        res = sarbot("image", rec, "-o", p, "--frames", f"{19 - n // 2}:{19 - n // 2 + n}",
                     "--grid", "-0.8:0.8:0.01,1.5:2.5:0.01", "--tx", "0", "--rx", "0")
        assert res.returncode == 0, res.stderr
        paths.append(p)
    res = sarbot("analyze", *paths, "--at", "0,2")
    assert res.returncode == 0, res.stderr
    gain = json.loads(res.stdout)["integration_gain"]
    assert gain["n_frames"] == [4, 8, 16]
    assert 0.7 < gain["alpha"] < 1.3  # coherent integration on the true trajectory


def assert_user_error(res, *fragments):
    assert res.returncode == 2, (res.returncode, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sarbot: error:"), res.stderr
    assert "Traceback" not in res.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_unreadable_file(tmp_path):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    assert_user_error(sarbot("image", junk, "-o", tmp_path / "x.h5", "--grid", "0:1:0.1,0:1:0.1"), "junk.h5", "not a readable HDF5")
    assert_user_error(sarbot("analyze", tmp_path / "missing.h5"), "missing.h5", "no such file")


def test_wrong_schema(tmp_path, recording):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["schema"] = "something.else"
    assert_user_error(sarbot("image", other, "-o", tmp_path / "x.h5", "--grid", "0:1:0.1,0:1:0.1"), "other.h5", "not a sarbot recording")
    # A recording is not an image.
    assert_user_error(sarbot("analyze", recording), "not a sarbot image")


def test_grid_without_points(recording, tmp_path):
    assert_user_error(sarbot("image", recording, "-o", tmp_path / "x.h5", "--grid", "1:0:0.1,0:1:0.1"), "no points")
    assert_user_error(sarbot("image", recording, "-o", tmp_path / "x.h5", "--grid", "0:1:0,0:1:0.1"), "step must be positive")
    assert_user_error(sarbot("image", recording, "-o", tmp_path / "x.h5", "--grid", "0:1"), "expected x0:x1:dx")


def test_frames_out_of_range(recording, tmp_path):
    assert_user_error(sarbot("image", recording, "-o", tmp_path / "x.h5", "--grid", "0:1:0.1,0:1:0.1", "--frames", "30:60"),
                      "frames 30:60 out of range", "38 frames")
    assert_user_error(sarbot("image", recording, "-o", tmp_path / "x.h5", "--grid", "0:1:0.1,0:1:0.1", "--frames", "x:y"), "--frames")


def test_unknown_radar(recording, tmp_path):
    assert_user_error(sarbot("image", recording, "-o", tmp_path / "x.h5", "--grid", "0:1:0.1,0:1:0.1", "--radar", "rear"),
                      "no radar named 'rear'", "left_front")


def test_bad_scene_names_the_field(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text('duration_s = 1.0\n[[target]]\nkind = "point"\nposition_m = [0, 2, "high"]\n')
    assert_user_error(sarbot("simulate", scene, "-o", tmp_path / "r.h5"), "scene.toml", "target[0].position_m[2]")
    scene.write_text('duration_s = -1.0\n')
    assert_user_error(sarbot("simulate", scene, "-o", tmp_path / "r.h5"), "duration_s", "must be positive")
    assert_user_error(sarbot("simulate", "no_such_scene", "-o", tmp_path / "r.h5"), "no_such_scene", "built-in")


def test_existing_output_is_not_overwritten(recording):
    before = recording.stat().st_size
    assert_user_error(sarbot("simulate", "point_target", "-o", recording), "exists already")
    assert recording.stat().st_size == before


def test_list_scenes():
    res = sarbot("simulate", "--list")
    assert res.returncode == 0 and "paper_pass_0.4" in res.stdout and "point_target" in res.stdout
    # each description's first sentence whole, not cut at its TOML line break ("... at r0 = 2 m from the")
    entries = res.stdout.replace("\n                   ", " ").splitlines()
    assert entries and all(e.rstrip().endswith(".") for e in entries), entries


def test_vibration_inverse_from_the_command_line(tmp_path):
    rec, img = tmp_path / "vib.h5", tmp_path / "vib_img.h5"
    assert sarbot("simulate", "paper_vibration", "-o", rec).returncode == 0
    # 29 frames around broadside: a 0.6 m aperture, six vibration periods.
    res = sarbot("image", rec, "-o", img, "--frames", "14:43", "--grid", "-0.12:0.12:0.0005,1.98:2.02:0.002",
                 "--tx", "0", "--rx", "0")
    assert res.returncode == 0, res.stderr
    res = sarbot("analyze", img, "--vibration", "--half-length", "0.1")
    assert res.returncode == 0, res.stderr
    vib = json.loads(res.stdout)["vibration"]
    assert vib["sidelobe_offset_m"] == pytest.approx(0.04, rel=0.05)
    assert vib["frequency_hz"] == pytest.approx(4.161, rel=0.05)
    assert vib["amplitude_m"] == pytest.approx(3.196e-4, rel=0.05)


def test_volume_grid(recording, tmp_path):
    out = tmp_path / "vol.h5"
    res = sarbot("image", recording, "-o", out, "--frames", "14:24", "--grid", "-0.1:0.1:0.01,1.9:2.1:0.01,0.1:0.5:0.1",
                 "--tx", "0", "--rx", "0")
    assert res.returncode == 0, res.stderr
    with h5py.File(out) as f:
        assert f["image"].shape == (5, 21, 21)
        np.testing.assert_allclose(f["z_m"][()], [0.1, 0.2, 0.3, 0.4, 0.5])
    assert_user_error(sarbot("analyze", out), "2-D")


def test_rio_from_the_command_line(tmp_path):
    scene = tmp_path / "drive.toml"
    scene.write_text(
        'duration_s = 20.0\nimu = true\nradars = ["left_front", "right_front"]\n'
        '[trajectory]\nkind = "path"\nstart_m = [-3.0, -2.0, 0.0]\nspeed_mps = 0.5\naccel_mps2 = 0.4\nstart_delay_s = 3.0\n'
        'segments = [["straight", 3.0], ["arc", 1.0, 90.0], ["straight", 2.0]]\n'
        '[detections]\ndetection_probability = 0.5\n[room]\nsize_m = [12.0, 9.0]\nspacing_m = 0.5\n'
    )
    rec, traj, tum = tmp_path / "drive.h5", tmp_path / "traj.h5", tmp_path / "traj.txt"
    res = sarbot("simulate", scene, "-o", rec)
    assert res.returncode == 0, res.stderr
    res = sarbot("rio", rec, "-o", traj, "--tum", tum)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["against_truth"]["distance_m"] > 6
    assert report["against_truth"]["final_drift_percent"] < 1.0
    assert len(tum.read_text().splitlines()) == report["poses"]
    with h5py.File(traj) as f:
        assert f.attrs["schema"] == "sarbot.trajectory" and f.attrs["source"] == "rio"
    # A recording with ADC but no detections cannot run odometry yet: one clear line.
    adc = tmp_path / "adc.h5"
    assert sarbot("simulate", "point_target", "-o", adc).returncode == 0
    assert_user_error(sarbot("rio", adc, "-o", tmp_path / "t2.h5"), "no /imu")


def _subparser(parser, command):
    import argparse

    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]


def test_choice_lists_are_read_from_their_sources_when_needed(monkeypatch):
    """Autofocus methods, windows and wire formats are not written out in the command line: a method added to
    the autofocus registry at run time (a tuple or a dict) is taken and listed by a parser built before."""
    import imaging.autofocus
    import imaging.core.windows
    from acquisition.cli import build_parser
    from drivers.radar import registry

    parser = build_parser()
    image = ["image", "rec.h5", "-o", "img.h5", "--grid", "0:1:0.1,1:2:0.1"]
    run = ["run", "--config", "rig.toml", "-o", "out"]
    with pytest.raises(SystemExit):
        parser.parse_args([*image, "--autofocus", "toy"])
    methods = imaging.autofocus.METHODS
    for grown in ((*methods, "toy"), {**{m: None for m in methods}, "toy": None}):
        monkeypatch.setattr(imaging.autofocus, "METHODS", grown)
        assert parser.parse_args([*image, "--autofocus", "toy"]).autofocus == "toy"
        assert parser.parse_args(["batch", "a.h5", "-o", "out", "--grid", "g", "--autofocus", "toy"]).autofocus == "toy"
        assert parser.parse_args([*run, "--map-refocus", "toy"]).map_refocus == "toy"
        assert "{" + ",".join([*methods, "toy"]) + "}" in _subparser(parser, "image").format_help()
    monkeypatch.setattr(imaging.core.windows, "WINDOWS", (*imaging.core.windows.WINDOWS, "kaiser"))
    args = parser.parse_args([*image, "--window", "kaiser", "--aperture-window", "kaiser"])
    assert (args.window, args.aperture_window) == ("kaiser", "kaiser")
    record_help = " ".join(_subparser(parser, "record").format_help().split())
    assert all(name in record_help for name in registry.names()) and f"default {registry.DEFAULT}" in record_help


def test_a_command_builds_its_own_parser_alone():
    """``FAMILIES`` names every command its family registers; a command's parser alone parses its arguments as
    the whole command line's does, and does not register (nor import for) another family's commands."""
    import argparse

    from acquisition.cli import FAMILIES, ArgumentParser, build_parser, command_of

    for family, commands in FAMILIES.items():
        sub = ArgumentParser(prog="t").add_subparsers()
        importlib.import_module(f"acquisition.cli.{family}").register(sub)
        assert tuple(sub.choices) == commands, family
    full = build_parser()
    argv = ["-q", "image", "rec.h5", "-o", "img.h5", "--grid=-1:1:0.1,1:2:0.1", "--frames", "3:9"]
    assert command_of(argv) == "image" and command_of(["-v", "--version"]) is None
    alone = build_parser("image")
    assert vars(alone.parse_args(argv)) == vars(full.parse_args(argv))
    commands = next(a for a in alone._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert set(commands) == set(FAMILIES["imaging"])
    assert build_parser("no-such-command")._actions[-1].choices.keys() == full._actions[-1].choices.keys()


def _choices():
    """What completion must offer, read from where sarbot keeps it (not written out in the test)."""
    from acquisition.exporters.ros2_bag import STORAGES
    from drivers.radar.ti_capture import LAYOUTS
    from imaging.autofocus import METHODS
    from imaging.core.rig import default_rig
    from imaging.sim.scene import builtin_scene_names

    return {"scenes": builtin_scene_names(), "radars": [r.name for r in default_rig().radars],
            "formats": [*STORAGES, *LAYOUTS], "autofocus": list(METHODS)}


@pytest.mark.parametrize("shell", ["bash", "zsh", "fish"])
def test_completion_scripts_carry_the_choices(shell):
    res = sarbot("completion", shell)
    assert res.returncode == 0, res.stderr
    assert "shtab" in res.stdout  # generated from the parser, not written by hand
    for kind, names in _choices().items():
        assert names, kind
        missing = [n for n in names if n not in res.stdout]
        assert not missing, f"{shell}: {kind} {missing} not in the script"


def test_bash_completes_choices_for_real():
    script = sarbot("completion", "bash").stdout
    probe = script + "\n".join([
        'COMP_WORDS=(sarbot image x.h5 --autofocus ""); COMP_CWORD=4; _shtab_sarbot; echo "${COMPREPLY[*]}"',
        "COMP_WORDS=(sarbot simulate paper_p); COMP_CWORD=2; _shtab_sarbot; echo \"${COMPREPLY[*]}\"",
        'COMP_WORDS=(sarbot image x.h5 --radar left_); COMP_CWORD=4; _shtab_sarbot; echo "${COMPREPLY[*]}"',
        "COMP_WORDS=(sarbot export x.h5 --storage s); COMP_CWORD=4; _shtab_sarbot; echo \"${COMPREPLY[*]}\"", ""])
    out = subprocess.run(["bash", "-c", probe], capture_output=True, text=True, check=True).stdout.splitlines()
    choices = _choices()
    assert out[0].split() == choices["autofocus"]
    assert out[1].split() == [s for s in choices["scenes"] if s.startswith("paper_p")] and out[1]
    assert out[2].split() == [r for r in choices["radars"] if r.startswith("left_")] and out[2]
    assert out[3] == "sqlite3"


def test_fish_and_zsh_take_the_scripts():
    """fish completes for real (``complete -C``); zsh loads the script and registers it for sarbot. Each
    skipped, saying so, where the shell is not installed (apt-get install fish zsh)."""
    import shutil

    if shutil.which("fish") is None and shutil.which("zsh") is None:
        pytest.skip("neither fish nor zsh is installed (apt-get install fish zsh)")
    if shutil.which("fish"):
        script = sarbot("completion", "fish").stdout
        res = subprocess.run(["fish", "--no-config", "-c", "source; complete -C 'sarbot image x.h5 --autofocus '"],
                             input=script, capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr
        assert [line.split("\t")[0] for line in res.stdout.splitlines()] == _choices()["autofocus"]
    if shutil.which("zsh"):
        script = sarbot("completion", "zsh").stdout
        res = subprocess.run(["zsh", "-f", "-c", "autoload -Uz compinit && compinit -u -d /dev/null; "
                              "eval \"$(cat)\" >/dev/null 2>&1; print -r -- $_comps[sarbot]"],
                             input=script, capture_output=True, text=True, timeout=60)
        assert res.returncode == 0 and res.stdout.strip() == "_shtab_sarbot", res.stderr


def _fake_distribution(site, package: str, name: str, version: str = "9.9") -> None:
    """A distribution as pip leaves it: its top-level module ``package`` (one file, as many on PyPI are) and
    a dist-info whose RECORD lists it."""
    site.mkdir(parents=True)
    (site / f"{package}.py").write_text(f'"""{name}: not sarbot\'s {package}."""\n')
    info = site / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "RECORD").write_text(f"{package}.py,,\n{info.name}/METADATA,,\n{info.name}/RECORD,,\n")


# Commands that import the package: rio's odometry; record's options (its wire formats). ``info`` builds only its own
# family's parser now, which needs nothing of drivers.
@pytest.mark.parametrize("package, command", [("rio", ["rio", "rec.h5", "-o", "traj.h5"]),
                                              ("drivers", ["record", "--config", "rec.h5", "-o", "out"])])
def test_a_package_of_another_distribution_in_place_of_sarbots_is_named_in_one_line(tmp_path, package, command):
    """``pip install rio`` (or ``drivers``) puts another project's package where sarbot's was; here a folder
    first on the path does the same. sarbot names the package, where it is, whose it is, and the way out."""
    import os

    site = tmp_path / "site"
    _fake_distribution(site, package, f"not-sarbot-{package}")
    (tmp_path / "rec.h5").write_bytes(b"not HDF5")  # the command gets as far as importing the package
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])])}
    res = subprocess.run([sys.executable, "-m", "acquisition.launcher", *command], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=300)
    assert res.returncode == 2, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith("sarbot: error: ") and "Traceback" not in res.stderr
    assert f"'{package}' at {site / package}.py" in line and f"not-sarbot-{package} 9.9" in line
    assert f"pip uninstall not-sarbot-{package}" in line
    # Without the stranger, the same command is the usual one-line error about the file.
    plain = subprocess.run([sys.executable, "-m", "acquisition.launcher", *command], capture_output=True, text=True,
                           cwd=tmp_path, timeout=300)
    assert plain.returncode == 2 and "another distribution" not in plain.stderr
    assert plain.stderr.startswith("sarbot: error: ") and "rec.h5" in plain.stderr


def test_the_installed_command_goes_through_the_launcher():
    from importlib.metadata import entry_points

    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "sarbot"]
    assert script.value == "acquisition.launcher:main"


def test_the_worker_stop_options_parse_reach_the_setup_and_their_help_says_the_daemons_defaults(tmp_path):
    """``run`` and ``demo`` take --worker-stop-timeout and --worker-hurry-timeout (``record`` starts no worker);
    given, they become the daemon's Setup fields, not given the Setup's own defaults stand, which the help
    says, as it says the unit's TimeoutStopSec that their sum must fit in."""
    import dataclasses
    import re
    from pathlib import Path

    from acquisition.cli import build_parser
    from acquisition.cli.daemon import record_setup
    from acquisition.cli.options import worker_stop_settings
    from acquisition.daemon import Setup

    rig = tmp_path / "rig.toml"
    rig.write_text("[imu]\nrate_hz = 400.0\n[radar.left]\nmount_yaw_deg = 90.0\n")
    parser = build_parser()
    run = ["run", "--config", str(rig), "-o", str(tmp_path / "out"), "--radar", "left=50001"]
    given = ["--worker-stop-timeout", "120", "--worker-hurry-timeout", "7.5"]
    setup = record_setup(parser.parse_args([*run, *given]))
    assert (setup.worker_stop_timeout_s, setup.worker_hurry_timeout_s) == (120.0, 7.5)
    assert worker_stop_settings(parser.parse_args(["demo", *given])) == {"worker_stop_timeout_s": 120.0,
                                                                         "worker_hurry_timeout_s": 7.5}
    defaults = {f.name: f.default for f in dataclasses.fields(Setup)}
    setup = record_setup(parser.parse_args(run))
    assert setup.worker_stop_timeout_s == defaults["worker_stop_timeout_s"] == 60.0
    assert setup.worker_hurry_timeout_s == defaults["worker_hurry_timeout_s"] == 15.0
    unit = (Path(__file__).resolve().parents[1] / "systemd/sarbot-record.service").read_text()
    stop_sec = re.search(r"^TimeoutStopSec=(\d+)$", unit, re.M).group(1)
    assert re.search(rf"^Environment=SARBOT_TIMEOUT_STOP_S={stop_sec}$", unit, re.M)  # the daemon is told it
    for command in ("run", "demo"):
        text = " ".join(_subparser(parser, command).format_help().split())
        assert "--worker-stop-timeout SECONDS" in text and "--worker-hurry-timeout SECONDS" in text
        assert f"(default {defaults['worker_stop_timeout_s']:g};" in text
        assert f"(default {defaults['worker_hurry_timeout_s']:g})" in text and f"TimeoutStopSec ({stop_sec};" in text
    assert "--worker-stop-timeout" not in _subparser(parser, "record").format_help()


@pytest.mark.parametrize("command", ["run", "demo"])
@pytest.mark.parametrize("option, value", [("--worker-stop-timeout", "0"), ("--worker-stop-timeout", "-5"),
                                           ("--worker-hurry-timeout", "nan"), ("--worker-hurry-timeout", "inf")])
def test_a_worker_stop_timeout_that_is_no_positive_number_is_one_line_naming_the_option(tmp_path, command, option,
                                                                                       value):
    rig = tmp_path / "rig.toml"
    rig.write_text("[imu]\nrate_hz = 400.0\n[radar.left]\nmount_yaw_deg = 90.0\n")
    args = (["run", "--config", rig, "-o", tmp_path / "out", "--radar", "left=50001"] if command == "run"
            else ["demo", "-o", tmp_path / "out"])
    res = sarbot(*args, option, value, "--duration", "1") if command == "run" else sarbot(*args, option, value)
    assert_user_error(res, f"{option} {float(value)}: must be a positive number of seconds")
    assert not (tmp_path / "out").exists()  # refused before anything started


def test_a_worker_stop_timeout_that_is_no_number_names_the_option():
    res = sarbot("demo", "--worker-hurry-timeout", "soon")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "argument --worker-hurry-timeout: invalid float value: 'soon'" in res.stderr
