import numpy as np
import pytest

from imaging.range_compression import range_compress

C = 299_792_458.0
F0, FSTEP = 77e9, 4e6


@pytest.mark.parametrize("n", [175, 176, 7])
@pytest.mark.parametrize("signed", [False, True])
def test_centring_is_the_phase_of_the_middle_sample(n, signed):
    """Centred profiles (made by placing the samples around position 0 before the FFT) are the plain
    profiles with the linear phase of the middle sample's frequency offset removed, bin by bin."""
    rng = np.random.default_rng(n)
    x = (rng.standard_normal((6, n)) + 1j * rng.standard_normal((6, n))).astype(np.complex64)
    plain = range_compress(x, F0, FSTEP, oversample=8, signed=signed, centred=False)
    centred = range_compress(x, F0, FSTEP, oversample=8, signed=signed, centred=True, guarded=True)
    m = (n - 1) // 2
    assert plain.carrier_hz == F0
    assert centred.carrier_hz == F0 + m * FSTEP
    np.testing.assert_array_equal(centred.range_axis_m, plain.range_axis_m)
    expected = plain.data * np.exp(2j * np.pi * m * FSTEP * plain.range_axis_m / C)
    assert np.abs(centred.data - expected).max() < 1e-6 * np.abs(expected).max()
    # The same windowed samples in their own order, and the kernel's guard bins left zero.
    np.testing.assert_array_equal(centred.samples, plain.samples)
    assert not centred.rows[:, 0].any() and not centred.rows[:, -2:].any()
    np.testing.assert_array_equal(centred.rows[:, 1:-2], centred.data)


def test_a_tone_peaks_at_its_range_with_unit_amplitude():
    n, r_two_way = 128, 3.7
    f = F0 + FSTEP * np.arange(n)
    x = np.exp(2j * np.pi * f * r_two_way / C).astype(np.complex64)  # the signal model of docs/signal-model.md
    prof = range_compress(x[None], F0, FSTEP, oversample=16, window="rectangular")
    k = np.argmax(np.abs(prof.data[0]))
    assert prof.range_axis_m[k] == pytest.approx(r_two_way, abs=prof.range_step_m)
    assert abs(prof.data[0, k]) == pytest.approx(1.0, abs=0.02)
    # Centred, the peak's phase is that of the carrier at the target's range (what backprojection removes).
    assert np.angle(prof.data[0, k] * np.exp(-2j * np.pi * prof.carrier_hz * prof.range_axis_m[k] / C)) == pytest.approx(0.0, abs=0.1)


@pytest.mark.parametrize("n", [175, 64])
def test_rows_written_into_a_reused_buffer_are_those_of_a_new_one(n):
    """Profiles compressed into a buffer an earlier block left full (``rows_out``, as form_image hands its
    blocks' buffers on) are the new buffer's bit for bit: guards, zero padding and spectrum; a buffer of
    the wrong shape is refused."""
    rng = np.random.default_rng(3)
    samples = (rng.standard_normal((40, n)) + 1j * rng.standard_normal((40, n))).astype(np.complex64)
    fresh = range_compress(samples, 77e9, 2.27e7, guarded=True, keep_samples=False, workers=2)
    used = np.full((40, 16 * n + 3), 7 - 3j, np.complex64)  # what an earlier block's FFT left, and more
    again = range_compress(samples, 77e9, 2.27e7, guarded=True, keep_samples=False, workers=2, rows_out=used)
    assert again.rows is used and np.shares_memory(again.data, used)
    np.testing.assert_array_equal(again.rows, fresh.rows)
    with pytest.raises(ValueError, match="rows_out"):
        range_compress(samples, 77e9, 2.27e7, guarded=True, rows_out=np.zeros((40, 16 * n + 2), np.complex64))
