"""Options more than one command takes, each said once, and the parsers of option values.

An option group (``imaging_options``, ``acquisition_options``, ``can_options``, ``view_option``,
``overwrite_option``) adds its arguments to a command's sub-parser. A value parser turns what the user
typed into plain values, or raises SarbotError naming the option and the value (exit 2, one line).
Choice lists come from the module that owns them (``ChoicesFrom``), never written out here.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
from pathlib import Path

from imaging.core.errors import SarbotError


# -- choices ----------------------------------------------------------------------------------------------
class ChoicesFrom:
    """An option's choices, read from ``module.attribute`` when argparse first needs them: to check a value
    or to print help. Not at import: registries (autofocus methods) may grow at run time, and the owning
    modules may be slow to import (numba), which a command that does not image should not pay for.

    ``first`` come before the source's names (e.g. "auto"). Works with a tuple, a list or a dict, or a
    function returning one.
    """

    def __init__(self, module: str, attribute: str, first: tuple[str, ...] = ()):
        self.module, self.attribute, self.first = module, attribute, first

    def names(self) -> list[str]:
        source = getattr(importlib.import_module(self.module), self.attribute)
        return [*self.first, *(source() if callable(source) else source)]

    def __iter__(self):
        return iter(self.names())

    def __contains__(self, value) -> bool:
        return value in self.names()

    def __len__(self) -> int:
        return len(self.names())


class _ChoicesReadLateFormatter(argparse.HelpFormatter):
    """argparse's help formatter, except that ``add_argument``'s check of an option's metavar (the one call
    without a default metavar) does not read ``ChoicesFrom`` choices: their module is imported when help
    is printed or a value is checked, not for every command."""

    def _metavar_formatter(self, action, default_metavar):
        if default_metavar is None and action.metavar is None and isinstance(action.choices, ChoicesFrom):
            return lambda size: ("CHOICE",) * size if isinstance(size, int) else ("CHOICE",)
        return super()._metavar_formatter(action, default_metavar)


class ArgumentParser(argparse.ArgumentParser):
    """sarbot's parser and sub-parsers: with choices read late (``ChoicesFrom``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _ChoicesReadLateFormatter)
        super().__init__(*args, **kwargs)


AUTOFOCUS_METHODS = ChoicesFrom("imaging.autofocus", "METHODS")
WINDOWS = ChoicesFrom("imaging.core.windows", "WINDOWS")
BACKPROJECTION_MODES = ChoicesFrom("imaging.backprojection", "MODES")
IMAGE_ALGORITHMS = ChoicesFrom("imaging.image_formation", "ALGORITHMS")
MAP_ALGORITHMS = ChoicesFrom("imaging.stripmap", "ALGORITHMS")


def reference_radar_names() -> list[str]:
    """The radars of the reference rig (docs/config/rig.md): what ``--radar`` completes to."""
    from imaging.core.rig import default_rig

    return [r.name for r in default_rig().radars]


def completes(action: argparse.Action, names: ChoicesFrom) -> argparse.Action:
    """Let the shell completion (``sarbot completion``) offer ``names`` for an argument that takes other
    values too (a scene's name or its TOML file): unlike ``choices``, nothing is refused."""
    action.completes = names
    return action


# -- option groups ----------------------------------------------------------------------------------------
def overwrite_option(s: argparse.ArgumentParser, help: str = "replace an existing output file") -> None:  # noqa: A002
    s.add_argument("--overwrite", action="store_true", help=help)


