"""Arming a TI radar and its DCA1000EVM: the configuration protocol against the reference exchange, the
radar CLI on a pty, and ``sarbot record --dca1000-arm --radar-cli`` end to end against both emulators."""

from __future__ import annotations

import functools
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA
from test_ti_capture import iwr1843_cfg, iwr1843_words

from drivers.radar.dca1000 import complex_1x_to_iq
from drivers.radar.dca1000_control import (
    Command,
    Dca1000Control,
    FpgaConfig,
    FpgaVersion,
    ProtocolError,
    decode_request,
    decode_response,
    encode_request,
    packet_delay_payload,
)
from drivers.radar.pcap import read_udp
from drivers.radar.ti_cfg import cfg_commands
from drivers.radar.ti_cli import TiRadarCli
from drivers.radar.ti_emulators import Dca1000Emulator, TiRadarCliPty
from imaging.core.errors import HardwareError
from imaging.io.recording import Recording

ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def reference() -> list[bytes]:
    """The board's replies in the reference exchange, in capture order."""
    return [d.payload for d in read_udp(SHARED_DATA / "dca1000_iwr1843_one_frame" / "config_commands.pcap")]


def reference_reply(command: int) -> bytes:
    return next(r for r in reference() if decode_response(r)[0] == command)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def board():
    em = Dca1000Emulator(lambda k: None, ("127.0.0.1", free_udp_port()), busy_after_config_s=0.15).start()
    yield em
    em.close()


def test_requests_are_framed_as_the_user_guide_says():
    # SPRUIJ4A table 13: 0xA55A, command, payload size, payload, 0xEEAA, little endian.
    assert encode_request(Command.SYSTEM_CONNECTION).hex() == "5aa509000000aaee"
    assert encode_request(Command.CONFIG_FPGA_GEN, FpgaConfig().payload()).hex() == "5aa50300060001020102031eaaee"
    assert FpgaConfig(lvds_lanes=4).payload().hex() == "0101010203" + "1e"
    # 1470-byte packets, 25 us = 3125 periods of the 125 MHz FPGA clock, reserved 0.
    assert encode_request(Command.CONFIG_PACKET_DELAY, packet_delay_payload(25)).hex() == "5aa50b000600be05350c0000aaee"
    assert decode_request(bytes.fromhex("5aa50b000600be05350c0000aaee")) == (0x0B, bytes.fromhex("be05350c0000"))
    for bad, why in (("5aa50900", "shorter"), ("a55a09000000aaee", "header"), ("5aa509000100aaee", "payload size"),
                     ("5aa5090000000000", "footer")):
        with pytest.raises(ProtocolError, match=why):
            decode_request(bytes.fromhex(bad))
    with pytest.raises(ValueError, match="5 to 500 us"):
        packet_delay_payload(2)


def test_encodings_agree_with_the_xwr_package():
    from xwr.capture import types

    for command, payload in ((Command.SYSTEM_CONNECTION, b""), (Command.CONFIG_FPGA_GEN, FpgaConfig().payload()),
                             (Command.CONFIG_PACKET_DELAY, packet_delay_payload(5.0)), (Command.RECORD_START, b"")):
        assert encode_request(command, payload) == types.Request(types.Command(int(command)), payload).to_bytes()
    reply = types.Response.from_bytes(reference_reply(Command.READ_FPGA_VERSION))
    assert FpgaVersion.from_status(reply.status) == FpgaVersion(2, 8, False)


def test_the_emulator_answers_the_reference_exchange_byte_for_byte(board):
    """The reference capture holds the board's answers to each command once, in code order."""
    commands = [decode_response(r)[0] for r in reference()]
    assert commands == [0x01, 0x02, 0x05, 0x06, 0x0B, 0x03, 0x04, 0x09, 0x0A, 0x0E]
    payloads = {0x0B: packet_delay_payload(25), 0x03: FpgaConfig().payload(), 0x04: bytes(18)}
    with Dca1000Control(board.address, ("127.0.0.1", 0), timeout_s=0.05, attempts=10) as dca:
        for command in commands:
            dca.request(Command(command), payloads.get(command, b""))
            if command == 0x03:
                time.sleep(0.2)  # the FPGA is deaf for a moment after its configuration
    assert [reply for _, reply in dca.transcript] == reference()


def test_arming_sequence_and_every_answer_match_the_reference(board):
    with Dca1000Control(board.address, ("127.0.0.1", 0), timeout_s=0.05) as dca:
        version = dca.arm(FpgaConfig(), 25.0)
        dca.stop_record()
    assert version == FpgaVersion(2, 8, False) and str(version) == "2.8 (record mode)"
    sent = [decode_request(q)[0] for q, _ in dca.transcript]
    # system connection, version, FPGA config, pings until it answers again, packet delay, start; then stop.
    assert sent[:3] == [0x09, 0x0E, 0x03] and sent[-3:] == [0x0B, 0x05, 0x06] and set(sent[3:-3]) == {0x09}
    for request, reply in dca.transcript:
        assert reply == reference_reply(decode_request(request)[0])
    assert [decode_request(q)[0] for q, a in board.transcript if a is None]  # pings the deaf FPGA did not answer
    assert board.packet_delay_us == pytest.approx(25.0) and not board.recording


