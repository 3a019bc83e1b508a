"""The displacement sensors: the one model that the true rig and the simulator use.

Each sensor sits on its bearing's pedestal and measures the rotor minus
pedestal displacement d at its plane [m]::

    r_s = c3 d^3                     probe-curve error (cubic_per_m2 = c3 [1/m^2])
    s'  = wc (d + r_s - s)           electronics: first-order low-pass, wc = 2 pi bandwidth_hz
    y   = gain s + n                 n white Gaussian, std noise_std_m per sample [m]

The linear part (d -> s -> y) is a block of the true rig's state-space
model (:func:`ambid.plant.true_rig.true_plant` places it); the cubic error
enters that model as the input r_s, evaluated at the start of each step and
held (:mod:`ambid.plant.simulator`, and its compiled kernel with
``PAR_CUBIC``); the noise is added to the sampled output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np


@dataclass(frozen=True)
class Sensors:
    """The four identical displacement sensors of a rig.

    Attributes:
        bandwidth_hz: low-pass corner frequency [Hz].
        gain: output per displacement [m/m].
        noise_std_m: std of the white output noise per sample [m].
        cubic_per_m2: probe-curve cubic coefficient c3 [1/m^2] (0: none).
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

        Returns:
            a_ss, b_ss, c_ss: each (n_channels, n_channels).
        """
        eye = np.eye(n_channels)
        wc = self.corner_rad_s
        return -wc * eye, wc * eye, self.gain * eye

    def draw_noise(self, rng: np.random.Generator, n_samples: int, n_channels: int = 4) -> np.ndarray:
        """The output noise of n_samples samples, (n_samples, n_channels) [m], from ``rng``'s stream."""
        return rng.standard_normal((n_samples, n_channels)) * self.noise_std_m
