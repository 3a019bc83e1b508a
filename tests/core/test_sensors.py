"""Displacement sensors: FRF, static curve, noise statistics and determinism."""

import numpy as np
import pytest

from ambid.sensors import (Sensor, discretize_sensor, frequency_response, initial_state, sensor_state_space,
                           sensor_step, simulate_sensor, static_curve)


def _sine_response(sensor, f_hz, dt, amplitude=1e-5):
    """Complex gain y/d of the sampled sensor at f_hz from a least-squares sine fit."""
    n_per = int(round(1 / (f_hz * dt)))
    n = 40 * n_per
    t = dt * np.arange(n)
    d = amplitude * np.sin(2 * np.pi * f_hz * t)
    y = simulate_sensor(sensor, d[:, None], dt, seed=0)[:, 0]
    keep = slice(n // 2, n)  # integer number of periods after the transient
    basis = np.column_stack([np.sin(2 * np.pi * f_hz * t[keep]), np.cos(2 * np.pi * f_hz * t[keep])])
    (s, c), *_ = np.linalg.lstsq(basis, y[keep], rcond=None)
    return (s + 1j * c) / amplitude


@pytest.mark.parametrize("order", [1, 2])
def test_sampled_frf_matches_closed_form(order):
    sensor = Sensor(bandwidth_hz=2000.0, gain=1.3, order=order, damping_ratio=0.6)
    dt = 1e-5
    for f in (200.0, 1000.0, 2500.0):
        h = _sine_response(sensor, f, dt)
        w = 2 * np.pi * f
        wc = 2 * np.pi * 2000.0
        jw = 1j * w
        exact = 1.3 / (jw / wc + 1) if order == 1 else 1.3 * wc**2 / (jw**2 + 1.2 * wc * jw + wc**2)
        # Held (sampled) input: the continuous response delayed by half a sample.
        expected = exact * np.exp(-jw * dt / 2)
        assert abs(h) == pytest.approx(abs(expected), rel=2e-3)
        assert np.angle(h / expected) == pytest.approx(0.0, abs=np.deg2rad(0.3))
        assert frequency_response(sensor, f) == pytest.approx(exact, rel=1e-12)


def test_state_space_matches_frequency_response():
    for order in (1, 2):
        sensor = Sensor(bandwidth_hz=3000.0, gain=0.9, order=order)
        a, b, c, d = sensor_state_space(sensor, 3)
        assert a.shape == (3 * order, 3 * order) and b.shape == (3 * order, 3) and c.shape == (3, 3 * order)
        for f in (10.0, 3000.0, 20000.0):
            h = c @ np.linalg.solve(2j * np.pi * f * np.eye(a.shape[0]) - a, b) + d
            assert np.allclose(h, frequency_response(sensor, f) * np.eye(3), rtol=1e-12, atol=1e-15)
        assert frequency_response(sensor, 3000.0) == pytest.approx(
            0.9 / (1j + 1) if order == 1 else 0.9 / (2j / np.sqrt(2)), rel=1e-12)


def test_noise_std_whiteness_and_seed_determinism():
    sensor = Sensor(bandwidth_hz=5000.0, noise_std_m=2e-6)
    zeros = np.zeros((20000, 2))
    y = simulate_sensor(sensor, zeros, 1e-4, seed=7)
    assert np.std(y, axis=0) == pytest.approx([2e-6, 2e-6], rel=0.03)
    assert np.all(np.abs(y.mean(axis=0)) < 4 * 2e-6 / np.sqrt(20000))
    r1 = np.corrcoef(y[:-1, 0], y[1:, 0])[0, 1]
    assert abs(r1) < 0.03
    assert abs(np.corrcoef(y[:, 0], y[:, 1])[0, 1]) < 0.03
    assert np.array_equal(y, simulate_sensor(sensor, zeros, 1e-4, seed=7))
    assert not np.allclose(y, simulate_sensor(sensor, zeros, 1e-4, seed=8))


def test_step_function_equals_batch_simulation():
    sensor = Sensor(bandwidth_hz=1500.0, gain=1.1, noise_std_m=1e-7, order=2, cubic_per_m2=2e6,
                    saturation_m=4e-4)
    dt = 1e-4
    d = 2e-4 * np.random.default_rng(3).standard_normal((300, 2))
    batch = simulate_sensor(sensor, d, dt, seed=11)
    disc = discretize_sensor(sensor, dt)
    rng = np.random.default_rng(11)
    x = initial_state(disc, d[0])
    out = np.empty_like(d)
    for k in range(d.shape[0]):
        x, out[k] = sensor_step(disc, x, d[k], rng)
    assert np.allclose(out, batch, rtol=1e-10, atol=1e-15)


def test_static_nonlinearity_at_steady_state():
    sat, c3 = 3e-4, 1e6
    sensor = Sensor(bandwidth_hz=5000.0, gain=2.0, cubic_per_m2=c3, saturation_m=sat)
    d = np.array([-2e-4, 5e-5, 2e-4, 1e-3])
    expected = 2.0 * sat * np.tanh((d + c3 * d**3) / sat)
    y = simulate_sensor(sensor, np.tile(d, (50, 1)), 1e-4, seed=0)
    assert np.allclose(y[-1], expected, rtol=1e-9)
    assert np.all(np.abs(y[-1]) < 2.0 * sat)
    # Unit slope at zero: the linearised sensor is gain * H(s).
    eps = 1e-9
    assert (static_curve(sensor, eps) - static_curve(sensor, -eps)) / (2 * eps) == pytest.approx(1.0, rel=1e-6)
    # Cubic only: the third harmonic of a slow sine is c3 A^3 / 4.
    cubic = Sensor(bandwidth_hz=1e5, cubic_per_m2=c3)
    amp, f, dt = 2e-4, 10.0, 1e-4
    t = dt * np.arange(1000)
    s = static_curve(cubic, amp * np.sin(2 * np.pi * f * t))
    third = 2 * abs(np.fft.rfft(s)[3]) / t.size
    assert third == pytest.approx(c3 * amp**3 / 4, rel=1e-9)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="bandwidth_hz"):
        Sensor(bandwidth_hz=0.0)
    with pytest.raises(ValueError, match="order"):
        Sensor(bandwidth_hz=100.0, order=3)
    with pytest.raises(ValueError, match="noise_std_m"):
        Sensor(bandwidth_hz=100.0, noise_std_m=-1.0)
    disc = discretize_sensor(Sensor(bandwidth_hz=100.0), 1e-4)
    with pytest.raises(ValueError, match="shape"):
        sensor_step(disc, np.zeros((2, 1)), np.zeros(3), np.random.default_rng(0))
    with pytest.raises(ValueError, match="NaN"):
        sensor_step(disc, np.zeros((1, 1)), np.array([np.nan]), np.random.default_rng(0))
    with pytest.raises(ValueError, match="n_samples"):
        simulate_sensor(Sensor(bandwidth_hz=100.0), np.zeros(5), 1e-4, seed=0)
