"""Import a TI raw ADC capture (``adc_data.bin`` from mmWave Studio or the DCA1000 CLI, with the radar's
``.cfg``) as a recording.

The capture holds samples only: the ``.cfg`` gives the waveform, the frame size and the ADC mode (real,
complex 1x, complex 2x), the layout and the sample format are read off the samples when not given
(``drivers.radar.ti_capture``), and times are frame
index x the ``frameCfg`` periodicity, counted from zero, because the capture has no clock. The radar's
motion is not in the file either; ``velocity_mps`` declares it (a rail or a cart at constant speed, or at
rest by default) and is written to ``/truth`` so the recording images as it is.

A capture file is either raw (``adc_data.bin``: the sample words, nothing else) or a pcap of the DCA1000's
data port as a network capture holds it (UDP 4098: sequence, byte count, samples), told apart by the pcap
magic. From a pcap the samples are placed by each datagram's byte count: a datagram lost on the wire leaves
zeros (said in a warning), a repeated one is dropped.

Real-only captures are imported as the analytic signal (complex64, positive frequencies only).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from drivers.radar.ti_capture import (
    LAYOUTS,
    SAMPLE_FORMATS,
    CaptureLayoutError,
    LayoutFit,
    capture_to_iq,
    capture_to_real,
    guess_sample_format,
    offset_binary_to_twos,
    rank_layouts,
    rank_real_layouts,
    real_to_analytic,
)
from drivers.radar.ti_cfg import load_ti_cfg
from imaging.core.errors import SarbotError
from imaging.core.rig import AntennaArray, Mount, RadarConfig
from imaging.core.trajectory import TrajectorySample
from imaging.io.recording import RecordingWriter

log = logging.getLogger(f"sarbot.{__name__}")

#: The best reading must score at least this (sideband ratio, or spectral peak for real captures), and beat
#: every other layout's reading by MARGIN_DB, to be taken without --layout.
MIN_SCORE_DB = 6.0
MARGIN_DB = 3.0
#: Real samples read in the other order are still sinusoids in pieces, so their spectral peak drops less
#: (4-11 dB on the real captures' I channels, 1-2 dB the other way round): a wider margin, else ask.
REAL_MARGIN_DB = 6.0
FRAMES_PER_WRITE = 64


PCAP_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")


def is_pcap(path: Path) -> bool:
    with open(path, "rb") as f:
        return f.read(4) in PCAP_MAGICS


def _pcap_stream(path: Path):
    """The DCA1000's sample stream out of a pcap of its data port, in byte order: each datagram placed by
    its byte count, a gap filled with zeros (warned), a datagram already placed dropped."""
    from drivers.radar.dca1000 import DATA_PORT, Dca1000Error, parse_data_packet
    from drivers.radar.pcap import read_udp

    try:
        packets = []
        for d in read_udp(path):
            if d.dst_port == DATA_PORT:
                _, byte_count, samples = parse_data_packet(d.payload)
                packets.append((byte_count, bytes(samples)))
    except Dca1000Error as exc:
        raise SarbotError(f"{path}: {exc}") from None
    if not packets:
        raise SarbotError(f"{path}: a pcap with no datagram to the DCA1000's data port {DATA_PORT}")
    at, lost = min(b for b, _ in packets), 0
    for byte_count, samples in sorted(packets, key=lambda p: p[0]):
        if byte_count + len(samples) <= at:
            continue  # repeated
        if byte_count > at:
            lost += byte_count - at
            yield bytes(byte_count - at)
        yield samples[at - byte_count:] if byte_count < at else samples
        at = byte_count + len(samples)
    if lost:
        log.warning("%s: %d bytes lost on the wire are zeros in the recording", path, lost)


def _file_stream(path: Path, chunk: int):
    with open(path, "rb") as f:
        while block := f.read(chunk):
            yield block


def _capture_bytes(paths: list[Path]) -> int:
    return sum(sum(map(len, _pcap_stream(p))) if is_pcap(p) else p.stat().st_size for p in paths)


def _words(paths: list[Path], frame_bytes: int):
    """Whole frames of the files taken as one stream, FRAMES_PER_WRITE at a time, as int16 words."""
    chunk = frame_bytes * FRAMES_PER_WRITE
    buf = bytearray()
    for path in paths:
        for block in (_pcap_stream(path) if is_pcap(path) else _file_stream(path, chunk)):
            buf += block
            whole = len(buf) // frame_bytes * frame_bytes
            if whole >= chunk:
                yield np.frombuffer(bytes(buf[:whole]), "<i2")
                del buf[:whole]
    whole = len(buf) // frame_bytes * frame_bytes
    if whole:
        yield np.frombuffer(bytes(buf[:whole]), "<i2")


def choose_layout(fits: list[LayoutFit], source: str) -> LayoutFit:
    """The reading that stands out of ``fits`` (best first); SarbotError listing every candidate reading
    with its score when none does."""
    best = fits[0]
    rivals = [f for f in fits[1:] if f.layout != best.layout]
    runner_up = rivals[0].score_db if rivals else -np.inf
    margin = MARGIN_DB if best.measure == "sideband ratio" else REAL_MARGIN_DB
    if not (best.score_db >= MIN_SCORE_DB and best.score_db - runner_up >= margin):
        table = "; ".join(f.describe() for f in fits)
        raise SarbotError(f"{source}: cannot tell the sample layout from the data; the candidate readings: {table}. "
                          f"Give --layout ({', '.join(LAYOUTS)}) and --iq-swap if the radar swaps I and Q")
    return best


def import_ti_capture(paths, cfg_path, output, *, layout: str = "auto", sample_format: str = "auto",
                      iq_swap: bool | None = None, radar_name: str = "ti", velocity_mps=(0.0, 0.0, 0.0),
                      overwrite: bool = False, progress=None) -> dict:
    """Write a recording from a TI raw capture; returns what was read (frames, layout, sample format...).

    Parameters
    ----------
    paths : list of path
        The capture's files in order (mmWave Studio splits long captures: ``adc_data_0.bin``, ``_1``...).
    cfg_path : path
        The TI ``.cfg`` the radar ran.
    layout : {"auto", "lvds2", "lvds4", "interleaved"}
    sample_format : {"auto", "twos", "offset"}
    iq_swap : bool or None
        Q before I; None: as the ``.cfg``'s adcbufCfg says (or as found, with ``layout="auto"``).
    velocity_mps : (3,) floats
        The radar's constant velocity in the world frame, m/s; it starts at the origin looking along +x.
    """
    paths = [Path(p) for p in paths]
    for p in paths:
        if not p.is_file():
            raise SarbotError(f"{p}: no such capture file")
    if layout not in ("auto", *LAYOUTS):
        raise SarbotError(f"--layout {layout!r}: expected auto or one of {', '.join(LAYOUTS)}")
    if sample_format not in ("auto", *SAMPLE_FORMATS):
        raise SarbotError(f"--sample-format {sample_format!r}: expected auto, twos or offset")
    velocity = np.asarray(velocity_mps, float)
    if velocity.shape != (3,) or not np.isfinite(velocity).all():
        raise SarbotError(f"--velocity {velocity_mps!r}: expected three finite numbers VX,VY,VZ in m/s")
    cfg = load_ti_cfg(cfg_path)
    source = ", ".join(str(p) for p in paths)
    total = _capture_bytes(paths)
    frames = total // cfg.frame_bytes
    sample_bytes = 4 if cfg.complex_output else 2
    if frames == 0:
        raise SarbotError(f"{source}: {total} bytes hold no whole frame of {cfg.frame_bytes} bytes ({cfg.chirps_per_frame} "
                          f"chirps x {cfg.n_rx} RX x {cfg.adc_samples} samples x {sample_bytes} bytes, from {cfg_path})")
    if total % cfg.frame_bytes:
        log.warning("%s: the last %d bytes are a partial frame and are left out", source, total % cfg.frame_bytes)
    shape = (cfg.chirps_per_frame, cfg.n_rx, cfg.adc_samples)

    head = next(_words(paths, cfg.frame_bytes))[: 4 * cfg.frame_bytes // 2]
    if sample_format == "auto":
        sample_format = guess_sample_format(head)
    if sample_format == "offset":
        head = offset_binary_to_twos(head)
    try:
        fits = rank_layouts(head, *shape, adc_output=cfg.adc_output) if cfg.complex_output else rank_real_layouts(head, *shape)
        if not cfg.complex_output:
            iq_swap = False  # real samples have no I/Q order
            if layout == "lvds4":
                layout = "interleaved"  # the same order for real samples
        if layout == "auto":
            chosen = choose_layout(fits, source)
            layout = chosen.layout
            iq_swap = chosen.iq_swap if iq_swap is None else iq_swap
        else:
            iq_swap = cfg.iq_swap if iq_swap is None else iq_swap
        chosen = next(f for f in fits if f.layout == layout and f.iq_swap == iq_swap)
        if fits[0].layout != layout and fits[0].score_db - chosen.score_db >= MARGIN_DB:
            log.warning("%s: read as %s, but the samples fit %s better", source, chosen.describe(), fits[0].describe())
    except CaptureLayoutError as exc:
        raise SarbotError(f"{source}: {exc}") from None
    log.info("%s: %d frames, %s %s samples, layout %s", source, frames, sample_format, cfg.adc_output, chosen.describe())

    wf = cfg.waveform()
    radar = RadarConfig(radar_name, wf, AntennaArray.uniform_tdm(wf), Mount())
    frame_ns = round(wf.frame_interval_s * 1e9)
    how = (f"TI raw capture ({source}; {cfg_path}; {cfg.adc_output}, layout {layout}, iq_swap {iq_swap}, "
           f"{sample_format} samples{'; the analytic signal of the real samples' if not cfg.complex_output else ''})")
    with RecordingWriter(output, [radar], truth=True, wire_format="imported",
                         adc_dtype="int16" if cfg.complex_output else "complex64", overwrite=overwrite,
                         root_attrs={"imported_from": how},
                         radar_attrs={radar_name: {"receive_stamp": "none"}}) as w:
        done = 0
        for words in _words(paths, cfg.frame_bytes):
            if sample_format == "offset":
                words = offset_binary_to_twos(words)
            if cfg.complex_output:
                iq = capture_to_iq(words, layout, *shape, iq_swap)
            else:
                iq = real_to_analytic(capture_to_real(words, layout, *shape))
            k = np.arange(done, done + iq.shape[0])
            t = k.astype(np.int64) * frame_ns
            w.append_frames(radar_name, iq, t, k.astype(np.uint32), t)
            done += iq.shape[0]
            if progress is not None:
                progress(done, frames)
        # The track the user declared, sampled at every frame and one interval past the last.
        k = np.arange(done + 1)
        t = k.astype(np.int64) * frame_ns
        n = t.size
        w.append_truth(TrajectorySample(t, velocity * (t[:, None] * 1e-9), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
                                        np.tile(velocity, (n, 1)), np.zeros((n, 3))))
        w.append_event(0, "import", "info", f"{how}: no clock in the capture, frame times are index x "
                       f"{wf.frame_interval_s * 1e3:g} ms; /truth is the declared constant velocity {velocity.tolist()} m/s")
    return {"frames": done, "adc_output": cfg.adc_output, "layout": layout, "iq_swap": iq_swap,
            "sample_format": sample_format, "measure": chosen.measure, "score_db": round(chosen.score_db, 1),
            "scores": {f.name: round(f.score_db, 1) for f in fits}}
