"""FRF estimators on synthetic spectra with known answers (ambid.frf.estimators)."""

import numpy as np
import pytest
from ambid.frf import (arithmetic_mean, errors_in_variables, h1, h2, indirect, log_mean, multiple_coherence,
                       per_period_frf, sine_amplitude, stepped_sine_frf, welch_frf)
from scipy import signal


def _cn(rng, *shape):
    return rng.standard_normal(shape) + 1j * rng.standard_normal(shape)


def _open_loop(g, m, ne, p, seed, noise_y=0.0, noise_u=0.0):
    """Spectra (M, Ne, P, L, ch) with Y = G U0 + noise, U = U0 + noise; U0 per
    (m, e) is fixed over the periods (periodic excitation)."""
    rng = np.random.default_rng(seed)
    n_lines, ny, nu = g.shape
    u0 = np.broadcast_to(_cn(rng, m, ne, 1, n_lines, nu), (m, ne, p, n_lines, nu))
    y0 = np.einsum("lab,meplb->mepla", g, u0)
    y = y0 + noise_y * _cn(rng, m, ne, p, n_lines, ny) / np.sqrt(2)
    u = u0 + noise_u * _cn(rng, m, ne, p, n_lines, nu) / np.sqrt(2)
    return y, u, u0


@pytest.mark.parametrize("ny,nu,ne", [(1, 1, 1), (3, 2, 2), (2, 2, 3)])
def test_all_estimators_exact_without_noise(ny, nu, ne):
    rng = np.random.default_rng(1)
    g = _cn(rng, 5, ny, nu)
    y, u, _ = _open_loop(g, 2, ne, 3, seed=2)
    estimates = [h1(y, u), arithmetic_mean(y, u), log_mean(y, u), errors_in_variables(y, u)]
    # closed loop-like: u = S r with an arbitrary invertible S, reference r given
    s = _cn(rng, 5, nu, nu) + 3 * np.eye(nu)
    r = np.einsum("lab,meplb->mepla", np.linalg.inv(s), u)
    estimates.append(indirect(y, u, r))
    estimates.append(per_period_frf(y, u, r).mean(axis=(0, 1)))
    if ny == nu:
        estimates.append(h2(y, u))
    for est in estimates:
        assert est.shape == (5, ny, nu)
        np.testing.assert_allclose(est, g, rtol=1e-10, atol=1e-12)


def test_reference_with_one_period_is_broadcast():
    rng = np.random.default_rng(3)
    g = _cn(rng, 4, 2, 2)
    y, u, u0 = _open_loop(g, 2, 2, 3, seed=4, noise_y=0.1)
    np.testing.assert_allclose(indirect(y, u, u0[:, :, :1]), indirect(y, u, u0))


def test_h1_h2_bias_under_output_and_input_noise():
    # SISO, random input per record: E H1 = G |U|^2 / (|U|^2 + s_u^2) with
    # input noise; H2 = S_yy / S_uy -> G (1 + s_y^2 / (|G|^2 E|U|^2)) with output noise.
    g = np.array([[[2.0 - 1.0j]]])
    rng = np.random.default_rng(5)
    u0 = _cn(rng, 1, 1, 4000, 1, 1) / np.sqrt(2)                # E|U|^2 = 1
    noise = _cn(rng, 1, 1, 4000, 1, 1) / np.sqrt(2)
    y_clean = g[0, 0, 0] * u0
    s_y = 1.0
    np.testing.assert_allclose(h1(y_clean + s_y * noise, u0)[0, 0, 0], g[0, 0, 0], rtol=0.03)
    expected_h2 = g[0, 0, 0] * (1 + s_y**2 / abs(g[0, 0, 0]) ** 2)
    np.testing.assert_allclose(h2(y_clean + s_y * noise, u0)[0, 0, 0], expected_h2, rtol=0.03)
    s_u = 0.7
    expected_h1 = g[0, 0, 0] / (1 + s_u**2)
    np.testing.assert_allclose(h1(y_clean, u0 + s_u * noise)[0, 0, 0], expected_h1, rtol=0.03)
    np.testing.assert_allclose(h2(y_clean, u0 + s_u * noise)[0, 0, 0], g[0, 0, 0], rtol=0.03)


