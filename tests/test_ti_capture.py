"""TI raw captures: the three byte layouts, finding layout and sample format from the data, and importing
the real AWR1243 and IWR1843 captures in ../shared/data as recordings that image."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA

from acquisition.importers.ti_capture import import_ti_capture
from drivers.radar.dca1000 import DATA_PORT, decode_complex_1x, parse_data_packet
from drivers.radar.pcap import read_udp
from drivers.radar.ti_cfg import load_ti_cfg
from drivers.radar.ti_capture import (
    LAYOUTS,
    capture_to_iq,
    guess_sample_format,
    iq_to_capture,
    offset_binary_to_twos,
    rank_layouts,
)
from imaging.core.errors import SarbotError
from imaging.io.recording import Recording

AWR1243 = SHARED_DATA / "awr1243_adc" / "adc_data.bin"
IWR1843 = SHARED_DATA / "dca1000_iwr1843_one_frame"

#: The .cfg files sarbot ships for the shared captures (what the AWR1243 file is known to hold; the IWR1843
#: profile cut to the 2 loops its one frame holds).
EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "ti"
AWR1243_CFG = EXAMPLES / "awr1243_adc.cfg"
IWR1843_CFG = EXAMPLES / "iwr1843_one_frame.cfg"


def reference_words(iq: np.ndarray, layout: str, iq_swap: bool) -> np.ndarray:
    """The documented word order written out sample by sample (independent of the vectorised code)."""
    frames, chirps, n_rx, samples, _ = iq.shape
    a, b = (1, 0) if iq_swap else (0, 1)
    out = []
    for f in range(frames):
        for c in range(chirps):
            if layout == "lvds2":
                for r in range(n_rx):
                    for s in range(0, samples, 2):
                        out += [iq[f, c, r, s, a], iq[f, c, r, s + 1, a], iq[f, c, r, s, b], iq[f, c, r, s + 1, b]]
            elif layout == "lvds4":
                for s in range(samples):
                    out += [iq[f, c, r, s, a] for r in range(n_rx)] + [iq[f, c, r, s, b] for r in range(n_rx)]
            else:
                for s in range(samples):
                    for r in range(n_rx):
                        out += [iq[f, c, r, s, a], iq[f, c, r, s, b]]
    return np.array(out, np.int16)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("iq_swap", [False, True])
def test_layouts_match_their_documented_word_order(layout, iq_swap):
    iq = np.random.default_rng(3).integers(-32768, 32767, (2, 3, 4, 6, 2), endpoint=True).astype(np.int16)
    words = iq_to_capture(iq, layout, iq_swap)
    np.testing.assert_array_equal(words, reference_words(iq, layout, iq_swap))
    np.testing.assert_array_equal(capture_to_iq(words, layout, 3, 4, 6, iq_swap), iq)


def beat_frames(frames=3, chirps=8, n_rx=4, samples=128, seed=0) -> np.ndarray:
    """int16 I/Q of two point targets as the radar sees them: positive beat frequencies, a phase and gain
    of each RX, receiver noise."""
    rng = np.random.default_rng(seed)
    n = np.arange(samples)
    z = np.zeros((frames, chirps, n_rx, samples), complex)
    for cycles, amp in ((17.3, 900.0), (41.8, 300.0)):
        rx = rng.uniform(0.7, 1.3, n_rx) * np.exp(2j * np.pi * rng.uniform(0, 1, n_rx))
        z += amp * rx[:, None] * np.exp(2j * np.pi * cycles * n / samples)
    z += 20 * (rng.standard_normal(z.shape) + 1j * rng.standard_normal(z.shape))
    return np.round(np.stack([z.real, z.imag], -1)).astype(np.int16)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("iq_swap", [False, True])
def test_the_layout_and_iq_order_are_found_from_the_samples(layout, iq_swap):
    """Two reflectors below 0.45 fs, as complex 2x delivers them."""
    iq = beat_frames()
    fits = rank_layouts(iq_to_capture(iq, layout, iq_swap), 8, 4, 128, adc_output="complex2x")
    assert (fits[0].layout, fits[0].iq_swap) == (layout, iq_swap)
    assert fits[0].score_db > 20
    # Its mirror (I and Q exchanged) is the worst reading, and no other layout comes near.
    assert (fits[-1].layout, fits[-1].iq_swap) == (layout, not iq_swap)
    assert max(f.score_db for f in fits if f.layout != layout) < fits[0].score_db - 5


def test_offset_binary_is_recognised():
    words = iq_to_capture(beat_frames(), "lvds2")
    assert guess_sample_format(words) == "twos"
    offset = offset_binary_to_twos(words)
    assert guess_sample_format(offset) == "offset"
    np.testing.assert_array_equal(offset_binary_to_twos(offset), words)
    assert offset_binary_to_twos(np.array([0, -32768, 32767, -1], np.int16)).tolist() == [-32768, 0, -1, 32767]


def test_awr1243_capture_imports_and_images(tmp_path):
    out = tmp_path / "awr1243.h5"
    got = import_ti_capture([AWR1243], AWR1243_CFG, out)
    assert (got["frames"], got["layout"], got["iq_swap"], got["sample_format"]) == (32, "interleaved", False, "offset")
    assert got["score_db"] > 10 and all(v < got["score_db"] - 6 for k, v in got["scores"].items()
                                           if not k.startswith("interleaved"))
    # The samples, read directly: offset binary, [frame][chirp][sample][RX][I, Q].
    raw = (np.fromfile(AWR1243, "<u2") ^ 0x8000).view(np.int16).reshape(32, 8, 256, 4, 2).transpose(0, 1, 3, 2, 4)
    with Recording(out) as rec:
        np.testing.assert_array_equal(rec.adc_iq("ti"), raw)
        assert rec.frame_time_ns("ti").tolist() == [k * 40_000_000 for k in range(32)]
        wf = rec.radar("ti").waveform
        x = rec.adc("ti")
    assert np.all(raw[:, :, 1] == 0)  # RX1 of that board is silent: the layout that shows it whole
    # The strongest range bin of the raw data (mean over chirps and live RX)...
    nfft = 4096
    profile = np.abs(np.fft.fft((x - x.mean(-1, keepdims=True)) * np.hanning(256), nfft, axis=-1))[:, :, [0, 2, 3]].mean((0, 1, 2))
    k = int(np.argmax(profile[1:nfft // 2])) + 1
    one_way_m = k * 299_792_458.0 * wf.sample_rate_hz / (nfft * wf.slope_hz_per_s) / 2
    # ...is where the backprojected image (radar at rest at the origin, looking along +x) has its peak.
    img = tmp_path / "img.h5"
    run = subprocess.run([sys.executable, "-m", "acquisition.cli", "-q", "image", str(out), "-o", str(img),
                          "--grid", "1:5:0.02,-2:2:0.02"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    metrics = json.loads(subprocess.run([sys.executable, "-m", "acquisition.cli", "-q", "analyze", str(img)],
                                        capture_output=True, text=True, check=True).stdout)
    assert metrics["range_to_target_m"] == pytest.approx(one_way_m, abs=0.03)
    assert 0.9 < metrics["range"]["ratio_to_theory"] < 1.15  # a focused range response, as wide as the bandwidth allows


def iwr1843_words() -> np.ndarray:
    packets = [d for d in read_udp(IWR1843 / "one_frame.pcap") if d.dst_port == DATA_PORT]
    return np.frombuffer(b"".join(bytes(parse_data_packet(d.payload)[2]) for d in packets), "<i2")


def iwr1843_cfg(tmp_path=None, loops: int = 2):
    """The capture's .cfg with the frame cut to what the capture holds (16384 bytes, 4 chirps: the shipped
    example), or to ``loops`` loops (a copy in ``tmp_path``)."""
    if loops == 2:
        return IWR1843_CFG
    path = tmp_path / "iwr1843.cfg"
    path.write_text(IWR1843_CFG.read_text().replace("frameCfg 0 1 2 0 100 1 0", f"frameCfg 0 1 {loops} 0 100 1 0"))
    return path


def test_the_shipped_iwr1843_cfg_is_the_radar_s_profile_cut_to_the_frame_the_capture_holds():
    shipped, radar = load_ti_cfg(IWR1843_CFG), load_ti_cfg(IWR1843 / "xwr18xx_profile.cfg")
    assert dataclasses.replace(shipped, loops=radar.loops) == radar
    assert shipped.frame_bytes == len(iwr1843_words()) * 2 == 16384


def test_a_dca1000_pcap_imports_directly_as_the_same_frame(tmp_path):
    """import-ti reads the network capture of the DCA1000's data port as it is (no adc_data.bin needed)."""
    out = tmp_path / "rec.h5"
    got = import_ti_capture([IWR1843 / "one_frame.pcap"], IWR1843_CFG, out)
    assert (got["frames"], got["layout"], got["iq_swap"]) == (1, "lvds2", True)
    with Recording(out) as rec:
        np.testing.assert_array_equal(rec.adc("ti")[0], decode_complex_1x(iwr1843_words().tobytes(), 4, 4, 256))


