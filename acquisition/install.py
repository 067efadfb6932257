"""``sarbot install-unit``: sarbot on a robot as a systemd service, in one command.

Under ``root`` (``/`` on the robot; a staging folder for a package or an image) it

1. declares the system user and group ``sarbot`` (in ``dialout``, for the IMU's serial port) in
   ``/usr/lib/sysusers.d/sarbot.conf`` and creates them with ``systemd-sysusers``;
2. creates a virtual environment (``/opt/sarbot/.venv``) and installs sarbot into it with pip, pinned by a
   constraints file when one is given;
3. writes ``/etc/sarbot/rig.toml`` (the default rig unless ``--config``) and ``/etc/sarbot/sarbot.env``
   (the command, ``record`` or ``run``, and the robot's ``--radar``/``--imu-port``/``--can`` options), and
   keeps both when they are there already: they are the robot's, not ours;
4. installs ``sarbot.target`` and ``sarbot-record.service`` into ``/etc/systemd/system`` with the paths
   and the user set to these, and checks them with ``systemd-analyze verify``;
5. stages ``/etc/sysctl.d/60-sarbot.conf``, which lets a radar socket have the 32 MB receive buffer its
   driver asks for (``net.core.rmem_max``; without it Linux caps the buffer, a few hundred kB by default,
   and a burst of frames overflows it). It applies at the next boot or ``sysctl --system``.

It enables and starts nothing: it prints the ``systemctl`` commands that do.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import shlex
import shutil
import subprocess
import sys
from importlib import resources
from pathlib import Path

from imaging.core.errors import SarbotError

log = logging.getLogger(f"sarbot.{__name__}")

UNITS = ("sarbot.target", "sarbot-record.service")
SYSCTL_DROP_IN = "/etc/sysctl.d/60-sarbot.conf"
#: The receive buffer a radar driver asks for (drivers.radar.udp.UdpReceiver's default), 32 MB.
RMEM_MAX_BYTES = 32 << 20
DEFAULT_VENV = "/opt/sarbot/.venv"


@dataclasses.dataclass
class InstallPlan:
    """What ``install_unit`` does. Paths other than ``root``, ``source``, ``config`` and ``constraints`` are
    as seen on the robot (inside ``root``).

    source : what pip installs (this checkout, a wheel, or a requirement such as ``sarbot==0.2``).
    no_deps : install sarbot alone (its dependencies already in the environment, e.g. from a wheelhouse).
    """

    root: Path = Path("/")
    venv: str = DEFAULT_VENV
    user: str = "sarbot"
    config: Path | None = None
    command: str = "record"
    devices: str = ""
    source: str = ""
    constraints: Path | None = None
    no_deps: bool = False
    python: str = sys.executable

    def __post_init__(self) -> None:
        if self.command not in ("record", "run"):
            raise SarbotError(f"--command: must be 'record' or 'run', got {self.command!r}")
        if not self.venv.startswith("/"):
            raise SarbotError(f"--venv: must be an absolute path on the robot, got {self.venv!r}")
        if not self.user or not self.user.replace("-", "").replace("_", "").isalnum():
            raise SarbotError(f"--user: not a valid user name: {self.user!r}")
        if self.config is not None and not self.config.is_file():
            raise SarbotError(f"--config: {self.config} does not exist")
        if self.constraints is not None and not self.constraints.is_file():
            raise SarbotError(f"--constraints: {self.constraints} does not exist")
        if not self.source:
            self.source = str(_project_source())
            pinned = Path(self.source) / "constraints.txt"
            if self.constraints is None and pinned.is_file():  # a checkout: the versions its tests passed with
                self.constraints = pinned

    def at(self, path: str) -> Path:
        """``path`` on the robot, under ``root``."""
        return self.root / path.lstrip("/")


def _project_source() -> Path | str:
    """This checkout when sarbot runs from one (an editable install), else the installed version by name."""
    here = Path(__file__).resolve().parents[1]
    if (here / "pyproject.toml").is_file():
        return here
    from importlib.metadata import version

    return f"sarbot=={version('sarbot')}"


def unit_text(name: str, plan: InstallPlan) -> str:
    """A unit file as shipped, with the venv's executable and the user of ``plan``.

    The units live once, in the project's top-level ``systemd/``; ``acquisition/systemd`` is a link to it,
    through which the wheel carries them as package data (and a checkout reads them in place).
    """
    text = resources.files("acquisition").joinpath("systemd", name).read_text()
    text = text.replace(f"{DEFAULT_VENV}/bin/sarbot", f"{plan.venv}/bin/sarbot")
    return text.replace("User=sarbot", f"User={plan.user}").replace("Group=sarbot", f"Group={plan.user}")


def _run(cmd: list[str], what: str) -> None:
    log.info("%s: %s", what, shlex.join(cmd))
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        tail = "\n".join((res.stderr or res.stdout).strip().splitlines()[-5:])
        raise SarbotError(f"{what} failed (exit {res.returncode}): {shlex.join(cmd)}\n{tail}")


def create_user(plan: InstallPlan) -> Path:
    conf = plan.at("/usr/lib/sysusers.d/sarbot.conf")
    conf.parent.mkdir(parents=True, exist_ok=True)
    conf.write_text(f"# sarbot's service user (systemd-sysusers); in dialout for the IMU's serial port\n"
                    f"u {plan.user} - \"sarbot acquisition\" /var/lib/sarbot\n"
                    f"m {plan.user} dialout\n")
    sysusers = shutil.which("systemd-sysusers")
    if sysusers is None:
        raise SarbotError("systemd-sysusers is not installed: this command needs systemd")
    cmd = [sysusers] + ([f"--root={plan.root}"] if plan.root != Path("/") else []) + [str(conf)]
    if plan.root != Path("/"):
        # A staging root needs the files sysusers edits; on the robot they exist.
        for name in ("passwd", "group", "shadow", "gshadow"):
            f = plan.at(f"/etc/{name}")
            f.parent.mkdir(parents=True, exist_ok=True)
            f.touch(exist_ok=True)
        group = plan.at("/etc/group")
        if "dialout:" not in group.read_text():
            with group.open("a") as g:
                g.write("dialout:x:20:\n")
    _run(cmd, "creating the user")
    return conf


def create_venv(plan: InstallPlan) -> Path:
    venv = plan.at(plan.venv)
    if not (venv / "bin" / "python").exists():
        _run([plan.python, "-m", "venv", str(venv)], "creating the virtual environment")
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet"]
    if plan.constraints is not None:
        pip += ["--constraint", str(plan.constraints)]
    if plan.no_deps:
        pip.append("--no-deps")
    _run([*pip, plan.source], "installing sarbot")
    exe = venv / "bin" / "sarbot"
    if not exe.exists():
        raise SarbotError(f"installing sarbot: {exe} was not created")
    return exe


def write_config(plan: InstallPlan) -> list[Path]:
    etc = plan.at("/etc/sarbot")
    etc.mkdir(parents=True, exist_ok=True)
    written = []
    rig = etc / "rig.toml"
    if rig.exists():
        log.info("keeping %s", rig)
    else:
        source = plan.config or Path(str(resources.files("imaging").joinpath("rigs", "default.toml")))
        shutil.copyfile(source, rig)
        written.append(rig)
    env = etc / "sarbot.env"
    if env.exists():
        log.info("keeping %s", env)
    else:
        env.write_text("# sarbot-record.service reads this (EnvironmentFile=).\n"
                       "# SARBOT_COMMAND: record (drivers and recorder) or run (also odometry and the live strip map)\n"
                       f"SARBOT_COMMAND={plan.command}\n"
                       "# SARBOT_DEVICES: this robot's devices, e.g.\n"
                       "#   --radar left_front=192.168.33.30:4098 --imu-port /dev/ttyUSB0 --can socketcan:can0\n"
                       f"SARBOT_DEVICES={plan.devices}\n")
        written.append(env)
    return written


def install_units(plan: InstallPlan) -> list[Path]:
    folder = plan.at("/etc/systemd/system")
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in UNITS:
        path = folder / name
        path.write_text(unit_text(name, plan))
        path.chmod(0o644)
        paths.append(path)
    return paths


def write_sysctl(plan: InstallPlan) -> Path:
    """The sysctl.d drop-in that allows the radar sockets their receive buffer (ours: written every time)."""
    path = plan.at(SYSCTL_DROP_IN)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("# sarbot: a radar driver asks for a 32 MB UDP receive buffer (a burst of frames at 55 MB/s);\n"
                    "# Linux caps SO_RCVBUF at net.core.rmem_max. Applied at boot, or now with: sysctl --system\n"
                    f"net.core.rmem_max = {RMEM_MAX_BYTES}\n")
    path.chmod(0o644)
    return path


def verify_units(plan: InstallPlan, units: list[Path]) -> None:
    """``systemd-analyze verify`` on the installed units. For a staging root, on copies whose executable
    path points into the staging root (``verify --root`` would look for the whole of systemd's own units
    there too)."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        log.warning("systemd-analyze is not installed: the units were not verified")
        return
    if plan.root == Path("/"):
        _run([analyze, "verify", *map(str, units)], "verifying the units")
        return
    import tempfile

    exe = f"{plan.venv}/bin/sarbot"
    with tempfile.TemporaryDirectory(prefix="sarbot-verify-") as tmp:
        copies = []
        for unit in units:
            copy = Path(tmp) / unit.name
            copy.write_text(unit.read_text().replace(exe, str(plan.at(exe))))
            copies.append(str(copy))
        _run([analyze, "verify", *copies], "verifying the units")


def install_unit(plan: InstallPlan) -> dict[str, list[str]]:
    """Everything above, in order; returns what was written (by kind)."""
    if plan.root == Path("/") and os.geteuid() != 0:
        raise SarbotError("install-unit creates a user and writes /etc and /opt: run it as root (sudo), "
                          "or give --root DIR to stage the files in a folder")
    done = {"user": [str(create_user(plan))], "venv": [str(create_venv(plan))]}
    done["config"] = [str(p) for p in write_config(plan)]
    units = install_units(plan)
    done["units"] = [str(p) for p in units]
    verify_units(plan, units)
    done["sysctl"] = [str(write_sysctl(plan))]
    return done