def test_xwr_client_arms_the_emulated_board():
    """An independent implementation of the protocol (the xwr package) drives the emulator."""
    from xwr.capture.api import DCA1000EVM

    em = Dca1000Emulator(lambda k: None, ("127.0.0.1", free_udp_port()), config_bind=("127.0.0.2", 0)).start()
    try:
        # xwr sends from and to the same port number, so the board sits on another loopback address.
        dca = DCA1000EVM(sys_ip="127.0.0.1", fpga_ip="127.0.0.2", config_port=em.address[1], data_port=0, timeout=0.1)
        dca.setup(delay=5.0)
        dca.start()
        assert em.recording and em.packet_delay_us == pytest.approx(5.0)
        dca.stop()
        assert not em.recording
    finally:
        em.close()


def test_lost_requests_are_sent_again_and_a_refusal_is_an_error(board):
    board.lose = 2
    with Dca1000Control(board.address, ("127.0.0.1", 0), timeout_s=0.05, attempts=3) as dca:
        dca.system_connection()
        assert len(dca.transcript) == 1
        board.refuse = {Command.RECORD_START}
        with pytest.raises(HardwareError, match=r"DCA1000 127\.0\.0\.1:\d+: start record failed \(status 1\)"):
            dca.start_record()
        board.version = FpgaVersion(2, 8, True)
        with pytest.raises(HardwareError, match="playback mode"):
            dca.arm()


def test_two_boards_answer_on_one_host_port():
    """Every DCA1000 of a rig replies to the host's port 4096: arming them one after the other shares it."""
    from drivers.radar.ti_arming import TiRadarControl

    boards = [Dca1000Emulator(lambda k: None, ("127.0.0.1", free_udp_port()), busy_after_config_s=0.05).start()
              for _ in range(2)]
    port = free_udp_port()
    try:
        armed = [TiRadarControl(f"r{k}", "unused.cfg", 0, dca_address=b.address, dca_listen=("127.0.0.1", port),
                                timeout_s=0.05).open() for k, b in enumerate(boards)]
        for a in armed:
            assert "recording" in a.arm()
        assert all(b.recording for b in boards)
        for a in armed:
            assert a.disarm() == []
        assert not any(b.recording for b in boards)
    finally:
        for b in boards:
            b.close()


def test_a_missing_board_is_named():
    with Dca1000Control(("127.0.0.1", free_udp_port()), ("127.0.0.1", 0), timeout_s=0.05, attempts=2) as dca:
        with pytest.raises(HardwareError, match=r"no reply to SYSTEM_CONNECTION after 2 attempt\(s\)"):
            dca.arm()


