"""Streaming FRF (ambid.frf.streaming) on the simulated 2x2 closed loop of frf_testbench.

The excitation is a real ExcitationDesign (orthogonal random-odd multisine),
laid out realisation-major and simulated as one continuous record with some
samples before and after the experiment.
"""

import numpy as np
import pytest
from ambid.excitation import design_multisine, design_noise, design_stepped_sine
from ambid.frf import (arithmetic_mean, bla_robust, distortion_levels, errors_in_variables, frf_noise_variance, h1,
                       h2, indirect, input_sensitivity, log_mean, multiple_coherence, output_noise_std,
                       period_spectra, sensitivity_peak, split_periods, stepped_sine_frf, welch_frf)
from ambid.frf.streaming import ESTIMATORS, FrfStream, loop_consistency, match_inputs
from frf_testbench import FS, controller_frf, loop_model, plant_frf, simulate

NAMES = (("y_1", "y_2"), ("u_1", "u_2"), ("r_1", "r_2"))
PRE, POST = 137, 250          # samples before and after the experiment
NOISE = 1e-7                  # measurement noise std [m]
BATCH = {"indirect": lambda y, u, r: indirect(y, u, r), "h1": lambda y, u, r: h1(y, u),
         "h2": lambda y, u, r: h2(y, u), "arithmetic_mean": lambda y, u, r: arithmetic_mean(y, u),
         "log_mean": lambda y, u, r: log_mean(y, u), "eiv": lambda y, u, r: errors_in_variables(y, u)}


def _record(design, loop, seed=1):
    """(PRE + total + POST, 6) samples y, u, r of one continuous closed-loop run."""
    r = np.zeros((PRE + design.total_samples + POST, 2))
    r[PRE:PRE + design.total_samples] = design.samples(0, design.total_samples)
    y, u = simulate(loop, r[None], NOISE, seed)
    return np.hstack([y[0], u[0], r])


def _stream(design, x, block, start=PRE, skip=(), **kw):
    """Feed x in blocks of ``block`` samples (row i is index i), leaving out rows in ``skip``."""
    s = FrfStream(design, *NAMES, start_index=start, **kw)
    gone = np.zeros(len(x), bool)
    for lo, hi in skip:
        gone[lo:hi] = True
    for k in range(0, len(x), block):
        rows = np.flatnonzero(~gone[k:k + block]) + k
        if rows.size:   # split a block at the removed rows
            cuts = np.flatnonzero(np.diff(rows) > 1) + 1
            for part in np.split(rows, cuts):
                s.add(int(part[0]), x[part])
    return s


def _batch_spectra(design, x, lines):
    seg = x[PRE:PRE + design.total_samples]
    d = design
    per = split_periods(seg, d.n_per_period, d.n_periods, d.n_transient_periods, d.n_realisations,
                        d.n_experiments)
    return period_spectra(per, lines), per