def test_a_datagram_lost_from_a_pcap_is_zeros_in_its_place_and_a_repeated_one_is_dropped(tmp_path, caplog):
    from drivers.radar.dca1000 import encode_data_packets
    from drivers.radar.pcap import write_udp

    words = iwr1843_words()
    packets = encode_data_packets(words.tobytes(), payload_bytes=1456)
    sent = packets[:3] + packets[4:] + [packets[5]]  # the fourth lost, the sixth again at the end
    pcap = tmp_path / "lossy.pcap"
    write_udp(pcap, [(4098, p) for p in sent])
    out = tmp_path / "rec.h5"
    import_ti_capture([pcap], IWR1843_CFG, out, layout="lvds2")
    assert "1456 bytes lost on the wire" in caplog.text
    expected = words.copy()
    expected[3 * 728:4 * 728] = 0
    with Recording(out) as rec:
        np.testing.assert_array_equal(rec.adc("ti")[0], decode_complex_1x(expected.tobytes(), 4, 4, 256))


@pytest.mark.parametrize("sample_format", ["twos", "offset"])
def test_iwr1843_capture_imports_in_either_sample_format(tmp_path, sample_format):
    words = iwr1843_words()
    data = words if sample_format == "twos" else offset_binary_to_twos(words)
    capture = tmp_path / "adc_data.bin"
    data.tofile(capture)
    out = tmp_path / "rec.h5"
    got = import_ti_capture([capture], iwr1843_cfg(tmp_path), out)
    assert (got["frames"], got["layout"], got["iq_swap"], got["sample_format"]) == (1, "lvds2", True, sample_format)
    with Recording(out) as rec:
        z = rec.adc("ti")[0]
    np.testing.assert_array_equal(z, decode_complex_1x(words.tobytes(), 4, 4, 256))
    flat = z.reshape(-1)
    for k, v in {4065: 223 + 120j, 3293: -90 - 615j, 415: -88 + 193j}.items():  # mmwave-capture-std's values
        assert flat[k] == v


