"""Directional FRFs: the forward FRF is the response of p = x + j y to a force turning with the spin, the
backward one to a force turning against it; forward and backward modes peak where the eigen-analysis puts
them, and a mode's whirl follows from its shape."""

import numpy as np
import pytest
from ambid.control.closed_loop import close_loop
from ambid.control.pid import PidParameters, pid_controller
from ambid.frf.directional import directional_frf, whirl
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model
from scipy import signal

RIG = make_rig({"rotor_speed_rpm": 12_000.0})
NAMES = (RIG.layout.outputs, RIG.layout.inputs)  # y_a_x y_b_x y_a_y y_b_y; u_...


def test_forward_and_backward_frfs_are_the_responses_to_rotating_forces():
    """The levitated loop r -> y at speed (stable), simulated by scipy with r turning with (or against) the
    spin at both planes in turn: p's phasor at +w over f's is H_f, at -w (conjugated) H_b."""
    loop = close_loop(true_linear_model(RIG, discrete=True), pid_controller(PidParameters(), RIG.dt))
    sys_d = signal.dlti(loop.a, loop.b, loop.c[:4], loop.d[:4], dt=RIG.dt)
    f0, n = 250.0, 6000  # 250 Hz is 150 periods of 40 samples: the phasor is one DFT bin
    t = np.arange(n) * RIG.dt
    d = directional_frf([f0], loop.freqresp([f0])[:, :4], None, *NAMES)
    tail = slice(n - 4000, n)
    e = np.exp(-2j * np.pi * f0 * t[tail])
    for plane in (0, 1):
        for sense, want in ((1.0, d.forward), (-1.0, d.backward)):
            r = np.zeros((n, 4))
            r[:, plane], r[:, plane + 2] = np.cos(2 * np.pi * f0 * t), sense * np.sin(2 * np.pi * f0 * t)
            _, y, _ = signal.dlsim(sys_d, r)
            p = y[tail][:, [0, 1]] + 1j * y[tail][:, [2, 3]]
            # f = e^{+-j w t}: p's coefficient of e^{+j w t} (forward) or the conjugate of its e^{-j w t} one
            phasor = (p * e[:, None]).mean(axis=0) if sense > 0 else np.conj((p / e[:, None]).mean(axis=0))
            np.testing.assert_allclose(phasor, want[0, :, plane], rtol=2e-3, atol=2e-3 * np.abs(want).max())


def test_forward_and_backward_modes_peak_where_the_eigen_analysis_puts_them():
    model = true_linear_model(RIG)
    s, vecs = np.linalg.eig(model.a)
    first = (s.imag > 2 * np.pi * 280) & (s.imag < 2 * np.pi * 340)
    pair = sorted(zip(s[first].imag / (2 * np.pi), (model.c @ vecs[:, first]).T), key=lambda x: x[0])
    (f_b, shape_b), (f_f, shape_f) = pair
    assert f_f - f_b > 5.0  # split by the spin
    assert whirl(shape_b, NAMES[0])[0] == "backward" and whirl(shape_f, NAMES[0])[0] == "forward"
    f = np.linspace(290, 330, 4001)
    d = directional_frf(f, true_linear_model(RIG, discrete=True).freqresp(f), None, *NAMES)
    assert f[np.argmax(np.abs(d.forward[:, 0, 0]))] == pytest.approx(f_f, abs=0.2)
    assert f[np.argmax(np.abs(d.backward[:, 0, 0]))] == pytest.approx(f_b, abs=0.2)
    # at standstill there is no direction: both FRFs equal, x-only shapes standing
    still = true_linear_model(make_rig(), discrete=True).freqresp(f)
    ds = directional_frf(f, still, None, *NAMES)
    np.testing.assert_allclose(ds.forward, ds.backward, atol=1e-6 * np.abs(ds.forward).max())
    assert whirl(np.array([1.0, 0.5, 0.0, 0.0]), NAMES[0])[0] == "standing"


def test_directional_variance_is_the_mean_of_the_four_element_variances():
    var = np.arange(1, 17, dtype=float).reshape(1, 4, 4)
    d = directional_frf([1.0], np.zeros((1, 4, 4)), var, *NAMES)
    # A->A: elements (0,0), (2,2), (0,2), (2,0)
    assert d.var_forward[0, 0, 0] == pytest.approx((1 + 11 + 3 + 9) / 4)


def test_an_frf_result_gives_its_directional_frfs():
    """The streaming estimate's own directional view equals directional_frf of its matrix."""
    import sys
    from pathlib import Path

    from ambid.excitation.spec import build_design
    from ambid.frf.streaming import FrfStream
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from session_testbench import simulate_closed_loop

    design = build_design("multisine", (20, 500), 20.0, 1e4, peak_current_a=0.4, n_periods=2, phases="random",
                          speed_rpm=12_000.0)
    names, x = simulate_closed_loop(RIG, design, 3000, seed=2)
    stream = FrfStream(design, names[:4], names[4:8], names[12:16], start_index=3000)
    stream.add(0, x[:, list(range(8)) + list(range(12, 16))])
    res = stream.estimate()
    d = res.directional()
    want = directional_frf(res.freq_hz, res.frf, res.var_noise, *NAMES)
    np.testing.assert_array_equal(d.forward, want.forward)
    np.testing.assert_array_equal(d.var_backward, want.var_backward)
    # measured against the true rig at speed: the forward FRF of plane A within a few % at most lines
    true = directional_frf(res.freq_hz, true_linear_model(RIG, discrete=True).freqresp(res.freq_hz), None, *NAMES)
    rel = np.abs(d.forward[:, 0, 0] - true.forward[:, 0, 0]) / np.abs(true.forward[:, 0, 0])
    assert np.median(rel) < 0.05


def test_the_planes_come_from_the_channel_names():
    """Whatever the order and whatever else the channels hold (an axial axis, a one-plane rig): the planes are
    the bearings with an x and a y channel, the same as in the radial order."""
    f = np.array([100.0, 300.0])
    g = true_linear_model(RIG, discrete=True).freqresp(f)
    radial = directional_frf(f, g, None, *NAMES)
    # the five-axis order (z last, its row and column zero here) gives the same 2 x 2 planes
    g5 = np.zeros((2, 5, 5), complex)
    g5[:, :4, :4] = g
    five = directional_frf(f, g5, None, NAMES[0] + ("y_z",), NAMES[1] + ("u_z",))
    np.testing.assert_array_equal(five.forward, radial.forward)
    # one plane (bearing A only, x then y): its 1 x 1 directional FRF is radial's A -> A
    one = directional_frf(f, g[:, [0, 2]][:, :, [0, 2]], None, ("y_a_x", "y_a_y"), ("u_a_x", "u_a_y"))
    np.testing.assert_allclose(one.forward[:, 0, 0], radial.forward[:, 0, 0], rtol=1e-12)
