"""Coverage bookkeeping of ``ambid validate`` (ambid.validation.coverage) and the excitation-level truth
of the magnets (ambid.fit.model_update.excitation_slopes)."""

import numpy as np
import pytest
from ambid.control.pid import PidParameters, pid_controller
from ambid.excitation.spec import build_design
from ambid.fit.model_update import closed_loop_noise_std, excitation_slopes
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import levitated_plant, true_linear_model
from ambid.validation.coverage import FRF_NOMINAL, clopper_pearson, coverage_table, frf_record
from scipy import linalg, stats


def test_clopper_pearson_against_closed_forms():
    # k = 0: upper = 1 - (alpha/2)^(1/n); k = n: lower = (alpha/2)^(1/n)
    n = 20
    assert clopper_pearson(0, n) == (0.0, pytest.approx(1 - 0.025 ** (1 / n)))
    assert clopper_pearson(n, n) == (pytest.approx(0.025 ** (1 / n)), 1.0)
    lo, hi = clopper_pearson(17, 20)
    # the exact interval holds the binomial tails at 2.5 % each
    assert stats.binom.sf(16, 20, lo) == pytest.approx(0.025, rel=1e-6)
    assert stats.binom.cdf(17, 20, hi) == pytest.approx(0.025, rel=1e-6)


def test_right_claims_give_nominal_coverage_and_unit_ratio():
    rng = np.random.default_rng(21)
    n_seeds, true = 400, 3.0
    records = []
    for _ in range(n_seeds):
        std = 0.1 * (1 + 0.2 * rng.uniform())             # each seed claims its own (right) sigma
        v = true + std * rng.standard_normal()
        g_true = np.ones((50, 2, 2), complex)
        var = np.full(g_true.shape, 1e-4) * np.logspace(0, 4, 50)[:, None, None]    # sigma over four decades
        g = g_true + np.sqrt(var / 2) * (rng.standard_normal(g_true.shape) + 1j * rng.standard_normal(g_true.shape))
        records.append(dict(frf={"k": frf_record(g, g_true, {"v": var})["v"]},
                            intervals={"p": dict(value=v, std=std, ci95=[v - 1.96 * std, v + 1.96 * std], true=true,
                                                 noise_only=True)}, noise=None))
    t = coverage_table(records)
    assert t["frf:k"]["nominal"] == pytest.approx(1 - np.exp(-4))
    assert t["frf:k"]["ci95"][0] < FRF_NOMINAL < t["frf:k"]["ci95"][1]
    assert abs(t["frf:k"]["z_rms"] - 1) < 0.02 and abs(t["frf:k"]["std_ratio"] - 1) < 0.1
    assert t["p"]["ci95"][0] < 0.95 < t["p"]["ci95"][1] and abs(t["p"]["std_ratio"] - 1) < 0.1
    # a claim half as wide as the truth shows as a ratio near 2 and a coverage far below 0.95
    for r in records:
        x = r["intervals"]["p"]
        s = x["std"] / 2
        x.update(std=s, ci95=[x["value"] - 1.96 * s, x["value"] + 1.96 * s])
    t2 = coverage_table(records)
    assert abs(t2["p"]["std_ratio"] - 2) < 0.2 and t2["p"]["ci95"][1] < 0.8


@pytest.fixture(scope="module")
def loop():
    rig = make_rig()
    pid = PidParameters()
    return rig, pid_controller(pid, rig.dt)


def _design(peak):
    return build_design("multisine", (10.0, 1000.0), 5.0, 10_000.0, peak_current_a=peak, n_periods=2,
                        n_realisations=1, n_transient_periods=1, grid="random_odd", mimo="orthogonal",
                        phases="random", seed=3)


def test_excitation_slopes_follow_the_quadratic_magnet_law(loop):
    # ks = dF/dg grows with the square of the current excursion (ks (1 + i^2 / ib^2) at the centre):
    # the shift over the small-signal slope scales with the excitation's power, ki barely moves
    rig, k = loop
    op = levitated_plant(rig)[1]
    ki1, ks1 = excitation_slopes(rig, k, _design(0.2))
    ki2, ks2 = excitation_slopes(rig, k, _design(0.4))
    ki0, ks0 = excitation_slopes(rig, k, _design(1e-4))   # the sensor noise alone
    np.testing.assert_allclose(ks0, op.ks_n_per_m, rtol=2e-4)
    np.testing.assert_allclose(ki0, op.ki_n_per_a, rtol=2e-4)
    d1, d2 = ks1 - ks0, ks2 - ks0
    assert np.all(d1 > 0)
    np.testing.assert_allclose(d2 / d1, 4.0, rtol=0.02)
    # size: 2 kc sigma_i^2 / s0^3 with kc 2 k cos(alpha) -> ks0 sigma_i^2 / (ib^2 + i0^2); sigma_i of order the rms
    mag = rig.true_magnet
    assert np.all(d2 / ks0 < 0.4**2 / mag.bias_current_a**2)
    assert np.all(np.abs(ki2 / ki0 - 1) < 0.01)