def test_means_match_independent_computation():
    rng = np.random.default_rng(6)
    g = _cn(rng, 3, 2, 2)
    y, u, _ = _open_loop(g, 3, 2, 4, seed=7, noise_y=0.2, noise_u=0.05)
    per = np.empty((3, 4, 3, 2, 2), complex)
    eiv = np.zeros((3, 2, 2), complex)
    for m in range(3):
        for line in range(3):
            eiv[line] += (y[m, :, :, line].mean(axis=1).T @ np.linalg.inv(u[m, :, :, line].mean(axis=1).T)) / 3
            for p in range(4):
                per[m, p, line] = y[m, :, p, line].T @ np.linalg.inv(u[m, :, p, line].T)
    np.testing.assert_allclose(per_period_frf(y, u), per, rtol=1e-10)
    np.testing.assert_allclose(arithmetic_mean(y, u), per.mean(axis=(0, 1)), rtol=1e-10)
    np.testing.assert_allclose(errors_in_variables(y, u), eiv, rtol=1e-10)


def test_log_mean_is_geometric_mean_without_phase_wrapping():
    # per-period FRFs G0 exp(eps_k) around G0 = -1 (phase +-pi): a naive log
    # would wrap; the result must be G0 exp(mean eps_k) exactly.
    rng = np.random.default_rng(8)
    g0 = -1.0 + 1e-3j
    eps = 0.2 * rng.standard_normal(6) + 0.3j * rng.standard_normal(6)
    gk = g0 * np.exp(eps)
    u = _cn(rng, 1, 1, 6, 1, 1)
    y = gk[None, None, :, None, None] * u
    np.testing.assert_allclose(log_mean(y, u)[0, 0, 0], g0 * np.exp(eps.mean()), rtol=1e-12)
    assert abs(log_mean(y, u)[0, 0, 0] - gk.mean()) > 1e-4     # differs from the arithmetic mean


def test_multiple_coherence_closed_form():
    rng = np.random.default_rng(9)
    g = np.array([[[1.5j]]])
    u = _cn(rng, 1, 1, 3000, 2, 1) / np.sqrt(2)
    s_n = 1.0
    y = g[0, 0, 0] * u + s_n * _cn(rng, 1, 1, 3000, 2, 1) / np.sqrt(2)
    expected = 2.25 / (2.25 + s_n**2)
    np.testing.assert_allclose(multiple_coherence(y, u), expected, atol=0.03)
    # noise-free MIMO: fully explained by both inputs, not by one alone
    gm = _cn(rng, 2, 2, 2)
    y2, u2, _ = _open_loop(gm, 1, 2, 1, seed=10)
    np.testing.assert_allclose(multiple_coherence(y2, u2), 1.0, atol=1e-10)


