"""A TI mmWave radar's command-line port (the demo firmware's UART CLI): send a ``.cfg`` line by line and
check that each is answered ``Done``.

The firmware echoes each line, answers (``Done``, ``Error ...``, ``... is not recognized as a CLI
command``, sometimes ``Ignored: ...``) and prints its prompt ``mmwDemo:/>``. Comment lines (``%``) and
blank lines of a ``.cfg`` are not sent. Not the ``xwr`` package's sender: that one sends ``%`` lines
(it takes ``#`` for comments), busy-waits on the port, and its errors do not say which line of the file
failed.
"""

from __future__ import annotations

import logging
import time

import serial

from imaging.core.errors import HardwareError

from .ti_cfg import cfg_commands

log = logging.getLogger(f"sarbot.{__name__}")

PROMPT = b"mmwDemo:/>"
START = "sensorStart"
STOP = "sensorStop"


class TiRadarCli:
    """One radar's CLI serial port.

    Parameters
    ----------
    port : str
        Device (``/dev/ttyACM0``; the lower-numbered of the two an XDS110 board shows).
    baudrate : int
        115200 on TI's demo firmware.
    timeout_s : float
        How long a command may take to be answered (``sensorStart`` takes longest: about a second).
    """

    def __init__(self, port: str, baudrate: int = 115200, timeout_s: float = 5.0):
        self.port_name = port
        self.timeout_s = timeout_s
        try:
            self.port = serial.Serial(port, baudrate, timeout=0.05)
        except (serial.SerialException, OSError) as exc:
            raise HardwareError(f"radar CLI {port}: cannot open it: {exc}") from None
        self.port.reset_input_buffer()
        self.sent: list[tuple[str, str]] = []  # (command, answer) in order

    def close(self) -> None:
        self.port.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def send(self, command: str, where: str = "") -> str:
        """Send one command and return the radar's answer (echo and prompt removed); HardwareError when it
        is not ``Done`` (``Ignored: ...`` is logged and accepted: the firmware skips what does not apply)."""
        self.port.write(command.encode("ascii") + b"\n")
        buf = bytearray()
        deadline = time.monotonic() + self.timeout_s
        while not buf.rstrip().endswith(PROMPT):
            if time.monotonic() > deadline:
                raise HardwareError(f"radar CLI {self.port_name}{where}: no answer to {command!r} within {self.timeout_s:g} s"
                                    + (f" (got {bytes(buf)!r})" if buf else " (is the demo firmware running?)"))
            buf += self.port.read(max(1, self.port.in_waiting))
        text = buf.decode("ascii", "replace").replace(PROMPT.decode(), "")
        lines = [ln.strip() for ln in text.replace("\r", "\n").split("\n") if ln.strip()]
        if lines and lines[0] == command:
            lines = lines[1:]  # the echo
        answer = " / ".join(lines)
        self.sent.append((command, answer))
        if answer == "Done" or (lines and lines[-1] == "Done"):
            return answer
        if answer.startswith("Ignored"):
            log.warning("radar CLI %s%s: %r: %s", self.port_name, where, command, answer)
            return answer
        raise HardwareError(f"radar CLI {self.port_name}{where}: {command!r} answered {answer!r}")

    def configure(self, text: str, source: str = "<cfg>") -> int:
        """Send a ``.cfg`` (without its ``sensorStart``: :meth:`start` comes once the capture is armed);
        returns the number of commands sent. An error names the file and line."""
        n = 0
        for lineno, command in cfg_commands(text):
            if command.split()[0] == START:
                continue
            self.send(command, f" ({source} line {lineno})")
            n += 1
        return n

    def start(self) -> None:
        self.send(START)

    def stop(self) -> None:
        self.send(STOP)