def test_split_capture_files_join_and_a_partial_frame_is_left_out(tmp_path, caplog):
    iq = beat_frames(frames=5, chirps=4, n_rx=4, samples=256)  # the .cfg's dimensions: 2 TX x 2 loops
    words = iq_to_capture(iq, "lvds2", True)
    cut = 3 * words.size // 7  # mid-frame, as mmWave Studio cuts files by size
    (tmp_path / "adc_data_0.bin").write_bytes(words[:cut].tobytes())
    (tmp_path / "adc_data_1.bin").write_bytes(words[cut:].tobytes() + b"\x01\x02\x03")
    out = tmp_path / "rec.h5"
    got = import_ti_capture([tmp_path / "adc_data_0.bin", tmp_path / "adc_data_1.bin"], iwr1843_cfg(tmp_path), out)
    assert got["frames"] == 5 and "partial frame" in caplog.text
    with Recording(out) as rec:
        np.testing.assert_array_equal(rec.adc_iq("ti"), iq)


def test_declared_velocity_becomes_the_truth(tmp_path):
    capture = tmp_path / "adc_data.bin"
    iq_to_capture(beat_frames(frames=4, chirps=4, samples=256), "lvds2", True).tofile(capture)
    out = tmp_path / "rec.h5"
    import_ti_capture([capture], iwr1843_cfg(tmp_path), out, velocity_mps=(0.0, 0.05, 0.0))
    with Recording(out) as rec:
        truth = rec.truth()
    assert truth.time_ns.tolist() == [k * 100_000_000 for k in range(5)]
    np.testing.assert_allclose(truth.position_m[-1], [0.0, 0.02, 0.0])


