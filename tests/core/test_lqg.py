"""The LQG controller: convention, delay, integral action, and why it is robustified."""

import numpy as np
import pytest
from ambid.control.closed_loop import check_controller_on_rig, close_loop
from ambid.control.lqg import LqgParameters, lqg_controller
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model

RIG = make_rig()


def _markov(k, n):
    """First n Markov parameters D, CB, CAB, ... of a discrete model."""
    out, x = [k.d], k.b
    for _ in range(n - 1):
        out.append(k.c @ x)
        x = k.a @ x
    return out


@pytest.mark.parametrize("delay", [1, 2])
def test_computational_delay(delay):
    k = lqg_controller(RIG, LqgParameters(delay_samples=delay))
    assert k.dt == RIG.dt and (k.n_inputs, k.n_outputs) == (4, 4)
    markov = _markov(k, delay + 1)
    for m in markov[:delay]:
        assert np.all(m == 0)  # ic[k] ignores y[k], ..., y[k - delay + 1]
    assert np.abs(markov[delay]).max() > 0
    assert close_loop(analytical_model(RIG).to_discrete(RIG.dt), k).is_stable()  # the design model


def test_integral_action_rejects_a_constant_input_disturbance():
    k = lqg_controller(RIG)
    for plant in (analytical_model(RIG).to_discrete(RIG.dt), true_linear_model(RIG, discrete=True)):
        loop = close_loop(plant, k)  # r enters like u: a constant r is a constant current offset
        dc = loop.c @ np.linalg.solve(np.eye(loop.n_states) - loop.a, loop.b) + loop.d
        y_dc, u_dc = dc[:4], dc[4:]
        assert np.abs(y_dc).max() < 1e-9  # [m/A]: no steady displacement
        assert np.allclose(u_dc, 0.0, atol=1e-6)  # the controller cancels the offset exactly


def test_plain_lqg_is_refused_on_the_true_rig():
    # Without process noise on the states and without the resonance weight the estimator cancels the
    # lightly damped anti-resonance where the housing mode sits: fine on paper, unstable on the rig.
    plain = lqg_controller(RIG, LqgParameters(state_noise=0.0, resonance_weight=0.0, displacement_scale_m=30e-6))
    assert close_loop(analytical_model(RIG).to_discrete(RIG.dt), plain).is_stable()
    with pytest.raises(ValueError, match="true rig: the closed loop is unstable"):
        check_controller_on_rig(RIG, plain)


def test_parameters_are_validated():
    for bad in (dict(displacement_scale_m=0.0), dict(delay_samples=0), dict(n_bending=1.5),
                dict(measurement_noise_m=-1.0), dict(regulate="rotor")):
        with pytest.raises(ValueError):
            LqgParameters(**bad)
