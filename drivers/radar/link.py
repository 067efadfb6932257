"""A radar link: where a radar's datagrams arrive, from whom, and in which wire format.

On the command line a link is ``NAME=[HOST:]PORT[,format=FORMAT][,source=ADDRESS][,id=RADAR_ID][,stamps=MODE][,OPTION=VALUE...]``:
``left=50001`` (SRF1 on loopback), ``left=192.168.1.10:50001,source=192.168.1.20,id=3`` (listen on the robot's
network, take datagrams only from the radar's address and with its id), ``iwr=4098,format=DCA1000,cfg=xwr18xx.cfg``.
``stamps`` chooses the receive time stamps: ``auto`` (the network card's where it can, else the kernel's),
``hardware`` or ``software`` (``drivers.radar.timestamping``).
The format's own options are checked by the format (``drivers.radar.registry``).
"""

from __future__ import annotations

import dataclasses
import ipaddress
from typing import Any

from imaging.core.errors import ConfigError, SarbotError
from imaging.core.waveform import Waveform

from . import registry
from .registry import WireFormat
from .stream import RadarStream
from .timestamping import MODES

#: Where a radar link listens unless told otherwise: nothing off this machine reaches it.
DEFAULT_HOST = "127.0.0.1"


@dataclasses.dataclass(frozen=True)
class RadarLink:
    """One radar's link. ``options`` are the wire format's (e.g. ``{"cfg": "radar.cfg"}`` for DCA1000);
    they are checked on construction and kept as the format's ``settings``."""

    name: str
    port: int
    host: str = DEFAULT_HOST
    wire_format: str = registry.DEFAULT
    options: dict = dataclasses.field(default_factory=dict)
    source: str | None = None  # the only sender address accepted (None: any)
    radar_id: int | None = None  # the only radar id accepted, for formats that carry one (None: any)
    receive_stamps: str = "auto"  # auto, hardware or software (drivers.radar.timestamping)
    format: WireFormat = dataclasses.field(init=False, repr=False, compare=False)
    settings: Any = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        where = f"radar.{self.name}"
        # Port 0: one the system picks when the driver binds, published by the daemon (``Setup.bound_ports``),
        # for programs that start both ends (the demo); a user names the port the radar sends to.
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port < 65536:
            raise ConfigError(f"{where}.port", f"{self.port!r} is not a UDP port (1-65535)")
        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            raise ConfigError(f"{where}.host", f"{self.host!r} is not an IP address") from None
        if self.source is not None:
            try:
                ipaddress.ip_address(self.source)
            except ValueError:
                raise ConfigError(f"{where}.source", f"{self.source!r} is not an IP address") from None
        if self.radar_id is not None and not 0 <= self.radar_id < 1 << 16:
            raise ConfigError(f"{where}.id", f"{self.radar_id} is not a radar id (0-65535)")
        if self.receive_stamps not in MODES:
            raise ConfigError(f"{where}.stamps", f"{self.receive_stamps!r} is not one of {', '.join(MODES)}")
        fmt = registry.get(self.wire_format, f"{where}.format")
        object.__setattr__(self, "format", fmt)
        object.__setattr__(self, "settings", fmt.configure(dict(self.options), where))

    def waveform(self, rig_waveform: Waveform) -> Waveform:
        """What the radar sends: fixed by the format's settings where they say (a TI .cfg), else the rig's."""
        return self.format.waveform(self.settings) or rig_waveform

    def open_stream(self, waveform: Waveform) -> RadarStream:
        return self.format.open_stream(waveform, self.settings, self.radar_id)


def parse_radar_link(text: str, option: str = "--radar", receive_stamps: str = "auto") -> RadarLink:
    """A link from ``NAME=[HOST:]PORT[,format=FORMAT][,OPTION=VALUE...]``; SarbotError naming the option
    and the part that is wrong. ``receive_stamps``: the link's unless it says ``stamps=``."""
    where = f"{option} {text!r}"
    name, sep, rest = text.partition("=")
    if not sep or not name.strip():
        raise SarbotError(f"{where}: expected NAME=[HOST:]PORT[,format=FORMAT][,OPTION=VALUE...]")
    address, *extras = rest.split(",")
    host, port_text = DEFAULT_HOST, address
    if address.startswith("["):  # [IPv6]:PORT
        host, _, port_text = address[1:].partition("]:")
    elif ":" in address:
        host, port_text = address.rsplit(":", 1)
    if not port_text.isdigit() or int(port_text) == 0:
        raise SarbotError(f"{where}: {port_text!r} is not a port number (1-65535)")
    options = {}
    for extra in extras:
        key, sep, value = extra.partition("=")
        if not sep or not key:
            raise SarbotError(f"{where}: {extra!r} is not OPTION=VALUE")
        options[key.strip()] = value.strip()
    wire_format = options.pop("format", registry.DEFAULT)
    source = options.pop("source", None)
    radar_id = options.pop("id", None)
    receive_stamps = options.pop("stamps", receive_stamps)
    if radar_id is not None and not radar_id.isdigit():
        raise SarbotError(f"{where}: id {radar_id!r} is not a radar id (0-65535)")
    try:
        return RadarLink(name.strip(), int(port_text), host or DEFAULT_HOST, wire_format, options, source,
                         None if radar_id is None else int(radar_id), receive_stamps)
    except ConfigError as exc:
        raise SarbotError(f"{where}: {exc}") from None