def imaging_options(s: argparse.ArgumentParser) -> None:
    """How images are formed: what ``image`` and ``batch`` share (a batch's job is an ``image``)."""
    completes(s.add_argument("--radar", help="radar name (needed when a recording has several)"),
              ChoicesFrom(__name__, "reference_radar_names"))
    s.add_argument("--frames", help="frame range A:B (B excluded); all by default")
    s.add_argument("--aperture", type=float, metavar="METRES",
                   help="image only the central METRES of the frames' track (a synthetic aperture of that length)")
    s.add_argument("--grid", required=True, help="x0:x1:dx,y0:y1:dy[,z or z0:z1:dz] in metres, world frame")
    s.add_argument("--trajectory", default="truth", help="'truth' or a trajectory HDF5 file")
    s.add_argument("--mode", default="linear", choices=BACKPROJECTION_MODES)
    s.add_argument("--window", default="hann", choices=WINDOWS)
    s.add_argument("--oversample", type=int, default=16, help="range FFT zero-padding factor (default 16: >= 60 dB "
                   "signal-to-error with linear interpolation)")
    s.add_argument("--aperture-window", default="rectangular", choices=WINDOWS,
                   help="slow-time taper over the aperture (default rectangular: -13.3 dB side lobes across range; "
                        "taylor: -35 dB, a 1.34x wider main lobe; analyze's theory allows for it)")
    s.add_argument("--algorithm", default="direct", choices=IMAGE_ALGORITHMS,
                   help="direct: every profile onto every pixel (default); ffbp: fast factorized backprojection, "
                        "a horizontal plane to one side of the track, about 25x faster on a 2 m aperture at about "
                        "-44 dB from the direct image (its bound and estimate go into the file)")
    s.add_argument("--autofocus", default="none", choices=AUTOFOCUS_METHODS,
                   help="estimate the radar's track error along its boresight (vibration, odometry drift) from the "
                        "image and form it again: pga (phase gradient) or entropy (minimum entropy over a bend plus "
                        "sinusoids; the default choice for vibration). The estimate goes into the file; analyze reports it")


def imaging_values(args) -> dict:
    """The ``imaging_options`` that say how an image is formed, as ``acquisition.batch`` names them."""
    return {"mode": args.mode, "window": args.window, "oversample": args.oversample, "algorithm": args.algorithm,
            "aperture_window": args.aperture_window, "autofocus": args.autofocus, "aperture_m": args.aperture}


def rig_override_option(s: argparse.ArgumentParser) -> None:
    s.add_argument("--rig", metavar="TOML",
                   help="each radar's mount and clock offset from this rig file (one sarbot calibrate wrote) instead "
                        "of what the recording holds")


def use_rig_file(rec, path: str | None) -> None:
    """``--rig``: the recording's radars with the mounts and time offsets of the rig file at ``path``."""
    if path:
        from imaging.core.rig import load_rig

        rec.use_mounts_of(load_rig(path), f"--rig {path}")


def can_options(s: argparse.ArgumentParser) -> None:
    s.add_argument("--can", help="python-can INTERFACE[:CHANNEL], e.g. socketcan:can0 or udp_multicast:239.74.163.2")
    s.add_argument("--can-arg", action="append", help="KEY=VALUE passed to python-can's Bus (repeat), e.g. port=43113")
    s.add_argument("--can-trigger-id", default="0x100", help="arbitration id of the sync box's trigger frame (default 0x100; 'none')")


