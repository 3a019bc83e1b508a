"""ambid.fit.model_update: the parametrised physical model against the rig's own models, and updating it."""

import numpy as np
import pytest
from ambid.fit.model_update import (PARAMETERS, bending_coordinates, nominal_parameters, physical_frf,
                                    physical_statespace, true_parameters, unmodelled_mode, update_physical_model)
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import levitated_plant, true_linear_model
from ambid.statespace import StateSpace

RIG = make_rig()
ROTOR = RIG.rotor_model()
F = np.linspace(10.0, 1000.0, 34)


def _agree(g: np.ndarray, ref: StateSpace, f: np.ndarray, rel: float) -> None:
    """|g - ref| <= rel * A * |ref| line by line, A = max over ref's poles of |s| / |s - p|.

    Two realisations of one model agree to a relative ``rel`` away from its poles; near a lightly damped
    pole the FRF's sensitivity to any rounding or realisation difference grows as the distance to the
    pole shrinks (A ~ 1 / (2 zeta) = Q at the peak: ~190 at the 310 Hz bending line), so a bound on the
    largest entry over the band would fail there on some BLAS kernels and be slack everywhere else."""
    poles = ref.poles()
    if ref.dt:
        poles = np.log(poles[np.abs(poles) > 0].astype(complex)) / ref.dt
    s = 2j * np.pi * f
    amp = np.max(np.abs(s)[:, None] / np.abs(s[:, None] - poles[None, :]), axis=1)
    r = ref.freqresp(f)
    err = np.abs(g - r).max(axis=(1, 2))
    bound = rel * np.maximum(amp, 1.0) * np.abs(r).max(axis=(1, 2))
    assert np.all(err <= bound), (f[np.argmax(err / bound)], np.max(err / bound))


def test_nominal_parameters_give_the_analytical_model():
    nom = nominal_parameters(RIG)
    assert nom["ki_n_per_a"] == RIG.magnet.ki and nom["ks_n_per_m"] == RIG.magnet.ks
    assert bending_coordinates(ROTOR).size == 2          # the first bending mode in the x and y planes
    assert bending_coordinates(ROTOR, 2).size == 2 and nom["bending_2_freq_hz"] == ROTOR.flexible_freq_hz[1]
    g = physical_frf(ROTOR, nom, F, 0.0)
    # the same matrices: rounding alone (measured 1.8e-10 x A on an EPYC with OpenBLAS' Haswell kernels)
    _agree(g, analytical_model(RIG), F, 1e-9)


def test_true_parameters_give_the_true_rig_sampled_and_continuous():
    true = {k: v for k, v in true_parameters(RIG).items() if k in PARAMETERS}
    _, op = levitated_plant(RIG)
    assert true["ks_n_per_m"] == pytest.approx(np.mean(op.ks_n_per_m))
    # the sampled (zero-order hold, delayed) model is what the simulator measures
    # two realisations (the true plant's states are transformed and reduced): they agree to ~1e-8 off the
    # poles (measured 6.7e-9 x A at most)
    g = physical_frf(ROTOR, true, F, RIG.dt)
    _agree(g, true_linear_model(RIG, discrete=True), F, 5e-8)
    # continuous, without the delay: the true plant's own matrices
    p, _ = levitated_plant(RIG)
    g_c = physical_frf(ROTOR, {**true, "delay_s": 0.0}, F, 0.0)
    _agree(g_c, StateSpace(p.a, p.b_u, p.c_y, np.zeros((4, 4))), F, 5e-8)
    # a delay of one sample and a half is z^-1 times the half-sample model
    half = physical_frf(ROTOR, {**true, "delay_s": 0.5 * RIG.dt}, F, RIG.dt)
    more = physical_frf(ROTOR, {**true, "delay_s": 1.5 * RIG.dt}, F, RIG.dt)
    np.testing.assert_allclose(more, half * np.exp(-2j * np.pi * F * RIG.dt)[:, None, None], rtol=1e-9)


def test_bending_frequency_is_the_rotors_modal_stiffness():
    # a stiffer shaft (E * c) scales the bending frequency by sqrt(c) and keeps the mode shapes, so with one
    # bending mode kept, its analytical model is the soft rig's physical model at the higher frequency
    soft = make_rig({"bending_modes": 1})
    stiff = make_rig({"bending_modes": 1, "youngs_modulus_pa": 1.1 * soft.youngs_modulus_pa})
    f1 = soft.rotor_model().flexible_freq_hz[0]
    assert stiff.rotor_model().flexible_freq_hz[0] == pytest.approx(f1 * np.sqrt(1.1), rel=1e-9)
    params = {**nominal_parameters(soft), "bending_freq_hz": f1 * np.sqrt(1.1)}
    g = physical_frf(soft.rotor_model(), params, F, 0.0)
    ref = analytical_model(stiff).freqresp(F)
    assert np.max(np.abs(g - ref)) <= 1e-7 * np.max(np.abs(ref))
    # the damping ratio parameter sets -Re(p) / |p| of the free-free bending poles
    ss = physical_statespace(soft.rotor_model(), {**params, "bending_damping_ratio": 0.03,
                                                  "ki_n_per_a": 1e-6, "ks_n_per_m": 0.0})
    p = ss.poles()
    p = p[np.argmin(np.abs(np.abs(p) - 2 * np.pi * f1 * np.sqrt(1.1)))]
    assert -p.real / abs(p) == pytest.approx(0.03, rel=1e-9)


