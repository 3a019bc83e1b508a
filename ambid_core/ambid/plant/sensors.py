"""The displacement sensors: the one model that the true rig and the simulator use.

Each sensor sits on its bearing's pedestal and measures the rotor minus
pedestal displacement d at its plane [m]::

    r_s = c3 d^3                     probe-curve error (cubic_per_m2 = c3 [1/m^2])
    s'  = wc (d + r_s - s)           electronics: first-order low-pass, wc = 2 pi bandwidth_hz
    y   = gain s + n                 n white Gaussian, std noise_std_m per sample [m]

Spinning, each probe also reads its track's runout (mechanical: the track
out of round or off the spin axis; electrical: conductivity, permeability
and residual magnetism varying round the track), a sum of harmonics of the
rotor angle theta added to y (:func:`runout_table`, :func:`runout`); the
rotor does not move with it. At standstill the track's static reading is
part of the calibration zero, so runout acts only while the rotor spins.

The linear part (d -> s -> y) is a block of the true rig's state-space
model (:func:`ambid.plant.true_rig.true_plant` places it); the cubic error
enters that model as the input r_s, evaluated at the start of each step and
held (:mod:`ambid.plant.simulator`, and its compiled kernel with
``AX_CUBIC``); the noise is added to the sampled output. A rig with an axial
bearing has a probe of its own kind on that axis (:meth:`ambid.plant.rig.Rig.axis_sensors`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ambid.channels import RADIAL, Layout, bearing_of, direction_of


@dataclass(frozen=True)
class Sensors:
    """Displacement sensors of one kind (a rig's radial probes, or its axial probe).

    Attributes
    ----------
    bandwidth_hz
        low-pass corner frequency [Hz].
    gain
        output per displacement [m/m].
    noise_std_m
        std of the white output noise per sample [m].
    cubic_per_m2
        probe-curve cubic coefficient c3 [1/m^2] (0: none).
    """

    bandwidth_hz: float
    gain: float = 1.0
    noise_std_m: float = 0.0
    cubic_per_m2: float = 0.0

    @classmethod
    def from_rig(cls, values: Mapping[str, Any]) -> "Sensors":
        """The sensors of a rig from its parameter values (``Rig.values``)."""
        return cls(float(values["sensor_bandwidth_hz"]), float(values["sensor_gain"]),
                   float(values["sensor_noise_m"]), float(values["sensor_cubic_per_m2"]))

    @property
    def corner_rad_s(self) -> float:
        """wc = 2 pi bandwidth_hz [rad/s]."""
        return 2 * math.pi * self.bandwidth_hz

    def probe_error(self, displacement_m: np.ndarray) -> np.ndarray:
        """r_s = c3 d^3 [m], the static curve's deviation from the straight line, shaped like d."""
        d = np.asarray(displacement_m, dtype=float)
        return self.cubic_per_m2 * d ** 3

    def static_curve(self, displacement_m: np.ndarray) -> np.ndarray:
        """Steady output y for a constant displacement d, noise aside: gain (d + c3 d^3) [m]."""
        d = np.asarray(displacement_m, dtype=float)
        return self.gain * (d + self.probe_error(d))

    def frequency_response(self, freq_hz: np.ndarray) -> np.ndarray:
        """Small-signal y/d at freq_hz, continuous time: gain / (1 + j f / bandwidth_hz), shaped like freq_hz."""
        f = np.asarray(freq_hz, dtype=float)
        return self.gain / (1 + 1j * f / self.bandwidth_hz)

    def filter_blocks(self, n_channels: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The linear electronics as s' = a_ss s + b_ss (d + r_s), y = c_ss s.

        Returns
        -------
        a_ss, b_ss, c_ss: each (n_channels, n_channels).
        """
        eye = np.eye(n_channels)
        wc = self.corner_rad_s
        return -wc * eye, wc * eye, self.gain * eye

    def draw_noise(self, rng: np.random.Generator, n_samples: int, n_channels: int = 4) -> np.ndarray:
        """The output noise of n_samples samples, (n_samples, n_channels) [m], from ``rng``'s stream."""
        return rng.standard_normal((n_samples, n_channels)) * self.noise_std_m


def filter_blocks(sensors: Sequence[Sensors]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The linear electronics of one sensor per axis as s' = a_ss s + b_ss (d + r_s), y = c_ss s.

    Returns
    -------
    a_ss, b_ss, c_ss: each (na, na), diagonal.
    """
    wc = np.array([x.corner_rad_s for x in sensors])
    return np.diag(-wc), np.diag(wc), np.diag([x.gain for x in sensors])


def noise_std(sensors: Sequence[Sensors]) -> np.ndarray:
    """The output noise std of one sensor per axis, (na,) [m]."""
    return np.array([x.noise_std_m for x in sensors])


def cubic(sensors: Sequence[Sensors]) -> np.ndarray:
    """The probe-curve cubic coefficients c3 of one sensor per axis, (na,) [1/m^2]."""
    return np.array([x.cubic_per_m2 for x in sensors])


RUNOUT_HARMONICS = 3  # harmonics of the rotor angle a rig file can give runout at
_RUNOUT_KINDS = {"mech": (1, 2), "elec": (1, 2, 3)}


def runout_table(values: Mapping[str, Any], layout: Layout = RADIAL) -> np.ndarray:
    """Runout of the radial probes as harmonics of the rotor angle theta, from a rig's parameter values.

    Each track has a profile rho(psi) = sum_h a_h cos(h psi + phi_h) (mechanical
    plus electrical); the x probe reads it at psi = theta, the y probe, a
    quarter turn on in the sense of the spin, at psi = theta - pi / 2, and
    track B's profile is turned by ``runout_b_phase_deg`` (beta):
    a cos(h (theta - gamma) + phi + h beta). A 1X runout thus reads as a
    forward circular orbit. An axial probe reads none here.

    Returns
    -------
    T: (RUNOUT_HARMONICS, na, 2) [m]; probe c (``layout`` order) reads
    sum_h T[h - 1, c, 0] cos(h theta) + T[h - 1, c, 1] sin(h theta).
    """
    t = np.zeros((RUNOUT_HARMONICS, len(layout), 2))
    beta = math.radians(float(values["runout_b_phase_deg"]))
    probes = [(c, beta if bearing_of(axis) == "b" else 0.0, math.pi / 2 if direction_of(axis) == "y" else 0.0)
              for c, axis in enumerate(layout.axes) if direction_of(axis) in ("x", "y")]
    for kind, harmonics in _RUNOUT_KINDS.items():
        for h in harmonics:
            a = float(values[f"runout_{kind}_{h}x_m"])
            phi = math.radians(float(values[f"runout_{kind}_{h}x_phase_deg"]))
            for c, track, gamma in probes:
                psi = phi + h * (track - gamma)
                t[h - 1, c] += a * math.cos(psi), -a * math.sin(psi)
    return t


def runout(table: np.ndarray, theta_rad: np.ndarray) -> np.ndarray:
    """The probes' runout at rotor angles theta [rad], shape theta.shape + (na,) [m] (table from
    :func:`runout_table`)."""
    th = np.asarray(theta_rad, dtype=float)[..., None]
    h = np.arange(1, table.shape[0] + 1)
    c, s = np.cos(h * th), np.sin(h * th)  # (..., H)
    return c @ table[:, :, 0] + s @ table[:, :, 1]
