"""The Doppler scale's estimate from the map's readings (rio.doppler_scale): a weighted mean with its prior,
its variance widened by the readings' disagreement."""

import numpy as np
import pytest

from rio.doppler_scale import DopplerScaleEstimator, inflated_weighted_mean


def test_one_reading_is_the_scalar_kalman_update_against_the_prior():
    mean, variance = inflated_weighted_mean([1.02], [0.005], 1.0, 0.05)
    gain = 0.05 ** 2 / (0.05 ** 2 + 0.005 ** 2)
    assert mean == pytest.approx(1 + gain * 0.02, rel=1e-12)
    assert variance == pytest.approx((1 - gain) * 0.05 ** 2, rel=1e-12)  # chi2 0.16 of 1: not widened


def test_readings_that_agree_within_their_sigmas_are_not_widened():
    rng = np.random.default_rng(4)
    values = 1.02 + rng.normal(0, 0.004, 400)
    mean, variance = inflated_weighted_mean(values, np.full(400, 0.004), 1.0, 0.05)
    plain = 1 / (1 / 0.05 ** 2 + 400 / 0.004 ** 2)
    assert abs(mean - 1.02) < 3 * np.sqrt(plain)
    assert variance == pytest.approx(plain, rel=0.15)  # chi2 / N about 1: at most slightly widened


def test_readings_that_disagree_widen_the_variance_by_their_chi2_per_degree_of_freedom():
    values, sigmas = np.array([0.967, 1.031]), np.array([0.008, 0.0063])
    mean, variance = inflated_weighted_mean(values, sigmas, 1.0, 0.05)
    w = np.array([1 / 0.05 ** 2, *(1 / sigmas ** 2)])
    x = np.array([1.0, *values])
    assert mean == pytest.approx(w @ x / w.sum(), rel=1e-12)
    chi2 = float(w @ (x - mean) ** 2)
    assert chi2 / 2 > 15
    assert variance == pytest.approx(chi2 / 2 / w.sum(), rel=1e-12)
    # both readings within 2 of the widened sigmas; as sure as they claim, each would be 4 sigma off
    assert np.all(np.abs(values - mean) < 2 * np.sqrt(variance))
    assert np.all(np.abs(values - mean) > 4 / np.sqrt(w.sum()))


def test_the_estimator_re_estimates_from_every_reading_in_any_order():
    readings = [(1.03, 0.006), (0.97, 0.008), (1.021, 0.004), (1.018, 0.005)]
    forward, backward = DopplerScaleEstimator(0.05), DopplerScaleEstimator(0.05)
    assert (forward.scale, forward.variance) == (1.0, 0.05 ** 2)
    for value, sigma in readings:
        forward.add(value, sigma)
    for value, sigma in reversed(readings):
        backward.add(value, sigma)
    assert forward.scale == pytest.approx(backward.scale, rel=1e-12)
    assert forward.variance == pytest.approx(backward.variance, rel=1e-12)
    assert (forward.scale, forward.variance) == inflated_weighted_mean(*zip(*readings), 1.0, 0.05)
