"""Recordings out to the formats other robotics tools read (MCAP for Foxglove, ROS 2 bags)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

#: The fields of an exported point, each little-endian float32, in this order.
POINT_FIELDS = ("x", "y", "z", "doppler", "snr")


def grid_db(magnitude: np.ndarray) -> np.ndarray:
    """The map a ``foxglove.Grid`` carries (the live view's and the MCAP export's): little-endian float32 dB,
    0 at the peak, floored at -120 dB where nothing is."""
    peak = float(magnitude.max()) or 1.0
    return (20.0 * np.log10(np.maximum(magnitude / peak, 1e-6))).astype("<f4")


def detection_scans(rec, name: str) -> Iterator[tuple[int, np.ndarray]]:
    """A radar's detections scan by scan: (scan time ns, points [N, 5] little-endian float32 in the order of
    ``POINT_FIELDS``, positions in the radar's frame)."""
    det = rec.detections(name)
    for scan in np.unique(det["scan"]):
        sel = det["scan"] == scan
        pts = np.column_stack([det["xyz_m"][sel], det["doppler_mps"][sel], det["snr_db"][sel]]).astype("<f4")
        yield int(det["time_ns"][sel][0]), pts
