"""The exit codes of ``sarbot``, and which error ends a command with which (see docs/cli.md)."""

from __future__ import annotations

import sys

from imaging.core.errors import HardwareError, SarbotError

EXIT_OK = 0
EXIT_FAILED = 1  # the command ran and failed at its work (odometry that diverged)
EXIT_USAGE = 2  # bad input: arguments, files, configuration
EXIT_DISK_FULL = 3  # recording stopped: no space left; the file is readable up to its last flush
EXIT_HARDWARE = 4  # a device did not answer or refused its configuration (DCA1000, radar CLI)
EXIT_INTERRUPTED = 130


def run_command(func, args) -> int:
    """``func(args)``'s exit code; a user's mistake or a device's refusal as one ``sarbot: error:`` line and
    its code, never a traceback."""
    try:
        return func(args)
    except HardwareError as exc:  # a SarbotError too: caught first for its own code
        print(f"sarbot: error: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    except SarbotError as exc:
        print(f"sarbot: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("sarbot: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