def test_realisation_inflation_reads_the_scatter_against_the_claim():
    from ambid.fit.correlated import realisation_inflation

    rng = np.random.default_rng(22)
    p, m = 6, 3
    a = rng.standard_normal((p, p))
    cov = a @ a.T + p * np.eye(p)
    chol = np.linalg.cholesky(cov)
    # deviations of M realisations from their mean scatter with M cov (the mean's covariance is cov):
    # each parameter's kappa is then chi2(M - 1) / (M - 1), and 4 times that when the scatter is twice as wide
    def draw(scale):
        x = scale * np.sqrt(m) * (rng.standard_normal((m, p)) @ chol.T)     # one realisation: m cov
        return x - x.mean(axis=0)                                           # deviations from their mean

    right = np.array([realisation_inflation(draw(1.0), cov)[0] for _ in range(2000)])
    wide = np.array([realisation_inflation(draw(2.0), cov)[0] for _ in range(2000)])
    # the pooled estimate (2 + 2 kappa) / 4 floored at 1, kappa = X ~ Exp(1) (two degrees of freedom):
    # E = P(X < 1) + E[(1 + X) / 2; X > 1] = 1 + 1 / (2 e); with kappa = 4 X, 1 - e^-1/4 + e^-1/4 (0.5 + 2.5)
    assert np.all(right >= 1.0) and abs(np.mean(right) - (1 + 0.5 / np.e)) < 0.03
    expected_wide = 1 - np.exp(-0.25) + np.exp(-0.25) * (0.5 + 2 * 1.25)
    assert abs(np.mean(wide) - expected_wide) < 0.12
    # one parameter twice as wide alone: its own factor finds it, the others' stay as if right (no spill-over)
    def one_wide():
        x = draw(1.0)
        x[:, 0] *= 2
        return realisation_inflation(x, cov)[0]
    f = np.mean([one_wide() for _ in range(2000)], axis=0)
    assert abs(f[0] - expected_wide) < 0.12 and np.all(np.abs(f[1:] - (1 + 0.5 / np.e)) < 0.05)
    # degrees of freedom of the pooled variance (Satterthwaite): the sandwich's own where the floor holds,
    # (2 + 2 kappa)^2 / (4 / nu_s + 2 kappa^2) where the scatter raises it
    x = draw(1.0)
    fac, dof = realisation_inflation(x, cov, 50.0)
    kappa = np.sum(x**2, axis=0) / (m * (m - 1) * np.diag(cov))
    pooled = (2 + 2 * kappa) / 4
    np.testing.assert_allclose(dof, np.where(pooled > 1, (2 + 2 * kappa) ** 2 / (4 / 50 + 2 * kappa**2), 50.0))
    ones, many = realisation_inflation(np.zeros((1, p)), cov)
    np.testing.assert_array_equal(ones, np.ones(p))
    assert np.all(np.isinf(many))
    # the 95 % interval it makes holds 95-97.5 % of the errors when the sandwich is right; Student's t of
    # 2 + M - 1 = 4 degrees of freedom (the rule before) held 99.6 %: too wide for a right sigma
    n = 4000
    hits = hits_t4 = 0
    sd = np.sqrt(np.diag(cov))
    for _ in range(n):
        err = rng.standard_normal(p) * sd
        f_k, nu = realisation_inflation(draw(1.0), cov, 200.0)
        half = np.sqrt(f_k) * sd
        hits += np.sum(np.abs(err) <= stats.t.ppf(0.975, nu) * half)
        hits_t4 += np.sum(np.abs(err) <= stats.t.ppf(0.975, 4) * half)
    assert 0.95 <= hits / (n * p) <= 0.975, hits / (n * p)
    assert hits_t4 / (n * p) > 0.99


