"""The DCA1000EVM's configuration protocol (UDP port 4096) and a client that arms it for recording.

Requests are ``u16 0xA55A | u16 command | u16 payload size | payload | u16 0xEEAA`` and replies
``u16 0xA55A | u16 command | u16 status | u16 0xEEAA``, little endian (TI SPRUIJ4A section 5, and TI's
``RF_API`` reference code; the same encodings as the ``xwr`` package's ``capture.types``). Status 0 is
success; the FPGA-version reply carries the version in its status: major in bits 0-6, minor in bits
7-13, bit 14 set in playback mode. The board answers from its own address (192.168.33.180 by default,
source port 1024 in the reference capture) to the host's configuration port.

Arming, as TI's DCA1000 CLI does it: system connection, FPGA version (refused in playback mode), FPGA
configuration (raw mode, LVDS lanes, LVDS capture, Ethernet stream, 16 bit), a wait until the FPGA answers
again, packet delay, start record. The radar starts after that (``ti_cli``), so the data stream begins
with the first frame at byte count 0.

Not the ``xwr`` package's client itself: it binds the data port too (taken here by the radar's driver
process), sends from and to the same port number (so a board and its emulator cannot share a host), has
no retries on a UDP protocol and checks replies with ``assert``.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import socket
import struct
import time

from imaging.core.errors import HardwareError

log = logging.getLogger(f"sarbot.{__name__}")

HEADER = 0xA55A
FOOTER = 0xEEAA
CONFIG_PORT = 4096
DEFAULT_ADDRESS = ("192.168.33.180", CONFIG_PORT)
MAX_PAYLOAD = 504
MAX_BYTES_PER_PACKET = 1470  # the FPGA's data datagram size limit, sent with the packet delay
FPGA_CLOCK_PERIOD_NS = 8
PACKET_DELAY_RANGE_US = (5.0, 500.0)  # SPRUIJ4A table 19


class Command(enum.IntEnum):
    RESET_FPGA = 0x01
    RESET_AR_DEV = 0x02
    CONFIG_FPGA_GEN = 0x03
    CONFIG_EEPROM = 0x04
    RECORD_START = 0x05
    RECORD_STOP = 0x06
    PLAYBACK_START = 0x07
    PLAYBACK_STOP = 0x08
    SYSTEM_CONNECTION = 0x09
    SYSTEM_ERROR_STATUS = 0x0A
    CONFIG_PACKET_DELAY = 0x0B
    CONFIG_DATA_MODE_AR_DEV = 0x0C
    INIT_FPGA_PLAYBACK = 0x0D
    READ_FPGA_VERSION = 0x0E


class ProtocolError(ValueError):
    pass


def encode_request(command: int, payload: bytes = b"") -> bytes:
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds the DCA1000's {MAX_PAYLOAD}")
    return struct.pack("<HHH", HEADER, command, len(payload)) + payload + struct.pack("<H", FOOTER)


def decode_request(data: bytes) -> tuple[int, bytes]:
    """(command, payload) of a request; ProtocolError saying what is wrong with it."""
    if len(data) < 8:
        raise ProtocolError(f"{len(data)} bytes: shorter than an empty request (8)")
    head, command, size = struct.unpack_from("<HHH", data)
    if head != HEADER:
        raise ProtocolError(f"header 0x{head:04x}, not 0x{HEADER:04x}")
    if len(data) != 8 + size:
        raise ProtocolError(f"payload size {size} but {len(data) - 8} payload bytes")
    if struct.unpack_from("<H", data, 6 + size)[0] != FOOTER:
        raise ProtocolError(f"footer 0x{struct.unpack_from('<H', data, 6 + size)[0]:04x}, not 0x{FOOTER:04x}")
    return command, bytes(data[6:6 + size])


def encode_response(command: int, status: int) -> bytes:
    return struct.pack("<HHHH", HEADER, command, status, FOOTER)


def decode_response(data: bytes) -> tuple[int, int]:
    """(command, status) of a reply; ProtocolError when it is not one."""
    if len(data) != 8:
        raise ProtocolError(f"{len(data)} bytes, a reply has 8")
    head, command, status, foot = struct.unpack("<HHHH", data)
    if head != HEADER or foot != FOOTER:
        raise ProtocolError(f"framing 0x{head:04x}...0x{foot:04x}, not 0x{HEADER:04x}...0x{FOOTER:04x}")
    return command, status


@dataclasses.dataclass(frozen=True)
class FpgaVersion:
    major: int
    minor: int
    playback: bool

    @classmethod
    def from_status(cls, status: int) -> "FpgaVersion":
        return cls(status & 0x7F, (status >> 7) & 0x7F, bool(status & 0x4000))

    def to_status(self) -> int:
        return (self.major & 0x7F) | (self.minor & 0x7F) << 7 | (0x4000 if self.playback else 0)

    def __str__(self) -> str:
        return f"{self.major}.{self.minor} ({'playback' if self.playback else 'record'} mode)"


@dataclasses.dataclass(frozen=True)
class FpgaConfig:
    """CONFIG_FPGA_GEN's six bytes. Only what a live Ethernet capture of raw 16-bit data needs is offered;
    the lane count is the radar's (2: xWR16xx/18xx/68xx, 4: xWR12xx/14xx)."""

    lvds_lanes: int = 2
    lvds_timeout: int = 30  # TI's CLI always sends 30 (its unit is not documented)

    def __post_init__(self) -> None:
        if self.lvds_lanes not in (2, 4):
            raise ValueError(f"lvds_lanes {self.lvds_lanes}: the DCA1000 takes 2 or 4 LVDS lanes")

    def payload(self) -> bytes:
        raw_mode, lvds_capture, ethernet_stream, bits_16 = 1, 1, 2, 3
        lanes = {4: 1, 2: 2}[self.lvds_lanes]
        return struct.pack("<6B", raw_mode, lanes, lvds_capture, ethernet_stream, bits_16, self.lvds_timeout)


