"""Receive time stamps (drivers/radar/timestamping.py): SO_TIMESTAMPING from the real kernel, what an interface
can stamp against Debian's ``ethtool -T``, the choice of stamps, and where it is said (health, the recording,
``sarbot info``). No card here has a PTP hardware clock: hardware stamps themselves cannot be produced, so
their slot of the control message and their path through driver and recorder are fed by hand."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from drivers.radar.srf1 import encode_frame
from drivers.radar.timestamping import (
    HARDWARE_FLAGS,
    SCM_TIMESTAMPING,
    SO_TIMESTAMPING,
    SOFTWARE_FLAGS,
    TimestampingInfo,
    choose_receive_stamps,
    interface_of,
    parse_scm_timestamping,
    software_stamp_ns,
    timestamping_info,
)
from drivers.radar.udp import UdpReceiver
from imaging.core.errors import SarbotError

REPO = Path(__file__).resolve().parents[1]


def _send(address, n: int, gap_s: float = 0.001) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for k in range(n):
            tx.sendto(struct.pack("<I", k) + bytes(60), address)
            time.sleep(gap_s)


@pytest.mark.parametrize("mode", ["auto", "software"])
def test_software_stamps_on_loopback_are_the_host_clock_and_increase(mode):
    rx = UdpReceiver("127.0.0.1", 0, receive_stamps=mode, coalesce_s=0)
    assert rx.stamps.source == "software" and not rx.hardware
    if mode == "auto":  # lo was asked, and said why not
        assert rx.stamps.interface == "lo" and "lacks a PTP hardware clock" in rx.stamps.reason
    got = []
    sender = threading.Thread(target=_send, args=(rx.address, 50))
    sender.start()
    deadline = time.monotonic() + 10
    while len(got) < 50 and time.monotonic() < deadline:
        r = rx.receive()
        if r is not None:
            got.append((r[1], time.time_ns()))
    sender.join()
    rx.close()
    stamps = np.array([g[0] for g in got], np.int64)
    taken = np.array([g[1] for g in got], np.int64)
    assert stamps.size == 50
    lag_ms = (taken - stamps) * 1e-6  # stamped by the kernel before the receive returned, on the same clock
    assert np.all(lag_ms >= 0) and np.all(lag_ms < 50), lag_ms
    assert np.all(np.diff(stamps) > 0)  # sent 1 ms apart: strictly increasing
    assert rx.last_nic_ns == 0 and rx.nic_unstamped == 0


def _kernel_cmsg(flags: int) -> tuple[bytes, int, int]:
    """The SCM_TIMESTAMPING the kernel attaches to one loopback datagram, with the host time before and after."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        rx.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPING, flags)
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(5)
        before = time.time_ns()
        tx.sendto(b"x", rx.getsockname())
        _, ancdata, _, _ = rx.recvmsg(64, 256)
        after = time.time_ns()
    (value,) = [v for level, kind, v in ancdata if level == socket.SOL_SOCKET and kind == SCM_TIMESTAMPING]
    return value, before, after


def test_scm_timestamping_as_the_kernel_writes_it_and_the_hardware_slot():
    value, before, after = _kernel_cmsg(SOFTWARE_FLAGS)
    assert len(value) == 48  # three 16-byte timespecs
    software, legacy, hardware = parse_scm_timestamping(value)
    assert before <= software <= after and legacy == 0 and hardware == 0
    # Hardware stamps asked on lo: the kernel still stamps in software, the card's slot stays empty.
    value, before, after = _kernel_cmsg(HARDWARE_FLAGS)
    software, legacy, hardware = parse_scm_timestamping(value)
    assert before <= software <= after and hardware == 0
    # The card's stamp is the third timespec (struct scm_timestamping ts[2]): seconds, then nanoseconds.
    with_card = value[:32] + struct.pack("qq", 1_700_000_037, 123_456_789)
    assert parse_scm_timestamping(with_card) == (software, 0, 1_700_000_037_123_456_789)
    # Where time_t is 32 bits, each timespec is 8 bytes.
    assert parse_scm_timestamping(struct.pack("iiiiii", 5, 6, 0, 0, 7, 8)) == (5_000_000_006, 0, 7_000_000_008)
    # The software stamp alone (the drivers' per-datagram read without hardware stamps): the same, both layouts.
    assert software_stamp_ns(with_card) == software and software_stamp_ns(value) == software
    assert software_stamp_ns(struct.pack("iiiiii", 5, 6, 0, 0, 7, 8)) == 5_000_000_006


