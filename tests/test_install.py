"""`sarbot install-unit` into a staging root: the user, the venv, the config and units that verify."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CLI = [sys.executable, "-m", "acquisition.cli"]
ROOT = Path(__file__).resolve().parents[1]

needs_systemd = pytest.mark.skipif(shutil.which("systemd-analyze") is None or shutil.which("systemd-sysusers") is None,
                                   reason="systemd-analyze and systemd-sysusers are not installed")


@needs_systemd
def test_install_unit_stages_user_venv_config_and_units_that_verify(tmp_path):
    root = tmp_path / "robot"
    devices = "--radar left_front=192.168.33.30:4098 --imu-port /dev/ttyUSB0"
    cmd = [*CLI, "install-unit", "--root", str(root), "--no-deps", "--command", "run", "--devices", devices]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "systemctl enable --now sarbot.target" in res.stdout

    # The user, made by systemd-sysusers from the shipped declaration, in dialout for the serial port.
    passwd = {line.split(":")[0]: line.split(":") for line in (root / "etc/passwd").read_text().splitlines()}
    assert passwd["sarbot"][5] == "/var/lib/sarbot" and passwd["sarbot"][6].endswith("nologin")
    group = {line.split(":")[0]: line.split(":") for line in (root / "etc/group").read_text().splitlines()}
    assert "sarbot" in group["dialout"][3].split(",")
    # The venv under /opt, sarbot's entry point in it, running the venv's own Python.
    exe = root / "opt/sarbot/.venv/bin/sarbot"
    assert exe.exists() and exe.read_text().splitlines()[0] == f"#!{root}/opt/sarbot/.venv/bin/python"
    # The configuration: the default rig and the devices given.
    assert (root / "etc/sarbot/rig.toml").read_text() == (ROOT / "imaging/rigs/default.toml").read_text()
    env = (root / "etc/sarbot/sarbot.env").read_text()
    assert "SARBOT_COMMAND=run\n" in env and f"SARBOT_DEVICES={devices}\n" in env
    # The units, pointing at that venv, verified by systemd itself (here again, independently).
    service = (root / "etc/systemd/system/sarbot-record.service").read_text()
    assert "ExecStart=/opt/sarbot/.venv/bin/sarbot $SARBOT_COMMAND --config /etc/sarbot/rig.toml" in service
    copies = tmp_path / "verify"
    copies.mkdir()
    for unit in ("sarbot.target", "sarbot-record.service"):  # the executable where it was staged
        text = (root / "etc/systemd/system" / unit).read_text()
        (copies / unit).write_text(text.replace("/opt/sarbot/.venv/bin/sarbot", str(exe)))
    verify = subprocess.run(["systemd-analyze", "verify", *map(str, sorted(copies.iterdir()))], capture_output=True,
                            text=True)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    # The sysctl drop-in that lets the radar sockets have their 32 MB receive buffer.
    assert f"sysctl: {root}/etc/sysctl.d/60-sarbot.conf" in res.stdout
    assert "net.core.rmem_max = 33554432\n" in (root / "etc/sysctl.d/60-sarbot.conf").read_text()

    # Run again (an update): the robot's own configuration is kept, the units are renewed.
    (root / "etc/sarbot/sarbot.env").write_text("SARBOT_COMMAND=record\nSARBOT_DEVICES=--imu-port /dev/ttyS1\n")
    (root / "etc/systemd/system/sarbot.target").write_text("[Unit]\n")
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (root / "etc/sarbot/sarbot.env").read_text().endswith("/dev/ttyS1\n")
    assert "WantedBy=multi-user.target" in (root / "etc/systemd/system/sarbot.target").read_text()
    assert sum(line.startswith("sarbot:") for line in (root / "etc/passwd").read_text().splitlines()) == 1


@pytest.mark.parametrize("args, message", [
    (["--config", "no-such-rig.toml"], "--config: no-such-rig.toml does not exist"),
    (["--command", "fly"], "--command: must be 'record' or 'run'"),
    (["--venv", "relative/venv"], "--venv: must be an absolute path"),
])
def test_install_unit_bad_options_are_one_line_errors(tmp_path, args, message):
    res = subprocess.run([*CLI, "install-unit", "--root", str(tmp_path / "robot"), *args], capture_output=True,
                         text=True, timeout=60, cwd=tmp_path)
    assert res.returncode == 2
    assert message in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "robot" / "opt").exists()  # nothing half-installed


def test_the_sysctl_drop_in_allows_the_receive_buffer_the_radar_driver_asks_for(tmp_path):
    """Linux caps SO_RCVBUF at net.core.rmem_max (208 kB by default): the drop-in raises it to what
    UdpReceiver asks for, in sysctl.d's "key = value" form, readable by everyone."""
    import inspect

    from acquisition.install import InstallPlan, write_sysctl
    from drivers.radar.udp import UdpReceiver

    path = write_sysctl(InstallPlan(root=tmp_path / "robot"))
    assert path == tmp_path / "robot/etc/sysctl.d/60-sarbot.conf"
    settings = dict(line.split(" = ") for line in path.read_text().splitlines() if line and not line.startswith("#"))
    asked = inspect.signature(UdpReceiver).parameters["rcvbuf_bytes"].default
    assert settings == {"net.core.rmem_max": str(asked)} and asked == 33554432
    assert path.stat().st_mode & 0o777 == 0o644
