"""Current-controlled switching power amplifier of one magnet coil.

Eqs. 2.19-2.24 of Hynynen (2011). The coil obeys (eq. 2.19)

    u = L di/dt + R i + ku dx/dt,

and the current controller sets the (switching-averaged) voltage

    u = sat(Gp (iref - i) + Gff iref),   |u| <= udc,

a proportional feedback plus a feedforward that covers the resistive drop
(Gff = R gives unit static gain). Unsaturated, the closed loop is first order
(eq. 2.20), Gcc(s) = g / (tau_cl s + 1) with tau_cl = L / (Gp + R) and
g = (Gp + Gff) / (Gp + R); the thesis neglects R, tau_cl = L / Gp. Saturated,
the current slews at di/dt = (+-udc - R i - ku dx/dt) / L, which limits the
large-signal (power) bandwidth to omega_BW ~ ln(9) udc / (L imax) (eq. 2.24).
PWM ripple is not modelled (the voltage is the switching-period average).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Amplifier:
    """Coil and current-controller data (one coil; shared by Nu identical ones).

    Attributes
    ----------
    inductance_h
        coil inductance L at the operating point [H].
    resistance_ohm
        coil resistance R [ohm].
    dc_link_voltage_v
        udc, the largest voltage magnitude [V].
    max_current_a
        imax [A]; the reference and the current stay <= imax.
    gain_v_per_a
        proportional current-controller gain Gp [V/A].
    feedforward_ohm
        Gff [V/A]; None means Gff = R (unit static gain).
    min_current_a
        lowest current [A]; None means -imax. Use 0 for the
        asymmetric half bridge of the thesis, whose coil current cannot
        reverse (then drive it with iref = ib +- ic).
    """

    inductance_h: float
    resistance_ohm: float
    dc_link_voltage_v: float
    max_current_a: float
    gain_v_per_a: float
    feedforward_ohm: float | None = None
    min_current_a: float | None = None

    def __post_init__(self) -> None:
        for name in ("inductance_h", "dc_link_voltage_v", "max_current_a", "gain_v_per_a"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"Amplifier.{name} must be finite and > 0, got {value!r}")
        if not np.isfinite(self.resistance_ohm) or self.resistance_ohm < 0:
            raise ValueError(f"Amplifier.resistance_ohm must be finite and >= 0, got {self.resistance_ohm!r}")
        if self.feedforward_ohm is not None and not np.isfinite(self.feedforward_ohm):
            raise ValueError(f"Amplifier.feedforward_ohm must be finite or None, got {self.feedforward_ohm!r}")
        if self.min_current_a is not None and not -self.max_current_a <= self.min_current_a < self.max_current_a:
            raise ValueError(
                f"Amplifier.min_current_a must lie in [-max_current_a, max_current_a), got {self.min_current_a!r}")

    @property
    def gff(self) -> float:
        """Feedforward gain Gff [V/A] (R unless given)."""
        return self.resistance_ohm if self.feedforward_ohm is None else self.feedforward_ohm

    @property
    def i_min(self) -> float:
        """Lowest current [A]."""
        return -self.max_current_a if self.min_current_a is None else self.min_current_a

    @property
    def time_constant_s(self) -> float:
        """Closed-loop time constant tau_cl = L / (Gp + R) [s] (eq. 2.20; L / Gp for R = 0)."""
        return self.inductance_h / (self.gain_v_per_a + self.resistance_ohm)

    @property
    def static_gain(self) -> float:
        """Small-signal DC gain (Gp + Gff) / (Gp + R) [-], 1 for Gff = R."""
        return (self.gain_v_per_a + self.gff) / (self.gain_v_per_a + self.resistance_ohm)

    @property
    def bandwidth_hz(self) -> float:
        """Small-signal -3 dB bandwidth 1 / (2 pi tau_cl) [Hz]."""
        return 1.0 / (2 * np.pi * self.time_constant_s)

    @property
    def power_bandwidth_rad_s(self) -> float:
        """Large-signal power bandwidth omega_BW = ln(9) udc / (L imax) [rad/s] (eq. 2.24)."""
        return np.log(9.0) * self.dc_link_voltage_v / (self.inductance_h * self.max_current_a)

    @property
    def rise_time_s(self) -> float:
        """Rise time 0 -> imax at full voltage, L imax / udc [s] (eq. 2.23, R neglected)."""
        return self.inductance_h * self.max_current_a / self.dc_link_voltage_v


def closed_loop_response(amp: Amplifier, freq_hz: np.ndarray) -> np.ndarray:
    """Small-signal frequency response im / iref = g / (j w tau_cl + 1), shape of freq_hz [-]."""
    w = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    return amp.static_gain / (1j * w * amp.time_constant_s + 1.0)


def amplifier_state_space(amp: Amplifier, n_amplifiers: int,
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Linear model of Nu independent amplifiers, x' = A x + B iref, im = C x + D iref.

    States are the coil currents [A]; inputs the reference currents [A].

    Returns
    -------
    (A, B, C, D), each of shape (Nu, Nu): A = -I / tau_cl, B = g I / tau_cl,
    C = I, D = 0.
    """
    if int(n_amplifiers) != n_amplifiers or n_amplifiers < 1:
        raise ValueError(f"n_amplifiers must be a positive integer, got {n_amplifiers!r}")
    eye = np.eye(int(n_amplifiers))
    tau = amp.time_constant_s
    return -eye / tau, amp.static_gain * eye / tau, eye.copy(), np.zeros_like(eye)


