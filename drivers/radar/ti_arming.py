"""Bring a TI radar and its DCA1000EVM up for a recording and down after it, in the order TI's tools use:
the radar's ``.cfg`` over its CLI (without ``sensorStart``), the DCA1000 armed and recording, then
``sensorStart``; at the end ``sensorStop``, then the DCA1000's record stop. Either device may be left to
the user (a DCA1000 armed by mmWave Studio, a radar started by its own flash configuration).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from imaging.core.errors import HardwareError

from .dca1000_control import (
    CONFIG_PORT,
    DEFAULT_ADDRESS,
    Dca1000Control,
    FpgaConfig,
    packet_delay_payload,
)
from .ti_cli import TiRadarCli

log = logging.getLogger(f"sarbot.{__name__}")


@dataclasses.dataclass(frozen=True)
class TiRadarControl:
    """What ``sarbot record`` drives for one DCA1000 radar (picklable settings; :meth:`open` does I/O)."""

    radar: str
    cfg_path: str
    data_port: int
    dca_address: tuple[str, int] | None = None  # None: the DCA1000 is not armed by sarbot
    dca_listen: tuple[str, int] = ("0.0.0.0", CONFIG_PORT)
    cli_port: str | None = None  # None: the radar is not configured by sarbot
    lvds_lanes: int = 2
    packet_delay_us: float = 25.0
    timeout_s: float = 1.0

    def open(self) -> "ArmedRadar":
        return ArmedRadar(self)


class ArmedRadar:
    def __init__(self, control: TiRadarControl):
        self.control = control
        self.dca_armed: str | None = None  # the board's address once it records
        self.cli: TiRadarCli | None = None
        self.started = False

    def _board(self) -> Dca1000Control:
        c = self.control
        return Dca1000Control(c.dca_address, c.dca_listen, timeout_s=c.timeout_s)

    def arm(self) -> str:
        """Configure, arm and start; returns what was done, for the log and the recording's events."""
        c = self.control
        done = []
        if c.cli_port:
            self.cli = TiRadarCli(c.cli_port)
            n = self.cli.configure(Path(c.cfg_path).read_text(errors="replace"), c.cfg_path)
            done.append(f"radar configured from {c.cfg_path} on {c.cli_port} ({n} commands, each Done)")
        if c.dca_address:
            # The reply port is held only while talking: every board of a rig answers on the host's port 4096.
            with self._board() as dca:
                version = dca.arm(FpgaConfig(c.lvds_lanes), c.packet_delay_us)
                self.dca_armed = dca.where
            done.append(f"DCA1000 {self.dca_armed} (FPGA {version}) recording, {c.lvds_lanes} LVDS lanes, "
                        f"packet delay {c.packet_delay_us:g} us")
        if self.cli:
            self.cli.start()
            self.started = True
            done.append("sensorStart Done")
        return "; ".join(done)

    def disarm(self) -> list[str]:
        """Stop the radar, then the DCA1000; returns what failed (the recording is closed either way)."""
        problems = []
        if self.cli:
            try:
                if self.started:
                    self.cli.stop()
            except HardwareError as exc:
                problems.append(str(exc))
            self.cli.close()
        if self.dca_armed:
            try:
                with self._board() as dca:
                    dca.stop_record()
            except HardwareError as exc:
                problems.append(str(exc))
            self.dca_armed = None
        return problems


def parse_arm_option(text: str) -> tuple[str, dict]:
    """``--dca1000-arm NAME[=HOST[:PORT]][,listen=[HOST:]PORT][,lanes=2|4][,delay_us=US]`` -> (name,
    TiRadarControl keyword arguments); ValueError saying what is wrong."""
    usage = "expected NAME[=HOST[:PORT]][,listen=[HOST:]PORT][,lanes=2|4][,delay_us=US]"
    head, *opts = text.split(",")
    name, _, where = head.partition("=")
    if not name:
        raise ValueError(usage)
    host, _, port = where.partition(":")
    try:
        kwargs: dict = {"dca_address": (host or DEFAULT_ADDRESS[0], int(port) if port else DEFAULT_ADDRESS[1])}
        for opt in opts:
            key, sep, value = opt.partition("=")
            if key == "listen" and sep:
                lhost, _, lport = value.rpartition(":")
                kwargs["dca_listen"] = (lhost or "0.0.0.0", int(lport))
            elif key == "lanes" and sep:
                kwargs["lvds_lanes"] = int(value)
            elif key == "delay_us" and sep:
                kwargs["packet_delay_us"] = float(value)
            else:
                raise ValueError(f"{opt!r}: {usage}")
    except ValueError as exc:
        raise ValueError(str(exc) if usage in str(exc) else usage) from None
    FpgaConfig(kwargs.get("lvds_lanes", 2))  # the lane count and the delay's range are checked before anything starts
    packet_delay_payload(kwargs.get("packet_delay_us", 25.0))
    for port_number in (kwargs["dca_address"][1], kwargs.get("dca_listen", ("", 0))[1]):
        if not 0 <= port_number < 65536:
            raise ValueError(f"port {port_number} is not in 0..65535")
    return name, kwargs
