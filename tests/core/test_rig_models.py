"""The true rig against the physics: magnet slopes, operating point, rotor, exported models."""

import numpy as np
import pytest
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig, without_true_factors
from ambid.plant.true_rig import levitated_plant, operating_point, true_linear_model

RHO = 7810.0
G = 9.81


def _central_difference(fun, x, h):
    return (fun(x + h) - fun(x - h)) / (2 * h)


def test_nonlinear_force_slopes_are_ki_ks():
    rig = make_rig()
    for mag, factors in ((rig.magnet, (1.0, 1.0)), (rig.true_magnet, (rig.true_ki_factor, rig.true_ks_factor))):
        dfdi = _central_difference(lambda i: mag.force(i, 0.0), 0.0, 1e-4)
        dfdx = _central_difference(lambda x: mag.force(0.0, x), 0.0, 1e-8)
        assert dfdi == pytest.approx(factors[0] * rig.magnet.ki, rel=1e-7)
        assert dfdx == pytest.approx(factors[1] * rig.magnet.ks, rel=1e-6)
    # at the levitated point: the operating point's slopes are the force law's
    op = operating_point(rig)
    mag, i0, x0 = rig.true_magnet, op.current_a[0], op.gap_m[0]
    assert _central_difference(lambda i: mag.force(i, x0), i0, 1e-4) == pytest.approx(op.ki_n_per_a[0], rel=1e-7)
    assert _central_difference(lambda x: mag.force(i0, x), x0, 1e-8) == pytest.approx(op.ks_n_per_m[0], rel=1e-6)
    # eq. 2.14 at x = 0: ks grows with the control current as (1 + ic^2 / ib^2), ki does not change
    assert op.ks_n_per_m[0] == pytest.approx(mag.ks * (1 + (i0 / 3.0) ** 2), rel=5e-3)
    assert op.ki_n_per_a[0] == pytest.approx(mag.ki, rel=1e-3)


def test_a_rig_without_its_true_factors_has_its_nominal_magnets_and_every_other_value():
    rig = make_rig({"axial_bearing": 1, "true_ki_factor": 1.1, "true_ks_factor": 0.9, "axial_true_ki_factor": 0.95,
                    "axial_true_ks_factor": 1.05})
    exact = without_true_factors(rig)
    for mag, nominal in ((exact.true_magnet, rig.magnet), (exact.axial_true_magnet, rig.axial_magnet)):
        # the force law's slopes at the centre: the nominal ki, ks (eqs. 2.16-2.17), no tolerance on top
        assert _central_difference(lambda i: mag.force(i, 0.0), 0.0, 1e-4) == pytest.approx(nominal.ki, rel=1e-7)
        assert _central_difference(lambda x: mag.force(0.0, x), 0.0, 1e-8) == pytest.approx(nominal.ks, rel=1e-6)
    changed = {k for k in rig.values if exact.values[k] != rig.values[k]}
    assert changed == {"true_ki_factor", "true_ks_factor", "axial_true_ki_factor", "axial_true_ks_factor"}
    assert rig.true_ki_factor == 1.1 and exact.name == rig.name   # the rig given is left as it was


def test_operating_point_carries_the_rotor_weight_with_zero_readings():
    rig = make_rig()
    plant, op = levitated_plant(rig)
    weight_per_axis = rig.rotor_mass_kg * G / np.sqrt(2.0)
    assert op.force_n[0] + op.force_n[1] == pytest.approx(weight_per_axis, rel=1e-9)  # x: bearings A + B
    assert op.force_n[2] + op.force_n[3] == pytest.approx(weight_per_axis, rel=1e-9)  # y
    assert np.allclose(plant.c_y @ op.state, 0.0, atol=1e-15)
    # an equilibrium of the affine model built around it
    xdot = plant.a @ op.state + plant.b_u @ op.current_a + plant.b_c
    assert np.max(np.abs(xdot)) < 1e-9 * np.max(np.abs(plant.b_c))
    assert 0 < op.current_a[0] < rig.current_limit_a


def test_rotor_mass_by_hand_and_first_bending_mode_inside_the_band():
    rig = make_rig()
    volume = (np.pi / 4 * 0.06**2 * 0.8 + np.pi / 4 * (0.12**2 - 0.06**2) * 0.2
              + 2 * np.pi / 4 * (0.10**2 - 0.06**2) * 0.04)
    assert rig.rotor_mass_kg == pytest.approx(RHO * volume, rel=1e-9)
    assert 33.0 < rig.rotor_mass_kg < 35.0
    free_free = rig.rotor_model().flexible_freq_hz
    assert 10.0 < free_free[0] < 1000.0 and free_free[0] == pytest.approx(313.4, abs=1.0)
    # the levitated true rig: a lightly damped mode near the first bending frequency, inside 10-1000 Hz
    poles = np.linalg.eigvals(true_linear_model(rig).a)
    f_hz, zeta = np.abs(poles.imag) / (2 * np.pi), -poles.real / np.abs(poles)
    bending = f_hz[(zeta < 0.02) & (f_hz > 250) & (f_hz < 400)]
    assert bending.size and np.all((10 < bending) & (bending < 1000))


def test_true_model_has_what_the_analytical_lacks():
    rig = make_rig()
    f = np.array([100.0, 177.0, 500.0])
    p_true = np.linalg.eigvals(true_linear_model(rig).a)
    p_an = np.linalg.eigvals(analytical_model(rig).a)

    def near(poles, hz):
        return np.any((np.abs(np.abs(poles.imag) / (2 * np.pi) - hz) < 10) & (poles.real < 0))

    assert near(p_true, 177.0) and not near(p_an, 177.0)  # housing mode
    # the exact discrete model and the ZOH of the Pade-delayed continuous model agree over the band
    g_exact = true_linear_model(rig, discrete=True).freqresp(np.linspace(10, 1000, 12))
    g_pade = true_linear_model(rig).to_discrete(rig.dt).freqresp(np.linspace(10, 1000, 12))
    err = np.linalg.norm(g_exact - g_pade, axis=(1, 2)) / np.linalg.norm(g_exact, axis=(1, 2))
    assert err.max() < 1e-3
    # and the delay is really there: without it the phase at 1 kHz differs by 2 pi f tau = 18 deg
    g0 = true_linear_model(make_rig({"extra_delay_s": 0.0}), discrete=True).freqresp([1000.0])[0, 0, 0]
    g1 = true_linear_model(rig, discrete=True).freqresp([1000.0])[0, 0, 0]
    assert np.degrees(np.angle(g0 / g1)) == pytest.approx(360 * 1000.0 * 50e-6, abs=0.5)
    assert analytical_model(rig).freqresp(f).shape == (3, 4, 4)


def test_sensor_gain_and_spin_speed_enter_the_models():
    f = np.array([50.0, 400.0])
    base = true_linear_model(make_rig(), discrete=True).freqresp(f)
    scaled = true_linear_model(make_rig({"sensor_gain": 0.9}), discrete=True).freqresp(f)
    assert np.allclose(scaled, 0.9 * base, rtol=1e-9, atol=1e-9 * np.abs(base).max())
    # gyroscopic coupling: x -> y transfer only when the rotor spins
    still = analytical_model(make_rig()).freqresp(f)
    spinning = analytical_model(make_rig({"rotor_speed_rpm": 12_000})).freqresp(f)
    assert np.abs(still[:, 2:, :2]).max() < 1e-10 * np.abs(still).max()
    assert np.abs(spinning[:, 2:, :2]).max() > 1e-3 * np.abs(spinning).max()