def test_errors_for_bad_inputs():
    rng = np.random.default_rng(11)
    g = _cn(rng, 4, 2, 2)
    y, u, u0 = _open_loop(g, 1, 2, 2, seed=12)
    with pytest.raises(ValueError, match="experiment"):
        arithmetic_mean(y[:, :1], u[:, :1])
    with pytest.raises(ValueError, match="singular"):
        h1(y[:, :1], u[:, :1])          # one experiment cannot separate two inputs
    r = np.array(u0)
    r[..., 2, :] = 0.0                   # a line that is not excited
    with pytest.raises(ValueError, match="excited"):
        indirect(y, u, r)
    with pytest.raises(ValueError, match="square"):
        h2(y[..., :1], u)
    bad = np.array(y)
    bad[0, 0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        h1(bad, u)
    with pytest.raises(ValueError, match=r"\(M, Ne, P, L\)"):
        h1(y[:, :, :, :3], u)
    with pytest.raises(ValueError, match="period spectra"):
        h1(y[0], u[0])


def test_sine_amplitude_exact_for_non_integer_periods():
    fs, f = 1000.0, 37.3
    t = np.arange(700) / fs
    amp = np.array([[0.5 * np.exp(0.3j), 2.0 * np.exp(-2.0j)]])
    x = np.abs(amp) * np.cos(2 * np.pi * f * t[:, None] + np.angle(amp)) + 0.1
    transient = np.zeros_like(x)
    transient[:100] = 5.0                 # garbage before settling
    got = sine_amplitude(np.stack([x + transient, 2 * x]), f, fs, n_settle=100)
    np.testing.assert_allclose(got, np.stack([amp[0], 2 * amp[0]]), rtol=1e-10)
    with pytest.raises(ValueError, match="freq_hz"):
        sine_amplitude(x, 600.0, fs)
    with pytest.raises(ValueError, match="one period"):
        sine_amplitude(x, 1.0, fs, n_settle=100)


def test_stepped_sine_frf_least_squares_and_errors():
    rng = np.random.default_rng(13)
    fs, freq = 1000.0, np.array([50.0, 120.0])
    g = _cn(rng, 2, 2, 2)
    t = np.arange(500) / fs
    ys, us = [], []
    for i, f in enumerate(freq):
        amp_u = _cn(rng, 2, 2)             # (Nu, Ne) complex amplitudes
        amp_y = g[i] @ amp_u
        sig = lambda a: np.real(a.T[:, None, :] * np.exp(2j * np.pi * f * t)[None, :, None])
        ys.append(sig(amp_y))
        us.append(sig(amp_u))
    np.testing.assert_allclose(stepped_sine_frf(ys, us, freq, fs), g, rtol=1e-9)
    with pytest.raises(ValueError, match="records"):
        stepped_sine_frf(ys[:1], us, freq, fs)
    with pytest.raises(ValueError, match="n_settle"):
        stepped_sine_frf(ys, us, freq, fs, n_settle=[0, 1, 2])


def test_welch_h1_recovers_fir_filters():
    fs, n = 1000.0, 2**14
    rng = np.random.default_rng(14)
    u = rng.standard_normal((n, 2))
    b = [[np.array([1.0, 0.5]), np.array([0.0, 0.2, 0.1])],
         [np.array([0.3, -0.4]), np.array([0.8, 0.0, 0.0, 0.2])]]
    y = np.stack([sum(signal.lfilter(b[i][j], 1.0, u[:, j]) for j in range(2)) for i in range(2)], axis=1)
    res = welch_frf(y, u, fs, 256, overlap=0.5)
    assert res.n_segments == (n - 256) // 128 + 1
    np.testing.assert_allclose(res.freq_hz, np.fft.rfftfreq(256, 1 / fs))
    w = 2 * np.pi * res.freq_hz / fs
    g = np.array([[[np.polyval(b[i][j][::-1], np.exp(-1j * wk)) for j in range(2)] for i in range(2)]
                  for wk in w])
    assert np.abs(res.frf - g).max() < 0.02
    assert res.coherence.min() > 0.99
    u_dead = np.array(u)
    u_dead[:, 1] = 0.0
    assert np.all(np.isnan(welch_frf(y, u_dead, fs, 256).frf))   # singular S_uu -> NaN, no raise
    with pytest.raises(ValueError, match="overlap"):
        welch_frf(y, u, fs, 256, overlap=1.0)
    with pytest.raises(ValueError, match="n_per_segment"):
        welch_frf(y, u, fs, n + 1)
    with pytest.raises(ValueError, match="share"):
        welch_frf(y[:-1], u, fs, 256)
    with pytest.raises(ValueError, match="freq_range_hz"):
        welch_frf(y, u, fs, 256, freq_range_hz=(600.0, 700.0))
