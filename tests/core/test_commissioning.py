"""The commissioning core without a session: the structured controller against its transfer function, the
fast loops against the state-space closed loop, the drawn plants against the posterior they claim, the noise
budget against a Lyapunov equation, the H-infinity synthesis against a frequency sweep of its own closed
loop, and the prediction of a verifying measurement against what it must collapse to without noise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg, signal, stats

from ambid.channels import RADIAL, Layout
from ambid.commissioning.limits import CurrentBudget, check_current
from ambid.commissioning.loops import block_inverse, coupled_blocks, input_sensitivity_frf, worst_peak
from ambid.commissioning.plants import draw_parameters, plant_set, plant_uncertainty
from ambid.commissioning.prediction import MeasurementModel, predict_peak
from ambid.control.closed_loop import close_loop, input_sensitivity, loop_robustness, residue_freqresp
from ambid.control.hinf import MixedSensitivityWeights, generalized_plant, mixed_sensitivity, reduce_controller, \
    with_delay
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.structured import Notch, StructuredAxis, bilinear_section, structured_axis_frf, structured_controller
from ambid.fit import fit_common_denominator
from ambid.fit.model_update import nominal_update_parameters, physical_discrete
from ambid.frf.sensitivity import zone_probabilities
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig

RIG = make_rig()
DT = RIG.dt


def test_structured_controller_is_its_transfer_functionbilinear_section_mapped_and_delayed():
    p = StructuredAxis(kp_a_per_m=9000.0, ti_s=0.04, td_s=2e-3, derivative_filter_n=20.0, lead_zero_hz=150.0,
                       lead_pole_hz=600.0, lowpass_hz=3000.0, lowpass_damping=0.6,
                       notches=(Notch(927.0, 0.2, 0.05), Notch(1700.0, 1.0, 0.1)))
    k = structured_controller([p] * 4, DT, RADIAL)
    assert np.all(k.d == 0) and k.input_names == RADIAL.outputs
    f = np.geomspace(2.0, 4900.0, 60)
    # the continuous design, written here from the module docstring, at Tustin's s = 2/dt tan(w dt / 2)
    s = 2j / DT * np.tan(np.pi * f * DT)
    wz, wp, wl, wn = (2 * np.pi * x for x in (150.0, 600.0, 3000.0, 927.0))
    c = (9000.0 * (1 + 1 / (0.04 * s) + 2e-3 * s / (1 + 2e-3 * s / 20.0)) * (1 + s / wz) / (1 + s / wp)
         / (s**2 / wl**2 + 1.2 * s / wl + 1) * (s**2 + 2 * 0.01 * wn * s + wn**2) / (s**2 + 2 * 0.05 * wn * s + wn**2))
    want = -c * np.exp(-2j * np.pi * f * DT)
    got = k.freqresp(f)
    assert np.allclose(got[:, 2, 2], want, rtol=1e-6)
    assert np.allclose(structured_axis_frf(p, f, DT), want, rtol=1e-9)
    assert np.all(got[:, 0, 1] == 0)   # decentralised
    a = np.array([[0.0, 1.0], [-4e7, -900.0]])
    ref = signal.cont2discrete((a, np.array([[0.0], [1.0]]), np.array([[1.0, 2.0]]), np.array([[0.5]])), DT,
                               method="bilinear")
    for x, y in zip(bilinear_section(a, np.array([[0.0], [1.0]]), np.array([[1.0, 2.0]]), np.array([[0.5]]), DT), ref):
        assert np.allclose(x, y, rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="depth"):
        Notch(900.0, 1.5, 0.1)


def test_loops_from_frequency_responses_are_the_state_space_closed_loops():
    plant = analytical_model(RIG).to_discrete(DT)
    k = pid_controller(PidParameters(), DT, RADIAL)
    f = np.geomspace(5.0, 4000.0, 300)
    want = input_sensitivity(plant, k, f)          # the closed loop's own state space
    g, kf = plant.freqresp(f), k.freqresp(f)
    assert np.allclose(input_sensitivity_frf(kf, g), want, rtol=1e-6, atol=1e-7)
    assert np.allclose(input_sensitivity_frf(np.diagonal(kf, axis1=1, axis2=2), g), want, rtol=1e-6, atol=1e-7)
    assert worst_peak(np.diagonal(kf, axis1=1, axis2=2), g[None])[0] == pytest.approx(
        np.abs(np.diagonal(want, axis1=1, axis2=2)).max(), rel=1e-6)
    r = residue_freqresp(plant, f)
    assert np.max(np.linalg.norm(r - g, axis=(1, 2)) / np.linalg.norm(g, axis=(1, 2))) < 1e-7
    # blocks: the x and y planes of a rotor at standstill are apart
    assert [list(b) for b in coupled_blocks(np.abs(r).max(axis=0) > 1e-7 * np.abs(r).max())] == [[0, 1], [2, 3]]
    rng = np.random.default_rng(4)
    m = rng.standard_normal((7, 5, 5)) + 1j * rng.standard_normal((7, 5, 5))
    m[:, 4, :4] = m[:, :4, 4] = 0
    m[:, :2, 2:4] = m[:, 2:4, :2] = 0
    blocks = coupled_blocks(np.abs(m).max(axis=0) > 0)
    assert [list(b) for b in blocks] == [[0, 1], [2, 3], [4]]
    m[:, 0, 2] = 1.0   # a 3 x 3 block now
    assert np.allclose(block_inverse(m, coupled_blocks(np.abs(m).max(axis=0) > 0)), np.linalg.inv(m))


def _update(values: dict, free: dict, corr: np.ndarray, q: dict | None = None, tight: bool = False) -> dict:
    """An update dict as identify writes it: name -> (std, log) for the free ones; ci95 read with the t quantile
    ``q[name]`` (default 1.96); with ``tight`` every other parameter with a tolerance free too, known to 1e-9."""
    if tight:
        from ambid.plant.tolerances import tolerance_for

        extra = {k: (1e-9 * abs(v) or 1e-15, False) for k, v in values.items()
                 if k not in free and not k.startswith("sensor_gain") and tolerance_for(k, RIG.tolerances) is not None}
        free = {**free, **extra}
        corr = linalg.block_diag(corr, np.eye(len(extra)))
    params = {}
    for name, v in values.items():
        row = {"value": v, "free": name in free}
        if name in free:
            sd, lg = free[name]
            half = (q or {}).get(name, 1.959964) * sd
            row.update(std=sd * (v if lg else 1.0), prior={"log": lg},
                       ci95=[v * np.exp(-half), v * np.exp(half)] if lg else [v - half, v + half])
        params[name] = row
    return {"parameters": params, "free": list(free), "correlation": corr.tolist()}


def test_drawn_plants_have_the_posterior_identify_claims():
    values = nominal_update_parameters(RIG)
    corr = np.array([[1.0, 0.8], [0.8, 1.0]])
    update = _update(values, {"ki_n_per_a": (0.5, False), "bending_damping_ratio": (0.2, True)}, corr,
                     {"bending_damping_ratio": float(stats.t.ppf(0.975, 4))})
    unc = plant_uncertainty(update, RIG)
    assert unc.dof[0] == np.inf and unc.dof[1] == pytest.approx(4.0, rel=1e-3)
    draws = draw_parameters(unc, 6000, np.random.default_rng(1))
    assert draws[0]["ki_n_per_a"] == values["ki_n_per_a"]   # the first is the estimate
    ki = np.array([d["ki_n_per_a"] for d in draws])
    z = np.log(np.array([d["bending_damping_ratio"] for d in draws]) / values["bending_damping_ratio"]) / 0.2
    assert np.std(ki) == pytest.approx(0.5, rel=0.05)
    # the damping's own Student t of 4 degrees of freedom: its 97.5 % point 2.78, not the normal's 1.96
    assert np.quantile(z, 0.975) == pytest.approx(stats.t.ppf(0.975, 4), rel=0.08)
    # a Gaussian copula's rank correlation: 6 / pi arcsin(rho / 2)
    assert stats.spearmanr(ki, z)[0] == pytest.approx(6 / np.pi * np.arcsin(0.4), abs=0.03)
    # an out-of-band bending mode no data reached is drawn from its tolerance (5 %)
    f3 = np.array([d["bending_3_freq_hz"] for d in draws])
    assert np.std(f3) / values["bending_3_freq_hz"] == pytest.approx(0.05 / 1.96, rel=0.07)
    with pytest.raises(ValueError, match="no updated physical model"):
        plant_uncertainty({"error": "every parameter is fixed"}, RIG)


def test_noise_current_is_the_lyapunov_equations():
    plant = physical_discrete(RIG.rotor_model(), nominal_update_parameters(RIG), DT)
    k = pid_controller(PidParameters(), DT, RADIAL)
    sigma = 0.2e-6
    budget = CurrentBudget(3.0, np.full(4, 0.7), np.full(4, 0.4), np.full(4, sigma), np.full(4, 0.02),
                           np.full(4, 1700.0), 560.0)
    check = check_current(plant, k, budget)
    # ic = Ck xk + Dk (y + v): the closed loop's state covariance from the discrete Lyapunov equation
    loop = close_loop(plant, k)
    n_p = plant.n_states
    bv = np.vstack([plant.b @ k.d, k.b]) * sigma
    p = linalg.solve_discrete_lyapunov(loop.a, bv @ bv.T)
    cic = np.hstack([k.d @ plant.c, k.c])
    var = np.diag(cic @ p @ cic.T) + np.diag(k.d @ k.d.T) * sigma**2
    assert np.allclose(check.noise_rms_a, np.sqrt(var), rtol=0.01)
    assert check.ok and check.current_margin_a == pytest.approx(3.0 - 1.1 - 4 * check.noise_rms_a.max(), rel=1e-9)
    assert n_p > 0


def test_hinf_synthesis_holds_its_gamma_and_the_loop():
    plant = physical_discrete(RIG.rotor_model(), nominal_update_parameters(RIG), DT)
    w = MixedSensitivityWeights(effort_corner_hz=600.0)
    k0, gamma = mixed_sensitivity(plant, w)
    k = with_delay(k0)
    assert np.all(k.d == 0) and np.all(np.abs(close_loop(plant, k).poles()) < 1)
    # the closed loop of the generalised plant, swept here: its largest singular value stays below gamma
    p, ncon, nmeas = generalized_plant(plant, w)
    f = np.geomspace(1.0, 4990.0, 2500)
    pf = p.freqresp(f)
    kf = k0._replace(b=k0.b / 1e6, d=k0.d / 1e6).freqresp(f)   # the synthesis' controller takes micrometres
    nz, nw = p.n_outputs - nmeas, p.n_inputs - ncon
    p11, p12, p21, p22 = pf[:, :nz, :nw], pf[:, :nz, nw:], pf[:, nz:, :nw], pf[:, nz:, nw:]
    t = p11 + p12 @ kf @ np.linalg.inv(np.eye(nmeas) - p22 @ kf) @ p21
    assert np.linalg.svd(t, compute_uv=False)[:, 0].max() <= gamma * 1.01
    rob = loop_robustness(plant, k)
    assert rob.sensitivity_peak.max() <= gamma * w.sensitivity_peak * 1.01
    kr = reduce_controller(k0, 40)
    assert kr.n_states == 40 and kr.d.shape == k0.d.shape
    with pytest.raises(ValueError, match="no controller reaches gamma"):
        mixed_sensitivity(plant, MixedSensitivityWeights(sensitivity_peak=0.2), gamma_max=0.5)


def test_prediction_collapses_to_the_loop_without_noise_and_widens_with_it():
    values = nominal_update_parameters(RIG)
    unc = plant_uncertainty(_update(values, {"ki_n_per_a": (1e-6, False)}, np.eye(1), tight=True), RIG)
    assert unc.prior_only == ()
    k = pid_controller(PidParameters(), DT, RADIAL)
    lines = np.arange(15.0, 1000.0, 10.0)
    g = plant_set(unc, [values], lines).frf[0]
    fit = fit_common_denominator(lines, g, None, order=12, delay_s=DT / 2)
    quiet = MeasurementModel(lines, np.full((lines.size, 4), 1e-30), 12, DT / 2, fit.model.poles)
    p0 = predict_peak(unc, k, quiet, n_samples=4, axes=RADIAL.axes)
    # no noise and no doubt: the simulated measurement is the loop's own peak in the band
    band = np.linspace(lines.min(), lines.max(), 8000)
    peak_band = worst_peak(np.diagonal(k.freqresp(band), axis1=1, axis2=2), residue_freqresp(
        physical_discrete(RIG.rotor_model(), values, DT), band)[None])[0]
    assert p0.ci95[0] == pytest.approx(peak_band, rel=2e-3) and p0.ci95[1] == pytest.approx(peak_band, rel=2e-3)
    assert p0.zones == zone_probabilities(np.array([peak_band]))
    noisy = MeasurementModel(lines, np.full((lines.size, 4), (0.02 * np.abs(g).max()) ** 2), 12, DT / 2,
                             fit.model.poles)
    p1 = predict_peak(unc, k, noisy, n_samples=12, axes=RADIAL.axes)
    assert p1.ci95[1] - p1.ci95[0] > 20 * (p0.ci95[1] - p0.ci95[0])
    # a measured peak is the largest of noisy values: noise raises it, which the interval must hold
    assert p1.value > peak_band


def test_a_layout_of_five_axes_is_tuned_in_two_groups():
    from ambid.commissioning.structured_tuning import axis_groups

    assert axis_groups(Layout(("a_x", "b_x", "a_y", "b_y", "z"))) == [[0, 1, 2, 3], [4]]
    assert axis_groups(Layout(("z",))) == [[0]]


def test_the_prediction_moves_the_posterior_to_the_new_loops_operating_point():
    """The magnets' slopes a run's excitation sees depend on the loop; the posterior is carried to the new loop by
    the ratio on the plant the data showed (the nominal rig moved to the update's estimates, its magnets those
    estimates), not on the drawing's: a nominal rig off by its tolerances gives the same ratio as the rig itself.
    The run's own controller leaves it where it is and linear magnets do not move it."""
    from dataclasses import replace
    from types import SimpleNamespace

    from ambid.commissioning.from_run import operating_point
    from ambid.excitation import design_multisine
    from ambid.fit.model_update import excitation_slopes, rig_values_for, slopes_as_parameters

    values = nominal_update_parameters(RIG)
    unc = plant_uncertainty(_update(values, {"ki_n_per_a": (0.5, False), "ks_n_per_m": (2000.0, False)},
                                    np.eye(2)), RIG)
    design = design_multisine((10.0, 1000.0), 10.0, RIG.sample_rate_hz, list(RADIAL.inputs), 0.4, n_periods=1,
                              n_realisations=1, seed=5)
    ran = pid_controller(PidParameters(kp_a_per_m=20_000.0, td_s=0.8e-3), DT)
    new = pid_controller(PidParameters(), DT)
    # the drawing misses the rig: ki 3 % high, ks 4 % low, the amplifier 10 % slow
    off = replace(RIG, values={**RIG.values, **rig_values_for(RIG, {
        "ki_n_per_a": 1.03 * values["ki_n_per_a"], "ks_n_per_m": 0.96 * values["ks_n_per_m"],
        "amplifier_bandwidth_hz": 0.9 * values["amplifier_bandwidth_hz"]})})
    assert nominal_update_parameters(off)["ks_n_per_m"] == pytest.approx(0.96 * values["ks_n_per_m"], rel=1e-12)
    run = SimpleNamespace(rig=off, controller=(ran, {}), design=design, nonlinear_magnets=True)
    at = operating_point(run, unc)
    assert at(ran).values == pytest.approx(unc.values, rel=1e-12)
    # the rig the data describe: the built-in one, its magnets exactly the estimates (no manufacturing factor)
    exact = replace(RIG, values={**RIG.values, "true_ki_factor": 1.0, "true_ks_factor": 1.0})

    def ratio(rig):
        a = slopes_as_parameters(*excitation_slopes(rig, ran, design), rig.layout)
        b = slopes_as_parameters(*excitation_slopes(rig, new, design), rig.layout)
        return {k: b[k] / a[k] for k in ("ki_n_per_a", "ks_n_per_m")}

    want, drawing = ratio(exact), ratio(replace(off, values={**off.values, "true_ki_factor": 1.0,
                                                              "true_ks_factor": 1.0}))
    moved_values = at(new).values
    for name in ("ki_n_per_a", "ks_n_per_m"):
        assert moved_values[name] == pytest.approx(unc.values[name] * want[name], rel=1e-9)
        assert abs(want[name] - 1) > 1e-5                 # the loops differ enough to move the slopes
        assert abs(drawing[name] - want[name]) > 1e-6     # and the drawing's ratio would have been another
    assert np.array_equal(at(new).cov, unc.cov)           # the data's spread is kept
    assert operating_point(SimpleNamespace(**{**vars(run), "nonlinear_magnets": False}), unc) is None