def acquisition_options(s: argparse.ArgumentParser) -> None:
    """The devices and the recorder: what ``record`` and ``run`` share."""
    from drivers.radar import registry

    s.add_argument("--config", required=True, help="rig TOML")
    s.add_argument("-o", "--output", required=True,
                   help="folder for the recording (created if missing): recording_YYYYMMDDTHHMMSS.h5, the local "
                        "time at the start; split parts _000.h5, _001.h5, ...; each file written is printed")
    s.add_argument("--radar", action="append",
                   metavar="NAME=[HOST:]PORT[,format=FORMAT][,source=ADDRESS][,id=RADAR_ID][,stamps=MODE][,OPTION=VALUE]",
                   help="where a radar's datagrams arrive (repeat per radar); HOST is the address to listen on "
                        f"(default 127.0.0.1); FORMAT one of the registered wire formats ({', '.join(registry.names())}; "
                        f"default {registry.DEFAULT}); source= the only sender address accepted, id= the only radar id "
                        "accepted (others are counted and ignored); stamps= auto, hardware or software (this link's "
                        "--receive-stamps); the format's own options, e.g. format=DCA1000,cfg=xwr18xx.cfg")
    s.add_argument("--dca1000", action="append", metavar="NAME=[HOST:]PORT:CFG",
                   help="shorthand for --radar NAME=[HOST:]PORT,format=DCA1000,cfg=CFG (a TI radar through a DCA1000; "
                        "HOST: this host's address on the DCA1000's network, e.g. 192.168.33.30; default 127.0.0.1)")
    s.add_argument("--dca1000-arm", action="append", metavar="NAME[=HOST[:PORT]][,listen=[HOST:]PORT][,lanes=2|4][,delay_us=US]",
                   help="arm that --dca1000 radar's capture card before recording and stop it after (its configuration "
                        "protocol; default address 192.168.33.180:4096, replies on this host's port 4096, 2 LVDS lanes "
                        "(4 for xWR12xx/14xx), packet delay 25 us)")
    s.add_argument("--radar-cli", action="append", metavar="NAME=DEVICE",
                   help="send that --dca1000 radar's .cfg to its CLI serial port (each line must be answered Done), "
                        "sensorStart once the DCA1000 records, sensorStop at the end")
    s.add_argument("--imu-port", help="serial device of the Xsens IMU (or the pty replay links)")
    s.add_argument("--radar-imu", action="append", metavar="NAME=DEVICE",
                   help="serial device of the Xsens IMU on that radar's own mount (repeat per radar; the rig declares it "
                        "as [radar.NAME.imu]); recorded in /radar/NAME/imu for `sarbot image --imu-aided`")
    can_options(s)
    s.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C / SIGTERM)")
    s.add_argument("--split-size", help="start a new file at this size (e.g. 2G)")
    s.add_argument("--split-time", type=float, help="start a new file after this many seconds")
    s.add_argument("--min-free", default="64M", help="stop recording cleanly when less disk space than this is left (default 64M)")
    s.add_argument("--health-endpoint", help="ZeroMQ endpoint to publish health on (tcp://HOST:PORT or ipc://PATH; default: loopback TCP on a port the system picks at bind, logged)")
    s.add_argument("--ptp4l", metavar="SOCKET", nargs="?", const="/var/run/ptp4l",
                   help="watch the host's linuxptp: ptp4l's port state, offset and path delay (through pmc on this "
                        "management socket, default /var/run/ptp4l) into health, /ptp and /events")
    s.add_argument("--receive-stamps", choices=("auto", "hardware", "software"), default="auto",
                   help="radar receive time stamps: the network card's (its PTP hardware clock; the interface must stamp "
                        "every packet, and setting that needs CAP_NET_ADMIN), the kernel's (software), or auto: the card's "
                        "where it can, else the kernel's (default); a link's stamps=MODE overrides it. Said in health, "
                        "sarbot info and each radar's receive_stamp in the recording (hardware also in /events)")
    s.add_argument("--phc2sys-log", metavar="FILE",
                   help="with --ptp4l: a file phc2sys's -m output goes to; its offset joins health and /ptp")


def worker_stop_options(s: argparse.ArgumentParser) -> None:
    """How long the workers may take at the stop: what ``run`` and ``demo`` share (``record`` starts no worker).
    No defaults here: they are the daemon's (``acquisition.daemon.Setup``), whose module is not imported for
    every command; the help says them, and tests/test_cli.py checks that it says them right."""
    s.add_argument("--worker-stop-timeout", type=float, metavar="SECONDS",
                   help="after the stop, how long the workers (odometry, strip map) may take to drain, finish and "
                        "write the trajectory and the map (default 60; their own budgets are cut to fit); one still "
                        "running then gets SIGTERM and writes what it has, its files saying stop_cut_short = 1")
    s.add_argument("--worker-hurry-timeout", type=float, metavar="SECONDS",
                   help="how long a worker sent SIGTERM at the stop may take to write what it has before it is "
                        "killed, its files lost (default 15). Under systemd the two and 5 s more must fit in the "
                        "unit's TimeoutStopSec (90; warned at the start where they do not)")


#: ``worker_stop_options`` and the daemon's fields they set (``acquisition.daemon.Setup``).
WORKER_STOP_OPTIONS = {"--worker-stop-timeout": "worker_stop_timeout_s",
                       "--worker-hurry-timeout": "worker_hurry_timeout_s"}


def worker_stop_settings(args) -> dict[str, float]:
    """The ``worker_stop_options`` given, as the daemon's Setup fields (those not given keep the daemon's
    defaults); SarbotError naming the option for a value that is not a positive number of seconds."""
    settings = {}
    for option, field in WORKER_STOP_OPTIONS.items():
        value = getattr(args, option.lstrip("-").replace("-", "_"), None)
        if value is not None:
            check_duration(value, option)
            settings[field] = value
    return settings


