"""Noise, BLA and distortion analysis on synthetic data (ambid.frf.uncertainty)."""

import numpy as np
import pytest
from ambid.frf import (bla_robust, distortion_levels, frf_noise_variance, output_noise_std, period_mean_variance,
                       period_spectra, split_periods)


def _cn(rng, *shape):
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)   # E|.|^2 = 1


def _bla_data(m, p, n_lines, sigma, s_nl, seed):
    """SISO spectra: Y = (G0 + Gs_m) U_m + V, |U_m| = 1 fixed over periods,
    Gs_m (stochastic NL, variance s_nl^2) per realisation, V (variance sigma^2) per period."""
    rng = np.random.default_rng(seed)
    g0 = np.exp(1j * np.linspace(0, 3, n_lines)) * (1 + np.arange(n_lines) / n_lines)
    u = np.broadcast_to(np.exp(2j * np.pi * rng.uniform(size=(m, 1, 1, n_lines, 1))), (m, 1, p, n_lines, 1))
    gs = s_nl * _cn(rng, m, 1, 1, n_lines, 1)
    y = (g0[:, None] + gs) * u + sigma * _cn(rng, m, 1, p, n_lines, 1)
    return y, u, g0


def test_robust_method_variances_match_theory():
    m, p, sigma, s_nl = 6, 8, 0.3, 0.2
    y, u, g0 = _bla_data(m, p, 500, sigma, s_nl, seed=1)
    bla = bla_robust(y, u)
    assert bla.frf.shape == bla.var_noise.shape == (500, 1, 1)
    assert (bla.n_realisations, bla.n_periods) == (m, p)
    var_noise_theory = sigma**2 / (p * m)
    var_total_theory = (s_nl**2 + sigma**2 / p) / m
    assert abs(bla.var_noise.mean() / var_noise_theory - 1) < 0.1
    assert abs(bla.var_total.mean() / var_total_theory - 1) < 0.1
    assert abs(bla.var_stochastic_nl.mean() / s_nl**2 - 1) < 0.15
    np.testing.assert_allclose(bla.var_bla_nl, np.clip(bla.var_total - bla.var_noise, 0, None))
    # the BLA scatters around G0 with the total variance
    assert abs(np.mean(np.abs(bla.frf[:, 0, 0] - g0) ** 2) / var_total_theory - 1) < 0.15


def test_without_nonlinearity_total_equals_noise_variance():
    y, u, _ = _bla_data(6, 8, 500, 0.3, 0.0, seed=2)
    bla = bla_robust(y, u, r=u[:, :, :1])
    assert abs(bla.var_total.mean() / bla.var_noise.mean() - 1) < 0.1
    # the clipped difference is biased up a little, but stays well below the
    # noise variance sigma^2 / P of one realisation's FRF
    assert bla.var_stochastic_nl.mean() < 0.3 * 0.3**2 / 8


def test_frf_noise_variance_single_realisation_and_errors():
    y, u, g0 = _bla_data(1, 5, 50, 0.1, 0.0, seed=3)
    g_m, var_n = frf_noise_variance(y, u)
    assert g_m.shape == var_n.shape == (1, 50, 1, 1)
    gk = (y / u)[0, 0, :, :, 0]                         # (P, L)
    np.testing.assert_allclose(var_n[0, :, 0, 0], gk.var(axis=0, ddof=1) / 5)
    np.testing.assert_allclose(g_m[0, :, 0, 0], y[0, 0].mean(axis=0)[:, 0] / u[0, 0, 0, :, 0])
    with pytest.raises(ValueError, match="M >= 2"):
        bla_robust(y, u)
    with pytest.raises(ValueError, match="P >= 2"):
        frf_noise_variance(y[:, :, :1], u[:, :, :1])


def test_period_mean_variance():
    rng = np.random.default_rng(4)
    x = _cn(rng, 2, 1, 6, 3, 2)
    mean, var = period_mean_variance(x)
    assert mean.shape == var.shape == (2, 1, 3, 2)
    np.testing.assert_allclose(mean, x.mean(axis=2))
    np.testing.assert_allclose(var, np.sum(np.abs(x - x.mean(axis=2, keepdims=True)) ** 2, axis=2) / 30)


def test_output_noise_std_ignores_the_periodic_part():
    n, p, sigma = 256, 6, 0.02
    rng = np.random.default_rng(5)
    t = np.arange(n)
    periodic = 3.0 * np.cos(2 * np.pi * 7 * t / n)[:, None] * np.array([1.0, -2.0])
    x = np.tile(periodic, (2 * 1 * (1 + p), 1))
    x = x + sigma * np.array([1.0, 2.0]) * rng.standard_normal(x.shape)
    est = output_noise_std(split_periods(x, n, p, 1, 2, 1))
    np.testing.assert_allclose(est, sigma * np.array([1.0, 2.0]), rtol=0.05)
    with pytest.raises(ValueError, match="P >= 2"):
        output_noise_std(split_periods(x[: 2 * 2 * n], n, 1, 1, 2, 1))


def test_distortion_levels_against_closed_form():
    # periodic distortion of amplitude a at odd lines, noise only at even
    n, p, m, sigma, a = 128, 8, 3, 0.01, 0.01
    rng = np.random.default_rng(6)
    t = np.arange(n)
    odd_lines, even_lines = np.array([3, 7, 11]), np.array([2, 6, 10])
    dist = sum(a * np.cos(2 * np.pi * k * t / n + rng.uniform(0, 6)) for k in odd_lines)
    x = dist[None, None, None, :, None] + sigma * rng.standard_normal((m, 1, p, n, 1))
    lv = distortion_levels(period_spectra(x, odd_lines), period_spectra(x, even_lines))
    noise_floor = 4 * sigma**2 / n / p           # var of the period mean at a line
    np.testing.assert_allclose(lv.odd_noise_power.mean(), noise_floor, rtol=0.25)
    expected_odd_db = 10 * np.log10((a**2 + noise_floor) / noise_floor)
    assert abs(lv.odd_db[0] - expected_odd_db) < 1.0
    assert abs(lv.even_db[0]) < 2.0
    none = distortion_levels(period_spectra(x, odd_lines), period_spectra(x, np.array([], int)))
    assert np.isnan(none.even_db).all() and none.even_power.shape == (0, 1)
