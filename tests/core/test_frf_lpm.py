"""The local polynomial / rational methods (ambid.frf.lpm) against closed forms the tests compute themselves.

* a known system with a transient (the test's own closed loop, tests/core/lpm_testbench.py, started
  from rest with an excitation that never repeats): the LPM's FRF equals the sampled model without noise,
  and beats a Hann-windowed (Welch) estimate of the same record by orders of magnitude with noise;
* the estimated noise covariance of [y; u] against the true one (sensor noise through the loop, closed form);
* the degrees of freedom: the 95 % circles |G - G0|^2 <= F(2, 2q) var cover the truth 95 % of the time;
* the local rational method where a resonance is sharper than the window;
* periodic segments measured without settling periods: the transient removed, the noise right.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal, stats

import lpm_testbench as tb
from ambid.frf.estimators import welch_frf
from ambid.frf.lpm import (dof_of, f_quantile, half_width_for, local_frf, periodic_transient_removal,
                           periodic_window)


def _rel_error(g: np.ndarray, g0: np.ndarray) -> np.ndarray:
    return np.linalg.norm(g - g0, axis=(1, 2)) / np.linalg.norm(g0, axis=(1, 2))


@pytest.fixture(scope="module")
def loop_record():
    """20 s of the test's closed loop from rest (its transient in the record), band-limited noise 10-800 Hz."""
    n = int(20 * tb.FS)
    r = tb.band_noise(n, (10.0, 800.0), 0.25, seed=11)
    y, u = tb.simulate(r, seed=11)
    y0, u0 = tb.simulate(r, seed=11, noise_m=0.0)
    return r, y, u, y0, u0


