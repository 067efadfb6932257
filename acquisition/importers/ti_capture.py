"""Import a TI raw ADC capture (``adc_data.bin`` from mmWave Studio or the DCA1000 CLI, with the radar's
``.cfg``) as a recording.

The capture holds samples only: the ``.cfg`` gives the waveform and the frame size, the layout and the
sample format are read off the samples when not given (``drivers.radar.ti_capture``), and times are frame
index x the ``frameCfg`` periodicity, counted from zero, because the capture has no clock. The radar's
motion is not in the file either; ``velocity_mps`` declares it (a rail or a cart at constant speed, or at
rest by default) and is written to ``/truth`` so the recording images as it is.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from drivers.radar.ti_capture import (
    LAYOUTS,
    SAMPLE_FORMATS,
    CaptureLayoutError,
    capture_to_iq,
    guess_sample_format,
    offset_binary_to_twos,
    rank_layouts,
)
from drivers.radar.ti_cfg import load_ti_cfg
from imaging.core.errors import SarbotError
from imaging.core.rig import AntennaArray, Mount, RadarConfig
from imaging.core.trajectory import TrajectorySample
from imaging.io.recording import RecordingWriter

log = logging.getLogger(f"sarbot.{__name__}")

#: The best reading must show at least this sideband ratio, and beat every other reading (its own mirror
#: aside) by MARGIN_DB, to be taken without --layout.
MIN_SIDEBAND_DB = 6.0
MARGIN_DB = 3.0
FRAMES_PER_WRITE = 64


def _words(paths: list[Path], frame_bytes: int):
    """Whole frames of the files taken as one stream, FRAMES_PER_WRITE at a time, as int16 words."""
    chunk = frame_bytes * FRAMES_PER_WRITE
    buf = bytearray()
    for path in paths:
        with open(path, "rb") as f:
            while block := f.read(chunk):
                buf += block
                whole = len(buf) // frame_bytes * frame_bytes
                if whole >= chunk:
                    yield np.frombuffer(bytes(buf[:whole]), "<i2")
                    del buf[:whole]
    whole = len(buf) // frame_bytes * frame_bytes
    if whole:
        yield np.frombuffer(bytes(buf[:whole]), "<i2")


def choose_layout(head: np.ndarray, chirps: int, n_rx: int, samples: int, source: str):
    """(layout, iq_swap, fits) read off the first frames; SarbotError when no reading stands out."""
    fits = rank_layouts(head, chirps, n_rx, samples)
    best = fits[0]
    rivals = [f for f in fits[1:] if f.layout != best.layout]
    runner_up = rivals[0].sideband_db if rivals else -np.inf
    table = "; ".join(f.describe() for f in fits)
    if not (best.sideband_db >= MIN_SIDEBAND_DB and best.sideband_db - runner_up >= MARGIN_DB):
        raise SarbotError(f"{source}: cannot tell the sample layout from the data ({table}); give --layout "
                          f"({', '.join(LAYOUTS)}) and --iq-swap if the radar swaps I and Q")
    return best.layout, best.iq_swap, fits


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
    if not cfg.complex_output:
        raise SarbotError(f"{cfg_path}: adcCfg sets real ADC output; sarbot imports complex (complex 1x) captures only")
    total = sum(p.stat().st_size for p in paths)
    frames = total // cfg.frame_bytes
    source = ", ".join(str(p) for p in paths)
    if frames == 0:
        raise SarbotError(f"{source}: {total} bytes hold no whole frame of {cfg.frame_bytes} bytes ({cfg.chirps_per_frame} "
                          f"chirps x {cfg.n_rx} RX x {cfg.adc_samples} samples x 4 bytes, from {cfg_path})")
    if total % cfg.frame_bytes:
        log.warning("%s: the last %d bytes are a partial frame and are left out", source, total % cfg.frame_bytes)
    shape = (cfg.chirps_per_frame, cfg.n_rx, cfg.adc_samples)

    head = next(_words(paths, cfg.frame_bytes))[: 4 * cfg.frame_bytes // 2]
    if sample_format == "auto":
        sample_format = guess_sample_format(head)
    if sample_format == "offset":
        head = offset_binary_to_twos(head)
    try:
        if layout == "auto":
            layout, found_swap, fits = choose_layout(head, *shape, source)
            iq_swap = found_swap if iq_swap is None else iq_swap
        else:
            fits = rank_layouts(head, *shape)
            iq_swap = cfg.iq_swap if iq_swap is None else iq_swap
            mine = next(f for f in fits if f.layout == layout and f.iq_swap == iq_swap)
            if fits[0] != mine and fits[0].sideband_db - mine.sideband_db >= MARGIN_DB:
                log.warning("%s: read as %s, but the samples fit %s better", source, mine.describe(), fits[0].describe())
    except CaptureLayoutError as exc:
        raise SarbotError(f"{source}: {exc}") from None
    chosen = next(f for f in fits if f.layout == layout and f.iq_swap == iq_swap)
    log.info("%s: %d frames, %s samples, layout %s", source, frames, sample_format, chosen.describe())

    wf = cfg.waveform()
    radar = RadarConfig(radar_name, wf, AntennaArray.uniform_tdm(wf), Mount())
    frame_ns = round(wf.frame_interval_s * 1e9)
    how = f"TI raw capture ({source}; {cfg_path}; layout {layout}, iq_swap {iq_swap}, {sample_format} samples)"
    with RecordingWriter(output, [radar], truth=True, wire_format="imported", adc_dtype="int16", overwrite=overwrite,
                         root_attrs={"imported_from": how}) as w:
        done = 0
        for words in _words(paths, cfg.frame_bytes):
            if sample_format == "offset":
                words = offset_binary_to_twos(words)
            iq = capture_to_iq(words, layout, *shape, iq_swap)
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
    return {"frames": done, "layout": layout, "iq_swap": iq_swap, "sample_format": sample_format,
            "sideband_db": round(chosen.sideband_db, 1), "scores": {f"{f.layout}{'/swap' if f.iq_swap else ''}":
                                                                   round(f.sideband_db, 1) for f in fits}}
