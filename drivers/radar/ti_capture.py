"""TI raw ADC captures (``adc_data.bin``): the byte layouts TI radars write through the DCA1000, and how to
tell from the samples which one a file is in.

A capture is int16 words, frame after frame, with no header. How one frame's words map to (chirp, RX,
sample, I/Q) depends on the radar family and its ``adcbufCfg``:

``lvds2``
    xWR16xx/18xx/68xx over two LVDS lanes (what sarbot's DCA1000 driver receives): per chirp, per RX,
    samples in pairs as four words ``I0 I1 Q0 Q1``, or ``Q0 Q1 I0 I1`` with the sample swap set
    (``adcbufCfg`` SampleSwap 1, TI's default).
``lvds4``
    xWR12xx/14xx over four LVDS lanes: per chirp, per sample, ``I`` of the four RX, then their ``Q``.
``interleaved``
    Channel-interleaved: per chirp, per sample, per RX, an ``I, Q`` pair (``Q, I`` with the swap set).

Samples are two's complement, or offset binary (0x8000 is zero) as some capture paths write them.

A file says none of this, so :func:`rank_layouts` scores each reading by its sideband ratio: a complex
FMCW beat signal read the right way has its targets at positive beat frequencies only (docs/signal-model.md's signal
model, and TI's complex-1x output: both reference captures in ``../shared/data`` put 12 and 22 dB more
power above zero than below). A wrong layout or a swapped I/Q pairs samples that do not belong together,
which spreads the power evenly over both sides or mirrors it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

LAYOUTS = ("lvds2", "lvds4", "interleaved")
SAMPLE_FORMATS = ("twos", "offset")


class CaptureLayoutError(ValueError):
    pass


def _check(words: np.ndarray, layout: str, chirps: int, n_rx: int, samples: int) -> int:
    if layout not in LAYOUTS:
        raise CaptureLayoutError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    per_frame = 2 * chirps * n_rx * samples
    if words.size % per_frame:
        raise CaptureLayoutError(f"{words.size} words are not whole frames of {per_frame} ({chirps} chirps x {n_rx} RX x "
                                 f"{samples} samples x I/Q)")
    if layout == "lvds2" and samples % 2:
        raise CaptureLayoutError(f"layout lvds2 carries samples in pairs; {samples} samples per chirp is odd")
    if layout == "lvds4" and n_rx != 4:
        raise CaptureLayoutError(f"layout lvds4 has one lane per RX and needs 4 RX, the configuration has {n_rx}")
    return words.size // per_frame


def capture_to_iq(words: np.ndarray, layout: str, chirps: int, n_rx: int, samples: int, iq_swap: bool = False) -> np.ndarray:
    """int16 (I, Q) [frames, chirps, n_rx, samples, 2] from a capture's int16 words (two's complement).

    Parameters
    ----------
    words : ndarray of int16, shape (N,)
        Whole frames of the capture.
    layout : {"lvds2", "lvds4", "interleaved"}
    chirps, n_rx, samples : int
        Chirps per frame, receivers, ADC samples per chirp.
    iq_swap : bool
        Q before I (``adcbufCfg`` SampleSwap 1); for ``lvds4``, Q lanes before I lanes.
    """
    words = np.asarray(words, np.int16).reshape(-1)
    frames = _check(words, layout, chirps, n_rx, samples)
    out = np.empty((frames, chirps, n_rx, samples, 2), np.int16)
    first, second = (1, 0) if iq_swap else (0, 1)  # where I and Q go of the words as they come
    if layout == "lvds2":
        quad = words.reshape(frames, chirps, n_rx, samples // 2, 2, 2)  # [pair][first/second part][sample 0/1]
        pairs = out.reshape(frames, chirps, n_rx, samples // 2, 2, 2)  # [pair][sample 0/1][I/Q]
        pairs[..., first] = quad[..., 0, :]
        pairs[..., second] = quad[..., 1, :]
    elif layout == "lvds4":
        lanes = words.reshape(frames, chirps, samples, 2, n_rx)  # [sample][first/second part][lane]
        out[..., first] = lanes[..., 0, :].transpose(0, 1, 3, 2)
        out[..., second] = lanes[..., 1, :].transpose(0, 1, 3, 2)
    else:
        pairs = words.reshape(frames, chirps, samples, n_rx, 2)
        out[..., first] = pairs[..., 0].transpose(0, 1, 3, 2)
        out[..., second] = pairs[..., 1].transpose(0, 1, 3, 2)
    return out


def iq_to_capture(iq: np.ndarray, layout: str, iq_swap: bool = False) -> np.ndarray:
    """The inverse of :func:`capture_to_iq`: int16 words of [frames, chirps, n_rx, samples, 2] (I, Q)."""
    iq = np.asarray(iq, np.int16)
    if iq.ndim == 4:
        iq = iq[None]
    frames, chirps, n_rx, samples, _ = iq.shape
    _check(np.empty(iq.size, np.int16), layout, chirps, n_rx, samples)
    first, second = (1, 0) if iq_swap else (0, 1)
    if layout == "lvds2":
        pairs = iq.reshape(frames, chirps, n_rx, samples // 2, 2, 2)
        words = np.stack([pairs[..., first], pairs[..., second]], axis=-2)
    elif layout == "lvds4":
        words = np.stack([iq[..., first].transpose(0, 1, 3, 2), iq[..., second].transpose(0, 1, 3, 2)], axis=-2)
    else:
        words = np.stack([iq[..., first], iq[..., second]], axis=-1).transpose(0, 1, 3, 2, 4)
    return np.ascontiguousarray(words, dtype="<i2").reshape(-1)


def offset_binary_to_twos(words: np.ndarray) -> np.ndarray:
    """Offset-binary int16 words (0x8000 is zero) as two's complement: the sign bit flipped."""
    return (np.asarray(words).view(np.uint16) ^ np.uint16(0x8000)).view(np.int16)