#: The device-control options of ``acquisition_options``, as the wire formats name them (``control_options``).
CONTROL_OPTIONS = ("--dca1000-arm", "--radar-cli")


def view_option(s: argparse.ArgumentParser) -> None:
    s.add_argument("--view", metavar="[HOST:]PORT",
                   help="serve the live map, pose, health and events on the Foxglove WebSocket protocol (loopback "
                        "unless HOST is given), e.g. --view 8765, then open ws://localhost:8765 in Foxglove")


# -- option values ----------------------------------------------------------------------------------------
def parse_frames(text: str | None) -> slice:
    if not text:
        return slice(None)
    parts = text.split(":")
    try:
        if len(parts) == 1:
            a = int(parts[0])
            return slice(a, a + 1)
        if len(parts) == 2:
            return slice(int(parts[0]) if parts[0] else None, int(parts[1]) if parts[1] else None)
    except ValueError:
        pass
    raise SarbotError(f"--frames {text!r}: expected A:B (frame indices, B excluded)")


def parse_channels(text: str | None, name: str) -> tuple[int, ...] | None:
    if text is None or text == "all":
        return None
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise SarbotError(f"--{name} {text!r}: expected comma-separated channel indices or 'all'") from None


def parse_xy(text: str, option: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
        return x, y
    except ValueError:
        raise SarbotError(f"{option} {text!r}: expected x,y in metres") from None


def parse_floats(text: str, n: int, option: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise SarbotError(f"{option} {text!r}: expected {n} finite numbers separated by commas")
    return values


def range_pair(text: str) -> tuple[float, float]:
    """``MIN:MAX`` metres (an argparse ``type``)."""
    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected MIN:MAX in metres") from None
    if not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"{text!r}: need 0 <= MIN < MAX")
    return lo, hi


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def new_output(path, overwrite: bool, option: str = "", inputs=()) -> Path:
    """An output file path, checked before any work: never one of the command's ``inputs`` (not even with
    ``--overwrite``), one that exists already only with ``--overwrite`` (nothing is destroyed unasked), and in
    a folder that exists and can be written. SarbotError naming the option and path otherwise."""
    path = Path(path)
    for source in inputs:
        if _same_file(path, Path(source)):
            raise SarbotError(f"{option}{path}: that is a file this command reads; choose another output")
    if path.is_dir():
        raise SarbotError(f"{option}{path}: is a folder; give a file name")
    if path.exists() and not overwrite:
        raise SarbotError(f"{option}{path}: exists already (use --overwrite to replace it)")
    check_writable_folder(path.parent if str(path.parent) else Path("."), option, path)
    return path


def check_writable_folder(folder: Path, option: str = "", shown=None) -> None:
    """SarbotError unless ``folder`` is an existing folder this process may create files in."""
    shown = folder if shown is None else shown
    if not folder.is_dir():
        raise SarbotError(f"{option}{shown}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SarbotError(f"{option}{shown}: folder {folder} is not writable")


def new_output_folder(path, option: str = "-o ") -> Path:
    """A folder to write into (created with its parents), or SarbotError naming the option and why not."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise SarbotError(f"{option}{path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SarbotError(f"{option}{path}: cannot create that folder ({exc.strerror})") from None
    check_writable_folder(path, option)
    return path


def write_output(path: Path, write, option: str = ""):
    """``write(path)``, an OSError on the way (permissions, a full disk, a folder gone) as a SarbotError."""
    try:
        return write(path)
    except OSError as exc:
        raise SarbotError(f"{option}{path}: cannot write ({exc.strerror or exc})") from None


def radar_targets(items: list[str] | None) -> dict[str, tuple[str, int]]:
    """``--radar NAME=[HOST:]PORT`` of replay: where to send each radar's datagrams."""
    out = {}
    for item in items or []:
        try:
            name, where = item.split("=", 1)
            host, port = where.rsplit(":", 1) if ":" in where else ("127.0.0.1", where)
            if name in out:
                raise SarbotError(f"--radar {item!r}: radar {name} given twice")
            out[name] = (host, int(port))
        except ValueError:
            raise SarbotError(f"--radar {item!r}: expected NAME=[HOST:]PORT") from None
        if not name or not host or not 0 < out[name][1] < 65536:
            raise SarbotError(f"--radar {item!r}: expected NAME=[HOST:]PORT with a port in 1..65535")
    return out


def named_paths(items: list[str] | None, option: str) -> dict[str, str]:
    """``OPTION NAME=PATH`` given once per radar: radar -> path."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, path = item.partition("=")
        if not (sep and name and path):
            raise SarbotError(f"{option} {item!r}: expected NAME=PATH")
        if name in out:
            raise SarbotError(f"{option} {item!r}: radar {name} given twice")
        out[name] = path
    return out


def radar_names(text: str | None, option: str, known: set[str]) -> list[str]:
    """``OPTION A,B``: radars among ``known`` (all of them when not given)."""
    if not text:
        return sorted(known)
    names = [n.strip() for n in text.split(",") if n.strip()]
    for n in names:
        if n not in known:
            raise SarbotError(f"{option} {n}: not a radar being recorded ({', '.join(sorted(known))})")
    return names


def can_config(args):
    """The ``can_options`` as a ``CanConfig`` (None without ``--can``)."""
    if not args.can:
        return None
    from drivers.can_driver import CanConfig

    interface, _, channel = args.can.partition(":")
    options = {}
    for item in args.can_arg or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SarbotError(f"--can-arg {item!r}: expected KEY=VALUE")
        options[key] = int(value) if value.lstrip("-").isdigit() else value
    try:
        trigger = int(args.can_trigger_id, 0) if args.can_trigger_id.lower() != "none" else None
    except ValueError:
        raise SarbotError(f"--can-trigger-id {args.can_trigger_id!r}: expected an arbitration id such as 0x100, or none") from None
    return CanConfig(interface, channel or None, trigger, options)


def size_bytes(text: str | None, option: str = "--split-size") -> int | None:
    if text is None:
        return None
    units = {"k": 1e3, "m": 1e6, "g": 1e9}
    t = text.strip().lower().removesuffix("b")
    try:
        value = float(t[:-1]) * units[t[-1]] if t and t[-1] in units else float(t)
    except ValueError:
        raise SarbotError(f"{option} {text!r}: expected a size such as 500M or 2G") from None
    if not (math.isfinite(value) and value > 0):
        raise SarbotError(f"{option} {text!r}: must be a positive size")
    return int(value)


def bus_endpoint(text: str | None, option: str = "--health-endpoint") -> str | None:
    """A ZeroMQ endpoint to bind: ``tcp://HOST:PORT`` (PORT 0 or ``*``: one the system picks, logged) or
    ``ipc://PATH``; SarbotError naming the option otherwise (None when not given)."""
    if text is None:
        return None
    scheme, sep, where = text.partition("://")
    if sep and scheme == "ipc" and where and "\x00" not in where:
        return text
    if sep and scheme == "tcp":
        host, colon, port = where.rpartition(":")
        host_ok = host and not any(c in host for c in "/ \x00") and (host != "[]")
        if colon and host_ok and (port == "*" or (port.isdigit() and int(port) < 65536)):
            return text
    raise SarbotError(f"{option} {text!r}: expected tcp://HOST:PORT (PORT 0: any free one) or ipc://PATH")


def check_duration(value: float | None, option: str = "--duration") -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise SarbotError(f"{option} {value}: must be a positive number of seconds")


def view_address(text: str | None) -> tuple[str, int] | None:
    """``--view [HOST:]PORT`` (None when not given)."""
    if not text:
        return None
    from ..workers.view import parse_view_address

    return parse_view_address(text)


#: Options whose values often start with a minus sign (negative coordinates), which argparse would
#: otherwise take for an option: ``--grid -1:1:0.01,...`` is joined to ``--grid=-1:1:0.01,...``.
NEGATIVE_VALUE_OPTIONS = ("--grid", "--at")


def join_negative_values(argv: list[str]) -> list[str]:
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in NEGATIVE_VALUE_OPTIONS and i + 1 < len(argv):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out
