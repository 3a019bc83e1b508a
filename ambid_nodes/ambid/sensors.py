"""Non-collocated displacement sensors: static curve, gain, low-pass, noise.

Signal chain of one sensor (the same for every channel)::

    d = true displacement [m]
    s = sat_m * tanh((d + c3 d^3) / sat_m)     static nonlinearity (probe curve)
    y = H(s) * gain + n                        electronics, then white noise

* c3 = ``cubic_per_m2`` [1/m^2]: cubic error, c3 d^3 at displacement d.
* sat_m = ``saturation_m`` [m]: the curve flattens towards +-sat_m (the
  probe's range); inf disables it. Both keep unit slope at d = 0, so the
  linearised sensor is ``gain * H(s)``.
* H(s) is a unit-DC-gain low-pass: first order 1 / (s / wc + 1), or second
  order wc^2 / (s^2 + 2 zeta wc s + wc^2), wc = 2 pi ``bandwidth_hz``.
* n is white, zero-mean Gaussian with std ``noise_std_m`` per sample [m].

The linear model is continuous-time; the per-sample step uses its exact
zero-order-hold discretisation (input held over the sample).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal


@dataclass(frozen=True)
class Sensor:
    """Displacement sensor data (one channel; shared by identical channels).

    Attributes:
        bandwidth_hz: low-pass corner frequency fc [Hz].
        gain: output per input displacement [m/m] (1 for a calibrated sensor).
        noise_std_m: std of the additive white output noise [m].
        order: 1 or 2, order of the low-pass.
        damping_ratio: zeta of the second-order low-pass [-].
        cubic_per_m2: cubic coefficient c3 [1/m^2].
        saturation_m: saturation level sat_m [m], inf for none.
    """

    bandwidth_hz: float
    gain: float = 1.0
    noise_std_m: float = 0.0
    order: int = 1
    damping_ratio: float = 1 / np.sqrt(2)
    cubic_per_m2: float = 0.0
    saturation_m: float = np.inf

    def __post_init__(self) -> None:
        if not np.isfinite(self.bandwidth_hz) or self.bandwidth_hz <= 0:
            raise ValueError(f"Sensor.bandwidth_hz must be finite and > 0, got {self.bandwidth_hz!r}")
        if not np.isfinite(self.gain) or self.gain == 0:
            raise ValueError(f"Sensor.gain must be finite and non-zero, got {self.gain!r}")
        if not np.isfinite(self.noise_std_m) or self.noise_std_m < 0:
            raise ValueError(f"Sensor.noise_std_m must be finite and >= 0, got {self.noise_std_m!r}")
        if self.order not in (1, 2):
            raise ValueError(f"Sensor.order must be 1 or 2, got {self.order!r}")
        if not np.isfinite(self.damping_ratio) or self.damping_ratio <= 0:
            raise ValueError(f"Sensor.damping_ratio must be finite and > 0, got {self.damping_ratio!r}")
        if not np.isfinite(self.cubic_per_m2):
            raise ValueError(f"Sensor.cubic_per_m2 must be finite, got {self.cubic_per_m2!r}")
        if not self.saturation_m > 0:
            raise ValueError(f"Sensor.saturation_m must be > 0 (inf for none), got {self.saturation_m!r}")


@dataclass(frozen=True)
class DiscreteSensor:
    """Zero-order-hold discretisation of one sensor's low-pass at ``dt_s``.

    Attributes:
        sensor: the continuous sensor.
        dt_s: sample period [s].
        ad, bd, cd: discrete filter matrices, shapes (order, order),
            (order, 1), (1, order); state advance x[k+1] = ad x[k] + bd s[k],
            output y[k] = cd x[k] (the filter adds no direct feed-through).
    """

    sensor: Sensor
    dt_s: float
    ad: np.ndarray
    bd: np.ndarray
    cd: np.ndarray


def static_curve(sensor: Sensor, displacement_m: np.ndarray) -> np.ndarray:
    """Static probe curve s(d) [m] (module docstring), shape of displacement_m."""
    d = np.asarray(displacement_m, dtype=float)
    s = d + sensor.cubic_per_m2 * d**3
    if np.isfinite(sensor.saturation_m):
        s = sensor.saturation_m * np.tanh(s / sensor.saturation_m)
    return s


def frequency_response(sensor: Sensor, freq_hz: np.ndarray) -> np.ndarray:
    """Linearised response y / d = gain H(j 2 pi f), shape of freq_hz [m/m]."""
    s = 2j * np.pi * np.asarray(freq_hz, dtype=float)
    wc = 2 * np.pi * sensor.bandwidth_hz
    if sensor.order == 1:
        h = 1.0 / (s / wc + 1.0)
    else:
        h = wc**2 / (s**2 + 2 * sensor.damping_ratio * wc * s + wc**2)
    return sensor.gain * h


def _single_state_space(sensor: Sensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    wc = 2 * np.pi * sensor.bandwidth_hz
    if sensor.order == 1:
        return np.array([[-wc]]), np.array([[wc]]), np.array([[sensor.gain]])
    # States (filtered position, its rate / wc) keep the matrices of order wc.
    return (np.array([[0.0, wc], [-wc, -2 * sensor.damping_ratio * wc]]),
            np.array([[0.0], [wc]]), np.array([[sensor.gain, 0.0]]))


def sensor_state_space(sensor: Sensor, n_sensors: int,
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Linearised model of n identical sensors, x' = A x + B d, y = C x + D d.

    States are grouped per sensor (``order`` states each; the first is the
    filtered displacement [m]). Noise and the static curve are left out.

    Returns:
        (A, B, C, D) of shapes (n order, n order), (n order, n), (n, n order), (n, n).
    """
    if int(n_sensors) != n_sensors or n_sensors < 1:
        raise ValueError(f"n_sensors must be a positive integer, got {n_sensors!r}")
    a1, b1, c1 = _single_state_space(sensor)
    eye = np.eye(int(n_sensors))
    return np.kron(eye, a1), np.kron(eye, b1), np.kron(eye, c1), np.zeros((int(n_sensors),) * 2)


