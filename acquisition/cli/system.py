"""``sarbot install-unit`` and ``completion``: sarbot on the robot as a service, and in the shell."""

from __future__ import annotations

import argparse
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

    s = sub.add_parser("completion", help="print a shell completion script: eval \"$(sarbot completion bash)\"")
    s.add_argument("shell", choices=list(COMPLETIONS), help="the shell (bash; zsh runs it with bashcompinit)")
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


def bash_completion(parser: argparse.ArgumentParser) -> str:
    """A bash completion script for ``parser``: the commands, and each command's options."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    top = [o for a in parser._actions for o in a.option_strings]
    cases = []
    for name, p in sub.choices.items():
        options = " ".join(o for a in p._actions for o in a.option_strings)
        cases.append(f'        {name}) opts="{options}" ;;')
    return "\n".join([
        "# bash completion for sarbot: eval \"$(sarbot completion bash)\" (e.g. in ~/.bashrc)",
        "_sarbot() {",
        '    local cur="${COMP_WORDS[COMP_CWORD]}" cmd="" opts="" w',
        '    for w in "${COMP_WORDS[@]:1:COMP_CWORD-1}"; do case "$w" in -*) ;; *) cmd="$w"; break ;; esac; done',
        '    if [ -z "$cmd" ]; then',
        f'        COMPREPLY=($(compgen -W "{" ".join(sub.choices)} {" ".join(top)}" -- "$cur")); return',
        "    fi",
        '    case "$cmd" in',
        *cases,
        "    esac",
        '    if [[ "$cur" == -* ]]; then COMPREPLY=($(compgen -W "$opts" -- "$cur")); else COMPREPLY=($(compgen -f -- "$cur")); fi',
        "}",
        "complete -o filenames -F _sarbot sarbot",
        ""])


#: Shell -> its completion script for a parser.
COMPLETIONS = {"bash": bash_completion}


def cmd_completion(args) -> int:
    from . import build_parser

    print(COMPLETIONS[args.shell](build_parser()), end="")
    return EXIT_OK
