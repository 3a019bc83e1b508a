"""The compiled per-sample kernels against an independent numpy computation of the same step."""

import copy
import math
import pickle

import numpy as np
import pytest
from ambid.plant import step_kernel as sk
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.rig import make_rig
from ambid.plant.simulator import CONTACT_SUBSTEPS, NOISE_BLOCK, PlantSimulator
from ambid.plant.true_rig import delayed_zoh, zoh_blocks
from ambid.statespace import StateSpace


def _reference_step(sim, x, u_prev, u, nonlinear, cubic):
    """One free-flight sample from the plant's continuous model, built here from the model blocks."""
    rig, p = sim.rig, sim.plant
    lim = rig.current_limit_a
    u_c = np.clip(u, -lim, lim)
    gap, cur, sd = p.c_gap @ x, p.c_current @ x, p.c_sensor @ x
    f = np.zeros(4)
    if nonlinear:  # eq. 2.14 minus its affine linearisation
        mag = rig.true_magnet
        kc = mag.k_magnet * math.cos(mag.pole_angle_rad)
        s0, ib = mag.air_gap_m, mag.bias_current_a
        f = (kc * ((ib + cur) ** 2 / (s0 - gap) ** 2 - (ib - cur) ** 2 / (s0 + gap) ** 2)
             - p.force_const - p.ki * cur - p.ks * gap)
    rs = cubic * sd**3
    phi, g1, g0 = delayed_zoh(p.a, p.b_u, rig.dt, p.delay_s)
    _, gw = zoh_blocks(p.a, np.column_stack([p.b_f, p.b_s, p.b_c]), rig.dt)
    x1 = phi @ x + g0 @ u_prev + g1 @ u_c + gw @ np.concatenate([f, rs, [1.0]])
    return x1, u_c


def _free_flight_sim(nonlinear, cubic=0.0, seed=2, rotor=None):
    rig = make_rig({"sensor_cubic_per_m2": cubic, "sensor_noise_m": 0.0}, rotor_import=rotor)
    sim = PlantSimulator(rig, seed=seed, nonlinear_magnets=nonlinear)
    sim.start_levitated()
    return sim


@pytest.mark.parametrize("nonlinear,cubic,n_bending", [(False, 0.0, None), (True, 0.0, None), (True, 1e6, None),
                                                       (True, 0.0, 1)])
def test_plant_kernel_is_the_numpy_step(nonlinear, cubic, n_bending):
    # n_bending = 1: a user rotor with fewer states than the built-in one
    rotor = None if n_bending is None else make_rig().rotor_model(n_bending=n_bending)
    sim = _free_flight_sim(nonlinear, cubic, rotor=rotor)
    if rotor is not None:
        assert sim.plant.n_states < PlantSimulator(make_rig()).plant.n_states
    ic0 = sim.operating_point.current_a
    rng = np.random.default_rng(5)
    x, u_prev = sim.x.copy(), ic0.copy()
    for k in range(40):
        u = ic0 + 0.05 * rng.standard_normal(4)
        if k == 7:
            u[2] = 5 * sim.rig.current_limit_a  # clipped
        clipped, contact = sim.step(u.tolist())
        x, u_prev = _reference_step(sim, x, u_prev, u, nonlinear, cubic)
        assert clipped == (k == 7) and not contact
        assert np.allclose(sim.x, x, rtol=1e-12, atol=1e-12 * np.abs(x).max())
        y = sim.plant.c_y @ x
        assert np.allclose(sim.output(), y, rtol=1e-10, atol=1e-12 * np.abs(y).max())
    assert sim.index == 40
    assert np.abs(sim.output()).max() > 1e-7  # the inputs moved the rotor
    if cubic:  # the cubic term matters at this displacement: the check above sees it
        x_lin, _ = _reference_step(sim, x, u_prev, ic0, nonlinear, 0.0)
        x_cub, _ = _reference_step(sim, x, u_prev, ic0, nonlinear, cubic)
        assert np.abs(x_lin - x_cub).max() > 1e-9 * np.abs(x).max()