def test_noise_free_frf_is_the_sampled_model_despite_the_transient(loop_record):
    r, _, _, y0, u0 = loop_record
    est = local_frf(y0, u0, r, fs_hz=tb.FS, band_hz=(10.0, 800.0), method="lpm")
    err = _rel_error(est.frf, tb.frf(est.freq_hz))
    assert np.median(err) < 1e-6 and err.max() < 1e-4
    # the record starts from rest under a running excitation: the transient is there, and removed
    assert np.max(np.abs(est.transient)) > 1e3 * np.max(np.abs(est.transient[:, len(est.bins) // 2:])) or \
        np.max(np.abs(est.transient)) > 0


def test_lpm_against_windowing_at_equal_noise(loop_record):
    """The window's leakage is a bias the LPM does not have: orders of magnitude below it without noise, several
    times below at a low noise; where the noise dominates, the Welch average of many segments is the smaller one
    (the LPM spends degrees of freedom on the local slopes), so the comparison stops there."""
    r, _, _, y0, u0 = loop_record

    def errors(y, u):
        est = local_frf(y, u, r, fs_hz=tb.FS, band_hz=(10.0, 800.0))
        n_seg = int(round(tb.FS / (est.freq_hz[1] - est.freq_hz[0])))   # Welch bins as far apart as the LPM's lines
        w = welch_frf(y, u, tb.FS, n_seg, r=r, freq_range_hz=(10.0, 800.0))
        return np.median(_rel_error(est.frf, tb.frf(est.freq_hz))), np.median(_rel_error(w.frf, tb.frf(w.freq_hz)))

    e_lpm, e_welch = errors(y0, u0)
    assert e_lpm < 1e-3 * e_welch, (e_lpm, e_welch)
    y, u = tb.simulate(r, seed=11, noise_m=tb.NOISE_M / 10)
    e_lpm, e_welch = errors(y, u)
    assert e_lpm < 0.5 * e_welch, (e_lpm, e_welch)


def test_noise_covariance_matches_the_loops_closed_form(loop_record):
    r, y, u, _, _ = loop_record
    est = local_frf(y, u, r, fs_hz=tb.FS, band_hz=(10.0, 800.0))
    a, b, c, d = tb.closed_loop()
    z = np.exp(2j * np.pi * est.freq_hz / tb.FS)
    # sensor noise n (white, variance s^2 per sample) -> [y; u]: E[V V^H] = s^2 H_n H_n^H with the DFT scaled 1/sqrt(n)
    h_n = np.array([c @ np.linalg.solve(zz * np.eye(a.shape[0]) - a, b[:, 4:]) + d[:, 4:] for zz in z])
    true_cov = tb.NOISE_M ** 2 * h_n @ np.conj(np.swapaxes(h_n, 1, 2))
    ratio = np.real(np.diagonal(est.noise_cov, axis1=1, axis2=2)) / np.real(np.diagonal(true_cov, axis1=1, axis2=2))
    # each line's estimate has q complex degrees of freedom: chi2_2q / 2q; its mean over ~700 lines is sharp
    assert abs(np.mean(ratio) - 1) < 0.05, np.mean(ratio, axis=0)
    q = int(est.dof[0])
    lo, hi = stats.chi2.ppf([0.005, 0.995], 2 * q) / (2 * q)
    inside = np.mean((ratio > lo) & (ratio < hi))
    assert inside > 0.95, inside


def test_intervals_cover_as_they_claim():
    """Monte Carlo over seeds: the 95 % circles from the estimated variance with q dof hold the truth 95 %."""
    n, hits, total = int(4 * tb.FS), 0, 0
    for seed in range(12):
        r = tb.band_noise(n, (20.0, 700.0), 0.25, seed=100 + seed)
        y, u = tb.simulate(r, seed=100 + seed, noise_m=0.3e-6)    # a noisier sensor: intervals of some size
        est = local_frf(y, u, r, fs_hz=tb.FS, band_hz=(20.0, 700.0), method="lpm")
        e2 = np.abs(est.frf - tb.frf(est.freq_hz)) ** 2 / est.var
        hits += int(np.sum(e2 <= f_quantile(0.95, est.dof)[:, None, None]))
        total += e2.size
    cover = hits / total
    # ~ 12 x 300 lines x 16 entries; the entries of a line share its noise: a wide binomial band still
    assert 0.93 < cover < 0.97, cover


def test_degrees_of_freedom_of_a_window():
    assert dof_of(8, 2, 2) == 17 - 3 - 6
    assert dof_of(half_width_for(2, 4), 2, 4) >= 8 > dof_of(half_width_for(2, 4) - 1, 2, 4)
    assert f_quantile(0.95, 10**6) == pytest.approx(-np.log(0.05), rel=1e-3)   # F(2, inf)/... -> exponential


def test_rational_method_where_a_resonance_is_sharper_than_the_window():
    """A mode of 0.05 % damping at 3 Hz resolution of the window: the polynomial cannot follow it, the rational can."""
    fs, n = 1000.0, 8000
    w0, zeta = 2 * np.pi * 137.0, 0.0005
    ad, bd, cd, dd, _ = signal.cont2discrete((np.array([[0, 1], [-w0 ** 2, -2 * zeta * w0]]), np.array([[0], [w0 ** 2]]),
                                              np.array([[1.0, 0]]), np.zeros((1, 1))),
                                             1 / fs, "zoh")
    rng = np.random.default_rng(5)
    u = rng.standard_normal((n, 1))
    _, y, _ = signal.dlsim((ad, bd, cd, dd, 1 / fs), u, x0=[0.3, 0.0])
    near = (120.0, 155.0)

    def err(method: str) -> float:
        est = local_frf(y, u, fs_hz=fs, band_hz=near, method=method, half_width=12)
        z = np.exp(2j * np.pi * est.freq_hz / fs)
        g0 = np.array([cd @ np.linalg.solve(zz * np.eye(2) - ad, bd) for zz in z])
        return float(np.max(np.abs(est.frf - g0) / np.abs(g0)))

    e_lpm, e_lrm, e_auto = err("lpm"), err("lrm"), err("auto")
    assert e_lrm < 0.01 * e_lpm and e_auto <= e_lrm * 1.0001, (e_lpm, e_lrm, e_auto)


@pytest.fixture(scope="module")
def periodic_record():
    """Multisine segments of P = 4 periods, one input at a time, from the loop's rest (no settling period)."""
    n_per, p = 400, 4
    lines = np.arange(2, 160, 2)
    r = tb.multisine_segments(n_per, p, lines)
    noise = tb.NOISE_M * 10 * np.random.default_rng(4).standard_normal(r.shape)
    out = {"noisy": tb.run_states(r, noise)[0], "clean": tb.run_states(r, 0 * noise)[0]}
    return n_per, p, lines, r, out, noise


def _periodic_g(n_per, p, lines, r, z, method="auto"):
    segs = z.reshape(4, p * n_per, 8)
    tf = periodic_transient_removal(segs, n_per, lines, method=method)
    ref = np.moveaxis(np.fft.rfft(r.reshape(4, p * n_per, 4)[:, :n_per], axis=1)[:, lines] * 2 / n_per, 0, -1)
    y, u = np.moveaxis(tf.spectra[..., :4], 0, -1), np.moveaxis(tf.spectra[..., 4:], 0, -1)
    return y @ np.linalg.inv(u), tf, ref


def test_periodic_transient_removed_without_settling_periods(periodic_record):
    n_per, p, lines, r, out, _ = periodic_record
    g0 = tb.frf(lines * tb.FS / n_per)
    g, tf, _ = _periodic_g(n_per, p, lines, r, out["clean"])
    raw = out["clean"].reshape(4, p, n_per, 8)
    spec = np.fft.rfft(raw, axis=2)[:, :, lines].mean(axis=1)
    g_raw = np.moveaxis(spec[..., :4], 0, -1) @ np.linalg.inv(np.moveaxis(spec[..., 4:], 0, -1))
    e, e_raw = np.median(_rel_error(g, g0)), np.median(_rel_error(g_raw, g0))
    assert e < 1e-4 < 0.01 < e_raw, (e, e_raw)


def test_periodic_noise_variance_and_coverage(periodic_record):
    n_per, p, lines, r, out, noise = periodic_record
    g0 = tb.frf(lines * tb.FS / n_per)
    g, tf, _ = _periodic_g(n_per, p, lines, r, out["noisy"])
    # the corrected spectra's noise: the clean run subtracted gives the noise alone, its spread at the lines
    _, tf_clean, _ = _periodic_g(n_per, p, lines, r, out["clean"])
    err = tf.spectra - tf_clean.spectra                                        # (Ne, L, 8) noise of each line
    predicted = np.real(np.diagonal(tf.noise_cov, axis1=-2, axis2=-1))
    ratio = np.mean(np.abs(err) ** 2, axis=(0, 1)) / np.mean(predicted, axis=(0, 1))
    assert np.all(np.abs(ratio - 1) < 0.2), ratio
    # G's intervals: var G_ij = sum_e (a_i C_e a_i^H) |U^-1_ej|^2
    g, var = tb.g_and_variance(tf.spectra, tf.noise_cov)
    dof = np.min(tf.dof, axis=0)[:, None, None]
    cover = np.mean(np.abs(g - g0) ** 2 / var <= f_quantile(0.95, dof))
    assert 0.9 < cover < 0.99, cover


def test_periodic_window_between_the_lines():
    w = periodic_window(4, 2)
    assert w.size == 18 and not np.any(w % 4 == 0) and w.min() == -11 and w.max() == 11
