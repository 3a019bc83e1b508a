"""Current-controlled amplifier: eqs. 2.20-2.24 and the voltage/current limits."""

import numpy as np
import pytest
import scipy.signal
from ambid.plant.amplifier import Amplifier, amplifier_state_space, amplifier_step, closed_loop_response

L_H, UDC_V, IMAX_A = 0.01, 150.0, 6.0


def _run(amp, reference, dt, i0=0.0, **kw):
    i = np.atleast_1d(np.asarray(i0, dtype=float))
    out = np.empty((len(reference), i.size))
    for k, r in enumerate(reference):
        i = amplifier_step(amp, i, r, dt, **kw)
        out[k] = i
    return out


def _crossing_time(t, x, level):
    k = np.flatnonzero(x >= level)[0]
    return t[k - 1] + (level - x[k - 1]) * (t[k] - t[k - 1]) / (x[k] - x[k - 1])


def _fundamental(x, w, dt):
    t = np.arange(x.size) * dt
    basis = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return np.hypot(c[0], c[1])


def test_small_signal_step_is_first_order_with_eq_2_20_time_constant():
    amp = Amplifier(L_H, 0.0, UDC_V, IMAX_A, gain_v_per_a=50.0)
    assert amp.time_constant_s == pytest.approx(L_H / 50.0)  # eq. 2.20, R = 0
    dt = 5e-5
    i = _run(amp, np.full(40, 0.5), dt)[:, 0]  # 25 V needed at the step: unsaturated
    t = dt * np.arange(1, 41)
    assert np.allclose(i, 0.5 * (1 - np.exp(-t / amp.time_constant_s)), atol=1e-12)
    # With resistance and Gff = R: unit gain, tau = L / (Gp + R).
    amp_r = Amplifier(L_H, 2.0, UDC_V, IMAX_A, gain_v_per_a=50.0)
    i = _run(amp_r, np.full(40, 0.5), dt)[:, 0]
    assert np.allclose(i, 0.5 * (1 - np.exp(-t * 52.0 / L_H)), atol=1e-12)
    assert abs(closed_loop_response(amp_r, amp_r.bandwidth_hz)) == pytest.approx(1 / np.sqrt(2))


def test_linear_state_space_matches_nonlinear_step_in_small_signal():
    amp = Amplifier(L_H, 1.5, UDC_V, IMAX_A, gain_v_per_a=80.0, feedforward_ohm=1.0)
    dt, n_amp = 1e-4, 3
    a, b, c, d = amplifier_state_space(amp, n_amp)
    assert a.shape == b.shape == c.shape == d.shape == (n_amp, n_amp)
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete((a, b, c, d), dt, method="zoh")
    ref = 0.3 * np.random.default_rng(1).standard_normal((200, n_amp))
    x = np.zeros(n_amp)
    i_lin = np.empty_like(ref)
    for k in range(ref.shape[0]):
        x = ad @ x + bd @ ref[k]
        i_lin[k] = cd @ x
    i_nl = _run(amp, ref, dt, i0=np.zeros(n_amp))
    assert np.allclose(i_nl, i_lin, atol=1e-12)
    assert amp.static_gain == pytest.approx(81.0 / 81.5)


def test_rise_time_under_voltage_saturation_and_power_bandwidth():
    amp = Amplifier(L_H, 0.0, UDC_V, IMAX_A, gain_v_per_a=5000.0)  # saturates on any large step
    dt = 1e-5
    i = _run(amp, np.full(60, IMAX_A), dt)[:, 0]
    t = dt * np.arange(1, 61)
    # The ramp is linear in time, so the 0 -> 90 % time scales to 0 -> imax.
    t_rise = _crossing_time(np.r_[0, t], np.r_[0, i], 0.9 * IMAX_A) / 0.9
    assert t_rise == pytest.approx(L_H * IMAX_A / UDC_V, rel=1e-3)  # eq. 2.23 with L constant
    assert amp.rise_time_s == pytest.approx(t_rise, rel=1e-3)
    assert np.log(9) / t_rise == pytest.approx(amp.power_bandwidth_rad_s, rel=1e-3)  # eq. 2.24
    assert i[-1] == pytest.approx(IMAX_A, abs=1e-6)
    # With resistance the saturated current is an exponential towards udc / R.
    amp_r = Amplifier(L_H, 2.0, UDC_V, IMAX_A, gain_v_per_a=5000.0)
    i = _run(amp_r, np.full(60, IMAX_A), dt)[:, 0]
    t90 = _crossing_time(np.r_[0, t], np.r_[0, i], 0.9 * IMAX_A)
    assert t90 == pytest.approx(-(L_H / 2.0) * np.log(1 - 2.0 * 0.9 * IMAX_A / UDC_V), rel=2e-3)
    # Exact piecewise solution: sub-steps do not change the answer.
    one = amplifier_step(amp_r, np.zeros(2), np.array([IMAX_A, -IMAX_A]), 3e-4)
    many = amplifier_step(amp_r, np.zeros(2), np.array([IMAX_A, -IMAX_A]), 3e-4, n_substeps=7)
    assert np.allclose(one, many, atol=1e-12) and one[0] == pytest.approx(-one[1])