def test_contact_entry_falls_back_to_substeps():
    sim = _free_flight_sim(nonlinear=True)
    lim = sim.rig.current_limit_a
    down = [-lim, -lim, -lim, -lim]  # both magnets pull down: the rotor falls onto the retainers
    before = copy.deepcopy(sim)
    for k in range(400):
        before_k = copy.deepcopy(sim)
        clipped, contact = sim.step(down)
        assert not clipped
        if contact:
            before = before_k
            break
    assert 0 < k < 399
    # the free-flight step of that sample would end beyond the clearance: the kernel must not take it
    n = before.plant.n_states
    x_free, _ = _reference_step(before, before.x.copy(), before._v[n:n + 4].copy(), np.array(down), True, 0.0)
    g = before.plant.c_gap @ x_free
    assert max(math.hypot(g[0], g[2]), math.hypot(g[1], g[3])) > before.rig.backup_clearance_m
    # instead: CONTACT_SUBSTEPS numpy sub-steps from the same start
    manual = copy.deepcopy(before)
    manual._v[n + 4:n + 8] = down
    manual._substeps()
    assert np.array_equal(sim.x, manual.x)
    assert not np.allclose(sim.x, x_free, rtol=1e-6, atol=0)
    assert sim.index == before.index + 1
    # in contact from the start: sub-steps again
    again = copy.deepcopy(sim)
    manual = copy.deepcopy(sim)
    assert again.step(down) == (False, True)
    manual._v[n + 4:n + 8] = down
    manual._substeps()
    assert np.array_equal(again.x, manual.x) and CONTACT_SUBSTEPS > 1


@pytest.mark.parametrize("nonlinear", [False, True])
def test_step_output_is_step_then_output(nonlinear):
    a = PlantSimulator(make_rig(), seed=11, nonlinear_magnets=nonlinear)
    b = PlantSimulator(make_rig(), seed=11, nonlinear_magnets=nonlinear)
    ca = ControllerStepper(pid_controller(PidParameters(), a.rig.dt), a.rig.current_limit_a)
    cb = copy.deepcopy(ca)
    y_b = b.output().tolist()
    n = NOISE_BLOCK + 300  # lift-off from rest (contact), free flight, a new noise block
    contacts = 0
    for k in range(n):
        y_a = a.output()
        ua = ca.step(y_a)
        ub = cb.step(y_b)
        fa = a.step(ua)
        rb = b.step_output(*ub)
        assert list(ua) == list(ub)
        assert fa == rb[4:]
        y_b = rb[:4]
        assert list(b.output()) == list(y_b)  # output() after step_output: the same noise, not the next
        contacts += rb[5]
    assert 0 < contacts < n and a.index == b.index == n
    assert np.array_equal(a.output(), b.output())
    assert np.array_equal(a.x, b.x)
    # the noise of sample k is row k of the stream
    rows = np.random.default_rng(11).standard_normal((2 * NOISE_BLOCK, 4)) * a.rig.sensor_noise_m
    assert np.array_equal(a.output(), a._aux[:4] + rows[n])


def test_noise_is_fixed_per_sample_however_read():
    a = PlantSimulator(make_rig(), seed=4)
    b = PlantSimulator(make_rig(), seed=4)
    a.start_levitated()
    b.start_levitated()
    ic0 = a.operating_point.current_a.tolist()
    for k in range(50):
        ya = a.output()
        if k % 3 == 0:  # b reads twice, or not at all
            assert np.array_equal(b.output(), b.output())
        a.step(ic0)
        b.step(ic0)
        if k % 3 == 1:
            assert np.array_equal(b.output(), a.output())
    assert np.array_equal(a.output(), b.output())
    assert not np.array_equal(ya, a.output())


def test_simulator_copies_and_pickles():
    sim = _free_flight_sim(nonlinear=True)
    ic0 = sim.operating_point.current_a.tolist()
    for _ in range(10):
        sim.step(ic0)
    for duplicate in (copy.deepcopy, lambda obj: pickle.loads(pickle.dumps(obj))):
        twin = duplicate(sim)
        r1 = sim.step_output(*ic0)
        r2 = twin.step_output(*ic0)
        assert r1 == r2 and twin.index == sim.index
        sim.step(ic0)  # the twin is independent: stepping sim leaves it
        assert twin.index == sim.index - 1


def test_plant_work_checks_the_matrix():
    with pytest.raises(ValueError, match="n \\+ 20, n \\+ 19"):
        sk.plant_work(np.zeros((10, 20)), 4, 4)
    with pytest.raises(ValueError, match="n \\+ 25, n \\+ 23"):
        sk.plant_work(np.zeros((10, 20)), 5, 4)


