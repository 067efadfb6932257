"""The Doppler fit's bias from elevation noise (issue 35): predicted by rio.ego_velocity.fit_gain, the vertical
cross-talk taken out by the default fit, whose covariance then covers its vertical error at speed."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rio.ego_velocity import EgoStatus, EgoVelocityConfig, fit_gain, sensor_velocity

MEASURED = dataclasses.replace(EgoVelocityConfig(), elevation_sigma_deg=0.0, azimuth_sigma_deg=0.0)
CORRECTED = EgoVelocityConfig()  # 3 deg elevation, 1 deg azimuth: the noise the scans below get; cross-talk removed
SPEED = np.array([0.6, 0.0, 0.0])  # along the boresight, m/s


def scene(n, el_mean_deg, el_half_spread_deg, seed=1):
    rng = np.random.default_rng(seed)
    el = np.radians(rng.uniform(el_mean_deg - el_half_spread_deg, el_mean_deg + el_half_spread_deg, n))
    az = np.radians(rng.uniform(-60, 60, n))
    return el, az, rng.uniform(1.0, 8.0, n), rng


def fit_errors(el, az, rng_m, rng, trials, config, el_sigma_deg=3.0, az_sigma_deg=1.0):
    """Velocity error [trials, 3] and z variance [trials] of the fit over noise draws of the same scene."""
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    err, var = [], []
    for _ in range(trials):
        el_m = el + np.radians(rng.normal(0, el_sigma_deg, el.size))
        az_m = az + np.radians(rng.normal(0, az_sigma_deg, el.size))
        xyz = rng_m[:, None] * np.column_stack([np.cos(el_m) * np.cos(az_m), np.cos(el_m) * np.sin(az_m), np.sin(el_m)])
        est = sensor_velocity(xyz, -u @ SPEED + rng.normal(0, 0.02, el.size), config)
        assert est.status is EgoStatus.OK
        err.append(est.velocity_mps - SPEED)
        var.append(est.covariance[2, 2])
    return np.asarray(err), np.asarray(var), u


def test_fit_gain_predicts_the_vertical_bias_and_the_default_fit_removes_it():
    el, az, rng_m, rng = scene(600, -10.0, 10.0)  # scatterers below the radar, as a floor robot's floor and legs
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    predicted = (fit_gain(u, math.radians(3.0), math.radians(1.0)) - np.eye(3)) @ SPEED
    assert -0.015 > predicted[2] > -0.025  # about a 1.5 deg pitch at 0.6 m/s
    trials = 200
    for config, expected in ((MEASURED, predicted[2]), (CORRECTED, 0.0)):
        err, _, _ = fit_errors(el, az, rng_m, np.random.default_rng(7), trials, config)
        standard_error = err[:, 2].std() / math.sqrt(trials)
        assert abs(err[:, 2].mean() - expected) < 3 * standard_error + 5e-4, (config, err[:, 2].mean(), expected)


def test_no_bias_without_elevation_noise_and_the_gain_is_identity():
    el, az, _, _ = scene(200, -10.0, 10.0)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    np.testing.assert_allclose(fit_gain(u, 0.0, 0.0), np.eye(3), atol=1e-12)
    # Symmetric about the horizon: the elevation noise's vertical bias averages out (it is odd in the elevation).
    el_sym = np.concatenate([el, -el])
    u_sym = np.column_stack([np.cos(el_sym) * np.cos(np.r_[az, az]), np.cos(el_sym) * np.sin(np.r_[az, az]), np.sin(el_sym)])
    assert abs(fit_gain(u_sym, math.radians(3.0))[2, 0]) < 1e-12


def test_corrected_covariance_covers_the_vertical_error_at_speed():
    """The fit on measured directions is confident and biased at speed (z NEES about 3); without the cross-talk
    the same covariance covers the error (NEES about 1)."""
    el, az, rng_m, _ = scene(600, -10.0, 10.0, seed=3)
    nees = {}
    for name, config in (("measured", MEASURED), ("corrected", CORRECTED)):
        err, var, _ = fit_errors(el, az, rng_m, np.random.default_rng(11), 150, config)
        nees[name] = float(np.mean(err[:, 2] ** 2 / var))
    assert nees["measured"] > 2.0
    assert 0.6 < nees["corrected"] < 1.4


def test_only_the_vertical_velocity_changes_and_a_radar_without_elevation_not_at_all():
    el, az, rng_m, rng = scene(80, -10.0, 10.0, seed=5)
    xyz = rng_m[:, None] * np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    doppler = -(xyz / rng_m[:, None]) @ SPEED + rng.normal(0, 0.02, el.size)
    plain, corrected = sensor_velocity(xyz, doppler, MEASURED), sensor_velocity(xyz, doppler, CORRECTED)
    np.testing.assert_array_equal(plain.velocity_mps[:2], corrected.velocity_mps[:2])
    np.testing.assert_array_equal(plain.covariance[:2, :2], corrected.covariance[:2, :2])
    # Scatterers below the radar: the plain fit's vertical velocity reads low by about 0.03 m/s per m/s forward.
    assert 0.01 < corrected.velocity_mps[2] - plain.velocity_mps[2] < 0.03
    flat = xyz.copy()
    flat[:, 2] = 0.0  # a linear array: no elevation measured, nothing to correct
    a, b = sensor_velocity(flat, doppler, MEASURED), sensor_velocity(flat, doppler, CORRECTED)
    np.testing.assert_array_equal(a.velocity_mps, b.velocity_mps)
    np.testing.assert_array_equal(a.covariance, b.covariance)
