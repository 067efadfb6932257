"""Real airborne SAR data (AFRL Gotcha, X band, antenna ~10 km from the scene, phase history referenced to
the scene centre): exercises the per-profile reference range and float64 geometry far from the origin."""

import numpy as np
import pytest
from conftest import SHARED_DATA
from reference_backprojection import backproject_reference

from imaging import metrics
from imaging.backprojection import PHASE_ROUNDING_RAD, backproject
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.io.phase_history import read_afrl_gotcha
from imaging.range_compression import range_compress

GOTCHA = SHARED_DATA / "afrl_gotcha_pass1_hh"


@pytest.fixture(scope="module")
def gotcha():
    if not GOTCHA.exists():
        pytest.fail(f"real data missing: {GOTCHA} (tests read ../shared/data beside the checkout)")
    ph = read_afrl_gotcha(GOTCHA)
    prof = range_compress(ph.samples, ph.f0_hz, ph.frequency_step_hz, window="rectangular", signed=True)
    return ph, prof


def plane(x, y):
    xx, yy = np.meshgrid(x, y)
    return np.stack([xx, yy, np.zeros_like(xx)], axis=-1)


def test_reads_four_files_of_pass_1(gotcha):
    ph, _ = gotcha
    assert ph.samples.shape == (469, 424)
    assert ph.bandwidth_hz == pytest.approx(424 * 1.471488e6, rel=1e-3)  # step fitted to float32 frequencies
    assert np.linalg.norm(ph.antenna_m, axis=1).min() > 10_000  # 10 km out, scene centre at the origin


def test_brightest_scatterer_focuses_to_theory(gotcha):
    ph, prof = gotcha
    x = y = np.arange(-40.0, 40.0, 0.25)
    coarse = backproject(prof, ph.antenna_m, ph.antenna_m, plane(x, y), reference_range_m=ph.reference_range_m)
    _, (px, py) = metrics.find_peak(coarse, x, y)
    xf, yf = np.arange(px - 3, px + 3, 0.02), np.arange(py - 3, py + 3, 0.02)
    fine = backproject(prof, ph.antenna_m, ph.antenna_m, plane(xf, yf), reference_range_m=ph.reference_range_m)
    centre = ph.antenna_m.mean(axis=0)
    look = -centre[:2] / np.linalg.norm(centre[:2])
    a = metrics.analyze_target(fine, xf, yf, look, half_length_m=2.0)
    slant = np.linalg.norm(centre)
    depression = np.arcsin(centre[2] / slant)
    aperture = np.linalg.norm(ph.antenna_m[-1] - ph.antenna_m[0])
    wavelength = SPEED_OF_LIGHT_MPS / (ph.f0_hz + 0.5 * ph.bandwidth_hz)
    # Rectangular windows; range width projected from slant to the ground plane.
    theory_range = metrics.range_resolution_theory_m(ph.bandwidth_hz, "rectangular") / np.cos(depression)
    theory_cross = metrics.cross_range_resolution_theory_m(wavelength, slant, aperture)
    assert a["range"]["half_power_width_m"] == pytest.approx(theory_range, rel=0.05)
    assert a["cross_range"]["half_power_width_m"] == pytest.approx(theory_cross, rel=0.05)
    # A strong isolated scatterer stands well above the rest of the scene.
    assert a["snr_db"] > 30


def test_kernel_matches_reference_and_matched_filter_on_real_data(gotcha):
    ph, prof = gotcha
    pts = plane(np.arange(-30.0, 30.0, 1.9), np.arange(-30.0, 30.0, 1.9))
    kwargs = dict(reference_range_m=ph.reference_range_m)
    linear = backproject(prof, ph.antenna_m, ph.antenna_m, pts, **kwargs)
    ref = backproject_reference(prof, ph.antenna_m, ph.antenna_m, pts, mode="linear", **kwargs)
    # The float32 kernel rounds each pixel's range offset within a phase budget of PHASE_ROUNDING_RAD (-80 dB);
    # blocks chosen by their own extent (not the grid's) take it here, 10 km out: 6e-5 of the peak measured.
    assert np.abs(linear - ref).max() < PHASE_ROUNDING_RAD * np.abs(ref).max()
    exact = backproject(prof, ph.antenna_m, ph.antenna_m, pts, mode="exact", **kwargs)
    ser = 20 * np.log10(np.linalg.norm(exact) / np.linalg.norm(linear - exact))
    assert ser > 50.0  # rectangular window (more high-frequency content than Hann) at 16x
