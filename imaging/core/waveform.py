"""The chirp-sequence FMCW TDM-MIMO waveform and the quantities derived from it."""

from __future__ import annotations

import dataclasses
import math

from imaging.core.config import require
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.windows import window_width_factor


@dataclasses.dataclass(frozen=True)
class Waveform:
    """One radar's chirp sequence. Defaults are the reference radar of docs/signal-model.md.

    A frame is ``chirps_per_frame`` chirps, one every ``chirp_interval_s``; chirp k is sent by TX
    ``k mod n_tx`` (TDM). Each chirp is sampled ``samples_per_chirp`` times at ``sample_rate_hz``
    (complex baseband), the instantaneous frequency rising at ``slope_hz_per_s`` from ``f0_hz``.
    """

    f0_hz: float = 76.0e9
    bandwidth_hz: float = 4.0e9
    chirp_duration_s: float = 180e-6
    chirp_interval_s: float = 200e-6
    chirps_per_frame: int = 256
    frame_interval_s: float = 52e-3
    sample_rate_hz: float = 977e3
    n_tx: int = 4
    n_rx: int = 4

    def __post_init__(self) -> None:
        require(self.f0_hz > 0, "f0_hz", f"must be positive, got {self.f0_hz}")
        require(self.bandwidth_hz > 0, "bandwidth_hz", f"must be positive, got {self.bandwidth_hz}")
        require(self.chirp_duration_s > 0, "chirp_duration_s", f"must be positive, got {self.chirp_duration_s}")
        require(
            self.chirp_interval_s >= self.chirp_duration_s,
            "chirp_interval_s",
            f"{self.chirp_interval_s} s is shorter than chirp_duration_s {self.chirp_duration_s} s",
        )
        require(self.n_tx >= 1, "n_tx", f"must be at least 1, got {self.n_tx}")
        require(self.n_rx >= 1, "n_rx", f"must be at least 1, got {self.n_rx}")
        require(
            self.chirps_per_frame >= self.n_tx and self.chirps_per_frame % self.n_tx == 0,
            "chirps_per_frame",
            f"must be a positive multiple of n_tx={self.n_tx}, got {self.chirps_per_frame}",
        )
        require(
            self.frame_interval_s >= self.chirps_per_frame * self.chirp_interval_s,
            "frame_interval_s",
            f"{self.frame_interval_s} s is shorter than the {self.chirps_per_frame} chirps it holds "
            f"({self.chirps_per_frame * self.chirp_interval_s:.6g} s)",
        )
        require(self.sample_rate_hz > 0, "sample_rate_hz", f"must be positive, got {self.sample_rate_hz}")
        require(
            self.samples_per_chirp >= 8,
            "sample_rate_hz",
            f"gives only {self.samples_per_chirp} samples per chirp (need at least 8)",
        )

    # -- derived quantities ---------------------------------------------------------------------
    @property
    def slope_hz_per_s(self) -> float:
        return self.bandwidth_hz / self.chirp_duration_s

    @property
    def samples_per_chirp(self) -> int:
        # The ADC samples while the chirp lasts; a tiny epsilon keeps 180us*1MHz from flooring to 179.
        return int(math.floor(self.sample_rate_hz * self.chirp_duration_s + 1e-9))

    @property
    def frequency_step_hz(self) -> float:
        """Frequency advance between two fast-time samples."""
        return self.slope_hz_per_s / self.sample_rate_hz

    @property
    def sampled_bandwidth_hz(self) -> float:
        """Bandwidth the ADC samples span (samples x step); sets the range resolution."""
        return self.samples_per_chirp * self.frequency_step_hz

    @property
    def centre_frequency_hz(self) -> float:
        """Frequency at the middle of the sampled part of the chirp."""
        return self.f0_hz + 0.5 * (self.samples_per_chirp - 1) * self.frequency_step_hz

    @property
    def wavelength_m(self) -> float:
        """Wavelength at the chirp centre frequency (the one behind cross-range resolution)."""
        return SPEED_OF_LIGHT_MPS / self.centre_frequency_hz

    @property
    def wavelength_f0_m(self) -> float:
        """Wavelength at the start frequency (lambda0, the array's design wavelength)."""
        return SPEED_OF_LIGHT_MPS / self.f0_hz

    @property
    def frame_duration_ns(self) -> int:
        """From the first chirp's start to the end of the last chirp interval, ns."""
        return int(round(self.chirps_per_frame * self.chirp_interval_s * 1e9))

    @property
    def chirps_per_tx(self) -> int:
        return self.chirps_per_frame // self.n_tx

    def range_bin_m(self, n_fft: int) -> float:
        """Two-way range spacing of an n_fft-point range FFT: c*fs/(n_fft*slope)."""
        return SPEED_OF_LIGHT_MPS * self.sample_rate_hz / (n_fft * self.slope_hz_per_s)

    @property
    def max_range_m(self) -> float:
        """Largest one-way range the complex-baseband ADC sees unambiguously."""
        return 0.5 * SPEED_OF_LIGHT_MPS * self.sample_rate_hz / self.slope_hz_per_s

    @property
    def max_unambiguous_velocity_mps(self) -> float:
        """Largest |range rate| per TX channel: lambda / (4 * n_tx * chirp_interval)."""
        return self.wavelength_m / (4.0 * self.n_tx * self.chirp_interval_s)

    def range_resolution_m(self, window: str = "hann") -> float:
        """Expected one-way half-power range width: factor * c / (2 B), B the sampled bandwidth."""
        return window_width_factor(window) * SPEED_OF_LIGHT_MPS / (2.0 * self.sampled_bandwidth_hz)

    def tdm_tx_order(self) -> list[int]:
        """TX index of every chirp of a frame."""
        return [k % self.n_tx for k in range(self.chirps_per_frame)]