def _ethtool_t(output: str) -> dict:
    """What ``ethtool -T`` printed: capabilities, PHC index (-1: none), transmit modes, receive filters."""
    sections, key = {"Capabilities": [], "Hardware Transmit Timestamp Modes": [], "Hardware Receive Filter Modes": []}, None
    phc = None
    for line in output.splitlines():
        if line.startswith("PTP Hardware Clock:"):
            value = line.split(":", 1)[1].strip()
            phc = -1 if value == "none" else int(value)
            key = None
        elif line.rstrip().endswith(":") or ":" in line and not line.startswith(("\t", " ")):
            name, _, rest = line.partition(":")
            key = name.strip() if name.strip() in sections else None
            if key and rest.strip() and rest.strip() != "none":
                sections[key].append(rest.strip())
        elif key and line.strip():
            sections[key].append(re.split(r"\s+", line.strip())[0])
    return {"capabilities": sections["Capabilities"], "phc_index": phc,
            "tx_modes": sections["Hardware Transmit Timestamp Modes"],
            "rx_filter_modes": sections["Hardware Receive Filter Modes"]}


def _ours(info: TimestampingInfo) -> dict:
    return {"capabilities": info.capabilities, "phc_index": info.phc_index, "tx_modes": info.tx_modes,
            "rx_filter_modes": info.rx_filter_modes}


def _need_ethtool() -> str:
    path = shutil.which("ethtool") or ("/usr/sbin/ethtool" if os.path.exists("/usr/sbin/ethtool") else None)
    if path is None:
        pytest.skip("ethtool is not installed (apt-get install ethtool): nothing to compare ETHTOOL_GET_TS_INFO with")
    return path


def test_ts_info_of_lo_is_what_ethtool_prints():
    ethtool = _need_ethtool()
    printed = _ethtool_t(subprocess.run([ethtool, "-T", "lo"], capture_output=True, text=True, check=True).stdout)
    assert printed["capabilities"], "ethtool -T lo printed no capabilities"
    assert _ours(timestamping_info("lo")) == printed
    with pytest.raises(OSError):
        timestamping_info("nosuchif0")


def test_ts_info_of_a_veth_in_a_namespace_is_what_ethtool_prints():
    """A veth pair between two network namespaces made here; each end asked from inside its namespace."""
    ethtool = _need_ethtool()
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2")
    tag = f"{os.getpid() % 100000}"
    a, b = f"sta{tag}", f"stb{tag}"
    made = []
    try:
        for ns in (a, b):
            res = subprocess.run(["ip", "netns", "add", ns], capture_output=True, text=True)
            if res.returncode != 0:
                pytest.skip(f"cannot make network namespaces here: {res.stderr.strip()}")
            made.append(ns)
        for cmd in (["ip", "link", "add", f"{a}v", "type", "veth", "peer", "name", f"{b}v"],
                    ["ip", "link", "set", f"{a}v", "netns", a], ["ip", "link", "set", f"{b}v", "netns", b],
                    ["ip", "-n", a, "addr", "add", "10.99.36.1/24", "dev", f"{a}v"], ["ip", "-n", a, "link", "set", f"{a}v", "up"]):
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                pytest.skip(f"cannot make a veth pair between namespaces: {' '.join(cmd)}: {res.stderr.strip()}")
        probe = ("import json, dataclasses; from drivers.radar.timestamping import timestamping_info, interface_of, "
                 "choose_receive_stamps as c; i = timestamping_info('{iface}'); print(json.dumps([i.capabilities, "
                 "i.phc_index, i.tx_modes, i.rx_filter_modes, interface_of('10.99.36.1'), interface_of('0.0.0.0', '10.99.36.2'), "
                 "dataclasses.asdict(c('10.99.36.1', mode='auto'))]))")
        ns, iface = a, f"{a}v"
        printed = _ethtool_t(subprocess.run(["ip", "netns", "exec", ns, ethtool, "-T", iface], capture_output=True,
                                            text=True, check=True).stdout)
        res = subprocess.run(["ip", "netns", "exec", ns, sys.executable, "-c", probe.format(iface=iface)],
                             capture_output=True, text=True, cwd=REPO, timeout=60)
        assert res.returncode == 0, res.stderr
        caps, phc, tx, rx, found, routed, choice = json.loads(res.stdout)
        assert {"capabilities": caps, "phc_index": phc, "tx_modes": tx, "rx_filter_modes": rx} == printed
        assert found[0] == iface  # the interface that holds the link's address
        assert routed[0] == iface and "routes to the radar's source 10.99.36.2" in routed[1]  # a wildcard bind
        assert choice["source"] == "software" and choice["interface"] == iface and "PTP hardware clock" in choice["reason"]
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def test_hardware_demanded_where_the_card_cannot_is_one_clear_line():
    with pytest.raises(SarbotError) as exc:
        UdpReceiver("127.0.0.1", 0, receive_stamps="hardware")
    text = str(exc.value)
    assert "\n" not in text and "lo" in text and "lacks a PTP hardware clock" in text and "hardware receive stamps" in text
    # A wildcard bind does not tell the interface: hardware needs the address, or the radar's source.
    with pytest.raises(SarbotError, match="every interface.*source=ADDRESS"):
        choose_receive_stamps("0.0.0.0", None, "hardware")
    assert choose_receive_stamps("0.0.0.0", None, "auto").source == "software"
    assert interface_of("0.0.0.0", "127.0.0.1")[0] == "lo"  # the route to the radar picks it
    with pytest.raises(SarbotError, match="choose one of auto, hardware, software"):
        choose_receive_stamps("127.0.0.1", None, "best")


