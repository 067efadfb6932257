"""systemd's notification protocol (sd_notify) without libsystemd: a datagram to $NOTIFY_SOCKET; and what
else the daemon learns of its unit from its environment."""

from __future__ import annotations

import os
import socket


def notify(state: str) -> bool:
    """Send ``state`` (e.g. "READY=1", "WATCHDOG=1", "STATUS=...") if run under systemd; True if sent."""
    address = os.environ.get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):
        address = "\0" + address[1:]  # abstract namespace
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        try:
            sock.sendto(state.encode(), address)
        except OSError:
            return False
    return True


def watchdog_interval_s() -> float | None:
    """Half of the watchdog timeout systemd asked for (WATCHDOG_USEC), or None when there is none."""
    usec = os.environ.get("WATCHDOG_USEC")
    pid = os.environ.get("WATCHDOG_PID")
    if not usec or (pid and int(pid) != os.getpid()):
        return None
    return int(usec) / 2e6


#: The unit's ``TimeoutStopSec`` in seconds, as the unit passes it on (systemd itself tells a service nothing of
#: its stop timeout): ``systemd/sarbot-record.service`` sets it beside ``TimeoutStopSec``.
UNIT_STOP_TIMEOUT_ENV = "SARBOT_TIMEOUT_STOP_S"


def unit_stop_timeout_s() -> float | None:
    """How long the unit gives the daemon to stop before systemd kills it (``SARBOT_TIMEOUT_STOP_S``, s; "infinity"
    as systemd spells it), or None where the daemon is not told (not under the unit). ValueError naming the
    variable for a value that is no positive number of seconds."""
    text = os.environ.get(UNIT_STOP_TIMEOUT_ENV, "").strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{UNIT_STOP_TIMEOUT_ENV}={text!r}: not a number of seconds") from None
    if not value > 0:
        raise ValueError(f"{UNIT_STOP_TIMEOUT_ENV}={text!r}: not a positive number of seconds")
    return value