def test_cfg_goes_to_the_radar_cli_line_by_line():
    radar = TiRadarCliPty().start()
    text = (SHARED_DATA / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg").read_text()
    try:
        with TiRadarCli(radar.port, timeout_s=2) as cli:
            n = cli.configure(text, "xwr18xx_profile.cfg")
            expected = [c for _, c in cfg_commands(text) if c != "sensorStart"]
            assert n == len(expected) == 28 and radar.received == expected  # no comments, no sensorStart
            assert all(answer == "Done" for _, answer in cli.sent)
            cli.start()
            assert radar.running
            cli.stop()
            assert not radar.running
    finally:
        radar.close()


def test_a_refused_line_names_the_file_line_and_answer():
    radar = TiRadarCliPty(refuse={"profileCfg": "Error -203"}).start()
    text = (SHARED_DATA / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg").read_text()
    try:
        with TiRadarCli(radar.port, timeout_s=2) as cli:
            with pytest.raises(HardwareError, match=r"\(x\.cfg line 29\): 'profileCfg 0 77 .*' answered 'Error -203'"):
                cli.configure(text, "x.cfg")
            assert radar.received[-1].startswith("profileCfg")  # nothing sent after it
            with pytest.raises(HardwareError, match="'bogus' is not recognized"):
                cli.send("bogus 1")
    finally:
        radar.close()


def test_a_silent_port_times_out():
    master, slave = os.openpty()
    try:
        with TiRadarCli(os.ttyname(slave), timeout_s=0.3) as cli:
            with pytest.raises(HardwareError, match="no answer to 'sensorStop' within 0.3 s .*demo firmware"):
                cli.stop()
    finally:
        os.close(master)
        os.close(slave)


def record(tmp_path, port, extra, duration_s=3.0):
    cmd = [sys.executable, "-m", "acquisition.cli", "record", "--config", str(ROOT / "imaging/rigs/default.toml"),
           "-o", str(tmp_path / "out"), "--dca1000", f"left_front={port}:{iwr1843_cfg(tmp_path)}", *extra,
           "--duration", str(duration_s)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)


def test_record_arms_the_board_and_starts_the_radar(tmp_path):
    """A real IWR1843 frame (the shared capture), streamed by the emulated board once it records and the
    radar is started: every frame sent is in the file, sample for sample."""
    frame = complex_1x_to_iq(iwr1843_words().tobytes(), 4, 4, 256)
    port = free_udp_port()
    board = Dca1000Emulator(lambda k: frame, ("127.0.0.1", port)).start()
    radar = TiRadarCliPty(on_start=board.radar_started, on_stop=board.radar_stopped).start()
    try:
        run = record(tmp_path, port, ["--dca1000-arm", f"left_front=127.0.0.1:{board.address[1]},listen=127.0.0.1:0",
                                      "--radar-cli", f"left_front={radar.port}"])
    finally:
        board.close()
        radar.close()
    assert run.returncode == 0, run.stderr
    sent = [decode_request(q)[0] for q, a in board.transcript if a is not None]
    assert sent[:3] == [0x09, 0x0E, 0x03] and sent[-3:] == [0x0B, 0x05, 0x06]
    commands = [c for _, c in cfg_commands(iwr1843_cfg(tmp_path).read_text()) if c != "sensorStart"]
    assert radar.received == commands + ["sensorStart", "sensorStop"]
    (path,) = (tmp_path / "out").glob("recording_*.h5")
    with Recording(path) as rec:
        n = rec.n_frames("left_front")
        assert 10 <= n == board.frames_sent  # 10 frames/s once armed; the radar stops before its driver does
        assert rec.valid("left_front").all()
        np.testing.assert_array_equal(rec.adc_iq("left_front"), np.broadcast_to(frame, (n, *frame.shape)))
        messages = [m for _, src, level, m in rec.events() if src == "radar.left_front"]
    assert any("sensorStart Done" in m and "FPGA 2.8 (record mode)" in m and f"{len(commands)} commands, each Done" in m
               for m in messages), messages


def test_a_radar_that_refuses_its_cfg_stops_the_run_with_exit_code_4(tmp_path):
    port = free_udp_port()
    board = Dca1000Emulator(lambda k: None, ("127.0.0.1", port)).start()
    radar = TiRadarCliPty(refuse={"frameCfg": "Error -1"}, on_start=board.radar_started).start()
    try:
        run = record(tmp_path, port, ["--dca1000-arm", f"left_front=127.0.0.1:{board.address[1]},listen=127.0.0.1:0",
                                      "--radar-cli", f"left_front={radar.port}"], duration_s=30)
    finally:
        board.close()
        radar.close()
    assert run.returncode == 4
    error = run.stderr.strip().splitlines()[-1]
    assert error.startswith("sarbot: error: radar CLI") and "iwr1843_one_frame.cfg line 17): 'frameCfg 0 1 2 0 100 1 0' answered 'Error -1'" in error
    assert not board.transcript  # the board is never armed for a radar that is not configured
    (path,) = (tmp_path / "out").glob("recording_*.h5")
    with Recording(path) as rec:
        assert any(level == "error" and "Error -1" in m for _, _, level, m in rec.events())


def test_a_board_that_does_not_answer_leaves_the_radar_stopped(tmp_path):
    radar = TiRadarCliPty().start()
    try:
        run = record(tmp_path, free_udp_port(), ["--dca1000-arm", f"left_front=127.0.0.1:{free_udp_port()},listen=127.0.0.1:0",
                                                 "--radar-cli", f"left_front={radar.port}"], duration_s=30)
    finally:
        radar.close()
    assert run.returncode == 4 and "no reply to SYSTEM_CONNECTION" in run.stderr.strip().splitlines()[-1]
    assert "sensorStart" not in radar.received


@pytest.mark.parametrize("extra, message", [
    (["--radar-cli", "left_rear=/dev/null"], "--radar-cli left_rear: not a DCA1000 radar of this recording"),
    (["--radar-cli", "left_front=/dev/nonexistent"], "no such device /dev/nonexistent"),
    (["--dca1000-arm", "left_front=192.168.33.180:4096,lanes=3"], "the DCA1000 takes 2 or 4 LVDS lanes"),
    (["--dca1000-arm", "left_front=host:port"], "expected NAME[=HOST[:PORT]]"),
    (["--dca1000-arm", "left_front,delay_us=1000"], "5 to 500 us"),
])
def test_bad_arming_options_are_one_line_errors(tmp_path, extra, message):
    run = record(tmp_path, free_udp_port(), extra)
    assert run.returncode == 2 and message in run.stderr and run.stderr.strip().count("\n") == 0
