"""The amplifier's limits on a controller: the control current and the voltage its noise costs.

The sensors' white noise ``v`` (std ``sigma`` per sample) reaches the control current through the loop,
``ic = K (I - G K)^-1 v``; the coil current follows ``ic`` through the current loop (first order,
``amplifier_bandwidth_hz``), and the voltage that takes is ``L di/dt``. Both are read by Parseval from
the responses on a uniform grid over (0, Nyquist). The budget, per axis:

* current: ``4 sigma_ic + |i_static| + r_peak <= i_limit``: four standard deviations of the noise, the
  current that carries the rotor's weight and the excitation's peak within the amplifier's limit on
  ``|ic + r|`` (a measurement must not clip);
* voltage: ``4 L sigma_di/dt <= u_dc / 2``: the noise may cost at most half the dc link (the rest is the
  excitation's and the disturbances').
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ambid.commissioning.loops import noise_current_frf
from ambid.control.closed_loop import residue_freqresp
from ambid.statespace import StateSpace

__all__ = ["CurrentBudget", "CurrentCheck", "check_current"]


@dataclass(frozen=True)
class CurrentBudget:
    """What the amplifier allows and what else uses it, per axis.

    Attributes
    ----------
    current_limit_a
        the limit on ``|ic + r|`` [A].
    static_a
        (na,) the current that carries the rotor's weight [A].
    excitation_peak_a
        (na,) the verifying experiment's peak excitation [A].
    noise_std_m
        (na,) sensor noise std per sample [m].
    inductance_h
        (na,) coil inductance [H].
    amplifier_bandwidth_hz
        (na,) the current loop's bandwidth [Hz].
    dc_link_voltage_v
        the amplifiers' dc link [V].
    """

    current_limit_a: float
    static_a: np.ndarray
    excitation_peak_a: np.ndarray
    noise_std_m: np.ndarray
    inductance_h: np.ndarray
    amplifier_bandwidth_hz: np.ndarray
    dc_link_voltage_v: float

    @property
    def noise_current_limit_a(self) -> np.ndarray:
        """The largest RMS noise current per axis the current budget leaves [A]."""
        room = self.current_limit_a - np.abs(self.static_a) - np.asarray(self.excitation_peak_a)
        return np.maximum(room, 0.0) / 4.0


@dataclass(frozen=True)
class CurrentCheck:
    """A controller against the budget.

    Attributes
    ----------
    noise_rms_a
        (na,) RMS control current the sensor noise causes [A].
    current_use_a
        (na,) ``4 sigma + |static| + r_peak`` [A].
    voltage_rms_v
        (na,) RMS coil voltage the noise costs, ``L sigma_di/dt`` [V].
    current_margin_a
        the smallest ``limit - use`` over the axes [A] (< 0: over the limit).
    voltage_margin_v
        the smallest ``u_dc / 2 - 4 L sigma_di/dt`` [V].
    """

    noise_rms_a: np.ndarray
    current_use_a: np.ndarray
    voltage_rms_v: np.ndarray
    current_margin_a: float
    voltage_margin_v: float

    @property
    def ok(self) -> bool:
        return self.current_margin_a >= 0 and self.voltage_margin_v >= 0

    def to_dict(self) -> dict:
        return dict(noise_rms_a=self.noise_rms_a.tolist(), current_use_a=self.current_use_a.tolist(),
                    voltage_rms_v=self.voltage_rms_v.tolist(), current_margin_a=self.current_margin_a,
                    voltage_margin_v=self.voltage_margin_v, within_limits=self.ok,
                    rule="4 sigma of the noise current + the static current + the excitation's peak within the "
                         "current limit; 4 sigma of the noise's coil voltage within half the dc link")


def check_current(plant: StateSpace, controller: StateSpace, budget: CurrentBudget, n_lines: int = 4096
                  ) -> CurrentCheck:
    """The noise current and voltage of ``controller`` on ``plant`` (module docstring).

    Parameters
    ----------
    plant
        discrete u (na) [A] -> y (na) [m].
    controller
        discrete y (na) [m] -> ic (na) [A].
    budget
        the amplifier's limits and the other uses.
    n_lines
        lines of the uniform grid.
    """
    dt = plant.dt
    f = (np.arange(n_lines) + 0.5) / n_lines * 0.5 / dt
    t = noise_current_frf(residue_freqresp(controller, f), residue_freqresp(plant, f), budget.noise_std_m)
    amp = 1.0 / (1.0 + 1j * f[:, None] / np.asarray(budget.amplifier_bandwidth_hz)[None, :])
    didt = t * (2j * np.pi * f[:, None, None] * amp[:, :, None])
    sigma_ic = np.sqrt(np.mean(np.sum(np.abs(t) ** 2, axis=2), axis=0))
    sigma_v = np.asarray(budget.inductance_h) * np.sqrt(np.mean(np.sum(np.abs(didt) ** 2, axis=2), axis=0))
    use = 4 * sigma_ic + np.abs(budget.static_a) + np.asarray(budget.excitation_peak_a)
    return CurrentCheck(sigma_ic, use, sigma_v, float(np.min(budget.current_limit_a - use)),
                        float(np.min(0.5 * budget.dc_link_voltage_v - 4 * sigma_v)))