def _random_controller(rng, n=6, p=4, q=4, proper=True):
    a = rng.standard_normal((n, n))
    a *= 0.9 / np.abs(np.linalg.eigvals(a)).max()  # stable
    d = np.zeros((q, p)) if proper else rng.standard_normal((q, p))
    return StateSpace(a, rng.standard_normal((n, p)), rng.standard_normal((q, n)), d, 1e-4)


def _numpy_steps(model, ys, limit):
    x = np.zeros(model.n_states)
    out = []
    for y in ys:
        out.append(np.clip(model.c @ x + model.d @ y, -limit, limit))
        x = model.a @ x + model.b @ y
    return np.array(out)


def test_controller_steps_match_numpy_and_each_other():
    rng = np.random.default_rng(8)
    model = _random_controller(rng)
    ys = rng.standard_normal((200, 4))
    limit = 2.0
    ref = _numpy_steps(model, ys, limit)
    assert np.abs(ref).max() == limit  # the saturation is exercised
    s1, s4, sa = (ControllerStepper(model, limit) for _ in range(3))
    out1 = np.array([s1.step(y) for y in ys])
    out4 = np.array([s4.step(list(y)) for y in ys])
    assert sa.strictly_proper and (sa.n_inputs, sa.n_outputs) == (4, 4)
    ahead = np.array([sa.current_output()] + [sa.step_ahead(y) for y in ys])
    tol = 1e-12 * np.abs(ref).max()
    assert np.allclose(out1, ref, rtol=0, atol=tol)
    assert np.allclose(out4, ref, rtol=0, atol=tol)
    assert np.allclose(ahead[:-1], ref, rtol=0, atol=tol)  # shifted by one: ic[0], ic[1], ...
    assert np.allclose(s1.x, s4.x, rtol=0, atol=1e-12 * np.abs(s1.x).max())
    assert np.allclose(sa.x, s4.x, rtol=0, atol=1e-12 * np.abs(s1.x).max())
    assert isinstance(s1.step(ys[0]), list) and isinstance(sa.step_ahead(ys[0]), list)


def test_controller_with_feedthrough_and_other_sizes():
    rng = np.random.default_rng(9)
    model = _random_controller(rng, p=3, q=2, proper=False)
    ys = rng.standard_normal((50, 3))
    ref = _numpy_steps(model, ys, 1.5)
    st = ControllerStepper(model, 1.5)
    assert np.allclose([st.step(y) for y in ys], ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert not st.strictly_proper
    with pytest.raises(ValueError, match="strictly proper"):
        st.current_output()
    with pytest.raises(ValueError, match="strictly proper"):
        st.step_ahead([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="feedthrough"):
        st.kernel_args(ahead=True)
    # five channels (the five-axis rig), strictly proper: the step ahead is the step one sample early
    five = _random_controller(rng, p=5, q=5)
    y5 = rng.standard_normal((30, 5))
    a5, b5 = ControllerStepper(five, 1.0), ControllerStepper(five, 1.0)
    ahead = [b5.current_output()] + [b5.step_ahead(y) for y in y5]
    assert np.allclose(ahead[:-1], [a5.step(y) for y in y5], rtol=0, atol=1e-12)
    assert a5.kernel_args(ahead=False)[1] == five.n_states


def test_pid_pipelined_and_copied():
    rig = make_rig()
    model = pid_controller(PidParameters(), rig.dt)
    a, b = ControllerStepper(model, 3.0), ControllerStepper(model, 3.0)
    a.set_steady_state([1.0, 1.1, 0.0, -0.2])
    b.set_steady_state([1.0, 1.1, 0.0, -0.2])
    assert np.allclose(b.current_output(), [1.0, 1.1, 0.0, -0.2], atol=1e-9)
    rng = np.random.default_rng(1)
    ys = 1e-5 * rng.standard_normal((100, 4))
    ahead = [b.current_output()] + [b.step_ahead(y) for y in ys]
    now = [a.step(y) for y in ys]
    assert np.allclose(ahead[:-1], now, rtol=0, atol=1e-12 * 3.0)
    twin = pickle.loads(pickle.dumps(a))
    assert twin.step(ys[0]) == a.step(ys[0])