def test_record_cli_refuses_hardware_stamps_on_lo(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text("[radar.left]\nwaveform = { chirps_per_frame = 8 }\n")
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "record", "--config", str(rig), "-o", str(tmp_path / "out"),
                          "--radar", "left=127.0.0.1:50999", "--receive-stamps", "hardware", "--duration", "1"],
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert "radar left: receive stamps hardware for 127.0.0.1: lo" in res.stderr and "lacks a PTP hardware clock" in res.stderr
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "record", "--config", str(rig), "-o", str(tmp_path / "out"),
                          "--radar", "left=50999,stamps=sometimes", "--duration", "1"],
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert res.returncode == 2 and "'sometimes' is not one of auto, hardware, software" in res.stderr, res.stderr


class _CardStampingReceiver:
    """A receiver as UdpReceiver with hardware stamps would be: each datagram with the host's stamp and the
    card's (PHC, here 37 s ahead of the host: a PHC on TAI); the card leaves every 5th frame's datagrams
    unstamped."""

    hardware = True
    foreign_source = 0
    rcvbuf_short = None

    def __init__(self, datagrams):
        self.datagrams = list(datagrams)
        self.last_nic_ns = 0

    def receive(self):
        if not self.datagrams:
            time.sleep(0.01)
            return None
        data, host_ns, nic_ns = self.datagrams.pop(0)
        self.last_nic_ns = nic_ns
        return data, host_ns, 0


