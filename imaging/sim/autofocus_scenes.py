"""Phase histories for judging an autofocus decision: a straight pass past one point target or past a field
of diffuse clutter, with a track error the imaging does not know and thermal noise at a stated image SNR.

Synthesised straight from the signal model (docs/signal-model.md: a point at two-way range r contributes
``exp(+j 2 pi f r / c)`` at chirp frequency f) as range-compressed ``ProfileBlock``s, not as a recording:
the errors here are not the recording simulator's vibration but those a different simulator would make
(a cubic drift, a vibration at another frequency, an along-track scale error), and a clutter field of
thousands of scatterers costs seconds this way.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.range_compression import range_compress

F0_HZ = 77e9
BANDWIDTH_HZ = 4e9
SAMPLES = 256
RANGE_M = 2.0
SPEED_MPS = 0.4


@dataclasses.dataclass(frozen=True)
class TrackErrorKind:
    """A track error the imaging does not know: a drift bent along the boresight (metres at the aperture's
    ends, quadratic and cubic), a vibration along the boresight, and an along-track scale error."""

    quadratic_m: float = 0.0
    cubic_m: float = 0.0
    vibration_hz: float = 0.0
    vibration_m: float = 0.0
    scale: float = 0.0

    def displacement_m(self, x_m: np.ndarray, half_m: float, time_s: np.ndarray) -> np.ndarray:
        """[P, 3] true antenna position less the assumed one."""
        u = x_m / half_m
        d = np.zeros((x_m.size, 3))
        d[:, 0] = self.scale * x_m
        d[:, 1] = self.quadratic_m * u ** 2 + self.cubic_m * u ** 3 + self.vibration_m * np.sin(2 * math.pi * self.vibration_hz * time_s + 0.4)
        return d


#: An error unlike the paper's: 1 mm of cubic and 0.5 mm of quadratic drift at the ends, a 6.1 Hz vibration
#: of 0.2 mm and the odometry 2 % long along the track.
INDEPENDENT_ERROR = TrackErrorKind(quadratic_m=0.5e-3, cubic_m=1e-3, vibration_hz=6.1, vibration_m=0.2e-3, scale=0.02)
NO_ERROR = TrackErrorKind()


@dataclasses.dataclass
class Pass:
    """A synthesised pass: blocks on the assumed track (what autofocus sees), blocks on the true track
    (the error known), the image grid's points [ny, nx, 3] and axes, and the scatterers."""

    blocks: list
    true_blocks: list
    points_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    scatterers_m: np.ndarray


def _antennas(aperture_m: float, spacing_m: float):
    x = np.arange(-aperture_m / 2, aperture_m / 2 + 1e-12, spacing_m)
    pos = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    return x, pos, (x - x[0]) / SPEED_MPS


def _samples(antenna_m: np.ndarray, scatterers_m: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
    """[P, SAMPLES] fast-time samples of the scatterers seen from co-located TX/RX at ``antenna_m``."""
    f = F0_HZ + np.arange(SAMPLES) * (BANDWIDTH_HZ / SAMPLES)
    out = np.zeros((antenna_m.shape[0], SAMPLES), np.complex128)
    for lo in range(0, scatterers_m.shape[0], 64):
        s = scatterers_m[lo:lo + 64]
        r = 2.0 * np.linalg.norm(antenna_m[:, None, :] - s[None, :, :], axis=2)  # [P, T] two-way
        out += np.einsum("ptn,t->pn", np.exp(2j * math.pi * r[:, :, None] * f[None, None, :] / SPEED_OF_LIGHT_MPS),
                         amplitudes[lo:lo + 64])
    return out


def _blocks(samples: np.ndarray, antenna_m: np.ndarray, time_s: np.ndarray) -> list:
    from imaging.autofocus.options import ProfileBlock

    prof = range_compress(samples.astype(np.complex64), F0_HZ, BANDWIDTH_HZ / SAMPLES, window="hann", guarded=True)
    direction = np.tile([0.0, 1.0, 0.0], (antenna_m.shape[0], 1))
    return [ProfileBlock(prof, antenna_m, antenna_m, time_s, direction)]


def synthesise_pass(scene: str, error: TrackErrorKind, snr_db: float, seed: int, aperture_m: float = 0.6,
                    spacing_m: float = 0.002, half_x_m: float = 0.1, half_y_m: float = 0.08, pixel_m: float = 0.002
                    ) -> Pass:
    """A pass past ``scene`` ("point": one unit scatterer at 2 m broadside; "clutter": complex Gaussian
    scatterers, about 4 per resolution cell, filling the grid and a margin), the antennas truly displaced by
    ``error``, complex white noise such that the error-free image's peak (point) or mean pixel power
    (clutter) stands ``snr_db`` above the noise image's mean pixel power."""
    rng = np.random.default_rng(seed)
    x, assumed, time_s = _antennas(aperture_m, spacing_m)
    true = assumed + error.displacement_m(x, aperture_m / 2, time_s)
    xs = np.arange(-half_x_m, half_x_m + 1e-12, pixel_m)
    ys = RANGE_M + np.arange(-half_y_m, half_y_m + 1e-12, 2 * pixel_m)
    xx, yy = np.meshgrid(xs, ys)
    points = np.stack([xx, yy, np.zeros_like(xx)], axis=-1)
    if scene == "point":
        scatterers, amps = np.array([[0.0, RANGE_M, 0.0]]), np.ones(1, complex)
    elif scene == "clutter":
        area = (2 * half_x_m + 0.06) * (2 * half_y_m + 0.06)
        cell = (SPEED_OF_LIGHT_MPS / (2 * BANDWIDTH_HZ)) * (SPEED_OF_LIGHT_MPS / F0_HZ) * RANGE_M / (2 * aperture_m)
        n = int(4 * area / cell)
        scatterers = np.column_stack([rng.uniform(-half_x_m - 0.03, half_x_m + 0.03, n),
                                      rng.uniform(RANGE_M - half_y_m - 0.03, RANGE_M + half_y_m + 0.03, n), np.zeros(n)])
        amps = (rng.standard_normal(n) + 1j * rng.standard_normal(n)) / math.sqrt(2)
    else:
        raise ValueError(f"scene {scene!r}: 'point' or 'clutter'")
    clean_true = _samples(true, scatterers, amps)
    noise = (rng.standard_normal(clean_true.shape) + 1j * rng.standard_normal(clean_true.shape)) / math.sqrt(2)
    # The noise scaled to the stated SNR in the image: both imaged once on the assumed track.
    from imaging.autofocus.estimate import backproject_blocks

    # Without an error the true track is the assumed one, and its samples need not be computed twice.
    clean_assumed = clean_true if error == NO_ERROR else _samples(assumed, scatterers, amps)
    signal_img = backproject_blocks(_blocks(clean_assumed, assumed, time_s), points)
    noise_img = backproject_blocks(_blocks(noise, assumed, time_s), points)
    level = np.abs(signal_img).max() ** 2 if scene == "point" else np.mean(np.abs(signal_img) ** 2)
    noise *= math.sqrt(level / np.mean(np.abs(noise_img) ** 2) / 10 ** (snr_db / 10))
    data = clean_true + noise
    return Pass(_blocks(data, assumed, time_s), _blocks(data, true, time_s), points, xs, ys, scatterers)
