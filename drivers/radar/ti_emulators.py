"""A TI radar and its DCA1000EVM, emulated at the wire level for tests and demos: the DCA1000's
configuration protocol on UDP, the radar's CLI on a pseudo-terminal, and the raw data stream on UDP once
the board records and the radar has been started. ``sarbot record`` cannot tell them from the hardware.
"""

from __future__ import annotations

import logging
import os
import socket
import struct
import threading
import time
import tty
from typing import Callable

import numpy as np

from ..emulators import close_fds
from .dca1000 import Dca1000Encoder
from .dca1000_control import (
    PACKET_DELAY_RANGE_US,
    Command,
    FpgaVersion,
    ProtocolError,
    decode_request,
    encode_response,
)
from .ti_cfg import TiRadarConfig, parse_ti_cfg

log = logging.getLogger(f"sarbot.{__name__}")

SUCCESS, FAILURE = 0, 1


class Dca1000Emulator:
    """A DCA1000EVM: answers configuration requests (to their sender) and streams frames while it records
    and its radar runs.

    Parameters
    ----------
    frame : callable(k) -> ndarray or None
        Frame k as int16 (I, Q) [chirps, n_rx, samples, 2]; None ends the data.
    data_target : (host, port)
        Where the data stream goes (the host's data port, in the real board's EEPROM).
    config_bind : (host, port)
        The board's configuration address; port 0 takes a free one (``address`` tells).
    version : FpgaVersion
        What READ_FPGA_VERSION answers (2.8 in record mode, as the reference capture).
    busy_after_config_s : float
        How long the FPGA ignores requests after CONFIG_FPGA_GEN, as the real one does.
    speed : float
        Multiple of real time for the frame period of the radar's configuration.
    refuse : set of int
        Commands answered with status 1 (failure), for tests of a board that will not.
    lose : int
        How many requests to lose (no answer) from now on, as a lossy link would.
    """

    def __init__(self, frame: Callable[[int], "np.ndarray | None"], data_target, config_bind=("127.0.0.1", 0),
                 version: FpgaVersion = FpgaVersion(2, 8, False), busy_after_config_s: float = 0.2, speed: float = 1.0,
                 refuse=(), lose: int = 0):
        self.frame = frame
        self.refuse = set(refuse)
        self.lose = lose
        self.data_target = data_target
        self.version = version
        self.busy_after_config_s = busy_after_config_s
        self.speed = speed
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(config_bind)
        self.sock.settimeout(0.05)
        self.address = self.sock.getsockname()
        self.data_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data_sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
        self.transcript: list[tuple[bytes, bytes | None]] = []  # (request, reply or None when unanswered)
        self.recording = False
        self.fpga_configured = False
        self.packet_delay_us: float | None = None
        self.radar_cfg: TiRadarConfig | None = None
        self.frames_sent = 0
        self.datagrams_sent = 0
        self._busy_until = 0.0
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._threads = [threading.Thread(target=self._serve, daemon=True), threading.Thread(target=self._stream, daemon=True)]

    def start(self) -> "Dca1000Emulator":
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        self._closed.set()
        for t in self._threads:
            t.join(timeout=5)
        self.sock.close()
        self.data_sock.close()

    # -- the radar's side (called by its CLI) ------------------------------------------------------
    def radar_started(self, cfg: TiRadarConfig) -> None:
        with self._lock:
            self.radar_cfg = cfg

    def radar_stopped(self) -> None:
        with self._lock:
            self.radar_cfg = None

    # -- configuration ------------------------------------------------------------------------------
    def _answer(self, command: int, payload: bytes) -> int:
        if command in self.refuse:
            return FAILURE
        if command == Command.CONFIG_FPGA_GEN:
            if len(payload) != 6 or payload[1] not in (1, 2) or payload[4] not in (1, 2, 3):
                return FAILURE
            self.fpga_configured = True
            self._busy_until = time.monotonic() + self.busy_after_config_s
        elif command == Command.CONFIG_PACKET_DELAY:
            if len(payload) != 6:
                return FAILURE
            delay_us = struct.unpack_from("<H", payload, 2)[0] * 8 / 1000
            if not PACKET_DELAY_RANGE_US[0] <= delay_us <= PACKET_DELAY_RANGE_US[1] + 0.01:
                return FAILURE
            self.packet_delay_us = delay_us
        elif command == Command.RECORD_START:
            # The real board says success even unconfigured (the reference exchange starts a record so).
            with self._lock:
                self.recording = True
        elif command == Command.RECORD_STOP:
            with self._lock:
                self.recording = False
        elif command == Command.READ_FPGA_VERSION:
            return self.version.to_status()
        elif command not in set(Command):
            return FAILURE
        return SUCCESS

    def _serve(self) -> None:
        while not self._closed.is_set():
            try:
                data, source = self.sock.recvfrom(2048)
            except socket.timeout:
                continue
            except OSError:
                return
            try:
                command, payload = decode_request(data)
            except ProtocolError as exc:
                log.debug("DCA1000 emulator: ignored a malformed request (%s)", exc)
                self.transcript.append((data, None))
                continue
            if time.monotonic() < self._busy_until or self.lose > 0:
                self.lose = max(self.lose - 1, 0) if time.monotonic() >= self._busy_until else self.lose
                self.transcript.append((data, None))
                continue
            reply = encode_response(command, self._answer(command, payload))
            self.transcript.append((data, reply))
            self.sock.sendto(reply, source)

    # -- data -----------------------------------------------------------------------------------------
    def _stream(self) -> None:
        encoder, k, next_t = None, 0, 0.0
        while not self._closed.is_set():
            with self._lock:
                cfg = self.radar_cfg if self.recording else None
            if cfg is None:
                encoder = None  # a new record starts its byte count at zero
                time.sleep(0.005)
                continue
            if encoder is None:
                encoder, next_t = Dca1000Encoder(cfg.iq_swap), time.monotonic()
            wait = next_t - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, 0.01))
                continue
            iq = self.frame(k)
            if iq is None:
                time.sleep(0.01)
                continue
            for d in encoder(k, 0, iq):
                self.data_sock.sendto(d, self.data_target)
                self.datagrams_sent += 1
            k += 1
            self.frames_sent = k
            next_t += cfg.frame_periodicity_ms * 1e-3 / self.speed


