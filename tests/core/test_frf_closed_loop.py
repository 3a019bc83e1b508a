"""FRF estimation on a simulated 2x2 AMB-like closed loop.

Plant (continuous, ZOH-discretised at 10 kHz): two decoupled rigid axes with
negative magnetic stiffness (unstable real poles at +-32 Hz) plus a lightly
damped bending mode at 350 Hz coupling both axes. Controller: decentralised
PD with a 2 kHz roll-off (Tustin), acting one sample late through the ZOH.
Sign convention as in ambid.frf: u = r - C y, y = P u + v (v: white
measurement noise, fed back through C).
"""

import numpy as np
import pytest
from ambid.frf import (bla_robust, distortion_levels, errors_in_variables, h1, indirect, input_sensitivity,
                       input_sensitivity_from_models, iso14839_zone, output_noise_std, period_spectra,
                       sensitivity_peak, split_periods, stepped_sine_frf, welch_frf)
from frf_testbench import FS
from frf_testbench import controller_frf as _controller
from frf_testbench import loop_model as _loop
from frf_testbench import plant_frf as _plant
from frf_testbench import simulate as _simulate
from scipy import signal

N = 512          # samples per period
PT = 2           # transient periods (slowest closed-loop pole decays in ~92 samples)


# --------------------------------------------------------------------------- test rig
# (the loop and its simulator: frf_testbench.py, shared with the streaming tests)

