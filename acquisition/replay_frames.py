"""A radar's recorded frames as replay sends them, lap after lap, read cheaply and checked.

The first lap reads each frame through HDF5 (``Recording.adc_iq``), which checks every chunk's Fletcher-32
checksum (see docs/formats/recording.md): that check and h5py's selection machinery cost more than encoding
and sending the frame. Later laps of a looped replay (``sarbot replay --laps``, a soak sends the same 500
frames a dozen times) read the frame's chunk as it lies in the file (``read_direct_chunk``: one copy, no
filter) and compare its CRC32C with the one the checked first lap gave: the bytes sent are those HDF5 checked,
or the replay stops. A file laid out otherwise (complex64 simulations, chunks of several frames, compression)
is read through HDF5 on every lap.
"""

from __future__ import annotations

import crc32c
import numpy as np

from imaging.core.errors import SarbotError
from imaging.io.recording import Recording

#: The only filter a chunk read raw may have been written with: HDF5's Fletcher-32 (4 bytes after the data).
FLETCHER32 = 3


class LapFrames:
    """``read(lap, k)``: frame ``k`` of ``radar`` as int16 [chirps, rx, samples, 2] (the wire's I/Q), for
    lap ``lap`` of a looped replay, lap 0 first. A frame of a later lap lies in a buffer kept from read to
    read: it holds until the next read."""

    def __init__(self, recording: Recording, radar: str, laps: int = 1):
        self.recording = recording
        self.radar = radar
        self._ds = recording.file[f"radar/{radar}/adc"]
        self._frame_shape = self._ds.shape[1:]
        self._frame_bytes = int(np.prod(self._frame_shape)) * self._ds.dtype.itemsize
        self.raw_reads = self._ds.dtype == np.dtype("<i2") and laps > 1 and self._chunk_is_one_plain_frame()
        self._crcs: dict[int, int] = {}  # frame -> CRC32C of its bytes as the checked read gave them
        self._chunk = np.empty(self._frame_bytes + 4 if self.raw_reads else 0, np.uint8)  # + Fletcher-32's 4 bytes

    def _chunk_is_one_plain_frame(self) -> bool:
        ds = self._ds
        filters = ds.id.get_create_plist()
        codes = {filters.get_filter(i)[0] for i in range(filters.get_nfilters())}
        return ds.chunks == (1, *self._frame_shape) and codes <= {FLETCHER32}

    def read(self, lap: int, k: int) -> np.ndarray:
        if lap == 0 or not self.raw_reads or k not in self._crcs:
            iq = self.recording.adc_iq(self.radar, slice(k, k + 1))[0]
            if self.raw_reads:
                self._crcs[k] = crc32c.crc32c(iq)
            return iq
        mask, raw = self._ds.id.read_direct_chunk((k,) + (0,) * len(self._frame_shape), out=self._chunk)
        data = raw[:self._frame_bytes]
        if mask != 0 or len(data) != self._frame_bytes or crc32c.crc32c(data) != self._crcs[k]:
            raise SarbotError(f"{self.recording.path}: /radar/{self.radar}/adc frame {k} changed on disk since the "
                              f"replay's first lap read it")
        return np.frombuffer(data, "<i2").reshape(self._frame_shape)
