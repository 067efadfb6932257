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


def radar_description(radar, tdm_tx_order) -> dict:
    """What a consumer needs to image a radar's raw frames without the recording (docs/export.md): the
    waveform, the TX order of the chirps, the antenna positions (radar frame) and the mount (radar -> base_link).

    Parameters
    ----------
    radar : imaging.core.rig.RadarConfig
    tdm_tx_order : array of int
        TX index of each chirp of a frame, as the recording stores it.
    """
    wf = radar.waveform
    return {**{k: getattr(wf, k) for k in ("f0_hz", "bandwidth_hz", "chirp_duration_s", "chirp_interval_s",
                                           "sample_rate_hz", "chirps_per_frame", "n_tx", "n_rx", "frame_interval_s")},
            "slope_hz_per_s": wf.slope_hz_per_s, "tdm_tx_order": [int(v) for v in tdm_tx_order],
            "tx_positions_m": radar.array.tx_positions_m.tolist(), "rx_positions_m": radar.array.rx_positions_m.tolist(),
            "mount": {"translation_m": radar.mount.translation_m.tolist(),
                      "rotation_xyzw": radar.mount.rotation_xyzw.tolist()}}


def sensor_clock_offset_ns(rec) -> int:
    """Sensor (PTP) time minus host (CLOCK_REALTIME) time, the median over every radar frame and IMU sample
    that carries both; 0 where the recording has neither.

    A replayed recording's sensor times are those of the original run while its host times are the day of
    the replay: this is what lies between them.
    """
    diffs = [rec.frame_time_ns(n) - rec.host_time_ns(n) for n in rec.radar_names if rec.n_frames(n)]
    imu = rec.imu()
    if imu is not None:
        diffs.append(np.asarray(imu["time_ns"], np.int64) - np.asarray(imu["host_time_ns"], np.int64))
    diffs = [d for d in diffs if d.size]
    return int(np.median(np.concatenate(diffs))) if diffs else 0


def sensor_span_ns(rec) -> tuple[int, int] | None:
    """First and last sensor time of the recording's data (radar frames and scans, IMU, CAN, triggers,
    truth), or None for an empty recording."""
    times = [rec.frame_time_ns(n) for n in rec.radar_names]
    imu = rec.imu()
    if imu is not None:
        times.append(np.asarray(imu["time_ns"], np.int64))
    times += [np.asarray(rec.can()["time_ns"], np.int64), np.asarray(rec.triggers(), np.int64)]
    truth = rec.truth()
    if truth is not None:
        times.append(np.asarray(truth.time_ns, np.int64))
    times = [t for t in times if t.size]
    if not times:
        return None
    return int(min(t.min() for t in times)), int(max(t.max() for t in times))


def event_sensor_times_ns(event_times_ns, offset_ns: int, span_ns: tuple[int, int] | None,
                          time_base: str = "") -> np.ndarray:
    """The recording's events on the sensor clock, which every other exported message carries.

    With ``time_base`` ``"host"`` (the recorder's files, ``Recording.events_time_base``) every event is on the
    host clock and is moved by ``offset_ns`` (:func:`sensor_clock_offset_ns`). Files that do not say (older
    recordings, imports) may mix the two: an event within the recording's sensor span (give or take a
    minute) is taken to be on the sensor clock already, any other is moved. One that still lies outside the
    span (a damaged or hand-made stamp) is put at the nearer end, so the file spans what the recording spans.
    """
    t = np.asarray(event_times_ns, np.int64)
    if span_ns is None or t.size == 0:
        return t
    lo, hi = span_ns
    if time_base == "host":
        return np.clip(t + offset_ns, lo, hi)
    margin = 60_000_000_000
    on_sensor_clock = (t >= lo - margin) & (t <= hi + margin)
    out = np.where(on_sensor_clock, t, t + offset_ns)
    return np.clip(out, lo, hi)
