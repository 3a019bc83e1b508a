"""The simulated rig: its resting start, its linear core, and its FRF against the exported model."""

import numpy as np
import pytest
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig
from ambid.plant.simulator import PlantSimulator
from ambid.plant.true_rig import true_linear_model


def test_starts_at_rest_on_the_backup_bearing():
    rig = make_rig()
    sim = PlantSimulator(rig, nonlinear_magnets=True)
    r0 = sim.bearing_radius()
    weight = rig.rotor_mass_kg * 9.81 / 2
    assert np.all(r0 > rig.backup_clearance_m)
    assert np.all(r0 < rig.backup_clearance_m + 3 * weight / rig.contact_stiffness_n_per_m)  # magnets pull too
    # straight down: equal negative displacement on both 45-deg axes
    g = sim.bearing_displacement
    assert np.all(g < 0) and g[0] == pytest.approx(g[2], rel=1e-6)
    y0 = sim.output()
    for _ in range(200):
        clipped, contact = sim.step([0.0, 0.0, 0.0, 0.0])
        assert contact and not clipped
    assert np.allclose(sim.bearing_radius(), r0, rtol=0, atol=1e-9)  # a static equilibrium
    assert np.allclose(sim.output(), y0, atol=5 * rig.sensor_noise_m)
    clipped, _ = sim.step([2 * rig.current_limit_a, 0.0, 0.0, 0.0])
    assert clipped


def test_linear_simulator_is_the_exported_discrete_model():
    rig = make_rig({"sensor_noise_m": 0.0})
    sim = PlantSimulator(rig, nonlinear_magnets=False)
    sim.start_levitated()
    model = true_linear_model(rig, discrete=True)
    ic0 = sim.operating_point.current_a
    rng = np.random.default_rng(3)
    du = 0.01 * rng.standard_normal((60, 4))
    x = np.zeros(model.n_states)
    for k in range(60):
        y_model = model.c @ x
        assert np.allclose(sim.output(), y_model, rtol=1e-7, atol=1e-13), k
        sim.step((ic0 + du[k]).tolist())
        x = model.a @ x + model.b @ du[k]
    assert np.max(np.abs(model.c @ x)) > 1e-7  # the input moved the rotor


def test_frf_of_the_true_linear_model_matches_the_nonlinear_simulation():
    # 2 % modal damping so that two periods of settling suffice (the default 0.5 % rings for 0.1 s)
    rig = make_rig({"sensor_noise_m": 0.0, "modal_damping_ratio": 0.02})
    sim = PlantSimulator(rig, nonlinear_magnets=True)
    sim.start_levitated()
    ctl = ControllerStepper(pid_controller(PidParameters(), rig.dt), rig.current_limit_a)
    ctl.set_steady_state(sim.operating_point.current_a)
    n, lines, amp = 1000, np.arange(1, 101), 1e-3  # 10 Hz grid, 10-1000 Hz, 1 mA per line
    phase = np.random.default_rng(1).uniform(0, 2 * np.pi, (lines.size, 4))
    t = np.arange(n)
    y_spec = np.empty((lines.size, 4, 4), complex)
    u_spec = np.empty_like(y_spec)
    for e in range(4):  # orthogonal experiments: input i shifted by 2 pi e i / 4
        ph = phase + 2 * np.pi * e * np.arange(4) / 4
        r = (amp * np.cos(2 * np.pi * np.outer(t, lines)[:, :, None] / n + ph[None])).sum(axis=1).tolist()
        ys, us = np.empty((n, 4)), np.empty((n, 4))
        for period in range(3):  # two to settle, one to measure
            for k in range(n):
                y = sim.output()
                ic = ctl.step(y)
                u = [ic[0] + r[k][0], ic[1] + r[k][1], ic[2] + r[k][2], ic[3] + r[k][3]]
                sim.step(u)
                ys[k], us[k] = y, u
        y_spec[:, :, e] = np.fft.rfft(ys, axis=0)[lines]
        u_spec[:, :, e] = np.fft.rfft(us, axis=0)[lines]
    g_meas = y_spec @ np.linalg.inv(u_spec)
    f = lines * rig.sample_rate_hz / n

    def err(model):
        g = model.freqresp(f)
        return np.linalg.norm(g_meas - g, axis=(1, 2)) / np.linalg.norm(g, axis=(1, 2))

    assert err(true_linear_model(rig, discrete=True)).max() < 0.01
    assert err(true_linear_model(rig).to_discrete(rig.dt)).max() < 0.01
    # the check discriminates: the analytical model misses the housing mode by far more
    assert err(analytical_model(rig).to_discrete(rig.dt)).max() > 0.5


def test_sensor_probe_curve_error_in_the_reading():
    c3 = 1e6  # 1/m^2: 3 % error at the 0.18 mm resting displacement
    rig = make_rig({"sensor_cubic_per_m2": c3, "sensor_noise_m": 0.0, "sensor_gain": 0.9})
    sim = PlantSimulator(rig)
    d = sim.plant.c_sensor @ sim.x  # true rotor-minus-pedestal displacement at the sensors
    assert np.allclose(sim.output(), 0.9 * (d + c3 * d**3), rtol=1e-9)
    assert np.all(np.abs(c3 * d**2) > 0.02)
