"""The transient model shared across the spectrum (ambid.frf.transient_model) against the closed form.

The test's own closed loop (tests/core/lpm_testbench.py: a rotor in two magnetic bearings per plane, a PD
controller, scipy only) runs multisine segments of P = 4 periods one after the other with no settling periods; the
transient of each segment is computed in closed form from the loop's state at the segment's start,
``C (I - zeta A)^-1 (I - A^n) (x0 - x_s)``. Checked:

* without noise the removed transient is that closed form (the model is exact for a linear loop), far closer than
  the local polynomial method gets;
* with noise the subtraction adds a few per cent to a line's variance where the local method adds ~13 %, and the
  variance ambid gives each corrected line, and so the 95 % circles of G, hold as they claim;
* a model short of poles is caught by the F test and corrected locally;
* a streamed experiment's segments give the batch numbers; bad input is refused in one line.
"""

from __future__ import annotations

import numpy as np
import pytest

import lpm_testbench as tb
from ambid.frf.lpm import f_quantile, periodic_transient_removal
from ambid.frf.transient_model import SegmentTransients, check_model_size, fit_band_bins, global_transient_removal

N_PER, P = 400, 4
LINES = np.arange(2, 160, 2)
NS = P * N_PER
SC = 2.0 / NS                      # the amplitude scaling of the spectra (period_spectra's, for P periods)


@pytest.fixture(scope="module")
def record():
    """Four segments (one input each) from rest, with and without sensor noise (10x the testbench's), the
    closed-form transients and the steady-state line spectra."""
    r = tb.multisine_segments(N_PER, P, LINES)
    noise = tb.NOISE_M * 10 * np.random.default_rng(4).standard_normal(r.shape)
    clean, states = tb.run_states(r, 0 * noise)
    noisy, _ = tb.run_states(r, noise)
    t = tb.segment_transients(r, states, N_PER, P, LINES)                     # (4, L, 8) unscaled DFT
    spec = np.fft.fft(clean.reshape(4, NS, 8), axis=1)[:, P * LINES]
    steady = (spec - t) * SC                                                    # (4, L, 8) amplitude scaling
    return dict(r=r, clean=clean.reshape(4, NS, 8), noisy=noisy.reshape(4, NS, 8), t=t, steady=steady)


def _rel(t_hat, t):
    return np.sqrt(np.mean(np.abs(t_hat - t) ** 2)) / np.sqrt(np.mean(np.abs(t) ** 2))


def _rounding_bound(model) -> float:
    """What float64 allows the noise-free transient: the least-squares fit of the model's basis at the fitted bins
    turns a relative error delta of the data into at most kappa delta of the fit (kappa: the condition number of
    the column-scaled basis, stacked real over imaginary), and the data's own rounding is delta ~ eps log2(n) (the
    FFT of n samples, Higham, Accuracy and Stability of Numerical Algorithms, 2002, sec. 24.1), with a factor 10
    for the simulation's and the closed form's rounding. Nothing of one machine's last digits."""
    bins = fit_band_bins(N_PER, P, LINES)
    basis = model.basis(np.exp(-2j * np.pi * bins / NS))
    x = np.concatenate([basis.real, basis.imag])
    kappa = np.linalg.cond(x / np.linalg.norm(x, axis=0))
    return 10 * kappa * np.finfo(float).eps * np.log2(NS)


def test_noise_free_transient_is_the_closed_form(record):
    g = global_transient_removal(record["clean"], N_PER, LINES)
    local = periodic_transient_removal(record["clean"], N_PER, LINES)
    e_global, e_local = _rel(g.transient / SC, record["t"]), _rel(local.transient / SC, record["t"])
    bound = _rounding_bound(g.model)
    assert bound < 1e-4, bound                  # a sanely conditioned model (a fit near singular says nothing)
    assert e_global < bound and e_global < 0.05 * e_local, (e_global, bound, e_local)
    # the corrected lines are the steady state to the same rounding (|max| <= the 2-norm of the error)
    assert np.max(np.abs(g.spectra - record["steady"])) < bound * np.linalg.norm(record["t"] * SC)
    # the loop's closed-loop poles are the model's (the x and y planes' two poles near 49 Hz, 0.3 Hz apart, within
    # 0.6 Hz; the others within 1e-4)
    a = tb.closed_loop()[0]
    ev = np.linalg.eigvals(a)
    ev = ev[(np.abs(ev) > 0.5) & (ev.imag >= 0)]
    dist = np.min(np.abs(ev[:, None] - g.model.poles[None, :]), axis=1)
    assert np.max(dist) < 2e-3 and np.median(dist) < 1e-4, dist


def _line_noise(g, record):
    """Each corrected line's error (against the closed-form steady state) over the variance ambid gives it."""
    err = g.spectra - record["steady"]
    pred = np.real(np.diagonal(g.noise_cov, axis1=-2, axis2=-1))
    return err, pred