def test_card_stamps_go_with_their_frames_through_driver_and_recorder_and_are_said(tmp_path):
    from acquisition.bus import BusPublisher
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.info import format_info, recording_info
    from acquisition.messages import RadarFrameMessage
    from acquisition.recorder import Recorder
    from drivers.radar.srf1 import Srf1Stream
    from imaging.core.rig import rig_from_dict
    from imaging.io.recording import Recording

    rig = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 8, "sample_rate_hz": 200e3,
                                                         "frame_interval_s": 0.01}}}})
    wf = rig.radar("left").waveform
    shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)
    t0, period = 1_700_000_000_000_000_000, 10_000_000
    datagrams, want_nic = [], []
    for k in range(30):
        parts = encode_frame(1, k, t0 + k * period, np.full(shape, k, np.int16))
        for j, d in enumerate(parts):
            host = t0 + k * period + 2_000_000 + j * 1000
            nic = 0 if k % 5 == 4 else host + 37_000_000_000 - 1_500_000  # a PHC on TAI, the card 1.5 ms earlier
            datagrams.append((d, host, nic))
        want_nic.append(nic)
    last_host_after_start = 2_000_000 + (len(parts) - 1) * 1000
    want_delay_ms = (last_host_after_start + 37_000_000_000 - 1_500_000 - wf.frame_duration_ns) * 1e-6
    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    rec = Recorder(tmp_path / "r.h5", rig, pub.endpoint, context=ctx, receive_stamps={"left": "hardware"})
    time.sleep(0.2)
    stop = threading.Event()
    loop = threading.Thread(target=radar_driver_loop,
                            args=(_CardStampingReceiver(datagrams), "left", Srf1Stream(shape[:3], radar_id=1), pub, stop))
    loop.start()
    deadline = time.monotonic() + 20
    while rec.frames["left"] < 30 and time.monotonic() < deadline:
        rec.step(timeout_ms=100)
    stop.set()
    loop.join(5)
    while rec.step(timeout_ms=200):
        pass
    assert rec.nic_unstamped == {"left": 6}  # frames 4, 9, ..., 29
    delay = rec.receive_delay["left"].stats()
    # Only the card's stamps, all 0.5 ms after the frame's end: no host stamp (1.5 ms later) mixed in.
    assert delay.frames == 24
    assert delay.median_ms == pytest.approx(want_delay_ms, abs=1e-6) and delay.p99_ms == pytest.approx(want_delay_ms, abs=1e-6)
    rec.close()
    pub.close()
    ctx.term()
    with Recording(tmp_path / "r.h5") as r:
        assert r.receive_stamp("left") == "hardware"
        counters = r.frame_counter("left")
        np.testing.assert_array_equal(r.nic_time_ns("left"), np.asarray(want_nic)[counters])
        # The host's stamps stay in host_time_ns, every frame, stamped by the card or not.
        np.testing.assert_array_equal(r.host_time_ns("left") - (t0 + counters.astype(np.int64) * period),
                                      last_host_after_start)
        messages = [m.decode() for m in r.file["events/message"][()]]
    assert any("no hardware receive stamp" in m for m in messages)
    info = recording_info(tmp_path / "r.h5")
    assert info["radars"]["left"]["receive_stamp"] == "hardware" and info["radars"]["left"]["nic_unstamped_frames"] == 6
    assert "receive stamps: hardware (the network card's PTP hardware clock" in format_info(info)


def test_record_on_lo_with_auto_stamps_says_software_in_health_recording_and_info(tmp_path):
    from acquisition.bus import Message
    from acquisition.daemon import Setup, record
    from acquisition.info import format_info, recording_info
    from acquisition.messages import Health
    from acquisition.processes import free_port
    from drivers.radar.link import RadarLink
    from imaging.core.rig import rig_from_dict
    from imaging.io.recording import Recording

    rig = rig_from_dict({"radar": {"left": {"waveform": {"chirps_per_frame": 8, "sample_rate_hz": 200e3,
                                                         "frame_interval_s": 0.01}}}})
    wf = rig.radar("left").waveform
    shape = (wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2)
    port = free_port(socket.SOCK_DGRAM)
    done = threading.Event()

    def radar():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            k = 0
            while not done.is_set():
                for d in encode_frame(1, k, time.time_ns(), np.full(shape, k % 100, np.int16)):
                    tx.sendto(d, ("127.0.0.1", port))
                k += 1
                time.sleep(0.01)

    reports = []
    sender = threading.Thread(target=radar)
    sender.start()
    try:
        (path,) = record(Setup(rig, [RadarLink("left", port)], flush_interval_s=0.2, health_interval_s=0.5),
                         tmp_path, duration_s=3.0, path=tmp_path / "r.h5", on_health=reports.append)
    finally:
        done.set()
        sender.join(5)
    assert reports and all(h.receive_stamp == {"left": "software"} and h.nic_unstamped == {} for h in reports)
    assert "software receive stamps: left" in reports[-1].line()
    parts = reports[-1].to_parts()  # as a health subscriber gets it
    back = Health.from_message(Message(parts.topic, 0, parts.sensor_time_ns, 0,
                                       msgpack.unpackb(msgpack.packb(parts.fields)), []))
    assert back.receive_stamp == {"left": "software"} and back.nic_unstamped == {}
    with Recording(path) as r:
        assert r.receive_stamp("left") == "software" and r.n_frames("left") > 50
        assert not r.nic_time_ns("left").any()  # no card stamps at all
        # Software stamps are no event (the attribute and its note say them); a frame cut at the start may be.
        assert not [e for e in r.events() if "stamp" in e[3]], r.events()
        note = r.file["radar/left"].attrs["receive_stamp_note"]
    assert note == ("receive stamps: software (CLOCK_REALTIME): lo (127.0.0.1 is loopback) lacks a PTP hardware clock; "
                    "hardware receive stamps (hardware-receive, hardware-raw-clock); the receive filter 'all' (it stamps nothing)")
    info = recording_info(path)
    assert info["radars"]["left"]["receive_stamp"] == "software"
    text = format_info(info)
    assert "receive stamps: software (the kernel's, CLOCK_REALTIME)" in text and "why: lo (127.0.0.1 is loopback) lacks" in text


