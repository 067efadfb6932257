"""The ``sarbot`` command line (see docs/cli.md).

One module per command family, each with a ``register(subparsers)`` that adds its commands beside their
handlers; a new family is one module and one line in ``FAMILIES``. Options several commands share, and
the parsers of option values, are in ``options``; exit codes in ``exit_codes``.

Every user mistake (a missing file, a wrong schema, a bad grid, frames out of range, an unknown radar,
an invalid configuration value) ends with one line ``sarbot: error: ...`` naming it, and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import threading
import time

#: When sarbot's command line was imported: the commands measure their stages from here (``sarbot -v image``).
STARTED = time.perf_counter()

from ..processes import configure_logging, ensure_jit_cache_dir
from .exit_codes import run_command
from .options import ArgumentParser, join_negative_values
from .start_up import collector_paused

#: The command families, in the order their commands are listed, each with the commands it registers: a
#: command's parser is built alone (``sarbot image`` need not build, nor import for, ``record``'s options).
FAMILIES = {
    "imaging": ("simulate", "image", "batch", "analyze", "experiment"),
    "odometry": ("rio", "calibrate"),
    "files": ("info", "export", "import-bag", "import-ti"),
    "daemon": ("record", "run", "replay", "demo"),
    "system": ("install-unit", "completion"),
}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("sarbot")
    except PackageNotFoundError:  # run from a checkout that is not installed
        return "unknown (not installed)"


class _VersionAction(argparse.Action):
    """``--version``, looking the version up only when asked (importlib.metadata costs every command ~30 ms)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):  # noqa: A002
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"sarbot {_version()}")  # on stdout, as argparse's own version action
        parser.exit()


def command_of(argv: list[str]) -> str | None:
    """The command an argument list asks for: its first word that is not an option (sarbot's own options
    take no values), or None."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser: with every command, or (``command``) with that one only, when it is one."""
    p = ArgumentParser(prog="sarbot", description="SAR imaging and radar-inertial odometry for mobile robots.")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only (no progress, no info lines)")
    p.add_argument("--version", action=_VersionAction, help="show the version and exit")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    families = [family for family, commands in FAMILIES.items() if command in commands] or list(FAMILIES)
    for family in families:
        importlib.import_module(f"{__name__}.{family}").register(sub)
    return p


#: Set by a command that has written and closed all it makes (``sarbot image``): the process that ran it as its
#: command may then end without the interpreter's teardown (``end_process``).
_nothing_left_to_close = False


def nothing_left_to_close() -> None:
    """Say that the command has written, flushed and closed every file it makes and left no thread running:
    the process may end at once after it (``end_process``)."""
    global _nothing_left_to_close
    _nothing_left_to_close = True


def end_process(code: int) -> int:
    """How a process whose command was :func:`main` ends (``python -m acquisition.cli``, the ``sarbot``
    launcher): at once where the command said it left nothing to close (:func:`nothing_left_to_close`) and
    no other thread runs, else by returning ``code`` for ``sys.exit``.

    At once means: the exit handlers run (``atexit``: logging's flush among them) and the standard streams
    are flushed, then ``os._exit``. What that skips is the interpreter's teardown, which frees the hundreds
    of thousands of objects numpy, h5py and numba made one by one: about 0.06-0.08 s of a loaded 2-core
    machine after a ``sarbot image`` whose files are closed already (benchmarks/image_command.py,
    ``command_stages_s.outside_command``). A stream that cannot be flushed (a closed pipe) ends the usual
    way, which reports it.
    """
    if not _nothing_left_to_close or threading.active_count() > 1:
        return code
    import atexit

    getattr(atexit, "_run_exitfuncs", lambda: None)()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return code
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    # Before anything imports numba: a choice list read from its module (autofocus methods) may import it.
    ensure_jit_cache_dir()
    argv = join_negative_values(sys.argv[1:] if argv is None else list(argv))
    with collector_paused():  # the command's modules live as long as the process (see start_up)
        args = build_parser(command_of(argv)).parse_args(argv)
    configure_logging(-1 if args.quiet else args.verbose)  # also every process the command starts (environment)
    return run_command(args.func, args)
