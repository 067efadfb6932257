"""The range-Doppler cube written plainly: the reference rio.pointcloud's in-place cube is checked against
(and benchmarked)."""

from __future__ import annotations

import numpy as np

from imaging.core.windows import get_window


def reference_cube(frame, radar, tx_order, config):
    """Same contract as rio.pointcloud.range_doppler_cube (cube and positions), in double precision: per TX,
    gather its chirps, window, FFT, fftshift; channels sorted by their virtual position."""
    n_c, n_r, n_s = frame.shape
    n_range = 1 << int(np.ceil(np.log2(n_s)))
    rng = np.fft.fft(np.asarray(frame, np.complex128) * get_window(config.range_window, n_s), n_range, axis=-1)
    tx_order = np.asarray(tx_order)
    per_tx, positions = [], []
    for i in range(radar.waveform.n_tx):
        slow = rng[np.flatnonzero(tx_order == i)]
        w = get_window(config.doppler_window, slow.shape[0])[:, None, None]
        per_tx.append(np.fft.fftshift(np.fft.fft(slow * w, axis=0), axes=0))
        positions.append(radar.array.tx_positions_m[i, 1] + radar.array.rx_positions_m[:, 1])
    order = np.argsort(np.concatenate(positions), kind="stable")
    return np.concatenate(per_tx, axis=1)[:, order], np.concatenate(positions)[order]