def test_what_a_card_lacks_for_stamping_every_datagram():
    """The capability masks of cards ethtool -T describes: one stamping only PTP's packets (as many do), one
    stamping all; bits as in include/uapi/linux/net_tstamp.h."""
    hw = 0b1000101  # hardware-transmit, hardware-receive, hardware-raw-clock
    ptp_only = TimestampingInfo("eth1", hw | 0b11010, 0, 0b11, 1 << 0 | 1 << 12)  # none, ptpv2-event
    assert ptp_only.capabilities == ["hardware-transmit", "software-transmit", "hardware-receive", "software-receive",
                                     "software-system-clock", "hardware-raw-clock"]
    assert ptp_only.tx_modes == ["off", "on"] and ptp_only.rx_filter_modes == ["none", "ptpv2-event"]
    assert ptp_only.hardware_lacks() == "the receive filter 'all' (it stamps none, ptpv2-event)"
    assert TimestampingInfo("eth2", hw, 1, 0b11, 0b11).hardware_lacks() is None
    assert TimestampingInfo("eth3", 0b11010, -1, 0, 0b10).hardware_lacks() == \
        "a PTP hardware clock; hardware receive stamps (hardware-receive, hardware-raw-clock)"


# -- DCA1000 frames: timed by their first datagram's receipt ---------------------------------------------------
def _dca1000_capture(frames: int):
    """A small DCA1000 stream: the shared capture's .cfg, ``frames`` frames of known samples as datagrams, and
    for each datagram the frame its first byte belongs to."""
    from drivers.radar.dca1000 import Dca1000Encoder, Dca1000Stream, parse_data_packet
    from drivers.radar.ti_cfg import load_ti_cfg
    from conftest import SHARED_DATA

    cfg = load_ti_cfg(SHARED_DATA / "dca1000_iwr1843_one_frame" / "xwr18xx_profile.cfg")
    encode = Dca1000Encoder(cfg.iq_swap)
    shape = (cfg.chirps_per_frame, cfg.n_rx, cfg.adc_samples, 2)
    datagrams = [d for k in range(frames) for d in encode(k, 0, np.full(shape, k + 1, np.int16))]
    first_of = [parse_data_packet(d)[1] // cfg.frame_bytes for d in datagrams]
    return cfg, Dca1000Stream(cfg), datagrams, first_of


def _run_driver(receiver, stream, frames: int):
    """The real driver loop on ``receiver``: the frames and events it publishes."""
    from acquisition.bus import BusPublisher, BusSubscriber
    from acquisition.driver_loops import radar_driver_loop
    from acquisition.messages import Event, RadarFrameMessage

    ctx = zmq.Context()
    pub = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    sub = BusSubscriber(pub.endpoint, topics=["radar/", "event"], context=ctx)
    time.sleep(0.2)
    stop = threading.Event()
    loop = threading.Thread(target=radar_driver_loop, args=(receiver, "dca", stream, pub, stop))
    loop.start()
    got, events = [], []
    deadline = time.monotonic() + 30
    while len(got) < frames and time.monotonic() < deadline:
        m = sub.receive(timeout_ms=200)
        if m is not None and m.topic == RadarFrameMessage.topic_of("dca"):
            got.append(RadarFrameMessage.from_message(m).frame)
        elif m is not None and m.topic == Event.TOPIC:
            events.append(Event.from_message(m).message)
    stop.set()
    loop.join(5)
    while (m := sub.receive(timeout_ms=200)) is not None:
        if m.topic == Event.TOPIC:
            events.append(Event.from_message(m).message)
    pub.close()
    sub.close()
    ctx.term()
    return got, events


class _StampKeepingReceiver:
    """A real UdpReceiver that keeps the kernel stamp of every datagram it returns."""

    def __init__(self, rx: UdpReceiver):
        self.rx, self.kept = rx, []

    def __getattr__(self, name):
        return getattr(self.rx, name)

    def receive(self):
        got = self.rx.receive()
        if got is not None:
            self.kept.append((got[0], got[1]))
        return got

    def receive_segments(self):  # what the driver loop calls: every datagram of a batch has its stamp
        got = self.rx.receive_segments()
        if got is not None:
            data, size, stamp, _ = got
            self.kept += [(bytes(data[o:o + size]), stamp) for o in range(0, len(data), size)]
        return got


def test_dca1000_frames_on_loopback_are_timed_by_the_kernel_stamp_of_their_first_datagram():
    """Software stamps (no card here stamps): a DCA1000 frame's time is the kernel's stamp of its first
    datagram, as the socket gave it; no card stamp, and no event about the card's clock."""
    from drivers.radar.dca1000 import parse_data_packet

    cfg, stream, datagrams, first_of = _dca1000_capture(4)
    rx = _StampKeepingReceiver(UdpReceiver("127.0.0.1", 0, receive_stamps="auto", coalesce_s=0))
    assert not rx.hardware and rx.stamps.source == "software"

    def send():
        time.sleep(0.3)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for k, d in enumerate(datagrams):
                tx.sendto(d, rx.address)
                if k % 20 == 19:
                    time.sleep(0.002)  # not faster than the socket's buffer takes them

    sender = threading.Thread(target=send)
    sender.start()
    frames, events = _run_driver(rx, stream, 4)
    sender.join()
    rx.close()
    first_stamp = {}
    for data, stamp in rx.kept:
        first_stamp.setdefault(parse_data_packet(data)[1] // cfg.frame_bytes, stamp)
    assert [f.frame_counter for f in frames] == [0, 1, 2, 3] and all(f.valid for f in frames)
    assert [f.frame_time_ns for f in frames] == [first_stamp[k] for k in range(4)]
    assert all(f.nic_receive_ns == 0 for f in frames)
    assert abs(frames[0].frame_time_ns - time.time_ns()) < 60e9  # the host's clock
    assert not any("network card" in e for e in events)


def test_dca1000_frames_with_card_stamps_are_timed_on_the_card_clock():
    """Hardware stamps (fed: no card here has a PHC): each DCA1000 frame's time is the card's stamp of its
    first datagram; where the card left it unstamped, its host stamp moved by the latest card-minus-host
    difference, so the series stays on the card's clock; the host stamp stays the frame's receive time; said
    once in /events."""
    cfg, stream, datagrams, first_of = _dca1000_capture(10)
    t0, period = 1_700_000_000_000_000_000, 50_000_000
    fed, first_host, first_nic, last_offset = [], {}, {}, {}
    offset = None
    for j, (d, k) in enumerate(zip(datagrams, first_of)):
        host = t0 + k * period + j * 1000
        # a PHC on TAI (37 s ahead), 1.5 ms earlier than the host, drifting 1 ppm; frames 4 and 9 unstamped
        nic = 0 if k % 5 == 4 else host + 37_000_000_000 - 1_500_000 + (host - t0) // 1_000_000
        first_host.setdefault(k, host)
        first_nic.setdefault(k, nic)
        last_offset.setdefault(k, offset)  # the card-minus-host difference known when the frame began
        offset = nic - host if nic else offset
        fed.append((d, host, nic))
    frames, events = _run_driver(_CardStampingReceiver(fed), stream, 10)
    assert [f.frame_counter for f in frames] == list(range(10))
    for f in frames:
        k = f.frame_counter
        want = first_nic[k] if first_nic[k] else first_host[k] + last_offset[k]
        assert f.frame_time_ns == want, k
        assert f.receive_ns == first_host[k]  # the host's stamp: latency and lag stay host-clock figures
    assert frames[4].frame_time_ns - first_host[4] == last_offset[4] != 37_000_000_000 - 1_500_000
    assert sum("frame times: the network card's stamp of each frame's first datagram (DCA1000" in e for e in events) == 1