def slew_voltage_v(amp: Amplifier, reference_a: np.ndarray, dt_s: float, offset_a: float = 0.0) -> np.ndarray:
    """The coil voltage that moves the current by the reference's largest step within one sample.

    ``L max|iref[k+1] - iref[k]| / dt + R (offset + max|iref|)`` (eq. 2.19 without the back EMF): where it
    exceeds the dc link, the current cannot reach the reference within a sample even at full voltage: the
    amplifier saturates and the coil current slews behind what was designed (eq. 2.23).

    Parameters
    ----------
    amp
        the coil's amplifier.
    reference_a
        (n,) or (n, Nu) reference current perturbations [A]; NaN rows separate pieces (no step across them).
    dt_s
        sample period [s].
    offset_a
        the constant current beside it (bias and working current) [A].

    Returns
    -------
    (Nu,) (a scalar for a 1-D reference) the voltage [V].
    """
    r = np.asarray(reference_a, dtype=float)
    step = np.nanmax(np.abs(np.diff(r, axis=0)), axis=0) if r.shape[0] > 1 else np.zeros(r.shape[1:])
    return amp.inductance_h * step / dt_s + amp.resistance_ohm * (abs(offset_a) + np.nanmax(np.abs(r), axis=0))


def amplifier_step(amp: Amplifier, current_a: np.ndarray, reference_a: np.ndarray, dt_s: float,
                   n_substeps: int = 1, back_emf_v: np.ndarray | float = 0.0) -> np.ndarray:
    """Advance coil currents over one sample with voltage and current limits.

    The reference (clipped to [i_min, imax]) and back-EMF ku dx/dt are held
    over ``dt_s``. The solution is exact and piecewise: the linear closed loop
    (exponential with tau_cl) while |u| <= udc, the saturated coil
    (exponential with L / R, a ramp if R = 0) while |u| = udc, switching when
    u reaches or leaves the limit (with held inputs it switches at most
    once). Currents are then clipped to [i_min, imax] (hardware limit).

    Parameters
    ----------
    amp
        amplifier data.
    current_a
        coil currents at the start, shape (Nu,) or scalar [A].
    reference_a
        reference currents iref, broadcastable to current_a [A].
    dt_s
        sample period [s].
    n_substeps
        sub-steps per sample (>= 1). The solution is exact for
        any value; more sub-steps only apply the current clip more often.
    back_emf_v
        velocity-induced voltage ku dx/dt, broadcastable [V].

    Returns
    -------
    Coil currents at the end of the sample, broadcast shape [A].
    """
    if not (np.isfinite(dt_s) and dt_s > 0) or int(n_substeps) != n_substeps or n_substeps < 1:
        raise ValueError(f"dt_s must be > 0 and n_substeps a positive integer, got {dt_s!r}, {n_substeps!r}")
    i_lo, i_hi = amp.i_min, amp.max_current_a
    i = np.asarray(current_a, dtype=float)
    iref = np.minimum(np.maximum(np.asarray(reference_a, dtype=float), i_lo), i_hi)
    e = np.asarray(back_emf_v, dtype=float)
    if not np.isfinite(i + iref + e).all():  # one reduction: per-sample cost matters
        raise ValueError("current_a, reference_a and back_emf_v must be finite")
    gp, udc = amp.gain_v_per_a, amp.dc_link_voltage_v
    u_free = (gp + amp.gff) * iref
    i_lin_inf = (u_free - e) / (gp + amp.resistance_ohm)
    # Fast path (the usual case): unsaturated at the start and at the asymptote,
    # and the asymptote within the current limits. The current then moves
    # monotonically inside the linear region, so one exponential is exact.
    if ((np.abs(u_free - gp * i) <= udc) & (np.abs(u_free - gp * i_lin_inf) <= udc)
            & (i_lin_inf >= i_lo) & (i_lin_inf <= i_hi)).all():
        out = i_lin_inf + (i - i_lin_inf) * np.exp(-dt_s / amp.time_constant_s)
        return np.minimum(np.maximum(out, i_lo), i_hi)
    i, iref, e = np.broadcast_arrays(i, iref, e)
    i = i.astype(float, copy=True)
    h = dt_s / int(n_substeps)
    for _ in range(int(n_substeps)):
        i = np.minimum(np.maximum(_substep(amp, i, iref, e, h), i_lo), i_hi)
    return i