def packet_delay_payload(delay_us: float) -> bytes:
    """CONFIG_PACKET_DELAY's payload: packet size, the delay in FPGA clock periods, and a reserved zero."""
    lo, hi = PACKET_DELAY_RANGE_US
    if not lo <= delay_us <= hi:
        raise ValueError(f"packet delay {delay_us} us: the DCA1000 takes {lo:g} to {hi:g} us")
    return struct.pack("<HHH", MAX_BYTES_PER_PACKET, int(delay_us * 1000 / FPGA_CLOCK_PERIOD_NS), 0)


class Dca1000Control:
    """The host side of the configuration protocol.

    Parameters
    ----------
    address : (host, port)
        The board's configuration address.
    bind : (host, port)
        Where replies come to: the board sends them to the host's port 4096 (its EEPROM setting), so
        that is the default; port 0 takes a free port, for a board (or emulator) that answers the sender.
    timeout_s, attempts : float, int
        Each request is sent up to ``attempts`` times, waiting ``timeout_s`` for its reply.
    """

    def __init__(self, address=DEFAULT_ADDRESS, bind=("0.0.0.0", CONFIG_PORT), timeout_s: float = 1.0, attempts: int = 3):
        self.address = (socket.gethostbyname(address[0]), int(address[1]))
        self.timeout_s = timeout_s
        self.attempts = attempts
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(bind)
        except OSError as exc:
            self.sock.close()
            raise HardwareError(f"DCA1000 {self.where}: cannot listen for its replies on UDP {bind[0]}:{bind[1]}: "
                                f"{exc.strerror}") from None
        self.transcript: list[tuple[bytes, bytes]] = []  # (request, reply) in order

    @property
    def where(self) -> str:
        return f"{self.address[0]}:{self.address[1]}"

    def close(self) -> None:
        self.sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def request(self, command: Command, payload: bytes = b"", attempts: int | None = None) -> int:
        """Send one request and return its reply's status; HardwareError when no reply comes."""
        data = encode_request(command, payload)
        for attempt in range(attempts or self.attempts):
            self.sock.sendto(data, self.address)
            deadline = time.monotonic() + self.timeout_s
            while (left := deadline - time.monotonic()) > 0:
                self.sock.settimeout(left)
                try:
                    reply, source = self.sock.recvfrom(2048)
                except (socket.timeout, ConnectionRefusedError):
                    break
                if source[0] != self.address[0]:
                    continue  # not the board
                try:
                    got, status = decode_response(reply)
                except ProtocolError as exc:
                    log.warning("DCA1000 %s: a reply that is none (%s): %s", self.where, exc, reply.hex())
                    continue
                if got != command:
                    log.debug("DCA1000 %s: late reply to 0x%02x ignored", self.where, got)
                    continue
                self.transcript.append((data, reply))
                log.debug("DCA1000 %s: %s -> status 0x%04x", self.where, command.name, status)
                return status
            log.debug("DCA1000 %s: no reply to %s (attempt %d)", self.where, command.name, attempt + 1)
        raise HardwareError(f"DCA1000 {self.where}: no reply to {command.name} after {attempts or self.attempts} "
                            f"attempt(s) of {self.timeout_s:g} s (is it powered, cabled, and this host on its subnet?)")

    def _expect_success(self, command: Command, payload: bytes = b"", step: str = "") -> None:
        status = self.request(command, payload)
        if status != 0:
            raise HardwareError(f"DCA1000 {self.where}: {step or command.name} failed (status {status})")

    def system_connection(self) -> None:
        self._expect_success(Command.SYSTEM_CONNECTION, step="system connection")

    def fpga_version(self) -> FpgaVersion:
        return FpgaVersion.from_status(self.request(Command.READ_FPGA_VERSION))

    def configure_fpga(self, config: FpgaConfig, ready_timeout_s: float = 5.0) -> None:
        self._expect_success(Command.CONFIG_FPGA_GEN, config.payload(), "FPGA configuration")
        # The FPGA ignores requests for a moment after being configured: ping until it answers.
        deadline = time.monotonic() + ready_timeout_s
        while True:
            try:
                self.request(Command.SYSTEM_CONNECTION, attempts=1)
                return
            except HardwareError:
                if time.monotonic() > deadline:
                    raise HardwareError(f"DCA1000 {self.where}: silent for {ready_timeout_s:g} s after its FPGA "
                                        "configuration") from None

    def configure_packet_delay(self, delay_us: float) -> None:
        self._expect_success(Command.CONFIG_PACKET_DELAY, packet_delay_payload(delay_us), "packet delay")

    def start_record(self) -> None:
        self._expect_success(Command.RECORD_START, step="start record")

    def stop_record(self) -> None:
        self._expect_success(Command.RECORD_STOP, step="stop record")

    def arm(self, config: FpgaConfig = FpgaConfig(), packet_delay_us: float = 25.0) -> FpgaVersion:
        """Everything before the radar starts: the board ready to stream; returns its FPGA version."""
        self.system_connection()
        version = self.fpga_version()
        if version.playback:
            raise HardwareError(f"DCA1000 {self.where}: FPGA {version}: it cannot record in playback mode "
                                "(set its switch to record and power-cycle it)")
        log.info("DCA1000 %s: FPGA %s", self.where, version)
        self.configure_fpga(config)
        self.configure_packet_delay(packet_delay_us)
        self.start_record()
        return version
