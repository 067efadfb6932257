"""Range profiles of chirps with the antenna positions they were sent and received at: what every image is
formed from, the one-shot image (``imaging.image_formation.frame_profiles``) and the live strip map
(``imaging.stripmap.StripMap.frames_profiles``) alike. See docs/signal-model.md."""

from __future__ import annotations

import typing

import numpy as np

from imaging.core.geometry import AntennaTrack, antenna_track
from imaging.core.rig import RadarConfig
from imaging.core.trajectory import Trajectory
from imaging.range_compression import RangeProfiles, range_bin_spacing_m, range_compress
from imaging.range_window import needed_bins, two_way_range_bounds_m, worth_it


class ChirpProfiles(typing.NamedTuple):
    """One profile per (chirp, channel), chirp by chirp: ``profiles`` data [P, bins], TX and RX phase centres
    ``tx_m``, ``rx_m`` [P, 3], the chirps' start times ``time_ns`` [P], and the antennas' ``track`` (one entry
    per chirp, every RX)."""

    profiles: RangeProfiles
    tx_m: np.ndarray
    rx_m: np.ndarray
    time_ns: np.ndarray
    track: AntennaTrack


def chirp_profiles(samples: np.ndarray, chirp_time_ns: np.ndarray, tx_index: np.ndarray, radar: RadarConfig,
                   trajectory: Trajectory, *, window: str, oversample: int, keep_samples: bool,
                   rx: np.ndarray | None = None, rx_centroid: bool = False, track_error=None,
                   workers: int | None = None, rows_out=None, image_box_m=None) -> ChirpProfiles:
    """Range-compress chirps and place their antennas.

    Parameters
    ----------
    samples : ndarray, complex, shape (C, R, samples)
        C chirps of R channels each (already selected, pre-summed or weighted as the caller wants).
    chirp_time_ns : ndarray, int64, shape (C,)
        Each chirp's start time.
    tx_index : ndarray, shape (C,)
        The TX that sent each chirp.
    window, oversample, keep_samples
        Range compression (``imaging.range_compression.range_compress``; ``keep_samples`` for "exact" mode).
    rx : ndarray of int, optional
        The radar's RX channels the R channels are (None: all of them, in order).
    rx_centroid : bool
        The R = 1 channel is the sum of all RX channels: placed at their centroid (for a symmetric row the
        sum's phase is the centroid's).
    track_error : imaging.core.track_error.TrackError, optional
        A displacement of the radar along its boresight the trajectory does not know (from autofocus).
    workers : int, optional
        FFT threads (-1: all cores).
    rows_out : ndarray or callable, optional
        A buffer to write the profiles' rows into (``range_compress``'s ``rows_out``: [C R, bins + 3]), or a
        function of that shape giving one (or None: a new buffer).
    image_box_m : (lo, hi), optional
        The corners of a box holding every pixel to be imaged from these profiles (metres, world frame, 3 each):
        only the bins between its nearest and farthest two-way range (``imaging.range_window.needed_bins``)
        are made, where that is cheaper (``range_compress``'s ``bins``).
    """
    track = antenna_track(radar, trajectory, chirp_time_ns, tx_index)
    if track_error is not None:
        d = track_error.at((track.time_ns - np.int64(track_error.time_origin_ns)) * 1e-9)[:, None] * track.boresight
        track.tx_m = track.tx_m + d
        track.rx_m = track.rx_m + d[:, None, :]
    wf = radar.waveform
    n_channels = samples.shape[1]
    if rx_centroid:
        rx_m = track.rx_m.mean(axis=1, keepdims=True)
    else:
        rx_m = track.rx_m if rx is None else track.rx_m[:, rx, :]
    tx_m = np.repeat(track.tx_m, n_channels, axis=0)  # one per profile, as rx_m
    n_fft = oversample * wf.samples_per_chirp
    bins = None
    if image_box_m is not None and samples.shape[0] and samples.shape[1]:
        step_m = range_bin_spacing_m(n_fft, wf.frequency_step_hz)
        near_m, far_m = two_way_range_bounds_m(tx_m, rx_m.reshape(-1, 3), *image_box_m)
        bins = needed_bins(near_m, far_m, step_m, n_fft)
        if bins[1] <= bins[0] or not worth_it(wf.samples_per_chirp, n_fft, bins[1] - bins[0]):
            bins = None  # the box lies beyond the profiles' range, or the window is most of it: all bins
    if callable(rows_out):
        width = n_fft if bins is None else bins[1] - bins[0]
        rows_out = rows_out((samples.shape[0] * n_channels, width + 3))
    profiles = range_compress(samples.reshape(-1, wf.samples_per_chirp), wf.f0_hz, wf.frequency_step_hz,
                              window=window, oversample=oversample, keep_samples=keep_samples, guarded=True,
                              workers=workers, rows_out=rows_out, bins=bins)
    return ChirpProfiles(profiles, tx_m, rx_m.reshape(-1, 3),
                         np.repeat(chirp_time_ns, n_channels), track)