def test_bad_captures_get_one_line_errors(tmp_path):
    cfg = iwr1843_cfg(tmp_path)
    small = tmp_path / "small.bin"
    small.write_bytes(b"\x00" * 1000)
    with pytest.raises(SarbotError, match="hold no whole frame of 16384 bytes"):
        import_ti_capture([small], cfg, tmp_path / "a.h5")
    noise = tmp_path / "noise.bin"
    np.random.default_rng(0).integers(-500, 500, 8192 * 3, dtype=np.int16).tofile(noise)
    with pytest.raises(SarbotError, match="cannot tell the sample layout.*--layout"):
        import_ti_capture([noise], cfg, tmp_path / "b.h5")
    assert not (tmp_path / "b.h5").exists()
    # The same noise with the layout given is taken as it is.
    assert import_ti_capture([noise], cfg, tmp_path / "c.h5", layout="lvds2")["frames"] == 3
    with pytest.raises(SarbotError, match="no such capture file"):
        import_ti_capture([tmp_path / "missing.bin"], cfg, tmp_path / "d.h5")
    run = subprocess.run([sys.executable, "-m", "acquisition.cli", "import-ti", str(noise), "--cfg", str(cfg), "-o",
                          str(tmp_path / "e.h5"), "--velocity", "1,2"], capture_output=True, text=True)
    assert run.returncode == 2 and run.stderr.strip().count("\n") == 0 and "--velocity '1,2'" in run.stderr


def _cfg(tmp_path, adc_output_fmt: int, swap: int = 1) -> Path:
    """The IWR1843 example (4 chirps x 4 RX x 256 samples) with another adcCfg output format and SampleSwap."""
    text = IWR1843_CFG.read_text().replace("adcCfg 2 1", f"adcCfg 2 {adc_output_fmt}").replace(
        "adcbufCfg -1 0 1 1 1", f"adcbufCfg -1 0 {swap} 1 1")
    path = tmp_path / f"fmt{adc_output_fmt}.cfg"
    path.write_text(text)
    return path


def echoes(reflectors, frames=2, chirps=4, n_rx=4, samples=256, seed=5, real=False) -> np.ndarray:
    """Beat signals of ``reflectors`` ((beat frequency in fractions of fs, amplitude), ...) with a phase and
    gain per RX and receiver noise: int16 I/Q [frames, chirps, n_rx, samples, 2], or real int16 samples."""
    rng = np.random.default_rng(seed)
    n = np.arange(samples)
    z = np.zeros((frames, chirps, n_rx, samples), complex)
    for f, amp in reflectors:
        rx = rng.uniform(0.8, 1.2, n_rx) * np.exp(2j * np.pi * rng.uniform(0, 1, n_rx))
        z += amp * rx[:, None] * np.exp(2j * np.pi * f * n)
    if real:
        return np.round(z.real + 20 * rng.standard_normal(z.shape)).astype(np.int16)
    z += 20 * (rng.standard_normal(z.shape) + 1j * rng.standard_normal(z.shape))
    return np.round(np.stack([z.real, z.imag], -1)).astype(np.int16)


#: A scene as a complex-1x radar sees it: the TX-RX coupling just above DC, a weak reflector at 0.3 fs and
#: the strongest one at 0.65 fs, beyond c fs / (4 slope) (OpenRadar's IWR1642 frame has its strongest
#: return at 5.2 m, past half the band, and was refused at +3.2 dB by a half-band test).
FAR_SCENE = ((0.006, 400.0), (0.3, 500.0), (0.65, 3000.0))


@pytest.mark.parametrize("iq_swap", [False, True])
def test_a_complex_1x_capture_with_its_strongest_reflector_past_half_the_band_is_read_right(tmp_path, iq_swap):
    iq = echoes(FAR_SCENE)
    words = iq_to_capture(iq, "lvds2", iq_swap)
    half_band = rank_layouts(words, 4, 4, 256, adc_output="complex2x")
    assert (half_band[0].layout, half_band[0].iq_swap) != ("lvds2", iq_swap)  # a half-band test gets it wrong
    capture = tmp_path / "adc_data.bin"
    words.tofile(capture)
    out = tmp_path / "rec.h5"
    got = import_ti_capture([capture], _cfg(tmp_path, 1, swap=int(not iq_swap)), out)  # the .cfg's swap is wrong
    assert (got["adc_output"], got["layout"], got["iq_swap"]) == ("complex1x", "lvds2", iq_swap)
    assert got["score_db"] > 8 and all(v < got["score_db"] - 6 for k, v in got["scores"].items() if k != "lvds2" +
                                        ("/swap" if iq_swap else ""))
    with Recording(out) as rec:
        np.testing.assert_array_equal(rec.adc_iq("ti"), iq)
        spectrum = np.abs(np.fft.fft(rec.adc("ti"), axis=-1)).mean((0, 1, 2))
    assert int(np.argmax(spectrum)) == round(0.65 * 256)  # the far reflector where it is, not at its mirror


