"""The registry of radar wire formats: how each one's datagrams become frames, and frames datagrams.

A wire format is one module that defines a ``WireFormat`` and one line in ``BUILTIN`` (or, for a format
that lives outside sarbot, a call to ``register``). The daemon, replay and the command line look formats
up by name here; none of them branches on a format.

Everything a ``WireFormat`` holds is a module-level function, so a link (with its format) can be sent to
a driver process, which the daemon starts with the ``spawn`` method.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing
from typing import Any, Callable, Protocol

import numpy as np

from imaging.core.errors import ConfigError
from imaging.core.waveform import Waveform

from .stream import RadarStream

#: Name -> module defining ``WIRE_FORMAT``; imported on first use.
BUILTIN = {
    "SRF1": "drivers.radar.srf1",
    "DCA1000": "drivers.radar.dca1000",
}
#: What recordings that were never on a wire (simulations, imports) replay as: the reference radar's format.
DEFAULT = "SRF1"


class FrameEncoder(Protocol):
    """One frame to the datagrams that carry it (replay's side); may keep state across frames."""

    def __call__(self, frame_counter: int, frame_time_ns: int, iq: np.ndarray) -> list[bytes]: ...


class PackedDatagrams(typing.NamedTuple):
    """A frame's datagrams back to back in one buffer: each ``size`` bytes, the last one possibly shorter.
    That is what one send with UDP segmentation offload takes (``drivers.radar.udp.UdpSender``), so a
    frame of hundreds of datagrams costs a few system calls and no Python object per datagram."""

    data: np.ndarray  # uint8, the datagrams back to back
    size: int  # bytes of every datagram but the last

    @property
    def count(self) -> int:
        return -(-self.data.size // self.size) if self.size else 0

    def split(self) -> list[bytes]:
        """The datagrams one by one (what a ``FrameEncoder`` returns)."""
        return [self.data[o:o + self.size].tobytes() for o in range(0, self.data.size, self.size)]


class PackedFrameEncoder(Protocol):
    """A ``FrameEncoder`` that returns the frame's datagrams packed (byte for byte the same datagrams), valid
    until its next call. ``frame_key`` names a frame that may come again (a looped replay's frame index):
    an encoder may keep what it needs to encode that frame again for less."""

    def __call__(self, frame_counter: int, frame_time_ns: int, iq: np.ndarray, frame_key=None) -> PackedDatagrams: ...


def no_settings(options: dict[str, str], where: str) -> None:
    """``configure`` of a format that takes no options: any option is an error."""
    if options:
        raise ConfigError(f"{where}.{sorted(options)[0]}", "unknown option (this wire format takes none)")


def no_waveform(settings: Any) -> None:
    """``waveform`` of a format whose datagrams follow the rig's waveform."""
    return None


def no_controls(link: Any, settings: dict) -> list:
    """``controls`` of a format whose radars nobody brings up: they send once powered."""
    return []


@dataclasses.dataclass(frozen=True)
class WireFormat:
    """One wire format.

    Attributes
    ----------
    name : str
        As on the command line (``--radar NAME=PORT,format=NAME``) and in a recording's ``wire_format``.
    summary : str
        One line for ``--help``.
    open_stream : callable(waveform, settings, radar_id) -> RadarStream
        The receiving side, run in the radar's driver process.
    open_encoder : callable(radar_id) -> FrameEncoder
        The sending side, for replay and emulated hardware.
    open_packed_encoder : callable(radar_id) -> PackedFrameEncoder, optional
        The same datagrams packed in one buffer, for formats whose datagrams are all of one size but the
        last: replay sends them with few system calls. None: replay sends ``open_encoder``'s one by one.
    configure : callable(options, where) -> settings
        Checks a link's options (``{"cfg": "radar.cfg"}``) and turns them into settings (picklable) for
        ``open_stream`` and ``waveform``; raises ConfigError naming ``where`` and the option.
    waveform : callable(settings) -> Waveform or None
        The waveform the settings fix, for formats whose configuration says what the radar sends (a TI
        ``.cfg``); it replaces the rig's. None: the rig's waveform holds.
    options : tuple of str
        The option names ``configure`` takes (for help texts).
    control_options : dict of str to callable(text) -> dict
        The command-line options that bring this format's devices up (``--radar-cli``), each with the parser
        of one value given (``NAME=DEVICE``, the radar's name first) into settings for ``controls``; a
        ValueError saying what is wrong. Empty: the format has no device to bring up.
    controls : callable(link, settings) -> list
        The devices to bring up for ``link`` (a ``RadarLink``) once its driver listens, and down before it
        stops (objects as ``acquisition.devices.DeviceBringUp`` takes them), from the settings its
        ``control_options`` gave, merged.
    """

    name: str
    summary: str
    open_stream: Callable[[Waveform, Any, "int | None"], RadarStream]
    open_encoder: Callable[[int], FrameEncoder]
    configure: Callable[[dict, str], Any] = no_settings
    waveform: Callable[[Any], "Waveform | None"] = no_waveform
    options: tuple[str, ...] = ()
    control_options: dict[str, Callable[[str], dict]] = dataclasses.field(default_factory=dict, hash=False)
    controls: Callable[[Any, dict], list] = no_controls
    open_packed_encoder: "Callable[[int], PackedFrameEncoder] | None" = None


_registered: dict[str, WireFormat] = {}


def register(wire_format: WireFormat) -> WireFormat:
    """Make ``wire_format`` known by its name (replacing a format of the same name); returns it."""
    _registered[wire_format.name] = wire_format
    return wire_format


def names() -> list[str]:
    """Every known format, built in or registered."""
    return sorted(set(BUILTIN) | set(_registered))


def get(name: str, where: str = "wire_format") -> WireFormat:
    """The format called ``name``; ConfigError naming ``where`` and the known formats otherwise."""
    if name not in _registered and name in BUILTIN:
        register(importlib.import_module(BUILTIN[name]).WIRE_FORMAT)
    try:
        return _registered[name]
    except KeyError:
        raise ConfigError(where, f"{name!r} is not a known wire format (known: {', '.join(names())})") from None


def taking_control_option(option: str) -> list[str]:
    """The formats whose devices ``option`` brings up (e.g. ``--radar-cli``: DCA1000)."""
    return [name for name in names() if option in get(name).control_options]


def for_replay(recorded: str | None, where: str = "wire_format") -> WireFormat:
    """The format a recording replays in: the one it was recorded in, or the default for recordings that
    never were on a wire ("simulated", imported, or written before the attribute existed)."""
    if recorded in (None, "", "simulated", "imported"):
        return get(DEFAULT)
    return get(recorded, where)
