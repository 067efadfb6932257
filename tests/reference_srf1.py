"""The SRF1 encoder as it was before the packed one (drivers.radar.srf1 up to ff18b4a): a datagram
at a time, header packed with struct, CRC32C over header and chunk. The tests hold the packed encoder to it
byte for byte."""

from __future__ import annotations

import numpy as np

from drivers.radar.srf1 import CRC, FLAG_PTP_LOCKED, HEADER, MAGIC, MAX_PAYLOAD, VERSION, _crc


def encode_frame(radar_id: int, frame_counter: int, frame_time_ns: int, iq: np.ndarray, ptp_locked: bool = True,
                 payload_bytes: int = MAX_PAYLOAD, version: int = VERSION) -> list[bytes]:
    """Datagrams of one frame; ``iq`` int16 [chirps, rx, samples, 2] (or any int16 array in wire order)."""
    data = np.ascontiguousarray(iq, dtype="<i2").tobytes()
    flags = FLAG_PTP_LOCKED if ptp_locked else 0
    out = []
    for off in range(0, len(data), payload_bytes):
        head = HEADER.pack(MAGIC, version, flags, radar_id, frame_counter & 0xFFFFFFFF, frame_time_ns, len(data), off)
        chunk = data[off:off + payload_bytes]
        if version >= 2:
            head += CRC.pack(_crc(head, chunk))
        out.append(head + chunk)
    return out
