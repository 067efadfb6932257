"""Progress: a tqdm bar with its ETA on a terminal, log lines elsewhere, nothing with -q; --version."""

import io
import logging
import subprocess
import sys

from acquisition.processes import VERBOSITY_ENV
from acquisition.progress import Progress

CLI = [sys.executable, "-m", "acquisition.cli"]


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_terminal_gets_a_bar_with_eta(monkeypatch):
    monkeypatch.setenv(VERBOSITY_ENV, "0")
    out = Terminal()
    progress = Progress("backproject", stream=out)
    for done in range(0, 11):
        progress(done, 10)
    text = out.getvalue()
    assert "backproject" in text and "10/10" in text and "100%" in text
    assert "<" in text  # tqdm's elapsed<remaining


def test_elsewhere_a_log_line_every_tenth_and_nothing_when_quiet(monkeypatch, caplog):
    monkeypatch.setenv(VERBOSITY_ENV, "0")
    caplog.set_level(logging.INFO, logger="sarbot")
    progress = Progress("simulate", stream=io.StringIO())
    for done in range(0, 101):
        progress(done, 100)
    lines = [r.getMessage() for r in caplog.records if "simulate:" in r.getMessage()]
    assert len(lines) == 11 and lines[-1].startswith("simulate: 100/100 (100%)")
    caplog.clear()
    monkeypatch.setenv(VERBOSITY_ENV, "-1")  # -q
    out = Terminal()
    quiet = Progress("simulate", stream=out)
    for done in range(0, 101):
        quiet(done, 100)
    assert out.getvalue() == "" and not [r for r in caplog.records if "simulate:" in r.getMessage()]


def test_quiet_command_and_version(tmp_path):
    res = subprocess.run([*CLI, "-q", "simulate", "point_target", "-o", str(tmp_path / "p.h5")], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    version = subprocess.run([*CLI, "--version"], capture_output=True, text=True)
    assert version.returncode == 0 and version.stdout.startswith("sarbot ")


def test_bash_completion_completes_commands_and_their_options():
    script = subprocess.run([*CLI, "completion", "bash"], capture_output=True, text=True, check=True).stdout
    probe = script + "\n".join([
        "COMP_WORDS=(sarbot rep); COMP_CWORD=1; _shtab_sarbot; echo \"${COMPREPLY[*]}\"",
        "COMP_WORDS=(sarbot -v replay --la); COMP_CWORD=3; _shtab_sarbot; echo \"${COMPREPLY[*]}\"",
        "COMP_WORDS=(sarbot image x.h5 --ov); COMP_CWORD=3; _shtab_sarbot; echo \"${COMPREPLY[*]}\"", ""])
    out = subprocess.run(["bash", "-c", probe], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out == ["replay", "--laps", "--oversample --overwrite"]