def test_validate_reuses_only_a_finished_seed_of_the_same_run(tmp_path):
    from ambid_cli.commands.validate import run_fingerprint, reusable_record

    fp = run_fingerprint("", False)
    assert fp != run_fingerprint("", True)                       # the magnet law is part of what a seed ran
    rec = tmp_path / "record.json"
    assert reusable_record(rec, fp) is None                         # not finished
    rec.write_text('{"fingerprint": "%s", "frf": {}}' % fp)
    assert reusable_record(rec, fp) == {"fingerprint": fp, "frf": {}}
    assert reusable_record(rec, "other") is None                    # another rig or code
    rec.write_text('{"fingerprint": "%s", "fr' % fp)          # cut short
    assert reusable_record(rec, fp) is None


def test_closed_loop_noise_std_against_parseval_over_the_unit_circle(loop):
    # the sensors' white noise through the loop, y = (I - G K)^-1 v: var(y_i) = sigma^2 mean over the unit circle
    # of sum_j |S_ij|^2 (Parseval; midpoint rule over 2^15 lines, fine enough for the 0.5 %-damped modes),
    # against the Lyapunov equation closed_loop_noise_std solves
    rig, k = loop
    g = true_linear_model(rig, discrete=True)
    n_lines = 1 << 15
    f = (np.arange(n_lines) + 0.5) / n_lines / (2 * rig.dt)
    s_out = np.linalg.inv(np.eye(4) - g.freqresp(f) @ k.freqresp(f))
    sigma = float(rig.values["sensor_noise_m"])
    expected = sigma * np.sqrt((np.abs(s_out) ** 2).sum(axis=2).mean(axis=0))
    np.testing.assert_allclose(closed_loop_noise_std(rig, k), expected, rtol=1e-4)
    assert np.all(expected > sigma)   # the loop colours and amplifies the sensor noise


def test_noise_interval_row_pools_the_outputs():
    rng = np.random.default_rng(4)
    records = []
    for _ in range(200):
        true, sd = np.full(4, 2e-7), np.full(4, 1e-9)
        v = true + sd * rng.standard_normal(4)
        ci = np.stack([v - 1.96 * sd, v + 1.96 * sd], axis=1)
        records.append(dict(frf={}, intervals={}, noise=v.tolist(),
                            noise_interval=dict(value=v.tolist(), std=sd.tolist(), ci95=ci.tolist(),
                                                true=true.tolist())))
    row = coverage_table(records)["noise_std (outputs pooled)"]
    assert row["n"] == 800 and row["ci95"][0] < 0.95 < row["ci95"][1] and abs(row["std_ratio"] - 1) < 0.08


def test_validate_does_not_reuse_a_seed_run_under_another_controller(tmp_path):
    from ambid_cli.commands.validate import run_fingerprint

    ctrl = tmp_path / "site.npz"
    ctrl.write_bytes(b"one")
    fp = run_fingerprint("", False, str(ctrl))
    assert fp != run_fingerprint("", False) and fp != run_fingerprint("", False, "lqg")
    ctrl.write_bytes(b"two")  # the same file name with another controller in it
    assert fp != run_fingerprint("", False, str(ctrl))


def test_with_bla_truth_moves_the_claimed_truth_and_keeps_the_rig_at_rest_beside_it():
    from ambid.validation.coverage import with_bla_truth

    # two seeds whose intervals hold the BLA's value (1.0) and miss the rig at rest (0.0)
    rec = lambda v: dict(frf={}, noise=None, intervals={
        "parameter:a": dict(value=v, std=0.1, ci95=[v - 0.196, v + 0.196], true=0.0, true_at_rest=0.0,
                            noise_only=False),
        "derived:total_lag_s": dict(value=v, std=0.1, ci95=[v - 0.196, v + 0.196], true=0.0, true_at_rest=0.0,
                                    noise_only=False),
        "mode_freq_hz:300Hz": dict(value=v, std=0.1, ci95=[v - 0.196, v + 0.196], true=1.0, noise_only=False)})
    records = [rec(0.95), rec(1.05)]
    bla = {"a": 1.0, "total_lag_s": 1.0, "b": 7.0}
    moved = [with_bla_truth(r, bla) for r in records]
    assert records[0]["intervals"]["parameter:a"]["true"] == 0.0            # the record itself is kept
    t = coverage_table(moved)
    for k in ("parameter:a", "derived:total_lag_s"):
        assert t[k]["coverage"] == 1.0 and t[k]["std_ratio"] == pytest.approx(0.5)
        assert t[k]["at_rest"]["coverage"] == 0.0 and t[k]["at_rest"]["shift_over_std"] == pytest.approx(10.0)
        assert "best linear approximation" in t[k]["claim"]
    assert "at_rest" not in t["mode_freq_hz:300Hz"]                          # a mode keeps its own truth
    pooled = t["pooled: parameters and modes"]
    assert pooled["coverage"] == 1.0 and pooled["at_rest"]["coverage"] == 0.5