def _substep(amp: Amplifier, i: np.ndarray, iref: np.ndarray, e: np.ndarray, h: float) -> np.ndarray:
    """Exact piecewise solution over h with at most one regime change."""
    L, R, gp, udc = amp.inductance_h, amp.resistance_ohm, amp.gain_v_per_a, amp.dc_link_voltage_v
    u_free = (gp + amp.gff) * iref  # u = u_free - gp i while unsaturated
    u0 = u_free - gp * i
    sat = np.abs(u0) > udc
    # Boundary currents where u = +udc / -udc.
    i_hi, i_lo = (u_free - udc) / gp, (u_free + udc) / gp
    # Linear regime: asymptote and time constant.
    tau_c = L / (gp + R)
    i_lin_inf = (u_free - e) / (gp + R)
    # Saturated regime: voltage, asymptote (ramp when R = 0).
    us = np.where(u0 > 0, udc, -udc)
    # Time to the regime change from the starting regime.
    i_bound_sat = np.where(u0 > 0, i_hi, i_lo)  # saturated: current moves toward this boundary
    t_sat = _time_to(i, i_bound_sat, L, R, us - e)
    u_inf = u_free - gp * i_lin_inf
    lin_exits = np.abs(u_inf) > udc
    i_bound_lin = np.where(u_inf > 0, i_hi, i_lo)
    t_lin = np.where(lin_exits, _exp_time(i, i_lin_inf, i_bound_lin, tau_c), np.inf)
    t1 = np.minimum(np.where(sat, t_sat, t_lin), h)
    # Phase 1 in the starting regime.
    i1_sat = _coil(i, t1, L, R, us - e)
    i1_lin = i_lin_inf + (i - i_lin_inf) * np.exp(-t1 / tau_c)
    i1 = np.where(sat, np.where(t1 < h, i_bound_sat, i1_sat), np.where(t1 < h, i_bound_lin, i1_lin))
    # Phase 2 in the other regime for the rest of the sub-step.
    t2 = h - t1
    i2_lin = i_lin_inf + (i1 - i_lin_inf) * np.exp(-t2 / tau_c)
    us2 = np.where(u_inf > 0, udc, -udc)
    i2_sat = _coil(i1, t2, L, R, us2 - e)
    return np.where(t2 > 0, np.where(sat, i2_lin, i2_sat), i1)


def _coil(i0: np.ndarray, t: np.ndarray, L: float, R: float, v: np.ndarray) -> np.ndarray:
    """Coil current after t at constant net voltage v: L di/dt = v - R i."""
    if R == 0.0:
        return i0 + v * t / L
    i_inf = v / R
    return i_inf + (i0 - i_inf) * np.exp(-R * t / L)


def _time_to(i0: np.ndarray, target: np.ndarray, L: float, R: float, v: np.ndarray) -> np.ndarray:
    """Time for the coil current to move from i0 to target at net voltage v (inf if never)."""
    if R == 0.0:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (target - i0) * L / v
        return np.where(np.isfinite(t) & (t >= 0), t, np.inf)
    return _exp_time(i0, v / R, target, L / R)


def _exp_time(i0: np.ndarray, i_inf: np.ndarray, target: np.ndarray, tau: float) -> np.ndarray:
    """Time for i_inf + (i0 - i_inf) exp(-t / tau) to reach target (inf if never)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (target - i_inf) / (i0 - i_inf)
        t = -tau * np.log(ratio)
    return np.where((ratio > 0) & (ratio <= 1) & np.isfinite(t), t, np.inf)