def _results_equal(a, b):
    for k in ("frf", "var_noise", "var_total", "coherence", "sensitivity", "noise_std",
              "sensitivity_peak"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    for k in ("odd_power", "even_power", "odd_noise_power", "odd_db", "even_db"):
        np.testing.assert_array_equal(getattr(a.distortion, k), getattr(b.distortion, k), err_msg=k)


@pytest.fixture(scope="module")
def loop():
    return loop_model()


@pytest.fixture(scope="module")
def exp(loop):
    d = design_multisine((20.0, 600.0), 20.0, FS, ("u_1", "u_2"), 0.3, n_periods=3,
                         n_realisations=3, n_transient_periods=1, grid="random_odd", seed=3)
    x = _record(d, loop)
    lines = np.concatenate([d.excited_lines, d.detection_lines_odd, d.detection_lines_even])
    spec, per = _batch_spectra(d, x, lines)
    n_exc, n_odd = d.excited_lines.size, d.detection_lines_odd.size
    return dict(design=d, x=x, Y=spec[:, :, :, :n_exc, :2], U=spec[:, :, :, :n_exc, 2:4],
                R=spec[:, :, :, :n_exc, 4:], Yodd=spec[:, :, :, n_exc:n_exc + n_odd, :2],
                Yeven=spec[:, :, :, n_exc + n_odd:, :2], periods=per)


@pytest.fixture(scope="module")
def streamed(exp):
    return _stream(exp["design"], exp["x"], 777)


def test_block_size_does_not_change_the_estimate(exp, streamed):
    ref = streamed.estimate()
    assert ref.complete and ref.n_realisations == 3 and ref.n_periods == 9 and not ref.gaps
    for block in (1, 10_000):
        _results_equal(_stream(exp["design"], exp["x"], block).estimate(), ref)


def test_streaming_equals_batch_on_the_whole_record(exp, streamed):
    d, Y, U, R = exp["design"], exp["Y"], exp["U"], exp["R"]
    for name in ESTIMATORS:
        np.testing.assert_allclose(streamed.estimate(name).frf, BATCH[name](Y, U, R), rtol=1e-12,
                                   atol=0, err_msg=name)
    res = streamed.estimate("indirect")
    bla = bla_robust(Y, U, R)
    np.testing.assert_allclose(res.var_noise, bla.var_noise, rtol=1e-12)
    np.testing.assert_allclose(res.var_total, bla.var_total, rtol=1e-12)
    np.testing.assert_allclose(res.coherence, multiple_coherence(Y, R), rtol=1e-12)
    s = input_sensitivity(U, R)
    np.testing.assert_allclose(res.sensitivity, s, rtol=1e-12)
    peak, idx = sensitivity_peak(s)
    np.testing.assert_allclose(res.sensitivity_peak, peak, rtol=1e-12)
    np.testing.assert_array_equal(res.sensitivity_peak_hz, d.freq_hz[idx])
    lv = distortion_levels(exp["Yodd"], exp["Yeven"])
    for k in ("odd_power", "odd_noise_power", "even_power", "even_noise_power", "odd_db", "even_db"):
        np.testing.assert_allclose(getattr(res.distortion, k), getattr(lv, k), rtol=1e-12, err_msg=k)
    np.testing.assert_allclose(res.noise_std, output_noise_std(exp["periods"][..., :2]), rtol=1e-12)
    np.testing.assert_array_equal(res.freq_hz, d.freq_hz)


def test_estimate_is_the_plant_within_its_noise(loop, exp, streamed):
    res = streamed.estimate()
    p_true = plant_frf(loop, res.freq_hz)
    err = np.linalg.norm(res.frf - p_true, axis=(1, 2)) / np.linalg.norm(p_true, axis=(1, 2))
    assert np.median(err) < 0.02
    z = np.abs(res.frf - p_true) ** 2 / res.var_noise    # the errors the period scatter predicts
    assert 0.4 < np.median(z) / np.log(2) < 2.5          # median of an exp(1) variable is ln 2
    assert 0.3 < res.nonlinear_ratio < 3.0               # linear loop: total ~ noise variance
    assert np.all(res.distortion.odd_db < 3.0) and np.all(res.distortion.even_db < 3.0)
    assert np.allclose(res.noise_std, NOISE, rtol=0.2)
    # u = r - C y, so the measured S and G agree with C at every line (up to the noise's
    # leakage through C); a controller 10 % off is seen at once
    c_jw = controller_frf(loop, res.freq_hz)
    assert loop_consistency(res.frf, res.sensitivity, c_jw).max() < 2e-3
    assert loop_consistency(res.frf, res.sensitivity, 1.1 * c_jw).min() > 1e-2


def test_gap_drops_exactly_the_affected_period(exp, streamed):
    d, x = exp["design"], exp["x"]
    n = d.n_per_period
    seg0 = PRE + d.segment_start(1, 0)                 # realisation 1, experiment 0
    p1 = seg0 + (d.n_transient_periods + 1) * n        # its steady-state period 1
    bad = x.copy()
    bad[p1:p1 + n] = 1e3                               # what is left of that period is garbage
    s = _stream(d, bad, 500, skip=[(p1 + 100, p1 + 130)])
    assert [(g.start_index, g.n_samples, g.periods) for g in s.gaps] == [(p1 + 100, 30, ((1, 0, 1),))]
    res = s.estimate()
    assert res.n_periods == 8 and res.gaps == s.gaps
    keep = [(m, p) for m in range(3) for p in range(3) if (m, p) != (1, 1)]
    pooled = [np.stack([exp[k][m, :, p] for m, p in keep], axis=1)[None] for k in ("Y", "U", "R")]
    np.testing.assert_allclose(res.frf, indirect(*pooled), rtol=1e-12)
    # per realisation: realisation 1 now has periods 0 and 2 only; the one-record noise
    # variance K var_n(G_m) is pooled over the realisations with K - 1 degrees of freedom
    keep_p = [[0, 1, 2], [0, 2], [0, 1, 2]]
    parts = [frf_noise_variance(*(exp[k][m:m + 1][:, :, keep_p[m]] for k in ("Y", "U", "R")))
             for m in range(3)]
    gm = np.concatenate([p[0] for p in parts])
    np.testing.assert_allclose(res.var_total, gm.var(axis=0, ddof=1) / 3, rtol=1e-12)
    k = np.array([3, 2, 3])
    s2 = sum((k[m] - 1) * k[m] * parts[m][1][0] for m in range(3)) / (k - 1).sum()
    np.testing.assert_allclose(res.var_noise, (s2 / 3 + s2 / 2 + s2 / 3) / 3 / 3, rtol=1e-12)


def test_gap_across_a_period_boundary_and_in_a_transient(exp, streamed):
    d, x = exp["design"], exp["x"]
    n, pt = d.n_per_period, d.n_transient_periods
    seg = PRE + d.segment_start(2, 1)
    # across the boundary of steady-state periods 0 and 1 of (m=2, e=1): both go
    s = _stream(d, x, 1000, skip=[(seg + (pt + 1) * n - 5, seg + (pt + 1) * n + 5)])
    assert s.gaps[0].periods == ((2, 1, 0), (2, 1, 1))
    assert s.estimate().n_periods == 7
    # inside a transient period: nothing lost, the estimate is unchanged bit for bit
    s = _stream(d, x, 1000, skip=[(seg + 10, seg + 300)])
    assert s.gaps[0].periods == () and s.gaps[0].n_samples == 290
    _results_equal(s.estimate(), streamed.estimate())


def test_progress_truncation_and_late_start(exp):
    d, x = exp["design"], exp["x"]
    seg_len = d.segment_start(1, 0)
    s = FrfStream(d, *NAMES, start_index=PRE)
    assert s.estimate() is None
    rep = s.add(0, x[:PRE + seg_len - 1])              # realisation 0 but its last sample
    assert rep.realisations_completed == () and s.estimate() is None
    p = s.progress()
    assert (p.periods_done, p.periods_total, p.realisations_done) == (5, 18, 0)
    rep = s.add(PRE + seg_len - 1, x[PRE + seg_len - 1:PRE + seg_len + 10])
    assert rep.realisations_completed == (0,) and rep.periods_completed == 1
    assert s.estimate().n_realisations == 1 and np.all(np.isnan(s.estimate().var_total))
    assert s.progress().time_left_s == pytest.approx((d.total_samples - seg_len - 10) / FS)
    # stopped after realisation 1 and half of 2: the result is the batch one on M = 2
    s.truncate(2 * seg_len + seg_len // 2)
    rep = s.add(PRE + seg_len + 10, x[PRE + seg_len + 10:])
    assert rep.finished and rep.realisations_completed == (1,)
    np.testing.assert_allclose(s.estimate().frf, indirect(*(exp[k][:2] for k in ("Y", "U", "R"))),
                               rtol=1e-12)
    # a stream started mid-experiment reports the samples it never saw as a gap
    late = _stream(d, x, 1000, skip=[(0, PRE + 700)])
    assert late.gaps[0].start_index == PRE and late.gaps[0].n_samples == 700
    assert late.gaps[0].periods == ((0, 0, 0),)        # the transient period is not listed


def test_bad_blocks_are_refused_and_change_nothing(exp):
    d, x = exp["design"], exp["x"]
    s = FrfStream(d, *NAMES, start_index=PRE)
    s.add(0, x[:1000])
    with pytest.raises(ValueError, match="index order"):
        s.add(500, x[500:1500])
    with pytest.raises(ValueError, match="NaN"):
        s.add(1000, np.full((10, 6), np.nan))
    with pytest.raises(ValueError, match=r"shape \(n, 6\)"):
        s.add(1000, x[1000:1010, :4])
    with pytest.raises(ValueError, match="estimator must be one of"):
        s.estimate("welch")
    with pytest.raises(ValueError, match="lacks channel"):
        s.columns(["y_1", "y_2", "u_1", "u_2", "r_1"])
    with pytest.raises(ValueError, match="sample period"):
        s.check_sample_period(1e-3)
    s.add(1000, x[1000:])
    assert not s.gaps
    _results_equal(s.estimate(), _stream(d, x, 777).estimate())


def test_match_inputs_by_axis_tag_or_position():
    u = ("u_a_x", "u_b_x", "u_a_y", "u_b_y")
    r = ("r_a_x", "r_b_x", "r_a_y", "r_b_y")
    assert match_inputs(("r_b_x", "a_x"), u, r) == (("u_b_x", "u_a_x"), ("r_b_x", "r_a_x"))
    assert match_inputs(("i1", "i2", "i3", "i4"), u, r) == (u, r)
    with pytest.raises(ValueError, match="excites inputs"):
        match_inputs(("q1", "q2"), u, r)


def test_stepped_sine_line_by_line(loop):
    d = design_stepped_sine((20.0, 600.0), 20.0, FS, ("u_1", "u_2"), 0.05, settle_s=0.05,
                            n_cycles=4, lines=[2, 7, 15])
    x = _record(d, loop, seed=4)
    s = _stream(d, x, 333)
    res = s.estimate()
    period, transient, _ = d.segment_layout()
    recs = {k: [] for k in ("y", "u", "r")}
    for m in range(d.n_realisations):
        a, b = PRE + d.segment_start(m, 0), PRE + d.segment_start(m, 0) + 2 * (d.segment_start(m, 1)
                                                                            - d.segment_start(m, 0))
        seg = x[a:b].reshape(2, -1, 6)
        for k, cols in zip(recs, (slice(0, 2), slice(2, 4), slice(4, 6))):
            recs[k].append(seg[..., cols])
    g = stepped_sine_frf(recs["y"], recs["u"], d.freq_hz, FS, transient * period, r_records=recs["r"])
    np.testing.assert_allclose(res.frf, g, rtol=1e-9)
    np.testing.assert_array_equal(res.freq_hz, d.freq_hz)
    assert np.isfinite(res.var_noise[0]).all() and np.isnan(res.var_noise[1]).all()  # P = 1 at k = 7
    p_true = plant_frf(loop, d.freq_hz)
    assert np.max(np.linalg.norm(res.frf - p_true, axis=(1, 2)) / np.linalg.norm(p_true, axis=(1, 2))) < 0.05


def test_noise_excitation_is_welch_without_overlap(loop):
    d = design_noise((20.0, 600.0), 20.0, FS, ("u_1", "u_2"), 0.1, n_periods=6, n_realisations=2)
    x = _record(d, loop, seed=5)
    s = _stream(d, x, 1000)
    res = s.estimate("indirect")
    n, pt, p = d.n_per_period, d.n_transient_periods, d.n_periods
    segs = x[PRE:PRE + d.total_samples].reshape(d.n_realisations * d.n_experiments, (pt + p) * n, 6)[:, pt * n:]
    w = welch_frf(segs[..., :2], segs[..., 2:4], FS, n, r=segs[..., 4:], overlap=0.0)
    np.testing.assert_allclose(res.frf, w.frf[d.excited_lines], rtol=1e-12)
    np.testing.assert_allclose(res.coherence, w.coherence[d.excited_lines], rtol=1e-12)
    assert np.all(np.isnan(res.var_noise)) and np.all(np.isnan(res.noise_std))
    with pytest.raises(ValueError, match="not periodic"):
        s.estimate("eiv")
