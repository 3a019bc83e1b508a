"""Both default controllers levitate the default rig; unstable combinations are refused."""

import re

import numpy as np
import pytest
from ambid.control.closed_loop import check_controller_on_rig, close_loop, loop_robustness
from ambid.control.lqg import lqg_controller
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig
from ambid.plant.simulator import PlantSimulator
from ambid.plant.true_rig import true_linear_model

RIG = make_rig()


def _controller(kind):
    return pid_controller(PidParameters(), RIG.dt) if kind == "pid" else lqg_controller(RIG)


@pytest.mark.parametrize("kind", ["pid", "lqg"])
def test_default_controllers_levitate_from_rest(kind):
    model = _controller(kind)
    check_controller_on_rig(RIG, model)
    sim = PlantSimulator(RIG, seed=7, nonlinear_magnets=True)
    ctl = ControllerStepper(model, RIG.current_limit_a)
    n, last = 12_000, 5_000  # 1.2 s, judged over the last 0.5 s
    contact = np.zeros(n, bool)
    y_log, ic_log, radius = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 2))
    for k in range(n):
        y = sim.output()
        ic = ctl.step(y)
        _, contact[k] = sim.step(ic)
        y_log[k], ic_log[k], radius[k] = y, ic, sim.bearing_radius()
    assert contact[0] and not contact[-last:].any()
    assert radius[-last:].max() < 0.05 * RIG.backup_clearance_m  # centred, not resting
    assert np.abs(y_log[-last:].mean(axis=0)).max() < 0.2e-6  # integral action: no offset
    assert y_log[-last:].std(axis=0).max() < 5 * RIG.sensor_noise_m
    # the currents carry the weight: the operating point's ic0
    assert ic_log[-last:].mean(axis=0) == pytest.approx(sim.operating_point.current_a, abs=0.01)


@pytest.mark.parametrize("kind", ["pid", "lqg"])
def test_default_controllers_are_robust_on_both_models(kind):
    model = _controller(kind)
    for plant in (analytical_model(RIG), true_linear_model(RIG, discrete=True)):
        rob = loop_robustness(plant, model)
        assert rob.zone in ("A", "B"), rob.sensitivity_peak
        assert np.all(rob.gain_margin_low < 0.8) and np.all(rob.gain_margin_high > 1.5)
        assert np.all(rob.phase_margin_deg > 20)
        # the figures are those of the sensitivity itself: |S| at the peak frequency, by direct evaluation
        j = int(np.argmax(rob.sensitivity_peak))
        f0 = rob.peak_freq_hz[j]
        pd = plant if plant.dt > 0 else plant.to_discrete(RIG.dt)
        p_jw, k_jw = pd.freqresp([f0])[0], model.freqresp([f0])[0]
        s = np.linalg.inv(np.eye(4) - k_jw @ p_jw)
        assert abs(s[j, j]) == pytest.approx(rob.sensitivity_peak[j], rel=1e-4)


def test_stability_check_refuses_a_too_weak_pid_naming_the_poles():
    weak = pid_controller(PidParameters(kp_a_per_m=2_000.0), RIG.dt)  # kp ki < ks: cannot hold the rotor
    with pytest.raises(ValueError, match="analytical model: the closed loop is unstable") as err:
        check_controller_on_rig(RIG, weak)
    # each distinct pole once (up to conjugation), with "xN" when it repeats (x and y axes, a conjugate pair)
    found = re.findall(r"z=([-+0-9.]+[-+][0-9.]+j) \([^)]*\)( x(\d+))?", str(err.value))
    named = [complex(z) for z, _, _ in found]
    counts = [int(n) if n else 1 for _, _, n in found]
    poles = close_loop(analytical_model(RIG).to_discrete(RIG.dt), weak).poles()
    unstable = poles[np.abs(poles) >= 1]
    assert sum(counts) == unstable.size > 0
    for z in unstable:
        assert min(abs(complex(z.real, abs(z.imag)) - w) for w in named) < 1e-4
    assert "Hz" in str(err.value)


def test_pid_parameters_are_validated_and_the_pid_carries_the_delay():
    with pytest.raises(ValueError, match="kp_a_per_m"):
        PidParameters(kp_a_per_m=-1.0)
    with pytest.raises(ValueError, match="lowpass_hz"):
        PidParameters(lowpass_hz=float("nan"))
    k = pid_controller(PidParameters(), RIG.dt)
    assert np.all(k.d == 0)  # ic[k] does not see y[k]
    assert np.abs(k.c @ k.b).max() > 0  # ... but y[k-1]
    # the realisation is the continuous PID of the docstring (Tustin is exact at low frequency), delayed
    p = PidParameters()
    f = np.array([2.0, 20.0])
    s = 2j * np.pi * f
    c = p.kp_a_per_m * (1 + 1 / (p.ti_s * s) + p.td_s * s / (1 + p.td_s * s / p.derivative_filter_n))
    c = -c / (1 + s / (2 * np.pi * p.lowpass_hz)) * np.exp(-s * RIG.dt)
    assert k.freqresp(f)[:, 0, 0] == pytest.approx(c, rel=2e-3)
    assert np.all(k.freqresp(f)[:, 0, 1] == 0)  # decentralised