def test_full_current_sine_tracks_below_and_slews_above_power_bandwidth():
    amp = Amplifier(L_H, 0.5, UDC_V, IMAX_A, gain_v_per_a=5000.0)
    w_slew = UDC_V / (L_H * IMAX_A)  # L imax w = udc: full-amplitude limit
    # Well below: the full-amplitude sine is reproduced.
    w, dt = 0.2 * w_slew, 1e-4
    n = int(round(3 * 2 * np.pi / w / dt))
    i = _run(amp, IMAX_A * np.sin(w * dt * np.arange(n)), dt)[:, 0]
    last = i[n // 3:]
    assert _fundamental(last, w, dt) == pytest.approx(IMAX_A, rel=0.01)
    # Above: bang-bang slewing at udc / L gives a triangle of amplitude pi udc / (2 w L).
    w, dt = np.pi * w_slew, 2e-5
    n = int(round(30 * 2 * np.pi / w / dt))
    i = _run(amp, IMAX_A * np.sin(w * dt * np.arange(n)), dt)[:, 0]
    last = i[n // 2:]
    triangle = np.pi**2 / 8 * _fundamental(last, w, dt)
    assert triangle == pytest.approx(np.pi * UDC_V / (2 * w * L_H), rel=0.03)
    assert triangle < 0.55 * IMAX_A


def test_current_limits_and_back_emf():
    amp = Amplifier(L_H, 1.0, UDC_V, IMAX_A, gain_v_per_a=100.0, min_current_a=0.0)
    i = _run(amp, np.full(300, 20.0), 1e-4)[:, 0]  # reference beyond imax
    assert np.all(i <= IMAX_A) and i[-1] == pytest.approx(IMAX_A, abs=1e-9)
    i = _run(amp, np.full(300, -3.0), 1e-4, i0=2.0)[:, 0]  # unipolar bridge: no reverse current
    assert np.all(i >= 0.0) and i[-1] == pytest.approx(0.0, abs=1e-9)
    amp = Amplifier(L_H, 1.0, UDC_V, IMAX_A, gain_v_per_a=100.0)
    i = _run(amp, np.full(300, 2.0), 1e-4, back_emf_v=10.0)[:, 0]
    assert i[-1] == pytest.approx((101.0 * 2.0 - 10.0) / 101.0, rel=1e-9)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="inductance_h"):
        Amplifier(0.0, 1.0, UDC_V, IMAX_A, 100.0)
    with pytest.raises(ValueError, match="min_current_a"):
        Amplifier(L_H, 1.0, UDC_V, IMAX_A, 100.0, min_current_a=IMAX_A)
    amp = Amplifier(L_H, 1.0, UDC_V, IMAX_A, 100.0)
    with pytest.raises(ValueError, match="finite"):
        amplifier_step(amp, np.zeros(2), np.array([0.0, np.nan]), 1e-4)
    with pytest.raises(ValueError, match="dt_s"):
        amplifier_step(amp, 0.0, 0.0, -1e-4)
    with pytest.raises(ValueError, match="n_amplifiers"):
        amplifier_state_space(amp, 0)


def test_slew_voltage_is_what_a_sample_at_full_voltage_can_move_and_no_more():
    """slew_voltage_v's bound, against the saturating amplifier: with the reference's largest step needing more
    than the dc link, even a stiff current loop ends the sample short of it (the coil slews at udc / L); a step
    within the bound is reached (a stiff loop: Gp so large that tau_cl << dt)."""
    from ambid.plant.amplifier import slew_voltage_v

    dt = 1e-4
    amp = Amplifier(L_H, 0.0, UDC_V, IMAX_A, gain_v_per_a=1e6)
    reach = UDC_V * dt / L_H                      # 1.5 A: what full voltage moves the coil current in a sample
    for step, follows in ((0.8 * reach, True), (1.25 * reach, False)):
        ref = np.array([0.0, step])
        need = slew_voltage_v(amp, ref, dt)
        assert need == pytest.approx(L_H * step / dt)
        assert (need <= UDC_V) == follows
        i = _run(amp, [step], dt, i0=0.0, n_substeps=50)[-1, 0]
        assert (abs(i - step) < 1e-3 * step) == follows, (step, i)
        if not follows:
            assert i == pytest.approx(reach, rel=1e-3)   # the ramp at full voltage: udc dt / L
    # the resistive share: R (offset + the reference's largest value), per input
    amp_r = Amplifier(L_H, 2.0, UDC_V, IMAX_A, gain_v_per_a=1e6)
    ref = np.array([[0.0, 0.0], [0.5, -1.0], [0.2, 0.0]])
    np.testing.assert_allclose(slew_voltage_v(amp_r, ref, dt, offset_a=3.0),
                               L_H * np.array([0.5, 1.0]) / dt + 2.0 * (3.0 + np.array([0.5, 1.0])))
