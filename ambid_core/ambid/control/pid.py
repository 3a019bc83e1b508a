"""The default position controller: a decentralised PID with filters, as a discrete state-space model.

A controller maps the measured displacements y [m] to the control currents
ic [A], minus sign included (ic = K(z) y), and carries one sample of
computational delay: ic[k] depends on y[k-1] and older, as in a digital
controller that samples, computes and applies at the next sample instant.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from ambid.channels import RADIAL, Layout
from ambid.quantity import check_ranges, quantity
from ambid.statespace import StateSpace, block_diag, delay, discretise, series


@dataclass(frozen=True)
class PidParameters:
    """Decentralised PID with a filtered derivative and a low-pass, per axis.

    C(s) = kp (1 + 1/(ti s) + td s / (1 + td s / n)) / (1 + s / (2 pi f_lp))

    The defaults are tuned for the default rig (docs/default_rig.md): input
    sensitivity peak 2.41 on the analytical model, 2.71 on the true rig
    (ISO 14839-3 zone A). An axial axis (``z``, rigs/five_axis.yaml) carries
    the whole rotor mass on one magnet pair: it takes its own proportional
    gain and derivative time, the rest as the radial axes.

    Attributes
    ----------
    kp_a_per_m
        proportional gain [A/m].
    ti_s
        integral time [s].
    td_s
        derivative time [s].
    derivative_filter_n
        derivative filter ratio N [-] (lead up to N).
    lowpass_hz
        first-order low-pass corner [Hz].
    delay_samples
        computational delay [samples].
    current_limit_a
        saturation of ic [A].
    axial_kp_a_per_m
        proportional gain of an axial axis [A/m].
    axial_td_s
        derivative time of an axial axis [s].
    """

    kp_a_per_m: float = quantity(12_000.0, "proportional gain", "A/m", 1.0, 1e9)
    ti_s: float = quantity(0.05, "integral time", "s", 1e-5, 1e4)
    td_s: float = quantity(1.5e-3, "derivative time", "s", 0.0, 1.0)
    derivative_filter_n: float = quantity(10.0, "derivative filter ratio N (lead up to N)", "", 1.0, 1000.0)
    lowpass_hz: float = quantity(5_000.0, "first-order low-pass corner", "Hz", 1.0, 1e6)
    delay_samples: int = quantity(1, "computational delay [samples]", "", 0, 100)
    current_limit_a: float = quantity(3.0, "saturation of ic", "A", 1e-3, 1e3)
    axial_kp_a_per_m: float = quantity(16_000.0, "proportional gain of an axial axis (rigs/five_axis.yaml)", "A/m",
                                       1.0, 1e9)
    axial_td_s: float = quantity(3.0e-3, "derivative time of an axial axis", "s", 0.0, 1.0)

    def __post_init__(self) -> None:
        check_ranges(self, "PID parameter")   # the ranges the node's parameters take too

def pid_axis(p: PidParameters, dt: float) -> StateSpace:
    """One axis of the PID, continuous design discretised by Tustin, y [m] -> ic [A], minus sign included.

    Realised with three well-scaled states (integral of y, derivative
    filter, low-pass), not from the transfer-function polynomials, whose
    coefficients span tens of decades.
    """
    kp, wl = p.kp_a_per_m, 2 * np.pi * p.lowpass_hz
    # states: x_i' = y; x_d' = wd (y - x_d); x_l' = wl (pid - x_l); ic = -x_l
    # pid = kp y + kp / ti x_i + kp td wd (y - x_d)
    wd = p.derivative_filter_n / p.td_s if p.td_s > 0 else 0.0
    kd = kp * p.td_s * wd
    pid_x = np.array([kp / p.ti_s, -kd, 0.0])
    pid_y = kp + kd
    a = np.array([[0.0, 0.0, 0.0], [0.0, -wd, 0.0], [0.0, 0.0, -wl]])
    a[2] += wl * pid_x
    b = np.array([[1.0], [wd], [wl * pid_y]])
    c = np.array([[0.0, 0.0, -1.0]])
    if wd == 0.0:  # no derivative action: drop its state
        a, b, c = a[np.ix_([0, 2], [0, 2])], b[[0, 2]], c[:, [0, 2]]
    ad, bd, cd, dd = discretise(a, b, c, np.zeros((1, 1)), dt, "bilinear")
    return StateSpace(ad, bd, cd, dd, dt)


def pid_controller(p: PidParameters, dt: float, layout: Layout = RADIAL) -> StateSpace:
    """Decentralised PID on every axis of ``layout`` (the rig's), with computational delay,
    y (na) [m] -> ic (na) [A]."""
    na = len(layout)
    axial = replace(p, kp_a_per_m=p.axial_kp_a_per_m, td_s=p.axial_td_s)
    axes = block_diag(*(pid_axis(axial if j in layout.axial else p, dt) for j in range(na)))
    k = series(axes, delay(na, p.delay_samples, dt))
    return k._replace(input_names=layout.outputs, output_names=layout.controls,
                      input_units=layout.units("y"), output_units=layout.units("ic"))


def pid_parameters_dict(p: PidParameters) -> dict:
    return asdict(p)
