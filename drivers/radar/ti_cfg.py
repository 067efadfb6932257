"""TI mmWave CLI ``.cfg`` files: the chirp, frame and channel settings a DCA1000 capture needs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from imaging.core.errors import ConfigError
from imaging.core.waveform import Waveform


@dataclasses.dataclass(frozen=True)
class TiRadarConfig:
    """What a raw capture's layout and waveform follow from (units as the TI CLI uses, converted below)."""

    start_freq_ghz: float
    idle_time_us: float
    ramp_end_time_us: float
    freq_slope_mhz_per_us: float
    adc_samples: int
    sample_rate_ksps: float
    rx_mask: int
    tx_order: tuple[int, ...]  # TX index of each chirp of a loop
    loops: int
    frame_periodicity_ms: float
    #: adcCfg's adcOutputFmt: "real" (0), "complex1x" (1, the IF band up to about 0.9 fs) or "complex2x" (2)
    adc_output: str = "complex1x"
    iq_swap: bool = True  # adcbufCfg SampleSwap: Q in the first (least significant) half of each pair

    @property
    def complex_output(self) -> bool:
        return self.adc_output != "real"

    @property
    def n_rx(self) -> int:
        return bin(self.rx_mask).count("1")

    @property
    def n_tx(self) -> int:
        return len(set(self.tx_order))

    @property
    def chirps_per_frame(self) -> int:
        return len(self.tx_order) * self.loops

    @property
    def frame_bytes(self) -> int:
        """Bytes of one frame as the DCA1000 streams it (int16 per real sample, two for complex)."""
        return self.chirps_per_frame * self.n_rx * self.adc_samples * (4 if self.complex_output else 2)

    def waveform(self) -> Waveform:
        fs = self.sample_rate_ksps * 1e3
        slope = self.freq_slope_mhz_per_us * 1e12
        sampling_s = self.adc_samples / fs
        return Waveform(
            f0_hz=self.start_freq_ghz * 1e9, bandwidth_hz=slope * sampling_s, chirp_duration_s=sampling_s,
            chirp_interval_s=(self.idle_time_us + self.ramp_end_time_us) * 1e-6, chirps_per_frame=self.chirps_per_frame,
            frame_interval_s=self.frame_periodicity_ms * 1e-3, sample_rate_hz=fs, n_tx=self.n_tx, n_rx=self.n_rx)


def cfg_commands(text: str) -> list[tuple[int, str]]:
    """(line number, command) of every line of a ``.cfg`` that is a command (``%`` comments and blank lines
    left out), as the radar's CLI is sent it and as it is parsed."""
    out = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("%", 1)[0].strip()
        if line:
            out.append((lineno, " ".join(line.split())))
    return out


def parse_ti_cfg(text: str, source: str = "<cfg>") -> TiRadarConfig:
    """Parse the commands sarbot needs; an error names the command and line."""
    cmds: dict[str, list[tuple[int, list[str]]]] = {}
    for lineno, command in cfg_commands(text):
        word, *args = command.split()
        cmds.setdefault(word, []).append((lineno, args))

    def need(word: str, n: int):
        if word not in cmds:
            raise ConfigError(word, "missing", source=source)
        for lineno, args in cmds[word]:
            if len(args) < n:
                raise ConfigError(f"{word} (line {lineno})", f"needs {n} values, has {len(args)}", source=source)
        return cmds[word]

    def num(value: str, word: str, lineno: int, kind=float):
        try:
            return kind(value)
        except ValueError:
            raise ConfigError(f"{word} (line {lineno})", f"{value!r} is not a number", source=source) from None

    (ln, profile), = need("profileCfg", 14)[:1]
    (lc, channel), = need("channelCfg", 2)[:1]
    (lf, frame), = need("frameCfg", 5)[:1]
    chirps = {}
    for lineno, args in need("chirpCfg", 8):
        start, end = num(args[0], "chirpCfg", lineno, int), num(args[1], "chirpCfg", lineno, int)
        tx_mask = num(args[7], "chirpCfg", lineno, int)
        if tx_mask <= 0 or tx_mask & (tx_mask - 1):
            raise ConfigError(f"chirpCfg (line {lineno})", f"TX mask {tx_mask} must enable exactly one TX (TDM)", source=source)
        for k in range(start, end + 1):
            chirps[k] = tx_mask.bit_length() - 1
    first, last = num(frame[0], "frameCfg", lf, int), num(frame[1], "frameCfg", lf, int)
    missing = [k for k in range(first, last + 1) if k not in chirps]
    if missing:
        raise ConfigError(f"frameCfg (line {lf})", f"uses chirps {missing} that no chirpCfg defines", source=source)
    adc_output = "complex1x"
    if "adcCfg" in cmds:
        la, adc = cmds["adcCfg"][0]
        if len(adc) >= 2:
            fmt = num(adc[1], "adcCfg", la, int)
            if fmt not in (0, 1, 2):
                raise ConfigError(f"adcCfg (line {la})", f"adcOutputFmt {fmt}: expected 0 (real), 1 (complex 1x) "
                                  "or 2 (complex 2x)", source=source)
            adc_output = ("real", "complex1x", "complex2x")[fmt]
    iq_swap = True
    if "adcbufCfg" in cmds:
        lb, buf = cmds["adcbufCfg"][0]
        # SDK 2+ puts a subframe index first (5 values); SDK 1.x has 4: format, swap, interleave, threshold.
        if len(buf) >= 4:
            iq_swap = num(buf[2] if len(buf) >= 5 else buf[1], "adcbufCfg", lb, int) != 0
    return TiRadarConfig(
        start_freq_ghz=num(profile[1], "profileCfg", ln), idle_time_us=num(profile[2], "profileCfg", ln),
        ramp_end_time_us=num(profile[4], "profileCfg", ln), freq_slope_mhz_per_us=num(profile[7], "profileCfg", ln),
        adc_samples=num(profile[9], "profileCfg", ln, int), sample_rate_ksps=num(profile[10], "profileCfg", ln),
        rx_mask=num(channel[0], "channelCfg", lc, int), tx_order=tuple(chirps[k] for k in range(first, last + 1)),
        loops=num(frame[2], "frameCfg", lf, int), frame_periodicity_ms=num(frame[4], "frameCfg", lf),
        adc_output=adc_output, iq_swap=iq_swap)


def load_ti_cfg(path: str | Path) -> TiRadarConfig:
    path = Path(path)
    if not path.exists():
        raise ConfigError("<file>", "no such file", source=str(path))
    return parse_ti_cfg(path.read_text(errors="replace"), source=str(path))