def test_the_verifying_fit_is_weighted_as_identify_weights_it_with_the_runs_scatter():
    """identify weights its fit by the noise and total variances its run estimates (a few degrees of freedom a
    line); the simulated verifying fit draws its estimates from the run's own line-to-line scatter and combines
    them by identify's rule."""
    from ambid.commissioning.prediction import measurement_model, verify_fit_weights
    from ambid.frf.uncertainty import fit_weight_variance

    rng = np.random.default_rng(3)
    lines = np.arange(15.0, 1000.0, 10.0)
    n, ny = lines.size, 4
    sens = np.broadcast_to(np.eye(ny) * 0.8, (n, ny, ny)).astype(complex)
    level = 1e-14 * (1 + lines / 500.0)                                      # (L,) smooth noise level
    dof = 8
    factors = rng.chisquare(dof, (n, ny, 1)) / dof                           # one estimate per line and output
    var_noise = level[:, None, None] * factors * np.ones((1, 1, ny))
    var_total = 3 * var_noise                                                # a distortion share of 3
    m = measurement_model(lines, var_total, sens, 12, DT / 2, np.zeros(12, complex), var_noise=var_noise)
    assert m.scatter.shape == (n * ny, 2)
    inner = m.scatter[4 * ny:-4 * ny]                                        # lines with six neighbours
    # each line over its neighbours' mean: chi2(dof)/dof over chi2(6 dof)/(6 dof), its variance 2/dof (1 + 1/6 ...)
    assert np.mean(inner[:, 0]) == pytest.approx(1.0, abs=0.1)
    assert np.var(inner[:, 0]) == pytest.approx(2 / dof * (1 + 1 / 6), rel=0.35)
    assert np.allclose(inner[:, 0], inner[:, 1])                             # noise and total scatter together
    # no scatter: identify's rule on the new loop's levels (gain sum_k |Sinv_kj|^2 = 1 / 0.8^2)
    still = MeasurementModel(lines, m.noise_var, 12, DT / 2, np.zeros(12, complex),
                             noise_only_var=m.noise_only_var, scatter=np.ones((4, 2)))
    w = verify_fit_weights(still, np.linalg.inv(sens), rng)
    gain = 1 / 0.8 ** 2
    expect = fit_weight_variance(m.noise_only_var[:, :, None] * gain * np.ones(ny),
                                 m.noise_var[:, :, None] * gain * np.ones(ny))
    assert np.allclose(w, expect, rtol=1e-12)
    # with the run's scatter the weights move line by line, about the same level
    w1 = verify_fit_weights(m, np.linalg.inv(sens), rng)
    ratio = w1[:, :, 0] / expect[:, :, 0]
    assert 0.1 < np.std(np.log(ratio)) < 1.5 and np.median(ratio) == pytest.approx(1.0, abs=0.3)
