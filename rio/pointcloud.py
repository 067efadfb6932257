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

    ``frame``: complex [chirps, n_rx, samples], or the wire's int16 I/Q [chirps, n_rx, samples, 2]. Channels
    are ordered by their virtual position; Doppler bin ``n_dop // 2`` is zero range rate (the spectrum is
    fft-shifted).

    Returns ``(cube, positions_m, tx_of_channel, n_range)``: complex64 [n_dop, n_tx * n_rx, n_range], float
    [n_tx * n_rx], int [n_tx * n_rx] and the range FFT length. The cube is the caller's (a fresh buffer).
    """
    cube, layout = PointCloudDetector(radar, tx_order, config).cube(frame)
    return cube, layout.positions_m, layout.tx_of_channel, layout.n_range


@dataclasses.dataclass(frozen=True)
class _Layout:
    """What a frame's shape, the waveform, the array and the TX order fix, the same for every scan."""

    n_range: int
    fired: np.ndarray | None  # chirp indices [M, n_tx] of each TX; None: they fire in turn (a view, no gather)
    range_window: np.ndarray  # float32 [samples]
    range_window_iq: np.ndarray  # float32 [2 * samples]: each value twice, for I and Q
    doppler_window: np.ndarray  # float32 [M], (-1)^m folded in for an even M (the fftshift for free)
    order: np.ndarray | None  # channels by virtual position; None: already in order
    positions_m: np.ndarray  # [n_tx * n_rx], sorted
    tx_of_channel: np.ndarray  # [n_tx * n_rx]
    spacing_m: float  # the virtual elements' spacing along sensor y (median)
    angle_shift: np.ndarray  # the fftshift of the angle spectrum as an index [n_ang]