def discretize_sensor(sensor: Sensor, dt_s: float) -> DiscreteSensor:
    """Exact zero-order-hold discretisation of the sensor filter (gain in cd)."""
    if not np.isfinite(dt_s) or dt_s <= 0:
        raise ValueError(f"dt_s must be finite and > 0, got {dt_s!r}")
    a, b, c = _single_state_space(sensor)
    n = a.shape[0]
    big = scipy.linalg.expm(np.block([[a, b], [np.zeros((1, n + 1))]]) * dt_s)
    return DiscreteSensor(sensor=sensor, dt_s=float(dt_s), ad=big[:n, :n], bd=big[:n, n:], cd=c)


def initial_state(disc: DiscreteSensor, displacement_m: np.ndarray) -> np.ndarray:
    """Filter state at rest at a constant displacement, shape (n_sensors, order) [m].

    Args:
        displacement_m: displacements of the sensors, shape (n_sensors,) [m].
    """
    s = static_curve(disc.sensor, np.atleast_1d(np.asarray(displacement_m, dtype=float)))
    x = np.zeros((s.size, disc.ad.shape[0]))
    x[:, 0] = s
    return x


def sensor_step(disc: DiscreteSensor, state: np.ndarray, displacement_m: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One sample of n sensors: output y[k], then advance the filter.

    Args:
        disc: from ``discretize_sensor``.
        state: filter states, shape (n_sensors, order) (``initial_state``).
        displacement_m: true displacements d[k], held over the sample,
            shape (n_sensors,) [m].
        rng: noise source, e.g. ``numpy.random.default_rng(seed)`` created
            once per run (one normal draw per sensor per sample).

    Returns:
        (new_state, measurement): shapes (n_sensors, order) and (n_sensors,) [m].
        The output depends on the state only (no feed-through), so y[k] does
        not yet see d[k].
    """
    x = np.asarray(state, dtype=float)
    d = np.atleast_1d(np.asarray(displacement_m, dtype=float))
    if x.ndim != 2 or x.shape[1] != disc.ad.shape[0] or d.shape != (x.shape[0],):
        raise ValueError(f"state must have shape (n_sensors, {disc.ad.shape[0]}) and displacement_m "
                         f"shape (n_sensors,), got {x.shape} and {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError("displacement_m contains NaN or inf")
    y = x @ disc.cd[0] + disc.sensor.noise_std_m * rng.standard_normal(d.size)
    x_new = x @ disc.ad.T + static_curve(disc.sensor, d)[:, None] * disc.bd[:, 0]
    return x_new, y


def simulate_sensor(sensor: Sensor, displacement_m: np.ndarray, dt_s: float, seed: int | None,
                    ) -> np.ndarray:
    """Whole record through the sensor, same result as repeated ``sensor_step``.

    Args:
        sensor: sensor data.
        displacement_m: true displacements, shape (n_samples, n_sensors) [m];
            the filter starts at rest at the first sample.
        dt_s: sample period [s].
        seed: seed of ``numpy.random.default_rng`` for the noise.

    Returns:
        Measurements, shape (n_samples, n_sensors) [m].
    """
    d = np.asarray(displacement_m, dtype=float)
    if d.ndim != 2:
        raise ValueError(f"displacement_m must have shape (n_samples, n_sensors), got {d.shape}")
    disc = discretize_sensor(sensor, dt_s)
    s = static_curve(sensor, d)
    # The filter starts at rest at s[0] (output cd x0 = gain s[0], unit DC gain),
    # so filter the deviation from s[0] from zero state.
    num, den = scipy.signal.ss2tf(disc.ad, disc.bd, disc.cd, np.zeros((1, 1)))
    y = sensor.gain * s[:1] + scipy.signal.lfilter(num[0], den, s - s[:1], axis=0)
    rng = np.random.default_rng(seed)
    return y + sensor.noise_std_m * rng.standard_normal(d.shape)
