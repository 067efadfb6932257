"""Reading classic libpcap files (Ethernet, IPv4, UDP): enough to replay captured datagrams."""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path
from typing import Iterator

from imaging.core.errors import FileFormatError


@dataclasses.dataclass
class UdpDatagram:
    time_ns: int
    src_port: int
    dst_port: int
    payload: bytes


def read_udp(path: str | Path) -> Iterator[UdpDatagram]:
    """UDP datagrams of a pcap file in capture order (other packets are skipped)."""
    data = Path(path).read_bytes()
    if len(data) < 24:
        raise FileFormatError(f"{path}: too short for a pcap file")
    magic = struct.unpack_from("<I", data)[0]
    if magic in (0xA1B2C3D4, 0xA1B23C4D):
        endian = "<"
    elif magic in (0xD4C3B2A1, 0x4D3CB2A1):
        endian = ">"
    else:
        raise FileFormatError(f"{path}: not a pcap file (magic 0x{magic:08x})")
    nano = magic in (0xA1B23C4D, 0x4D3CB2A1)
    linktype = struct.unpack_from(endian + "I", data, 20)[0]
    if linktype != 1:
        raise FileFormatError(f"{path}: link type {linktype} is not Ethernet")
    i = 24
    while i + 16 <= len(data):
        sec, frac, incl, _ = struct.unpack_from(endian + "IIII", data, i)
        i += 16
        pkt = data[i:i + incl]
        i += incl
        if len(pkt) < 14 + 20 + 8 or struct.unpack_from(">H", pkt, 12)[0] != 0x0800:
            continue
        ihl = (pkt[14] & 0x0F) * 4
        if pkt[14 + 9] != 17:
            continue
        udp = pkt[14 + ihl:]
        sport, dport, ulen = struct.unpack_from(">HHH", udp)
        yield UdpDatagram(sec * 1_000_000_000 + frac * (1 if nano else 1000), sport, dport, bytes(udp[8:ulen]))


def write_udp(path: str | Path, datagrams, src_port: int = 1024, time_step_ns: int = 10_000) -> None:
    """A classic pcap file of UDP datagrams (``(dst_port, payload)`` pairs, in order), as a capture of the
    DCA1000's link would hold them: Ethernet, IPv4 (192.168.33.180 to 192.168.33.30, TI's defaults; the
    addresses are only written into the file), UDP, checksums zero. For tests and for making captures."""
    out = [struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)]
    src, dst = bytes([192, 168, 33, 180]), bytes([192, 168, 33, 30])
    for k, (dst_port, payload) in enumerate(datagrams):
        udp = struct.pack(">HHHH", src_port, dst_port, 8 + len(payload), 0) + payload
        ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), k & 0xFFFF, 0, 64, 17, 0, src, dst)
        frame = bytes(12) + b"\x08\x00" + ip + udp
        t = k * time_step_ns
        out.append(struct.pack("<IIII", t // 1_000_000_000, t % 1_000_000_000 // 1000, len(frame), len(frame)) + frame)
    Path(path).write_bytes(b"".join(out))