def test_subtraction_adds_little_noise_and_the_line_variance_holds(record):
    g = global_transient_removal(record["noisy"], N_PER, LINES)
    local = periodic_transient_removal(record["noisy"], N_PER, LINES)
    err, pred = _line_noise(g, record)
    # the corrected lines' variance, channel by channel (4 segments x 79 lines each)
    ratio = np.mean(np.abs(err) ** 2, axis=(0, 1)) / np.mean(pred, axis=(0, 1))
    assert np.all(np.abs(ratio - 1) < 0.25), ratio
    # the transient's own error, over a line's noise: a few per cent for the model, ~13 % for local fits
    d_global = np.mean(np.abs(g.transient / SC - record["t"]) ** 2 / (pred / SC ** 2))
    d_local = np.mean(np.abs(local.transient / SC - record["t"]) ** 2 / (pred / SC ** 2))
    assert d_global < 0.08 and d_global < 0.5 * d_local, (d_global, d_local)
    assert 0.0 < np.median(g.lever) < 0.05 and np.mean(g.local) < 0.05, (np.median(g.lever), np.mean(g.local))


def test_intervals_of_g_cover_as_they_claim(record):
    g = global_transient_removal(record["noisy"], N_PER, LINES)
    g0 = tb.frf(LINES * tb.FS / N_PER)
    gh, var = tb.g_and_variance(g.spectra, g.noise_cov)
    dof = np.min(g.dof, axis=0)[:, None, None]
    cover = np.mean(np.abs(gh - g0) ** 2 / var <= f_quantile(0.95, dof))
    assert 0.92 < cover < 0.98, cover


def test_a_model_short_of_poles_is_corrected_locally(record):
    short = global_transient_removal(record["noisy"], N_PER, LINES, n_pairs=2, n_real=0)
    full = global_transient_removal(record["noisy"], N_PER, LINES)
    local = periodic_transient_removal(record["noisy"], N_PER, LINES, method="lpm")
    assert np.mean(short.local) > 3 * np.mean(full.local), (np.mean(short.local), np.mean(full.local))

    def err(x):
        return np.mean(np.abs(x.transient / SC - record["t"]) ** 2)
    # corrected where the F test found it missing, the short model still beats local fits everywhere
    assert err(short) < 0.5 * err(local), (err(short), err(local))
    _, pred = _line_noise(short, record)
    e = np.abs(short.spectra - record["steady"]) ** 2
    assert np.mean(e) / np.mean(pred) < 1.3


def test_streamed_segments_give_the_batch_result(record):
    x = np.concatenate([record["noisy"], np.tile(record["r"].reshape(4, NS, 4)[:, :N_PER], (1, P, 1))], axis=2)
    st = SegmentTransients(N_PER, P, LINES, n_noisy=8)
    assert st.method == "global"
    for s in range(4):
        for k in range(P):
            done = st.add(s, k, x[s, k * N_PER:(k + 1) * N_PER])
        assert done and st.complete(s)
    batch = global_transient_removal(record["noisy"], N_PER, LINES)
    for s in range(4):
        np.testing.assert_allclose(st.results[s].spectra, batch.spectra[s], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(st.results[s].noise_cov, batch.noise_cov[s], rtol=1e-9, atol=1e-30)
        np.testing.assert_allclose(st.noise_var_time(s), batch.noise_var_time[s], rtol=1e-12)
        ref = np.fft.rfft(record["r"].reshape(4, NS, 4)[s, :N_PER], axis=0)[LINES] * 2 / N_PER
        np.testing.assert_allclose(st.spectra(s)[:, 8:], ref, atol=1e-12)
    # a segment missing a period is left out
    st.add(4, 1, x[0, :N_PER])
    assert not st.complete(4)


def test_too_few_bins_fall_back_to_local_fits():
    lines = np.arange(2, 12, 2)                     # 5 lines: the bins up to 1.5 x the top one are too few
    with pytest.raises(ValueError, match="too few for a model"):
        check_model_size(N_PER, P, lines)
    assert SegmentTransients(N_PER, P, lines, n_noisy=8).method == "auto"


@pytest.mark.parametrize("args, match", [
    ((np.zeros((NS, 8)), N_PER, np.array([0, 2])), "lines must be"),
    ((np.zeros((NS, 8)), N_PER, np.array([2, 200])), "lines must be"),
    ((np.zeros((N_PER, 8)), N_PER, LINES), "P >= 2"),
    ((np.full((NS, 8), np.nan), N_PER, LINES), "NaN"),
])
def test_bad_input_is_refused(args, match):
    with pytest.raises(ValueError, match=match):
        global_transient_removal(*args)