class PointCloudDetector:
    """``detect`` for one radar and TX order, for scan after scan: the windows, the chirps of each TX and the
    channels' order are made once (per frame shape), and the 2 MB cube is one buffer reused, filled straight
    from the int16 I/Q. The live odometry runs it on every scan of every radar, where that setup and the
    page faults of a fresh cube cost about as much as the FFTs. The cube ``cube`` returns is overwritten by
    the next call; the point clouds are the caller's."""

    def __init__(self, radar: RadarConfig, tx_order, config: PointCloudConfig = PointCloudConfig()):
        self.radar = radar
        self.tx_order = np.asarray(tx_order)
        self.config = config
        self._layout: _Layout | None = None
        self._buffer: np.ndarray | None = None
        self._magnitude: np.ndarray | None = None
        self._cfar_buffers: tuple | None = None  # ca_cfar_peaks' noise map and work buffers

    def layout(self, shape: tuple[int, int, int]) -> _Layout:
        """The layout for frames [chirps, n_rx, samples] of ``shape`` (made on the first, or a new shape)."""
        if self._layout is not None and (*self._buffer.shape[:2], self._layout.range_window.size) == tuple(shape):
            return self._layout
        wf, n_c, n_r, n_s = self.radar.waveform, *shape
        n_range = 1 << int(np.ceil(np.log2(n_s)))
        fired = _chirps_of_each_tx(self.tx_order, wf.n_tx, n_c)  # [M, Nt]
        n_dop = fired.shape[0]
        w = get_window(self.config.doppler_window, n_dop)
        if n_dop % 2 == 0:
            # (-1)^m in slow time moves the spectrum by half its length: the fftshift, for free.
            w = w * np.where(np.arange(n_dop) % 2, -1.0, 1.0)
        array = self.radar.array
        positions = (array.tx_positions_m[: wf.n_tx, 1, None] + array.rx_positions_m[None, :, 1]).ravel()
        tx_of_channel = np.repeat(np.arange(wf.n_tx), n_r)
        order = np.argsort(positions, kind="stable")
        order = None if np.all(order == np.arange(order.size)) else order
        if order is not None:
            positions, tx_of_channel = positions[order], tx_of_channel[order]
        n_ang = max(self.config.angle_fft_size, positions.size)
        range_window = get_window(self.config.range_window, n_s).astype(np.float32)
        self._layout = _Layout(n_range, None if np.array_equal(fired.ravel(), np.arange(n_c)) else fired,
                               range_window, np.repeat(range_window, 2), w.astype(np.float32),
                               order, positions, tx_of_channel, float(np.median(np.diff(positions))),
                               scipy.fft.fftshift(np.arange(n_ang)))
        self._buffer = np.zeros((n_c, n_r, n_range), np.complex64)
        return self._layout

    def cube(self, frame: np.ndarray) -> tuple[np.ndarray, _Layout]:
        """The cube of ``range_doppler_cube`` (in this detector's buffer: overwritten by the next call) and
        the layout."""
        iq = frame.dtype == np.int16
        if iq and frame.shape[-1:] != (2,):
            raise ValueError(f"I/Q samples need a last axis of 2 (I, Q); got shape {frame.shape}")
        shape = frame.shape[:3]
        if len(shape) != 3 or frame.ndim != 3 + iq:
            raise ValueError(f"a frame is [chirps, rx, samples] (complex) or [chirps, rx, samples, 2] (int16 I/Q); "
                             f"got shape {frame.shape}")
        layout = self.layout(shape)
        wf, n_c, n_r, n_s = self.radar.waveform, *shape
        n_range = layout.n_range
        # Single precision throughout: ADC samples carry 16 bits, and numpy's FFT would work in double. One
        # zero-padded buffer, windowed in place and transformed in place, for both FFTs. The windows are
        # real: applied to the real and imaginary parts as floats (a complex product would be 6 flops for 2).
        cube = self._buffer
        if iq:
            # I and Q side by side, as complex64 lays them out: the window repeated for each (a contiguous
            # inner loop, where a window broadcast over the last axis of 2 would make numpy loop 2 at a time).
            np.multiply(frame.reshape(n_c, n_r, 2 * n_s), layout.range_window_iq,
                        out=cube.view(np.float32)[..., : 2 * n_s])
        else:
            np.multiply(frame, layout.range_window, out=cube[..., :n_s])
        cube[..., n_s:] = 0
        cube = scipy.fft.fft(cube, axis=-1, overwrite_x=True)  # [C, R, Nr]
        if layout.fired is None:
            slow = cube.reshape(-1, wf.n_tx, n_r, n_range)  # chirps fire the TXs in turn: a view
        else:
            slow = cube[layout.fired]  # [M, Nt, R, Nr]
        n_dop = slow.shape[0]
        slow.view(np.float32)[...] *= layout.doppler_window[:, None, None, None]
        slow = scipy.fft.fft(slow, axis=0, overwrite_x=True)
        if n_dop % 2:
            slow = scipy.fft.fftshift(slow, axes=0)
        cube = slow.reshape(n_dop, wf.n_tx * n_r, n_range)  # channel = tx * n_rx + rx
        if layout.order is not None:
            cube = cube[:, layout.order, :]
        return cube, layout

    def detect(self, frame: np.ndarray) -> "PointCloud":
        """Point cloud of one frame: complex [chirps, n_rx, samples] or int16 I/Q [chirps, n_rx, samples, 2]."""
        cube, layout = self.cube(frame)
        # |cube|^2 in a buffer of the detector's own (1 MB a scan not allocated, nor faulted in after a trim).
        magnitude = self._magnitude
        if magnitude is None or magnitude.shape != cube.shape:
            magnitude = self._magnitude = np.empty(cube.shape, np.float32)
        np.square(np.abs(cube, out=magnitude), out=magnitude)
        power = np.sum(magnitude, axis=1)
        return _points(cube, layout, self.radar, self.config, power, self._cfar(power))

    def _cfar(self, power: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``cfar_2d``'s detections as Doppler and range bins (row-major) and its noise map: the CA-CFAR in one
        numba pass with buffers of the detector's own (rio.pointcloud_kernels, the same numbers to the bit), an
        ordered-statistic CFAR by ``cfar_2d``."""
        config = self.config
        if config.cfar != "ca":
            hits, noise = cfar_2d(power, config)
            return *np.nonzero(hits), noise
        from rio.pointcloud_kernels import ca_cfar_peaks

        if self._cfar_buffers is None or self._cfar_buffers[0].shape != power.shape:
            work = [np.empty(power.shape, np.float32) for _ in range(3)]
            self._cfar_buffers = (np.empty(power.shape), *work, np.empty(power.shape[1]))
        outer, inner = _cfar_boxes(config)
        noise = self._cfar_buffers[0]
        d, r = ca_cfar_peaks(np.ascontiguousarray(power, np.float32), outer, inner,
                             10 ** (config.threshold_db / 10), *self._cfar_buffers)
        return d, r, noise


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


def _cfar_boxes(config: PointCloudConfig) -> tuple[tuple[int, int], tuple[int, int]]:
    """The CFAR's boxes (Doppler, range) in cells: the training ring's outer edge and the guard within it."""
    (gd, gr), (td, tr) = config.guard_cells, config.training_cells
    return (2 * (gd + td) + 1, 2 * (gr + tr) + 1), (2 * gd + 1, 2 * gr + 1)


def cfar_2d(power: np.ndarray, config: PointCloudConfig) -> tuple[np.ndarray, np.ndarray]:
    """Detections (boolean mask) and the noise estimate of a range-Doppler power map [Doppler, range]."""
    outer, inner = _cfar_boxes(config)
    if config.cfar == "ca":
        # Mean of the training ring: (sum over the outer box - sum over the guard box) / cells in the ring.
        # Doppler wraps around; range does not.
        s_out = scipy.ndimage.uniform_filter(power, outer, mode=("wrap", "nearest")) * np.prod(outer)
        s_in = scipy.ndimage.uniform_filter(power, inner, mode=("wrap", "nearest")) * np.prod(inner)
        noise = (s_out - s_in) / (np.prod(outer) - np.prod(inner))
    elif config.cfar == "os":
        td, tr = config.training_cells
        footprint = np.ones(outer, bool)
        footprint[td:td + inner[0], tr:tr + inner[1]] = False
        noise = scipy.ndimage.percentile_filter(power, 100 * config.os_rank, footprint=footprint, mode="wrap")
    else:
        raise ValueError(f"unknown CFAR {config.cfar!r} (ca, os)")
    threshold = noise * 10 ** (config.threshold_db / 10)
    hits = power > threshold
    # A detection is also the largest of its 3 x 3 neighbourhood (Doppler wraps, the range's edge cell is its
    # own neighbour), tested at the cells over the threshold only (some hundreds of the map's 16 k): a
    # maximum filter over the whole map cost a third of the CFAR, for the same mask.
    d, r = np.nonzero(hits)
    peak = power[d, r]
    largest = np.ones(d.size, bool)
    n_dop, n_range = power.shape
    columns = (np.maximum(r - 1, 0), r, np.minimum(r + 1, n_range - 1))  # np.clip costs more than the test
    for step_d in (-1, 0, 1):
        rows = (d + step_d) % n_dop
        for step_r, cols in zip((-1, 0, 1), columns):
            if step_d or step_r:
                largest &= power[rows, cols] <= peak
    hits[d[~largest], r[~largest]] = False
    return hits, noise


def _parabolic_v(y_m1: np.ndarray, y0: np.ndarray, y_p1: np.ndarray) -> np.ndarray:
    """Offset of the vertex of the parabola through three equally spaced points (element-wise)."""
    denom = y_m1 - 2 * y0 + y_p1
    safe = np.where(denom == 0, 1.0, denom)
    return np.where(denom == 0, 0.0, 0.5 * (y_m1 - y_p1) / safe)


def detect(frame: np.ndarray, radar: RadarConfig, tx_order, config: PointCloudConfig = PointCloudConfig()) -> PointCloud:
    """Point cloud of one frame ``frame`` complex [chirps, n_rx, samples] (or int16 I/Q [..., 2]) of ``radar``
    (scan after scan of one radar: ``PointCloudDetector``)."""
    return PointCloudDetector(radar, tx_order, config).detect(frame)


def _points(cube: np.ndarray, layout: _Layout, radar: RadarConfig, config: PointCloudConfig,
            power: np.ndarray, cfar: tuple[np.ndarray, np.ndarray, np.ndarray]) -> PointCloud:
    """Detections of a range-Doppler cube (``PointCloudDetector.cube``) and its ``power`` summed over the
    virtual channels (non-coherently) [Doppler, range], with ``cfar`` (its CFAR's Doppler bins, range bins
    in row-major order, and noise map: ``PointCloudDetector._cfar``): refinement, angle of arrival."""
    wf = radar.waveform
    positions, tx_of_channel, n_range = layout.positions_m, layout.tx_of_channel, layout.n_range
    n_dop = cube.shape[0]
    range_bin_m = 0.5 * SPEED_OF_LIGHT_MPS * wf.sample_rate_hz / (n_range * wf.slope_hz_per_s)  # one-way
    dop_idx, rng_idx, noise = cfar
    near = rng_idx < int(np.ceil(config.min_range_m / range_bin_m))
    if near.any():
        dop_idx, rng_idx = dop_idx[~near], rng_idx[~near]
    if dop_idx.size > config.max_detections:
        keep = np.argsort(power[dop_idx, rng_idx])[::-1][: config.max_detections]
        dop_idx, rng_idx = dop_idx[keep], rng_idx[keep]
    # Doppler: bin spacing in range rate for one TX's slow time (n_tx chirp intervals).
    t_slow = wf.n_tx * wf.chirp_interval_s
    v_bin = wf.wavelength_m / (2 * n_dop * t_slow)
    spacing = layout.spacing_m  # virtual element spacing along sensor y
    n_ang = max(config.angle_fft_size, positions.size)
    d, r = dop_idx, rng_idx
    inner = (r > 0) & (r < n_range - 1)
    r_lo, r_hi = np.maximum(r - 1, 0), np.minimum(r + 1, n_range - 1)
    # The power in dB only where the peaks are refined (a few hundred cells of the map's 16 k): at each
    # detection, its range neighbours and its Doppler neighbours, in one gather.
    cells = np.concatenate([d, d, d, (d - 1) % n_dop, (d + 1) % n_dop]), np.concatenate([r, r_lo, r_hi, r, r])
    logp_at = (10 * np.log10(power[cells] + 1e-30)).reshape(5, -1)
    logp_d_r = logp_at[0]
    dr = np.where(inner, _parabolic_v(logp_at[1], logp_d_r, logp_at[2]), 0.0)
    dd = _parabolic_v(logp_at[3], logp_d_r, logp_at[4])
    rng_m = (r + dr) * range_bin_m
    v = (d + dd - n_dop // 2) * v_bin
    # TDM motion: TX i fired i chirp intervals after TX 0; remove the phase the motion added.
    f_d = 2 * v / wf.wavelength_m
    # The phase of each TX, not of each channel: the channels of one TX share it (the same numbers, computed
    # n_rx times fewer), gathered to the channels after the exponential.
    tx_phase = np.exp(-2j * np.pi * f_d[:, None] * np.arange(wf.n_tx)[None, :] * wf.chirp_interval_s)
    snaps = cube[d, :, r] * tx_phase[:, tx_of_channel]
    spec = (np.abs(scipy.fft.fft(snaps, n_ang, axis=1)) ** 2)[:, layout.angle_shift]  # [D, n_ang], fftshifted
    q = np.argmax(spec, axis=1)
    rows = np.arange(q.size)
    inner_q = (q > 0) & (q < n_ang - 1)
    # dB only at the peak and its two neighbours (3 of each row's n_ang bins are read).
    lq = 10 * np.log10(spec[rows[:, None], np.stack([np.maximum(q - 1, 0), q, np.minimum(q + 1, n_ang - 1)], axis=1)]
                       + 1e-30)
    dq = np.where(inner_q, _parabolic_v(lq[:, 0], lq[:, 1], lq[:, 2]), 0.0)
    # Element phase -2 pi / lambda * y * sin(az): the spectrum peaks at q/n = -y_step sin(az) / lambda.
    s_az = -(q + dq - n_ang // 2) / n_ang * wf.wavelength_m / spacing
    ok = np.abs(s_az) <= 1
    az = np.arcsin(s_az[ok])
    rng_m = rng_m[ok]
    xyz = np.column_stack([rng_m * np.cos(az), rng_m * np.sin(az), np.zeros(az.size)])
    snr = logp_d_r[ok] - 10 * np.log10(noise[d, r][ok] + 1e-30)
    return PointCloud(xyz, v[ok], snr, rng_m, az)
