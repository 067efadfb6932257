"""`sarbot install-unit` into a staging root: the user, the venv, the config and units that verify."""

import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

CLI = [sys.executable, "-m", "acquisition.cli"]
ROOT = Path(__file__).resolve().parents[1]

needs_systemd = pytest.mark.skipif(shutil.which("systemd-analyze") is None or shutil.which("systemd-sysusers") is None,
                                   reason="systemd-analyze and systemd-sysusers are not installed")
UNITS = ("sarbot.target", "sarbot-record.service")


def assert_staged_units_verify(root: Path, copies: Path) -> None:
    """``systemd-analyze verify`` on the units staged under ``root``, their executable pointed at the staged
    venv's (verify checks that it exists)."""
    exe = root / "opt/sarbot/.venv/bin/sarbot"
    copies.mkdir()
    for unit in UNITS:
        text = (root / "etc/systemd/system" / unit).read_text()
        (copies / unit).write_text(text.replace("/opt/sarbot/.venv/bin/sarbot", str(exe)))
    verify = subprocess.run(["systemd-analyze", "verify", *map(str, sorted(copies.iterdir()))], capture_output=True,
                            text=True)
    assert verify.returncode == 0, verify.stdout + verify.stderr


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
    assert_staged_units_verify(root, tmp_path / "verify")
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


def _copy_checkout(dst: Path) -> Path:
    """The project's files as a clone has them (no venv, caches or build output), symbolic links kept."""
    skip = {".venv", ".git", "site", "build", "dist", "__pycache__", ".pytest_cache", ".hypothesis", "sarbot-demo"}
    shutil.copytree(ROOT, dst, symlinks=True,
                    ignore=lambda _d, names: [n for n in names if n in skip or n.endswith(".egg-info")])
    return dst


@needs_systemd
def test_the_wheel_carries_the_units_of_the_top_level_systemd_folder_and_installs_them(tmp_path):
    """The units live once, in ``systemd/``; a wheel built from the checkout carries them, and
    ``sarbot install-unit`` run from that wheel in a fresh venv (not from this checkout) stages units that
    ``systemd-analyze verify`` accepts."""
    src = _copy_checkout(tmp_path / "src")
    dist = tmp_path / "dist"
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(dist), str(src)],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    (wheel,) = dist.glob("sarbot-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        for unit in UNITS:
            assert zf.read(f"acquisition/systemd/{unit}") == (ROOT / "systemd" / unit).read_bytes()

    # A fresh venv with the wheel alone; sarbot's dependencies from this interpreter's site-packages (a path
    # entry only: its editable sarbot is not activated, so `acquisition` can come only from the wheel).
    fresh = tmp_path / "fresh"
    subprocess.run([sys.executable, "-m", "venv", str(fresh)], check=True, timeout=300)
    py = fresh / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "--quiet", "--no-deps", str(wheel)], check=True, timeout=300,
                   capture_output=True)
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    (Path(site) / "sarbot_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    where = subprocess.run([str(py), "-c", "import acquisition; print(acquisition.__file__)"], capture_output=True,
                           text=True, cwd=tmp_path, timeout=120)
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()).is_relative_to(fresh), where.stdout

    root = tmp_path / "robot"
    res = subprocess.run([str(fresh / "bin" / "sarbot"), "install-unit", "--root", str(root), "--no-deps",
                          "--source", str(wheel)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    for unit in UNITS:
        staged = (root / "etc/systemd/system" / unit).read_text()
        assert staged == (ROOT / "systemd" / unit).read_text()  # the defaults: same venv path and user
    assert_staged_units_verify(root, tmp_path / "verify")


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