def _noisy_true_frf(seed=0, rel_noise=0.01):
    g = true_linear_model(RIG, discrete=True).freqresp(F)
    scale = np.abs(g[:, [0, 1, 2, 3], [0, 1, 2, 3]]).mean(axis=1)[:, None, None]  # per line
    var = (rel_noise * scale) ** 2 * np.ones(g.shape)
    rng = np.random.default_rng(seed)
    noise = np.sqrt(var / 2) * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape))
    return g + noise, var


def test_updating_from_20_percent_off_recovers_ki_and_ks():
    g, var = _noisy_true_frf()
    true = true_parameters(RIG)
    start = nominal_parameters(RIG)
    start.update(ki_n_per_a=0.8 * true["ki_n_per_a"], ks_n_per_m=1.2 * true["ks_n_per_m"],
                 support_freq_hz=170.0, support_damping_ratio=0.03, support_gain_per_kg=1 / 17.0)
    up = update_physical_model(ROTOR, F, g, var, start, dt_s=RIG.dt)
    r = up.result
    assert set(up.free) == {"ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz", "bending_freq_hz",
                            "bending_damping_ratio", "support_freq_hz", "support_damping_ratio",
                            "support_gain_per_kg", "delay_s"}
    est = dict(zip(r.names, r.theta))
    std = dict(zip(r.names, r.std))
    for name in ("ki_n_per_a", "ks_n_per_m"):
        assert abs(est[name] / true[name] - 1) < 0.01, name
        assert abs(est[name] - true[name]) < 4 * std[name] + 2e-3 * true[name], name
    assert est["bending_freq_hz"] == pytest.approx(true["bending_freq_hz"], rel=1e-3)
    assert est["support_freq_hz"] == pytest.approx(true["support_freq_hz"], rel=0.01)
    assert up.parameters["sensor_gain_a_x"] == 1.0 and "sensor_gain_a_x" not in r.names  # fixed
    d = up.to_dict()
    assert d["parameters"]["ki_n_per_a"]["free"] and not d["parameters"]["sensor_gain_b_y"]["free"]
    assert d["parameters"]["ks_n_per_m"]["ci95"][0] < est["ks_n_per_m"] < d["parameters"]["ks_n_per_m"]["ci95"][1]


def test_ki_and_all_sensor_gains_together_are_not_identifiable():
    g, var = _noisy_true_frf()
    start = nominal_parameters(RIG)
    free = ["ki_n_per_a", "sensor_gain_a_x", "sensor_gain_b_x", "sensor_gain_a_y", "sensor_gain_b_y"]
    with pytest.raises(ValueError, match="not identifiable.*ki_n_per_a"):
        update_physical_model(ROTOR, F, g, var, start, free=free, dt_s=RIG.dt)


def test_bad_parameters_are_refused_with_the_reason():
    nom = nominal_parameters(RIG)
    g, var = _noisy_true_frf()
    with pytest.raises(ValueError, match="missing"):
        physical_statespace(ROTOR, {"ki_n_per_a": 100.0})
    with pytest.raises(ValueError, match="support mode needs all"):
        physical_statespace(ROTOR, {**nom, "support_freq_hz": 100.0})
    with pytest.raises(ValueError, match="unknown parameters"):
        update_physical_model(ROTOR, F, g, var, {**nom, "kii": 1.0})
    with pytest.raises(ValueError, match="no start value"):
        update_physical_model(ROTOR, F, g, var, nom, free=["support_freq_hz"])
    with pytest.raises(ValueError, match=r"\(L, 4, 4\)"):
        update_physical_model(ROTOR, F, g[:, :2], var[:, :2], nom)
    with pytest.raises(ValueError, match="dt_s"):
        physical_frf(ROTOR, nom, F, -1.0)
    rigid = make_rig({"bending_modes": 0})
    with pytest.raises(ValueError, match="no adjustable bending mode"):
        physical_statespace(rigid.rotor_model(), nom)


def test_unmodelled_mode_is_the_strongest_mode_the_nominal_model_lacks():
    nominal = analytical_model(RIG)       # bending modes at ~310 and ~927 Hz
    f = [177.0, 310.4, 600.0, 926.6]
    z = [0.02, 0.005, 0.01, 0.005]
    s = [5.0, 50.0, 1.0, 40.0]
    assert unmodelled_mode(f, z, s, nominal, (10.0, 1000.0)) == (177.0, 0.02)
    assert unmodelled_mode(f, z, s, nominal, (200.0, 1000.0)) == (600.0, 0.01)   # 177 Hz is outside the band
    assert unmodelled_mode([310.4, 926.6], [0.005, 0.005], [1.0, 1.0], nominal, (10.0, 1000.0)) is None
    with pytest.raises(ValueError, match="same length"):
        unmodelled_mode([1.0], [0.1, 0.2], [1.0], nominal, (0.0, 10.0))
