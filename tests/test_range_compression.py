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


@pytest.mark.parametrize("n", [175, 64])
@pytest.mark.parametrize("centred", [True, False])
@pytest.mark.parametrize("window", ["hann", "rectangular"])
def test_a_window_of_bins_is_those_bins_of_the_full_profile(n, centred, window):
    """``bins``: the chirp-z transform's bins are the full FFT's (to -120 dB of the largest), on the same range
    axis and carrier, with the kernel's zero guards, the same kept samples, and anywhere in the profile."""
    rng = np.random.default_rng(n)
    x = (rng.standard_normal((700, n)) + 1j * rng.standard_normal((700, n))).astype(np.complex64)
    full = range_compress(x, F0, FSTEP, window=window, centred=centred, guarded=True)
    n_fft = 16 * n
    for k0, k1 in ((0, 40), (n_fft // 3, n_fft // 3 + n_fft // 5), (n_fft - 90, n_fft)):
        part = range_compress(x, F0, FSTEP, window=window, centred=centred, guarded=True, bins=(k0, k1))
        assert part.n_bins == k1 - k0 and part.rows.shape == (700, k1 - k0 + 3)
        assert np.abs(part.data - full.data[:, k0:k1]).max() < 1e-6 * np.abs(full.data).max()
        np.testing.assert_allclose(part.range_axis_m, full.range_axis_m[k0:k1], rtol=1e-12)
        assert part.carrier_hz == full.carrier_hz and part.bandwidth_hz == full.bandwidth_hz
        assert not part.rows[:, 0].any() and not part.rows[:, -2:].any()
        np.testing.assert_array_equal(part.samples, full.samples)


def test_a_wide_window_is_made_by_the_full_fft_and_bad_bins_are_refused():
    from imaging.range_window import worth_it

    x = np.ones((3, 175), np.complex64)
    assert worth_it(175, 2800, 560) and not worth_it(175, 2800, 1400)
    wide = range_compress(x, F0, FSTEP, guarded=True, bins=(100, 1500))  # cheaper as the whole profile
    assert wide.n_bins == 2800 and wide.range_start_m == 0.0
    np.testing.assert_array_equal(wide.data, range_compress(x, F0, FSTEP, guarded=True).data)
    for bad in ((5, 5), (-1, 10), (0, 2801)):
        with pytest.raises(ValueError, match="bins"):
            range_compress(x, F0, FSTEP, bins=bad)
    with pytest.raises(ValueError, match="bins"):
        range_compress(x, F0, FSTEP, signed=True, bins=(0, 10))


def test_a_window_into_a_reused_buffer_of_another_width():
    """form_image hands a block's buffer to the next (RowBuffers), whose window may be a few bins wider or
    narrower: the view it takes is written whole, guards included."""
    from imaging.image_formation import RowBuffers

    rng = np.random.default_rng(5)
    x = (rng.standard_normal((50, 175)) + 1j * rng.standard_normal((50, 175))).astype(np.complex64)
    buffers = RowBuffers()
    buffers.give(np.full((60, 520), 3 + 1j, np.complex64))
    rows = buffers.take((50, 403))
    assert rows is not None and rows.flags.c_contiguous
    used = range_compress(x, F0, FSTEP, guarded=True, bins=(600, 1000), rows_out=rows)
    np.testing.assert_array_equal(used.rows, range_compress(x, F0, FSTEP, guarded=True, bins=(600, 1000)).rows)
    buffers.give(used.rows)
    wider = buffers.take((60, 521))  # too large for it: a new buffer
    assert buffers.new_buffers == 1 and not np.shares_memory(wider, used.rows)


def test_range_bounds_hold_every_point_of_the_box():
    from imaging.range_window import needed_bins, two_way_range_bounds_m

    rng = np.random.default_rng(2)
    tx = rng.uniform(-1, 1, (30, 3))
    rx = tx + rng.uniform(-0.05, 0.05, (30, 3))
    lo, hi = np.array([0.5, 1.5, 0.2]), np.array([1.5, 2.5, 0.4])
    near, far = two_way_range_bounds_m(tx, rx, lo, hi)
    g = rng.uniform(lo, hi, (5000, 3))
    r = np.linalg.norm(tx[:, None] - g, axis=2) + np.linalg.norm(rx[:, None] - g, axis=2)
    assert near <= r.min() and r.max() <= far and far - near < 1.5 * (r.max() - r.min())
    # A box's corner nearest every antenna: the bound is reached.
    assert two_way_range_bounds_m(np.zeros((1, 3)), np.zeros((1, 3)), (1.0, 0.0, 0.0), (2.0, 1.0, 1.0))[0] == 2.0
    k0, k1 = needed_bins(near, far, 0.005, 4000)
    assert k0 * 0.005 <= near - 0.015 and (k1 - 1) * 0.005 >= far + 0.015
    assert needed_bins(-1.0, 50.0, 0.005, 4000) == (0, 4000)


def test_one_range_bin_spacing_for_the_whole_profile_and_a_window_of_it():
    from imaging.range_compression import range_bin_spacing_m

    x = np.ones((3, 175), np.complex64)
    step_m = range_bin_spacing_m(2800, FSTEP)
    assert step_m == 299_792_458.0 / (2800 * FSTEP)  # c / (n_fft frequency step), to the bit
    assert range_compress(x, F0, FSTEP).range_step_m == step_m
    window = range_compress(x, F0, FSTEP, guarded=True, bins=(600, 1000))
    assert window.range_step_m == step_m and window.range_start_m == 600 * step_m


@pytest.mark.parametrize("bins", [None, (600, 1000)])
def test_the_ffts_thread_count_leaves_the_profiles_bit_for_bit(bins):
    """Every row is transformed alone, so the FFT's thread count (``workers``: form_image asks for one per core)
    leaves the rows the same bit for bit, whole profiles and windows of bins (the chirp-z transform's two FFTs)
    alike."""
    rng = np.random.default_rng(11)
    x = (rng.standard_normal((300, 175)) + 1j * rng.standard_normal((300, 175))).astype(np.complex64)
    one = range_compress(x, F0, FSTEP, guarded=True, bins=bins, workers=1)
    for workers in (2, 3):
        np.testing.assert_array_equal(range_compress(x, F0, FSTEP, guarded=True, bins=bins, workers=workers).rows,
                                      one.rows)
