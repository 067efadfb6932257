"""Errors a user can cause and fix: each message names the problem and where it is."""


class SarbotError(Exception):
    """A user-facing error: bad input, a missing file, a value out of range.

    The command line prints ``str(error)`` on one line and exits with code 2; no traceback.
    """


class ConfigError(SarbotError, ValueError):
    """An invalid configuration value; ``field`` is its dotted path, e.g. ``radar.left.waveform.f0_hz``."""

    def __init__(self, field: str, message: str, source: str | None = None):
        self.field = field
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{field}: {message}")


class FileFormatError(SarbotError):
    """A file that cannot be read, or is not of the schema expected."""


class HardwareError(SarbotError):
    """A device that did not answer, or refused what it was sent (the DCA1000, a radar's CLI). The message
    names the device, the step and what came back; the command line exits with code 4."""
