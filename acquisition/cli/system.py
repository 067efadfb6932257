"""``sarbot install-unit`` and ``completion``: sarbot on the robot as a service, and in the shell."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from .exit_codes import EXIT_OK


def register(sub) -> None:
    s = sub.add_parser("install-unit", help="install sarbot as a systemd service: user, venv under /opt, config, units",
                       description="Create the service user (systemd-sysusers), a virtual environment with sarbot, "
                                   "/etc/sarbot/{rig.toml,sarbot.env} (kept when present) and the systemd units, "
                                   "verified with systemd-analyze. Enables nothing: it prints the commands that do.",
                       epilog="example: sudo sarbot install-unit --command run --devices "
                              "'--radar left_front=192.168.33.30:4098 --imu-port /dev/ttyUSB0'")
    s.add_argument("--root", default="/", help="install under this folder instead of / (staging a package or image)")
    s.add_argument("--venv", default="/opt/sarbot/.venv", help="virtual environment on the robot (default /opt/sarbot/.venv)")
    s.add_argument("--user", default="sarbot", help="service user and group (default sarbot)")
    s.add_argument("--config", help="rig TOML to install as /etc/sarbot/rig.toml (default: the reference rig)")
    s.add_argument("--command", default="record", help="what the service runs: record or run (default record)")
    s.add_argument("--devices", default="", help="the robot's --radar/--imu-port/--can options, in quotes")
    s.add_argument("--source", help="what pip installs (default: this checkout, or this version of sarbot)")
    s.add_argument("--constraints", help="pip constraints file pinning the dependencies")
    s.add_argument("--no-deps", action="store_true", help="install sarbot alone (dependencies already there)")
    s.set_defaults(func=cmd_install_unit)

    s = sub.add_parser("completion", help="print a shell completion script: eval \"$(sarbot completion bash)\"",
                       epilog="bash: eval \"$(sarbot completion bash)\" in ~/.bashrc; zsh: sarbot completion zsh > "
                              "~/.zfunc/_sarbot (a folder on $fpath); fish: sarbot completion fish > "
                              "~/.config/fish/completions/sarbot.fish")
    s.add_argument("shell", choices=SHELLS, help="the shell")
    s.set_defaults(func=cmd_completion)


def cmd_install_unit(args) -> int:
    from ..install import InstallPlan, install_unit

    plan = InstallPlan(root=Path(args.root), venv=args.venv, user=args.user,
                       config=Path(args.config) if args.config else None, command=args.command, devices=args.devices,
                       source=args.source or "", constraints=Path(args.constraints) if args.constraints else None,
                       no_deps=args.no_deps)
    done = install_unit(plan)
    for kind, paths in done.items():
        for path in paths:
            print(f"{kind}: {path}")
    staged = Path(args.root) != Path("/")
    print(("staged under " + args.root + "; on the robot: " if staged else "installed; next: ")
          + "systemctl daemon-reload && systemctl enable --now sarbot.target"
          + " (edit /etc/sarbot/sarbot.env for this robot's devices first)")
    return EXIT_OK


#: Shells ``sarbot completion`` writes a script for (shtab generates each from the parser).
SHELLS = ("bash", "zsh", "fish")


def completion_script(parser: argparse.ArgumentParser, shell: str) -> str:
    """shtab's completion script for ``parser`` in ``shell``: commands, options, and the choices of each
    option (read from their sources, ``ChoicesFrom``), besides the names an argument ``completes`` to."""
    import shtab

    for action in _all_actions(parser):
        names = getattr(action, "completes", None)
        if names is not None:
            # printf one per line: zsh and fish take lines, bash's compgen -W words
            action.complete = shtab.cmd("printf '%s\\n' " + " ".join(shlex.quote(n) for n in names))
        elif action.choices is not None and not isinstance(action, argparse._SubParsersAction):
            action.choices = list(action.choices)  # ChoicesFrom read once, here
    return shtab.complete(parser, shell=shell).rstrip("\n") + "\n"  # ends its last line: can be appended to


def _all_actions(parser: argparse.ArgumentParser):
    for action in parser._actions:
        yield action
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _all_actions(sub)


def cmd_completion(args) -> int:
    from . import build_parser

    print(completion_script(build_parser(), args.shell), end="")
    return EXIT_OK
