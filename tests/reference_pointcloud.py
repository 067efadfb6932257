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


def reference_points(cube, layout, radar, config, power):
    """Detections of a cube and its power map as rio.pointcloud made them before the numba CFAR (aa20a74):
    ``cfar_2d`` (numpy and scipy) for the whole map, the TDM phase of every channel, the angle spectrum in dB
    over all its bins. rio.pointcloud's detector must give these numbers to the bit."""
    from imaging.core.constants import SPEED_OF_LIGHT_MPS
    from rio.pointcloud import PointCloud, _parabolic_v, cfar_2d

    import scipy.fft

    wf = radar.waveform
    positions, tx_of_channel, n_range = layout.positions_m, layout.tx_of_channel, layout.n_range
    n_dop = cube.shape[0]
    range_bin_m = 0.5 * SPEED_OF_LIGHT_MPS * wf.sample_rate_hz / (n_range * wf.slope_hz_per_s)
    hits, noise = cfar_2d(power, config)
    hits[:, : int(np.ceil(config.min_range_m / range_bin_m))] = False
    d, r = np.nonzero(hits)
    if d.size > config.max_detections:
        keep = np.argsort(power[d, r])[::-1][: config.max_detections]
        d, r = d[keep], r[keep]
    v_bin = wf.wavelength_m / (2 * n_dop * wf.n_tx * wf.chirp_interval_s)
    n_ang = max(config.angle_fft_size, positions.size)
    logp = lambda dd, rr: 10 * np.log10(power[dd, rr] + 1e-30)  # noqa: E731
    r_lo, r_hi = np.maximum(r - 1, 0), np.minimum(r + 1, n_range - 1)
    dr = np.where((r > 0) & (r < n_range - 1), _parabolic_v(logp(d, r_lo), logp(d, r), logp(d, r_hi)), 0.0)
    dd = _parabolic_v(logp((d - 1) % n_dop, r), logp(d, r), logp((d + 1) % n_dop, r))
    rng_m = (r + dr) * range_bin_m
    v = (d + dd - n_dop // 2) * v_bin
    f_d = 2 * v / wf.wavelength_m
    snaps = cube[d, :, r] * np.exp(-2j * np.pi * f_d[:, None] * tx_of_channel[None, :] * wf.chirp_interval_s)
    spec = scipy.fft.fftshift(np.abs(scipy.fft.fft(snaps, n_ang, axis=1)) ** 2, axes=1)
    q = np.argmax(spec, axis=1)
    lq = 10 * np.log10(spec + 1e-30)
    rows = np.arange(q.size)
    dq = np.where((q > 0) & (q < n_ang - 1), _parabolic_v(lq[rows, np.maximum(q - 1, 0)], lq[rows, q],
                                                          lq[rows, np.minimum(q + 1, n_ang - 1)]), 0.0)
    s_az = -(q + dq - n_ang // 2) / n_ang * wf.wavelength_m / layout.spacing_m
    ok = np.abs(s_az) <= 1
    az = np.arcsin(s_az[ok])
    rng_m = rng_m[ok]
    xyz = np.column_stack([rng_m * np.cos(az), rng_m * np.sin(az), np.zeros(az.size)])
    snr = logp(d, r)[ok] - 10 * np.log10(noise[d, r][ok] + 1e-30)
    return PointCloud(xyz, v[ok], snr, rng_m, az)