def test_at_own_excitation_moves_only_the_magnets_slopes_by_the_sessions_own_excitation():
    from ambid.fit.model_update import slopes_as_parameters
    from ambid.validation.bla_truth import SLOPES, at_own_excitation

    bla = {"ki_n_per_a": 179.0, "ks_n_per_m": 8.7e5, "ks_b_over_a": 0.998, "delay_s": 5e-5, "total_lag_s": 1.7e-4}
    # a session whose grid stiffens the magnets more than the seeds' mean does
    own = slopes_as_parameters(np.array([179.1, 179.3, 179.1, 179.3]), np.array([8.70e5, 8.72e5, 8.70e5, 8.72e5]))
    assert own["ki_n_per_a"] == pytest.approx(179.2) and own["ks_b_over_a"] == pytest.approx(8.72 / 8.70)
    mean = {"ki_n_per_a": 179.15, "ks_n_per_m": 8.705e5, "ks_b_over_a": 1.0}
    est = at_own_excitation(bla, own, mean)
    assert est["ki_n_per_a"] == pytest.approx(179.05) and est["ks_n_per_m"] == pytest.approx(8.705e5)
    assert est["ks_b_over_a"] == pytest.approx(0.998 + 8.72 / 8.70 - 1.0)
    assert {k: est[k] for k in ("delay_s", "total_lag_s")} == {"delay_s": 5e-5, "total_lag_s": 1.7e-4}
    assert bla["ki_n_per_a"] == 179.0                                          # the pooled one is kept
    # a slope without the session's own value (linear magnets: none) stays pooled
    assert at_own_excitation(bla, {}, mean) == bla and set(SLOPES) <= set(bla)


def test_noise_free_twin_is_the_loop_without_noise_and_the_bla_of_linear_magnets_is_the_rig_at_rest(loop):
    # with linear magnets the simulated rig is its small-signal model: the noise-free twin measures it (to what
    # eight transient periods leave of the lift-off: 1e-7), and the BLA parameters are the rig's at rest; with
    # the magnets' law they move by the magnets' slopes at the excitation level (Bussgang) and more
    from ambid.control.pid import PidParameters
    from ambid.fit.model_update import nominal_update_parameters, total_lag, true_parameters
    from ambid.validation.bla_truth import Twin, bla_parameters, noise_free_twin, variance_on

    rig, ctl = loop
    d = build_design("multisine", (10.0, 1000.0), 5.0, 10_000.0, peak_current_a=0.4, n_periods=1,
                     n_realisations=2, n_transient_periods=8, grid="random_odd", mimo="orthogonal",
                     phases="random", seed=3)
    limit = PidParameters().current_limit_a
    lin = noise_free_twin(rig, ctl, limit, d, nonlinear_magnets=False)
    g0 = true_linear_model(rig, discrete=True).freqresp(lin.freq_hz)
    assert np.max(np.abs(lin.frf - g0)) < 1e-6 * np.max(np.abs(g0))
    truth = true_parameters(rig)
    names = sorted(nominal_update_parameters(rig)) + ["support_damping_ratio", "support_freq_hz",
                                                      "support_gain_per_kg"]
    free = ["ki_n_per_a", "ks_n_per_m", "ks_b_over_a", "amplifier_bandwidth_hz", "sensor_bandwidth_hz", "delay_s",
            "bending_freq_hz", "bending_damping_ratio", "support_freq_hz"]
    var = variance_on([10.0, 1000.0], np.full((2, 4, 4), 1e-18), lin.freq_hz)      # equal weights
    assert var.shape == lin.frf.shape and np.allclose(var, 1e-18)
    at_rest = bla_parameters(rig, [Twin(lin.freq_hz, lin.frf, var)], names, free)
    for k in free:
        assert at_rest[k] == pytest.approx(truth[k], rel=3e-5, abs=1e-12), (k, at_rest[k], truth[k])
    nl = noise_free_twin(rig, ctl, limit, d)
    bla = bla_parameters(rig, [Twin(nl.freq_hz, nl.frf, var)], names, free)
    ki_x, ks_x = excitation_slopes(rig, ctl, d)
    # one twin of two realisations: its stochastic distortion is not averaged out, a few 1e-4 of ki and ks
    assert bla["ki_n_per_a"] == pytest.approx(np.mean(ki_x), rel=5e-4)
    assert bla["ks_n_per_m"] == pytest.approx(np.mean(ks_x), rel=5e-4)
    assert bla["ks_n_per_m"] / truth["ks_n_per_m"] - 1 > 5e-4                 # the excitation stiffens the magnets
    assert bla["total_lag_s"] == pytest.approx(total_lag(bla)) and bla["total_lag_s"] != total_lag(truth)


