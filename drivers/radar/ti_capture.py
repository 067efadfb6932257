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
FMCW beat signal read the right way has its targets at positive beat frequencies only (the beat-signal sign
convention of docs/signal-model.md). A wrong layout or a swapped I/Q pairs samples that do not belong
together, which spreads the power evenly over both sides or mirrors it.

Which part of the spectrum is "negative" depends on the ADC mode (``adcCfg``'s adcOutputFmt). In complex 1x
the IF band reaches about 0.9 fs: a reflector beyond c fs / (4 slope) lies in the upper half of the FFT and
is no mirror image, and only the tenth of the band just below DC (0.9-1 fs) is empty. So the ratio
compares the band just above DC with the band of the same width just below it, whose width is what the
mode leaves empty (:data:`IMAGE_BAND`): 0.1 fs in complex 1x, 0.45 fs in complex 2x. The strongest echoes
near DC (the TX-RX coupling, the mount, the nearest clutter) then decide, wherever the far reflectors are.

Real-only captures (adcOutputFmt 0) have no I/Q order: :func:`rank_real_layouts` scores their two sample
orders by how peaky the spectrum is (a scrambled order smears it; the other order of real samples
smears it less, so it needs a wider margin), and :func:`real_to_analytic`
turns them into the complex beat signal sarbot images (the analytic signal: positive frequencies only).
"""

from __future__ import annotations

import dataclasses

import numpy as np

LAYOUTS = ("lvds2", "lvds4", "interleaved")
#: Real samples have two orders: per chirp, per RX, the samples (lvds2); or per chirp, per sample, the RX
#: (lvds4 and interleaved, which are the same for real samples).
REAL_LAYOUTS = ("lvds2", "interleaved")
SAMPLE_FORMATS = ("twos", "offset")
ADC_OUTPUTS = ("real", "complex1x", "complex2x")
#: Complex ADC modes: the fraction of the sample rate just below DC that holds no beat signal.
IMAGE_BAND = {"complex1x": 0.1, "complex2x": 0.45}


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
    """How well one reading of a capture fits an FMCW beat signal."""

    layout: str
    iq_swap: bool
    #: complex: median over (chirp, RX) of the power just above over just below DC (:func:`sideband_db`);
    #: real: the spectrum's peak over its median (:func:`spectral_peak_db`)
    score_db: float
    measure: str = "sideband ratio"

    def describe(self) -> str:
        return f"{self.layout}{' (Q before I)' if self.iq_swap else ''}: {self.measure} {self.score_db:+.1f} dB"

    @property
    def name(self) -> str:
        return f"{self.layout}{'/swap' if self.iq_swap else ''}"


def sideband_db(samples: np.ndarray, image_band: float = 0.5) -> float:
    """Median over profiles of 10 log10(power just above / power just below DC) along the last axis.

    Both bands are ``image_band`` of the sample rate wide (at most half of it: 0.5 compares the whole
    positive half with the whole negative half); the mean is removed and DC and Nyquist are left out.
    nan when no profile has power on either side.
    """
    x = np.asarray(samples, np.complex64)
    x = x - x.mean(axis=-1, keepdims=True)
    n = x.shape[-1]
    m = max(1, min(int(image_band * n), (n - 1) // 2))
    power = np.abs(np.fft.fft(x, axis=-1)) ** 2
    upper, lower = power[..., 1:m + 1].sum(-1), power[..., n - m:].sum(-1)
    live = (upper > 0) & (lower > 0)
    if not live.any():
        return float("nan")
    return float(np.median(10 * np.log10(upper[live] / lower[live])))


def _best_first(fits: list[LayoutFit]) -> list[LayoutFit]:
    return sorted(fits, key=lambda f: -np.nan_to_num(f.score_db, nan=-np.inf))


def _head(words: np.ndarray, per_frame: int, max_frames: int) -> np.ndarray:
    frames = min(words.size // per_frame, max_frames)
    if frames < 1:
        raise CaptureLayoutError(f"{words.size} words hold no whole frame of {per_frame}")
    return np.asarray(words[: frames * per_frame], np.int16)


def rank_layouts(words: np.ndarray, chirps: int, n_rx: int, samples: int, max_frames: int = 4,
                 adc_output: str = "complex1x") -> list[LayoutFit]:
    """Every layout and I/Q order that can hold these dimensions, best fit first (two's-complement words of a
    complex capture, at least one whole frame; the first ``max_frames`` frames are scored).

    ``adc_output`` ("complex1x" or "complex2x") sets the bands the sideband ratio compares (:data:`IMAGE_BAND`).
    """
    if adc_output not in IMAGE_BAND:
        raise CaptureLayoutError(f"ADC output {adc_output!r}: expected one of {', '.join(IMAGE_BAND)}")
    head = _head(words, 2 * chirps * n_rx * samples, max_frames)
    fits = []
    for layout in LAYOUTS:
        for swap in (False, True):
            try:
                iq = capture_to_iq(head, layout, chirps, n_rx, samples, swap)
            except CaptureLayoutError:
                continue
            z = iq[..., 0].astype(np.float32) + 1j * iq[..., 1].astype(np.float32)
            fits.append(LayoutFit(layout, swap, sideband_db(z, IMAGE_BAND[adc_output])))
    return _best_first(fits)


def capture_to_real(words: np.ndarray, layout: str, chirps: int, n_rx: int, samples: int) -> np.ndarray:
    """int16 [frames, chirps, n_rx, samples] from a real-only capture's words (:data:`REAL_LAYOUTS`;
    "lvds4" reads as "interleaved", the same order for real samples)."""
    words = np.asarray(words, np.int16).reshape(-1)
    if layout not in LAYOUTS:
        raise CaptureLayoutError(f"layout {layout!r}: expected one of {', '.join(REAL_LAYOUTS)}")
    per_frame = chirps * n_rx * samples
    if words.size % per_frame:
        raise CaptureLayoutError(f"{words.size} words are not whole frames of {per_frame} ({chirps} chirps x {n_rx} RX x "
                                 f"{samples} real samples)")
    if layout == "lvds2":
        return words.reshape(-1, chirps, n_rx, samples)
    return words.reshape(-1, chirps, samples, n_rx).transpose(0, 1, 3, 2)


def spectral_peak_db(samples: np.ndarray) -> float:
    """10 log10 of the largest over the median of the mean magnitude spectrum of real profiles (last axis;
    mean removed, DC and the negative half left out): high when each profile holds its own samples."""
    x = np.asarray(samples, np.float32)
    x = x - x.mean(axis=-1, keepdims=True)
    n = x.shape[-1]
    mag = np.abs(np.fft.rfft(x * np.hanning(n), axis=-1)).reshape(-1, n // 2 + 1).mean(0)[1:]
    med = float(np.median(mag))
    return float(20 * np.log10(mag.max() / med)) if med > 0 else float("nan")


def rank_real_layouts(words: np.ndarray, chirps: int, n_rx: int, samples: int, max_frames: int = 4) -> list[LayoutFit]:
    """The two sample orders of a real-only capture, best fit first (by :func:`spectral_peak_db`)."""
    head = _head(words, chirps * n_rx * samples, max_frames)
    return _best_first([LayoutFit(layout, False, spectral_peak_db(capture_to_real(head, layout, chirps, n_rx, samples)),
                                  "spectral peak") for layout in REAL_LAYOUTS])


def real_to_analytic(samples: np.ndarray) -> np.ndarray:
    """complex64 analytic signal of real profiles along the last axis (mean removed): the beat signal with
    its positive frequencies only, at the same amplitude, as complex ADC output would give it."""
    from scipy.signal import hilbert

    x = np.asarray(samples, np.float32)
    return hilbert(x - x.mean(axis=-1, keepdims=True), axis=-1).astype(np.complex64)
