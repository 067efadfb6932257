"""Point clouds from raw TDM-MIMO frames: range FFT, Doppler FFT per virtual channel, CFAR, angle of arrival.

For one frame (chirps x RX x samples): range FFT along fast time; the chirps of each TX form its slow time,
Doppler FFT along it; the range-Doppler power summed over all virtual channels goes through a cell-averaging
(or ordered-statistic) CFAR; at each detection the virtual-array snapshot is corrected for the TDM
motion phase (TX i fires i chirp intervals after TX 0, so a moving target's phase has advanced by
2 pi f_d i T_r) and an FFT across the virtual array gives the azimuth. Peaks are refined by parabolic
interpolation in range, Doppler and angle. The default array is a horizontal line, so elevation is zero.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.fft
import scipy.ndimage

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.rig import RadarConfig
from imaging.core.windows import get_window


@dataclasses.dataclass(frozen=True)
class PointCloudConfig:
    """Processing settings (SI units)."""

    range_window: str = "hann"
    doppler_window: str = "hann"
    angle_fft_size: int = 64
    cfar: str = "ca"  # "ca" cell averaging, "os" ordered statistic
    guard_cells: tuple[int, int] = (2, 2)  # (Doppler, range)
    training_cells: tuple[int, int] = (4, 8)
    threshold_db: float = 13.0
    os_rank: float = 0.75  # ordered statistic: this quantile of the training cells
    min_range_m: float = 0.3
    max_detections: int = 256


@dataclasses.dataclass
class PointCloud:
    """Detections of one frame: xyz_m [D, 3] sensor frame, doppler_mps [D] (range rate), snr_db [D]."""

    xyz_m: np.ndarray
    doppler_mps: np.ndarray
    snr_db: np.ndarray
    range_m: np.ndarray
    azimuth_rad: np.ndarray


def range_doppler_cube(frame: np.ndarray, radar: RadarConfig, tx_order: np.ndarray, config: PointCloudConfig):
    """Complex cube [Doppler, virtual channel, range] and the virtual channels' positions along sensor y.

    ``frame``: complex [chirps, n_rx, samples]. Channels are ordered by their virtual position; Doppler bin
    ``n_dop // 2`` is zero range rate (the spectrum is fft-shifted).

    Returns ``(cube, positions_m, tx_of_channel, n_range)``: complex64 [n_dop, n_tx * n_rx, n_range], float
    [n_tx * n_rx], int [n_tx * n_rx] and the range FFT length.
    """
    wf = radar.waveform
    n_c, n_r, n_s = frame.shape
    n_range = 1 << int(np.ceil(np.log2(n_s)))
    # Single precision throughout: ADC samples carry 16 bits, and numpy's FFT would work in double. One
    # zero-padded buffer, windowed in place and transformed in place, for both FFTs: this runs on every scan
    # of every radar, and copies cost as much as the FFTs.
    cube = np.zeros((n_c, n_r, n_range), np.complex64)
    np.multiply(frame, get_window(config.range_window, n_s).astype(np.float32), out=cube[..., :n_s])
    cube = scipy.fft.fft(cube, axis=-1, overwrite_x=True)  # [C, R, Nr]
    fired = _chirps_of_each_tx(tx_order, wf.n_tx, n_c)  # [M, Nt]
    if np.array_equal(fired.ravel(), np.arange(n_c)):
        slow = cube.reshape(fired.shape[0], wf.n_tx, n_r, n_range)  # chirps fire the TXs in turn: a view
    else:
        slow = cube[fired]  # [M, Nt, R, Nr]
    n_dop = slow.shape[0]
    w = get_window(config.doppler_window, n_dop)
    if n_dop % 2 == 0:
        # (-1)^m in slow time moves the spectrum by half its length: the fftshift, for free.
        w = w * np.where(np.arange(n_dop) % 2, -1.0, 1.0)
    slow *= w.astype(np.float32)[:, None, None, None]
    slow = scipy.fft.fft(slow, axis=0, overwrite_x=True)
    if n_dop % 2:
        slow = scipy.fft.fftshift(slow, axes=0)
    cube = slow.reshape(n_dop, wf.n_tx * n_r, n_range)  # channel = tx * n_rx + rx
    positions = (radar.array.tx_positions_m[: wf.n_tx, 1, None] + radar.array.rx_positions_m[None, :, 1]).ravel()
    tx_of_channel = np.repeat(np.arange(wf.n_tx), n_r)
    order = np.argsort(positions, kind="stable")
    if np.any(order != np.arange(order.size)):
        cube, positions, tx_of_channel = cube[:, order, :], positions[order], tx_of_channel[order]
    return cube, positions, tx_of_channel, n_range


def _chirps_of_each_tx(tx_order, n_tx: int, n_chirps: int) -> np.ndarray:
    """Chirp indices [M, n_tx]: row m holds the m-th chirp of every TX (the TXs' common slow time)."""
    tx_order = np.asarray(tx_order)
    if tx_order.shape != (n_chirps,):
        raise ValueError(f"tx_order has {tx_order.size} entries for a frame of {n_chirps} chirps")
    per_tx = [np.flatnonzero(tx_order == i) for i in range(n_tx)]
    counts = {c.size for c in per_tx}
    if len(counts) != 1 or 0 in counts:
        raise ValueError(f"tx_order fires the {n_tx} TXs {[c.size for c in per_tx]} times per frame; "
                         "TDM-MIMO needs every TX equally often")
    return np.stack(per_tx, axis=1)


def cfar_2d(power: np.ndarray, config: PointCloudConfig) -> tuple[np.ndarray, np.ndarray]:
    """Detections (boolean mask) and the noise estimate of a range-Doppler power map [Doppler, range]."""
    gd, gr = config.guard_cells
    td, tr = config.training_cells
    outer = (2 * (gd + td) + 1, 2 * (gr + tr) + 1)
    inner = (2 * gd + 1, 2 * gr + 1)
    if config.cfar == "ca":
        # Mean of the training ring: (sum over the outer box - sum over the guard box) / cells in the ring.
        # Doppler wraps around; range does not.
        s_out = scipy.ndimage.uniform_filter(power, outer, mode=("wrap", "nearest")) * np.prod(outer)
        s_in = scipy.ndimage.uniform_filter(power, inner, mode=("wrap", "nearest")) * np.prod(inner)
        noise = (s_out - s_in) / (np.prod(outer) - np.prod(inner))
    elif config.cfar == "os":
        footprint = np.ones(outer, bool)
        footprint[td:td + inner[0], tr:tr + inner[1]] = False
        noise = scipy.ndimage.percentile_filter(power, 100 * config.os_rank, footprint=footprint, mode="wrap")
    else:
        raise ValueError(f"unknown CFAR {config.cfar!r} (ca, os)")
    threshold = noise * 10 ** (config.threshold_db / 10)
    local_max = power == scipy.ndimage.maximum_filter(power, size=3, mode=("wrap", "nearest"))
    return (power > threshold) & local_max, noise


def _parabolic_v(y_m1: np.ndarray, y0: np.ndarray, y_p1: np.ndarray) -> np.ndarray:
    """Offset of the vertex of the parabola through three equally spaced points (element-wise)."""
    denom = y_m1 - 2 * y0 + y_p1
    safe = np.where(denom == 0, 1.0, denom)
    return np.where(denom == 0, 0.0, 0.5 * (y_m1 - y_p1) / safe)


def detect(frame: np.ndarray, radar: RadarConfig, tx_order, config: PointCloudConfig = PointCloudConfig()) -> PointCloud:
    """Point cloud of one frame ``frame`` complex [chirps, n_rx, samples] of ``radar``."""
    wf = radar.waveform
    cube, positions, tx_of_channel, n_range = range_doppler_cube(frame, radar, tx_order, config)
    n_dop = cube.shape[0]
    power = np.sum(np.abs(cube) ** 2, axis=1)  # non-coherent over the virtual channels
    range_bin_m = 0.5 * SPEED_OF_LIGHT_MPS * wf.sample_rate_hz / (n_range * wf.slope_hz_per_s)  # one-way
    hits, noise = cfar_2d(power, config)
    hits[:, : int(np.ceil(config.min_range_m / range_bin_m))] = False
    dop_idx, rng_idx = np.nonzero(hits)
    if dop_idx.size > config.max_detections:
        keep = np.argsort(power[dop_idx, rng_idx])[::-1][: config.max_detections]
        dop_idx, rng_idx = dop_idx[keep], rng_idx[keep]
    # Doppler: bin spacing in range rate for one TX's slow time (n_tx chirp intervals).
    t_slow = wf.n_tx * wf.chirp_interval_s
    v_bin = wf.wavelength_m / (2 * n_dop * t_slow)
    spacing = np.median(np.diff(positions))  # virtual element spacing along sensor y
    n_ang = max(config.angle_fft_size, positions.size)
    logp = 10 * np.log10(power + 1e-30)
    d, r = dop_idx, rng_idx
    inner = (r > 0) & (r < n_range - 1)
    r_lo, r_hi = np.clip(r - 1, 0, n_range - 1), np.clip(r + 1, 0, n_range - 1)
    dr = np.where(inner, _parabolic_v(logp[d, r_lo], logp[d, r], logp[d, r_hi]), 0.0)
    dd = _parabolic_v(logp[(d - 1) % n_dop, r], logp[d, r], logp[(d + 1) % n_dop, r])
    rng_m = (r + dr) * range_bin_m
    v = (d + dd - n_dop // 2) * v_bin
    # TDM motion: TX i fired i chirp intervals after TX 0; remove the phase the motion added.
    f_d = 2 * v / wf.wavelength_m
    snaps = cube[d, :, r] * np.exp(-2j * np.pi * f_d[:, None] * tx_of_channel[None, :] * wf.chirp_interval_s)
    spec = scipy.fft.fftshift(np.abs(scipy.fft.fft(snaps, n_ang, axis=1)) ** 2, axes=1)  # [D, n_ang]
    q = np.argmax(spec, axis=1)
    lq = 10 * np.log10(spec + 1e-30)
    rows = np.arange(q.size)
    inner_q = (q > 0) & (q < n_ang - 1)
    dq = np.where(inner_q, _parabolic_v(lq[rows, np.clip(q - 1, 0, n_ang - 1)], lq[rows, q],
                                        lq[rows, np.clip(q + 1, 0, n_ang - 1)]), 0.0)
    # Element phase -2 pi / lambda * y * sin(az): the spectrum peaks at q/n = -y_step sin(az) / lambda.
    s_az = -(q + dq - n_ang // 2) / n_ang * wf.wavelength_m / spacing
    ok = np.abs(s_az) <= 1
    az = np.arcsin(s_az[ok])
    rng_m = rng_m[ok]
    xyz = np.column_stack([rng_m * np.cos(az), rng_m * np.sin(az), np.zeros(az.size)])
    snr = logp[d, r][ok] - 10 * np.log10(noise[d, r][ok] + 1e-30)
    return PointCloud(xyz, v[ok], snr, rng_m, az)