def test_a_complex_2x_capture_is_read_with_the_half_band_test(tmp_path):
    iq = echoes(((0.02, 400.0), (0.12, 900.0), (0.4, 300.0)))
    capture = tmp_path / "adc_data.bin"
    iq_to_capture(iq, "interleaved", True).tofile(capture)
    got = import_ti_capture([capture], _cfg(tmp_path, 2), tmp_path / "rec.h5")
    assert (got["adc_output"], got["layout"], got["iq_swap"]) == ("complex2x", "interleaved", True)


def test_a_real_only_capture_is_found_in_its_sample_order_and_imported_as_the_analytic_signal(tmp_path):
    x = echoes(((0.05, 600.0), (0.21, 1500.0)), real=True)  # [frames, chirps, rx, samples]: the lvds2 order
    capture = tmp_path / "adc_data.bin"
    np.ascontiguousarray(x, "<i2").tofile(capture)
    out = tmp_path / "rec.h5"
    got = import_ti_capture([capture], _cfg(tmp_path, 0), out)
    assert (got["adc_output"], got["layout"], got["iq_swap"], got["measure"]) == ("real", "lvds2", False, "spectral peak")
    assert got["score_db"] > got["scores"]["interleaved"] + 15
    with Recording(out) as rec:
        z = rec.adc("ti")
    assert z.dtype == np.complex64 and z.shape == (2, 4, 4, 256)
    np.testing.assert_allclose(z.real, x - x.mean(-1, keepdims=True), atol=1e-3)  # the samples, as the real part
    spectrum = np.abs(np.fft.fft(z, axis=-1)).mean((0, 1, 2))
    assert int(np.argmax(spectrum)) == round(0.21 * 256)
    assert 20 * np.log10(spectrum[round(0.21 * 256)] / spectrum[256 - round(0.21 * 256)]) > 30  # no mirror image


def test_a_real_only_capture_in_the_order_that_looks_alike_asks_for_its_layout(tmp_path):
    """Per sample, per RX: read per RX, per sample, each profile is the same sinusoids in four decimated
    pieces, nearly as peaky -- too close to call, so the candidates are listed; --layout imports it."""
    x = echoes(((0.05, 600.0), (0.21, 1500.0)), real=True)
    capture = tmp_path / "adc_data.bin"
    np.ascontiguousarray(x.transpose(0, 1, 3, 2), "<i2").tofile(capture)
    with pytest.raises(SarbotError, match=r"candidate readings: interleaved: spectral peak \+5[0-9.]+ dB; lvds2"):
        import_ti_capture([capture], _cfg(tmp_path, 0), tmp_path / "auto.h5")
    out = tmp_path / "rec.h5"
    got = import_ti_capture([capture], _cfg(tmp_path, 0), out, layout="lvds4")  # the same order for real samples
    assert got["layout"] == "interleaved"
    with Recording(out) as rec:
        np.testing.assert_allclose(rec.adc("ti").real, x - x.mean(-1, keepdims=True), atol=1e-3)


def test_an_ambiguous_capture_lists_every_candidate_reading_with_its_score(tmp_path):
    capture = tmp_path / "noise.bin"
    np.random.default_rng(1).integers(-500, 500, 8192 * 2, dtype=np.int16).tofile(capture)
    with pytest.raises(SarbotError) as err:
        import_ti_capture([capture], IWR1843_CFG, tmp_path / "rec.h5")
    message = str(err.value)
    assert "the candidate readings:" in message and "--layout" in message
    assert message.count("sideband ratio") == 6  # three layouts, each in both I/Q orders