#: Arguments each command of the xWR18xx demo CLI needs at least (SDK 3.x); others are unknown.
CLI_COMMANDS = {
    "sensorStop": 0, "sensorStart": 0, "flushCfg": 0, "dfeDataOutputMode": 1, "channelCfg": 3, "adcCfg": 2,
    "adcbufCfg": 5, "profileCfg": 14, "chirpCfg": 8, "frameCfg": 7, "advFrameCfg": 0, "lowPower": 2,
    "guiMonitor": 7, "cfarCfg": 9, "multiObjBeamForming": 3, "clutterRemoval": 2, "calibDcRangeSig": 5,
    "extendedMaxVelocity": 2, "lvdsStreamCfg": 4, "compRangeBiasAndRxChanPhase": 17,
    "measureRangeBiasAndRxChanPhase": 3, "CQRxSatMonitor": 5, "CQSigImgMonitor": 3, "analogMonitor": 2,
    "aoaFovCfg": 5, "cfarFovCfg": 4, "calibData": 3, "bpmCfg": 4,
}
PROMPT = b"mmwDemo:/>"


class TiRadarCliPty:
    """A TI radar's demo-firmware CLI on a pseudo-terminal (``port`` is the device to open).

    It echoes each line and answers ``Done``, ``'x' is not recognized as a CLI command`` or ``Error``
    as the firmware does; ``sensorStart`` checks the configuration sent since ``flushCfg`` and starts the
    radar (``on_start(cfg)``). ``refuse`` maps a command word to the answer that refuses it, for tests of
    a radar that will not take its configuration.
    """

    def __init__(self, on_start: Callable[[TiRadarConfig], None] | None = None, on_stop: Callable[[], None] | None = None,
                 refuse: dict[str, str] | None = None):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.on_start, self.on_stop = on_start, on_stop
        self.refuse = dict(refuse or {})
        self.received: list[str] = []
        self.config_lines: list[str] = []
        self.running = False
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> "TiRadarCliPty":
        self._thread.start()
        return self

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=5)
        close_fds(self.master, self.slave)

    def answer(self, line: str) -> str:
        word, *args = line.split()
        if word in self.refuse:
            return self.refuse[word]
        if word not in CLI_COMMANDS:
            return f"'{word}' is not recognized as a CLI command"
        if len(args) < CLI_COMMANDS[word]:
            return "Error: Invalid usage of the CLI command"
        if word == "flushCfg":
            self.config_lines = []
        elif word == "sensorStop":
            if self.running and self.on_stop:
                self.on_stop()
            self.running = False
        elif word == "sensorStart":
            try:
                cfg = parse_ti_cfg("\n".join(self.config_lines), "radar")
            except ValueError as exc:
                return f"Error -1 ({exc})"
            if self.on_start:
                self.on_start(cfg)
            self.running = True
        else:
            self.config_lines.append(line)
        return "Done"

    def _run(self) -> None:
        import select

        buf = b""
        while not self._closed.is_set():
            if not select.select([self.master], [], [], 0.05)[0]:
                continue
            try:
                buf += os.read(self.master, 4096)
            except OSError:
                return
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                line = raw.decode("ascii", "replace").strip()
                if not line:
                    continue
                self.received.append(line)
                os.write(self.master, raw.rstrip(b"\r") + b"\r\n" + self.answer(line).encode() + b"\r\n" + PROMPT)