def _multisine(lines, n_real, amp, seed, orthogonal=True):
    """One period (M, Ne, N, Nu) of random-phase multisines, amp [A] per line.

    Orthogonal: input i of experiment e carries the phase factor
    exp(-2j pi i e / Nu) (a DFT matrix, unitary up to scaling); else one input
    at a time."""
    nu = 2
    rng = np.random.default_rng(seed)
    phase = np.exp(2j * np.pi * rng.uniform(size=(n_real, 1, len(lines), nu)))
    t = (np.exp(-2j * np.pi * np.outer(np.arange(nu), np.arange(nu)) / nu) if orthogonal
         else np.eye(nu))                            # t[i, e]
    spec = np.zeros((n_real, nu, N // 2 + 1, nu), complex)
    spec[:, :, lines, :] = amp * phase * t.T[None, :, None, :]
    return np.fft.irfft(spec, N, axis=2) * N / 2     # |X[k]| = amp, see period_spectra


def _experiment(loop, lines, n_real, n_per, amp, noise_std, seed, cubic=0.0, orthogonal=True):
    """Simulate the standard layout; return r, y, u as (n_samples, 2) records."""
    r1 = _multisine(lines, n_real, amp, seed, orthogonal)
    r = np.tile(r1, (1, 1, PT + n_per, 1)).reshape(n_real * 2, (PT + n_per) * N, 2)
    y, u = _simulate(loop, r, noise_std, seed + 1, cubic)
    return tuple(x.reshape(-1, 2) for x in (r, y, u))


def _spectra(x, lines, n_real, n_per):
    return period_spectra(split_periods(x, N, n_per, PT, n_real, 2), lines)


def _rel_err(g, ref):
    return np.linalg.norm(g - ref, axis=(1, 2)) / np.linalg.norm(ref, axis=(1, 2))


@pytest.fixture(scope="module")
def loop():
    lp = _loop()
    a_cl = np.block([[lp["ap"] - lp["bp"] @ lp["dc"] @ lp["cp"], -lp["bp"] @ lp["cc"]],
                     [lp["bc"] @ lp["cp"], lp["ac"]]])
    assert np.abs(np.linalg.eigvals(a_cl)).max() < 0.995   # stable, transient << PT periods
    assert np.abs(np.linalg.eigvals(lp["ap"])).max() > 1.01  # open loop unstable
    return lp


LINES = np.arange(1, 31)          # 19.5 .. 586 Hz, around the 350 Hz mode
M_NOM, P_NOM, NOISE = 4, 4, 1e-7  # realisations, periods, noise std [m]


@pytest.fixture(scope="module", params=[True, False], ids=["orthogonal", "one-at-a-time"])
def nominal(loop, request):
    r, y, u = _experiment(loop, LINES, M_NOM, P_NOM, 0.05, NOISE, seed=0, orthogonal=request.param)
    return dict(r=r, y=y, u=u, R=_spectra(r, LINES, M_NOM, P_NOM), Y=_spectra(y, LINES, M_NOM, P_NOM),
                U=_spectra(u, LINES, M_NOM, P_NOM))


# --------------------------------------------------------------------------- tests

def test_indirect_recovers_plant_within_its_noise_level(loop, nominal):
    p_true = _plant(loop, LINES * FS / N)
    g = indirect(nominal["Y"], nominal["U"], nominal["R"])
    err = _rel_err(g, p_true)
    assert np.median(err) < 0.015 and err.max() < 0.05
    # the errors are those the period scatter predicts: E|G - P|^2 = var_noise
    bla = bla_robust(nominal["Y"], nominal["U"], nominal["R"])
    z = np.abs(g - p_true) ** 2 / bla.var_noise
    assert 0.5 < z.mean() < 2.0
    assert _rel_err(errors_in_variables(nominal["Y"], nominal["U"]), p_true).max() < 0.05


def test_transient_periods_must_be_dropped(loop):
    # noise-free: with the transient dropped the estimate is exact to the
    # leftover transient (~exp(-2 N / 92)); keeping it costs orders of magnitude
    r, y, u = _experiment(loop, LINES, 1, 2, 0.05, 0.0, seed=2)
    p_true = _plant(loop, LINES * FS / N)
    good = indirect(*(_spectra(x, LINES, 1, 2) for x in (y, u, r)))
    bad = indirect(*(period_spectra(split_periods(x, N, PT + 2, 0, 1, 2), LINES) for x in (y, u, r)))
    assert _rel_err(good, p_true).max() < 1e-4
    assert _rel_err(bad, p_true).max() > 100 * _rel_err(good, p_true).max()


def test_h1_is_biased_towards_minus_inverse_controller_in_closed_loop(loop):
    # Strong fed-back noise: expected H1 = (P A - C^-1 B)(A + B)^-1 with
    # A = S Phi_r S^H, B = S C Phi_v C^H S^H, S = (I + C P)^-1.
    m_real, n_per, amp, sigma = 24, 4, 0.01, 6e-7
    r, y, u = _experiment(loop, LINES, m_real, n_per, amp, sigma, seed=3)
    R, Y, U = (_spectra(x, LINES, m_real, n_per) for x in (r, y, u))
    f = LINES * FS / N
    p, c = _plant(loop, f), _controller(loop, f)
    s = input_sensitivity_from_models(p, c)
    c_inv = np.linalg.inv(c)
    # per record: R R^H = 2 amp^2 I over the two orthogonal experiments; E V V^H = 2 (4 s^2/N) I
    a = 2 * amp**2 * s @ np.conj(np.swapaxes(s, 1, 2))
    sc = s @ c
    b = 2 * 4 * sigma**2 / N * sc @ np.conj(np.swapaxes(sc, 1, 2))
    h1_expected = (p @ a - c_inv @ b) @ np.linalg.inv(a + b)

    g_h1, g_ind = h1(Y, U), indirect(Y, U, R)
    assert np.median(_rel_err(g_h1, p)) > 0.2            # grossly biased ...
    assert np.median(_rel_err(g_h1, h1_expected)) < 0.1  # ... as predicted ...
    closer = (np.linalg.norm(g_h1 + c_inv, axis=(1, 2)) < np.linalg.norm(p + c_inv, axis=(1, 2)))
    assert closer.mean() > 0.8                           # ... towards -C^-1
    assert np.median(_rel_err(g_ind, p)) < 0.1           # the indirect one is not


def test_output_noise_std_from_period_scatter(loop, nominal):
    # y noise in closed loop is S_o v, S_o = (I + P C)^-1: its variance is
    # sigma^2 times the mean over frequency of the row sums of |S_o|^2.
    f = np.arange(4096) * FS / 4096
    s_o = np.linalg.inv(np.eye(2) + _plant(loop, f) @ _controller(loop, f))
    expected = NOISE * np.sqrt((np.abs(s_o) ** 2).sum(axis=2).mean(axis=0))
    est = output_noise_std(split_periods(nominal["y"], N, P_NOM, PT, M_NOM, 2))
    assert np.allclose(est, expected, rtol=0.1)
    assert np.allclose(est, NOISE, rtol=0.2)     # the loop barely colours it here


@pytest.fixture(scope="module")
def random_odd():
    rng = np.random.default_rng(7)
    odd = np.arange(1, 64, 2).reshape(-1, 4)     # groups of 4 odd lines up to 1.2 kHz
    det_odd = odd[np.arange(len(odd)), rng.integers(0, 4, len(odd))]
    return np.setdiff1d(odd, det_odd), det_odd, np.arange(2, 64, 2)


@pytest.mark.parametrize("cubic", [0.0, 2.0], ids=["linear", "cubic"])
def test_odd_distortion_and_bla_variance(loop, random_odd, cubic):
    exc, det_odd, det_even = random_odd
    r, y, u = _experiment(loop, exc, 4, 4, 0.05, NOISE, seed=11, cubic=cubic)
    levels = distortion_levels(_spectra(y, det_odd, 4, 4), _spectra(y, det_even, 4, 4))
    bla = bla_robust(*(_spectra(x, exc, 4, 4) for x in (y, u, r)))
    ratio = np.median(bla.var_total / bla.var_noise)
    assert np.all(levels.even_db < 3.0)          # odd nonlinearity: no even lines
    if cubic:
        assert np.all(levels.odd_db > 10.0)
        assert ratio > 2.0
        assert np.median(bla.var_stochastic_nl / (4 * bla.var_noise)) > 1.0
    else:
        assert np.all(levels.odd_db < 3.0)
        assert 0.4 < ratio < 1.6


def test_input_sensitivity_peak_and_zone(loop, nominal):
    s_data = input_sensitivity(nominal["U"], nominal["R"])
    f = LINES * FS / N
    s_true = input_sensitivity_from_models(_plant(loop, f), _controller(loop, f))
    assert _rel_err(s_data, s_true).max() < 0.02
    peak, idx = sensitivity_peak(s_data)
    peak_true, idx_true = sensitivity_peak(s_true)
    assert np.allclose(peak, peak_true, rtol=0.05)
    assert np.array_equal(idx, idx_true)
    assert iso14839_zone(peak.max()) == iso14839_zone(peak_true.max()) == "A"


def test_sensitivity_zone_of_a_weakly_damped_loop():
    lp = _loop(kd=12.0)     # less derivative action: peak ~4.6 -> zone C
    f = np.arange(1, 60) * FS / N
    peak, _ = sensitivity_peak(input_sensitivity_from_models(_plant(lp, f), _controller(lp, f)))
    assert 4.0 < peak.max() < 5.0 and iso14839_zone(peak.max()) == "C"


def test_stepped_sine_one_input_at_a_time(loop):
    freq = np.array([40.0, 120.0, 330.0, 360.0, 700.0])
    n_settle, n_rec = 1500, 1000
    t = np.arange(n_settle + n_rec) / FS
    r = np.zeros((freq.size, 2, t.size, 2))
    for e in range(2):
        r[:, e, :, e] = 0.05 * np.sin(2 * np.pi * freq[:, None] * t)
    y, u = (x.reshape(r.shape) for x in _simulate(loop, r.reshape(-1, t.size, 2), 2e-8, seed=5))
    g = stepped_sine_frf(list(y), list(u), freq, FS, n_settle, r_records=list(r))
    assert _rel_err(g, _plant(loop, freq)).max() < 0.03


def test_welch_indirect_with_random_noise_and_swept_sine(loop):
    n = 2**14
    rr = 0.05 * np.random.default_rng(1).standard_normal((1, n, 2))
    y, u = _simulate(loop, rr, 2e-8, seed=6)
    res = welch_frf(y[0], u[0], FS, 512, r=rr[0], freq_range_hz=(20.0, 800.0))
    assert res.n_segments == 63 and res.frf.shape == (res.freq_hz.size, 2, 2)
    err = _rel_err(res.frf, _plant(loop, res.freq_hz))
    assert np.median(err) < 0.06
    assert np.all(res.coherence > 0.5)
    # one swept input at a time, both experiments pooled
    t = np.arange(n) / FS
    chirp = 0.05 * signal.chirp(t, 10.0, t[-1], 1000.0)
    rs = np.zeros((2, n, 2))
    rs[0, :, 0] = rs[1, :, 1] = chirp
    y, u = _simulate(loop, rs, 2e-8, seed=7)
    res = welch_frf(y, u, FS, 1024, r=rs, freq_range_hz=(30.0, 900.0))
    assert np.median(_rel_err(res.frf, _plant(loop, res.freq_hz))) < 0.08