def test_drawn_nominal_rig_states_the_drawn_values_and_never_the_truth():
    # validate's nominal model: the true rig missed by one draw from each tolerance, written as a rig file
    from ambid.fit.model_update import nominal_update_parameters
    from ambid.plant.tolerances import Z95
    from ambid.validation.coverage import draw_nominal_rig

    rig = make_rig()
    for seed in range(3):
        over, drawn = draw_nominal_rig(rig, np.random.default_rng([seed, 26]))
        nominal = make_rig(over)
        values = nominal_update_parameters(nominal)
        for name in ("ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz", "sensor_bandwidth_hz", "bending_freq_hz",
                     "bending_damping_ratio"):
            assert values[name] == pytest.approx(drawn[name]["nominal"], rel=1e-9), name
            assert values[name] != pytest.approx(drawn[name]["true"], rel=1e-6), name
        # ki's draw: 5 % is 1.96 prior standard deviations
        d = drawn["ki_n_per_a"]
        assert d["nominal"] == pytest.approx(d["true"] * (1 + 0.05 / Z95 * d["z"]))
        # the delay's range 0..1 sample moved with its draw, as a range in seconds
        lo, hi = (float(x) for x in over["tolerances"]["delay_s"].split(".."))
        assert hi - lo == pytest.approx(rig.dt) and (lo + hi) / 2 == pytest.approx(drawn["delay_s"]["nominal"])
        assert nominal.values["sensor_noise_m"] == rig.values["sensor_noise_m"]       # the rest as it was


def test_pooled_row_counts_every_parameter_and_mode_interval():
    rec = lambda v: dict(frf={}, intervals={
        "parameter:a": dict(value=v, std=1.0, ci95=[v - 1.96, v + 1.96], true=0.0, noise_only=False),
        "mode_freq_hz:300Hz": dict(value=-v, std=2.0, ci95=[-v - 3.92, -v + 3.92], true=0.0, noise_only=False),
        "derived:total_lag_s": dict(value=5.0, std=1.0, ci95=[3.0, 7.0], true=0.0, noise_only=False)}, noise=None)
    t = coverage_table([rec(0.5), rec(3.0)])
    pooled = t["pooled: parameters and modes"]
    assert pooled["n"] == 4 and pooled["covered"] == 3                  # the total lag is its own row
    assert pooled["std_ratio"] == pytest.approx(np.sqrt((0.25 + 0.0625 + 9 + 2.25) / 4))
    assert t["derived:total_lag_s"]["coverage"] == 0.0


def test_predicted_peak_row_counts_the_cases_inside_their_interval():
    from ambid.validation.coverage import predicted_peak_row

    # three cases inside (the bounds count), one above, one below, one without a measurement (tune refused)
    cases = [dict(predicted=dict(value=2.1, ci95=[2.0, 2.2]), measured=m) for m in (2.0, 2.15, 2.2, 2.25, 1.9)]
    cases.append(dict(predicted=None, measured=None, refused="no controller holds every drawn plant"))
    row = predicted_peak_row(cases)
    assert row["n"] == 5 and row["covered"] == 3 and row["coverage"] == pytest.approx(0.6)
    assert row["nominal"] == 0.95 and row["ci95"] == list(clopper_pearson(3, 5))
    # claimed std: the half width over 1.96 (0.05102); errors 0.1, -0.05, -0.1, -0.15, 0.2
    s = 0.1 / 1.959964
    assert row["std_ratio"] == pytest.approx((0.085 / 5) ** 0.5 / s)
    assert predicted_peak_row(cases[-1:]) is None
