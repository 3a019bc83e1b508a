"""StateSpace: frequency response, discretisation, interconnections, and the levitation monitor."""

import numpy as np
import pytest
from ambid.control.closed_loop import check_stability, close_loop
from ambid.plant.levitation import LevitationMonitor
from ambid.statespace import StateSpace, block_diag, delay, discretise, series, statespace_from_dict
from scipy import signal


def mass_spring(m=2.0, k=800.0, c=4.0) -> StateSpace:
    return StateSpace([[0, 1], [-k / m, -c / m]], [[0], [1 / m]], [[1, 0]], [[0]])


def test_freqresp_matches_closed_form():
    f = np.array([0.5, 3.0, 20.0])
    s = 2j * np.pi * f
    expected = 1 / (2.0 * s**2 + 4.0 * s + 800.0)
    assert np.allclose(mass_spring().freqresp(f)[:, 0, 0], expected, rtol=1e-12)


def test_discrete_freqresp_matches_scipy_dfreqresp():
    d = mass_spring().to_discrete(1e-3)
    w = np.linspace(0.01, 3.0, 7)
    _, h = signal.dfreqresp((d.a, d.b, d.c, d.d, d.dt), w=w)
    assert np.allclose(d.freqresp(w / (2 * np.pi * d.dt))[:, 0, 0], np.squeeze(h), rtol=1e-10)


@pytest.mark.parametrize("method", ["zoh", "bilinear"])
def test_discretise_is_scipys_cont2discrete_to_the_bit(method):
    """ambid's own discretisation (no scipy.signal import in a controller node) gives scipy's matrices."""
    rng = np.random.default_rng(7)
    for n, m, p in ((1, 1, 1), (3, 1, 1), (9, 4, 4), (20, 4, 8)):
        a, b = rng.normal(size=(n, n)) * 300.0, rng.normal(size=(n, m))
        c, d = rng.normal(size=(p, n)), rng.normal(size=(p, m))
        ours = discretise(a, b, c, d, 1e-4, method)
        for x, y in zip(ours, signal.cont2discrete((a, b, c, d), 1e-4, method=method)[:4]):
            assert x.shape == y.shape and np.array_equal(x, y)


def test_delay_is_z_to_the_minus_n():
    dt = 1e-4
    f = np.array([10.0, 1000.0])
    h = delay(2, 3, dt).freqresp(f)
    assert np.allclose(h[:, 0, 0], np.exp(-3j * 2 * np.pi * f * dt))
    assert np.allclose(h[:, 0, 1], 0)


def test_series_and_block_diag():
    a, b = mass_spring(), mass_spring(1.0, 100.0, 1.0)
    f = np.array([1.0, 7.0])
    g = series(a, b).freqresp(f)[:, 0, 0]
    assert np.allclose(g, a.freqresp(f)[:, 0, 0] * b.freqresp(f)[:, 0, 0])
    bd = block_diag(a, b).freqresp(f)
    assert np.allclose(bd[:, 1, 1], b.freqresp(f)[:, 0, 0]) and np.allclose(bd[:, 0, 1], 0)


def test_dict_round_trip():
    a = mass_spring()._replace(input_names=("u",), output_names=("y",), input_units=("N",), output_units=("m",))
    b = statespace_from_dict(a.to_dict())
    assert np.array_equal(a.a, b.a) and b.output_units == ("m",)


def test_bad_shapes_and_nan_named():
    with pytest.raises(ValueError, match="inconsistent shapes"):
        StateSpace(np.eye(2), np.ones((3, 1)), np.ones((1, 2)), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="NaN"):
        StateSpace([[np.nan]], [[1]], [[1]], [[0]])


def test_close_loop_input_sensitivity_matches_formula():
    dt = 1e-3
    plant = mass_spring().to_discrete(dt)
    k = StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[-300.0]], dt)  # ic = -300 y
    loop = close_loop(plant, k)
    f = np.array([1.0, 5.0, 40.0])
    p = plant.freqresp(f)[:, 0, 0]
    s_expected = 1 / (1 - (-300.0) * p)
    assert np.allclose(loop.freqresp(f)[:, 1, 0], s_expected, rtol=1e-9)
    assert np.allclose(loop.freqresp(f)[:, 0, 0], p * s_expected, rtol=1e-9)


def test_check_stability_names_unstable_poles():
    dt = 1e-3
    unstable = StateSpace([[0, 1], [400.0, 0]], [[0], [1]], [[1, 0]], [[0]])  # negative stiffness
    weak = StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[-100.0]], dt)
    with pytest.raises(ValueError, match="unstable poles: z="):
        check_stability(unstable, weak, "test loop")


def test_levitation_monitor_blocks():
    mon = LevitationMonitor(clearance_m=1e-4, settle_samples=100)
    y = np.full((200, 4), 1e-6)
    contact = np.zeros(200, bool)
    contact[:10] = True
    mon.add_block(0, y, contact)
    f = mon.figures()
    assert mon.levitated() and f["lift_off_index"] == 10 and f["samples_evaluated"] == 100
    assert f["displacement_rms_m"] == pytest.approx(1e-6)
    mon.add_block(200, y, np.ones(200, bool))
    assert not mon.levitated() and mon.figures()["contact_samples_after_settling"] == 200


def test_levitation_monitor_judges_a_run_that_ended_before_its_settled_window():
    """A run that ends early (a node died 8 s into 30 s) is judged over what it ran after lift-off: six
    seconds of good levitation read as levitated, with their true RMS, not as 0 um and 'not levitated'."""
    dt = 1e-4
    mon = LevitationMonitor(clearance_m=2.5e-4, settle_samples=150_000, after_lift_off=5000)
    rng = np.random.default_rng(3)
    contact = np.zeros(1000, bool)
    for first in range(0, 80_000, 1000):
        y = rng.normal(0.0, 2e-6, (1000, 4))
        c = contact
        if first == 0:  # on the retainer for 300 samples, then a lift-off transient of 1 ms
            y[:300] = -2.4e-4
            y[300:310] = -1.5e-4
            c = contact.copy()
            c[:300] = True
        mon.add_block(first, y, c)
    f = mon.figures()
    assert f["lift_off_index"] == 300 and f["evaluated_from_index"] == 5300 and f["evaluated_to_index"] == 80_000
    assert f["samples_evaluated"] == 80_000 - 5300 and mon.levitated()
    assert f["displacement_rms_m"] == pytest.approx(2e-6, rel=0.02)
    assert f["contact_samples"] == 300 and f["contact_samples_after_settling"] == 0
    # nothing judged yet: no figure pretends to be one
    empty = LevitationMonitor(2.5e-4, 100).figures()
    assert empty["samples_evaluated"] == 0 and empty["evaluated_from_index"] is None and not empty["levitated"]
    # a touch-down after lift-off starts the lift-off window again: nothing levitated to judge since
    mon.add_block(80_000, np.zeros((1000, 4)), np.r_[np.ones(10, bool), np.zeros(990, bool)])
    assert mon.figures()["samples_evaluated"] == 0 and mon.figures()["lift_off_index"] == 80_010
    assert not mon.levitated()
