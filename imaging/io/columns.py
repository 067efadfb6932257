"""The recording writer's datasets as appendable columns, each found once and its length kept here.

A radar's ``adc`` column (a row per chunk, Fletcher-32 its only filter) takes its frames as whole stored
chunks (``imaging.io.fletcher32``); every other column appends through h5py.
"""

from __future__ import annotations

import h5py
import numpy as np


class Column:
    """An appendable dataset with its length, dtype and row shape kept here: asking h5py for them, and
    finding the dataset by its path, on every append was most of the recorder's time per frame (four radars
    and the IMU: about 700 appends a second)."""

    def __init__(self, ds: h5py.Dataset):
        self.ds = ds
        self.dtype = ds.dtype
        self.rows = ds.shape[0]
        self.row_shape = ds.shape[1:]
        self._object = ds.dtype.kind == "O"
        self._row_per_chunk: bool | None = None
        self._chunk: np.ndarray | None = None  # one stored chunk (row and checksum), reused: append_rows

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.rows, *self.row_shape)

    def append(self, values) -> None:
        values = np.asarray(values, dtype=object) if self._object else np.asarray(values)
        n = self.rows + values.shape[0]
        self.ds.resize(n, axis=0)
        self.ds[self.rows:n] = values
        self.rows = n

    @property
    def row_per_chunk(self) -> bool:
        """Whether each row is a chunk of its own whose only filter is Fletcher-32 (a radar's ``adc``): such
        rows are written as whole stored chunks (``append_rows``)."""
        if self._row_per_chunk is None:
            dcpl = self.ds.id.get_create_plist()
            self._row_per_chunk = (not self._object and self.ds.chunks == (1, *self.row_shape)
                                   and dcpl.get_nfilters() == 1 and dcpl.get_filter(0)[0] == h5py.h5z.FILTER_FLETCHER32)
        return self._row_per_chunk

    def append_rows(self, rows) -> None:
        """Append rows given one by one (each ``row_shape``), without stacking them first.

        Where each row is a chunk with only the Fletcher-32 filter, each goes to the file as the chunk HDF5
        would store (its bytes and checksum, ``write_direct_chunk``): no copy into the chunk cache, none into
        the filter's buffer, HDF5's word-at-a-time checksum replaced by a vectorised one of the same value."""
        rows = list(rows)
        for row in rows:
            if np.shape(row) != self.row_shape:
                raise ValueError(f"{self.ds.name}: a row of shape {np.shape(row)} does not fit {self.row_shape}")
        if not self.row_per_chunk:
            if rows:
                self.append(np.stack([np.asarray(r, self.dtype) for r in rows]))
            return
        n = self.rows + len(rows)
        self.ds.resize(n, axis=0)
        # numba (0.27 s, ~45 MB) only where frames are written: readers of recordings never import it.
        from imaging.io.fletcher32 import checksummed_chunk

        if self._chunk is None:
            self._chunk = np.empty(int(np.prod(self.row_shape)) * self.dtype.itemsize + 4, np.uint8)
        zeros = (0,) * len(self.row_shape)
        for k, row in enumerate(rows):
            chunk = checksummed_chunk(np.asarray(row).astype(self.dtype, copy=False), self._chunk)
            self.ds.id.write_direct_chunk((self.rows + k, *zeros), chunk)
        self.rows = n


class Columns:
    """The writer's datasets by path (``"imu"`` gives a view of the group: ``["time_ns"]``), each looked up once."""

    def __init__(self, f: h5py.File, prefix: str = "", cache: dict | None = None):
        self._f, self._prefix, self._cache = f, prefix, {} if cache is None else cache

    def clear(self) -> None:
        """Forget every column found (the writer's close)."""
        self._cache.clear()

    def __getitem__(self, path: str):
        path = self._prefix + path
        if path not in self._cache:
            node = self._f[path]
            self._cache[path] = Column(node) if isinstance(node, h5py.Dataset) else \
                Columns(self._f, path + "/", self._cache)
        return self._cache[path]