def guess_sample_format(words: np.ndarray) -> str:
    """"offset" when the samples crowd the ends of the int16 range (a small signal in offset binary reads
    as values near -32768 and +32767 in two's complement), else "twos"."""
    w = np.abs(np.asarray(words[: 1 << 20], np.int32))
    return "offset" if w.size and float(np.median(w)) > 16384 else "twos"


@dataclasses.dataclass(frozen=True)
class LayoutFit:
    """How well one reading of a capture fits a complex FMCW beat signal."""

    layout: str
    iq_swap: bool
    sideband_db: float  # median over (chirp, RX) of power at positive over negative beat frequencies

    def describe(self) -> str:
        return f"{self.layout}{' (Q before I)' if self.iq_swap else ''}: sideband ratio {self.sideband_db:+.1f} dB"


def sideband_db(samples: np.ndarray) -> float:
    """Median over profiles of 10 log10(power at positive / power at negative frequencies) along the last
    axis (mean removed, DC and Nyquist bins left out); nan when no profile has power on either side."""
    x = np.asarray(samples, np.complex64)
    x = x - x.mean(axis=-1, keepdims=True)
    n = x.shape[-1]
    power = np.abs(np.fft.fft(x, axis=-1)) ** 2
    upper, lower = power[..., 1:(n + 1) // 2].sum(-1), power[..., n // 2 + 1:].sum(-1)
    live = (upper > 0) & (lower > 0)
    if not live.any():
        return float("nan")
    return float(np.median(10 * np.log10(upper[live] / lower[live])))


def rank_layouts(words: np.ndarray, chirps: int, n_rx: int, samples: int, max_frames: int = 4) -> list[LayoutFit]:
    """Every layout and I/Q order that can hold these dimensions, best fit first (two's-complement words,
    at least one whole frame; the first ``max_frames`` frames are scored)."""
    per_frame = 2 * chirps * n_rx * samples
    frames = min(words.size // per_frame, max_frames)
    if frames < 1:
        raise CaptureLayoutError(f"{words.size} words hold no whole frame of {per_frame}")
    head = np.asarray(words[: frames * per_frame], np.int16)
    fits = []
    for layout in LAYOUTS:
        for swap in (False, True):
            try:
                iq = capture_to_iq(head, layout, chirps, n_rx, samples, swap)
            except CaptureLayoutError:
                continue
            z = iq[..., 0].astype(np.float32) + 1j * iq[..., 1].astype(np.float32)
            fits.append(LayoutFit(layout, swap, sideband_db(z)))
    return sorted(fits, key=lambda f: -np.nan_to_num(f.sideband_db, nan=-np.inf))
