"""The structured position controller AMB engineers deploy: per axis a PID with lead/lag, a low-pass and
notch filters for the bending modes, as a discrete state-space model.

Per axis, y [m] -> ic [A], minus sign included, the continuous design

    C(s) = kp (1 + 1/(ti s) + td s / (1 + td s / n)) (1 + s/wz) / (1 + s/wp) L(s) prod_k N_k(s)

with a second-order low-pass ``L(s) = 1 / (s^2/wl^2 + 2 zl s/wl + 1)`` and notches
``N_k(s) = (s^2 + 2 zz wk s + wk^2) / (s^2 + 2 zp wk s + wk^2)`` (depth ``zz / zp`` at ``wk``, half-width
``zp``), each section discretised by Tustin (bilinear, no prewarping: the frequency response is
``C(j 2/dt tan(w dt / 2))`` exactly, :func:`structured_axis_frf`) and realised with states of like size,
then one sample of computational delay, as :mod:`ambid.control.pid` does. The default PID is the special
case of no lead/lag, a first-order low-pass and no notch.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from ambid.channels import RADIAL, Layout
from ambid.quantity import check_ranges, quantity, required
from ambid.statespace import StateSpace, block_diag, delay, series


@dataclass(frozen=True)
class Notch:
    """One notch filter.

    Attributes
    ----------
    freq_hz
        centre frequency [Hz].
    depth
        gain at the centre, zeta_zero / zeta_pole, in (0, 1] [-] (1: no notch).
    width
        damping ratio of its poles, its relative half-width [-].
    """

    freq_hz: float
    depth: float
    width: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.freq_hz) and self.freq_hz > 0):
            raise ValueError(f"notch freq_hz = {self.freq_hz!r} must be > 0 Hz")
        if not (np.isfinite(self.depth) and 0 < self.depth <= 1):
            raise ValueError(f"notch depth = {self.depth!r} must lie in (0, 1]")
        if not (np.isfinite(self.width) and 1e-4 <= self.width <= 2):
            raise ValueError(f"notch width = {self.width!r} must lie in [1e-4, 2]")


@dataclass(frozen=True)
class StructuredAxis:
    """One axis of the structured controller (module docstring).

    Attributes
    ----------
    kp_a_per_m, ti_s, td_s, derivative_filter_n
        the PID's terms, as :class:`ambid.control.pid.PidParameters`'s (td_s 0: no derivative).
    lead_zero_hz, lead_pole_hz
        the lead/lag's zero and pole [Hz] (equal: none; zero below pole: lead).
    lowpass_hz
        second-order low-pass corner [Hz].
    lowpass_damping
        its damping ratio [-].
    notches
        the notch filters.
    """

    kp_a_per_m: float = required("proportional gain", "A/m", 1e-9, 1e9)
    ti_s: float = quantity(0.05, "integral time", "s", 1e-5, 1e4)
    td_s: float = quantity(1.5e-3, "derivative time (0: no derivative)", "s", 0.0, 1.0)
    derivative_filter_n: float = quantity(10.0, "derivative filter ratio n", "", 1.0, 1000.0)
    lead_zero_hz: float = quantity(1000.0, "the lead/lag's zero", "Hz", 1e-3, 1e7)
    lead_pole_hz: float = quantity(1000.0, "the lead/lag's pole", "Hz", 1e-3, 1e7)
    lowpass_hz: float = quantity(5000.0, "second-order low-pass corner", "Hz", 1.0, 1e7)
    lowpass_damping: float = quantity(0.7, "the low-pass's damping ratio", "", 0.05, 5.0)
    notches: tuple[Notch, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        check_ranges(self, "structured controller:")
        object.__setattr__(self, "notches", tuple(n if isinstance(n, Notch) else Notch(**n) for n in self.notches))

    def to_dict(self) -> dict:
        """JSON-able, :func:`structured_axis_from_dict` reads it back."""
        return asdict(self)


def structured_axis_from_dict(d: dict) -> StructuredAxis:
    """Inverse of :meth:`StructuredAxis.to_dict`."""
    d = dict(d)
    d["notches"] = tuple(Notch(**n) for n in d.get("notches", ()))
    return StructuredAxis(**d)


def _sections(p: StructuredAxis) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The continuous sections (A, B, C, D) of one axis, each SISO with states of like size."""
    out = []
    kp = p.kp_a_per_m
    # PID: x_i' = y, x_d' = wd (y - x_d); pid = kp y + kp/ti x_i + kd (y - x_d), kd = kp td wd
    if p.td_s > 0:
        wd = p.derivative_filter_n / p.td_s
        kd = kp * p.td_s * wd
        out.append((np.array([[0.0, 0.0], [0.0, -wd]]), np.array([[1.0], [wd]]),
                    np.array([[kp / p.ti_s, -kd]]), np.array([[kp + kd]])))
    else:
        out.append((np.zeros((1, 1)), np.ones((1, 1)), np.array([[kp / p.ti_s]]), np.array([[kp]])))
    if p.lead_zero_hz != p.lead_pole_hz:   # (1 + s/wz)/(1 + s/wp) = wp/wz + (1 - wp/wz) wp/(s + wp)
        wz, wp = 2 * np.pi * p.lead_zero_hz, 2 * np.pi * p.lead_pole_hz
        out.append((np.array([[-wp]]), np.array([[wp]]), np.array([[1 - wp / wz]]), np.array([[wp / wz]])))
    wl, zl = 2 * np.pi * p.lowpass_hz, p.lowpass_damping  # time-scaled companion form: states y_f, y_f'/wl
    out.append((wl * np.array([[0.0, 1.0], [-1.0, -2 * zl]]), wl * np.array([[0.0], [1.0]]),
                np.array([[1.0, 0.0]]), np.zeros((1, 1))))
    for n in p.notches:
        if n.depth >= 1:
            continue
        w, zp = 2 * np.pi * n.freq_hz, n.width
        zz = n.depth * zp
        out.append((w * np.array([[0.0, 1.0], [-1.0, -2 * zp]]), w * np.array([[0.0], [1.0]]),
                    np.array([[0.0, 2 * (zz - zp)]]), np.ones((1, 1))))
    return out


def bilinear_section(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, dt: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The bilinear (Tustin) discretisation of a small section, as ``scipy.signal.cont2discrete(...,
    method="bilinear")`` computes it (an explicit inverse: tuning builds thousands of them)."""
    inv = np.linalg.inv(np.eye(a.shape[0]) - 0.5 * dt * a)
    bd = inv @ b * dt
    return inv @ (np.eye(a.shape[0]) + 0.5 * dt * a), bd, c @ inv, d + 0.5 * c @ bd


def structured_axis(p: StructuredAxis, dt: float) -> StateSpace:
    """One axis, y [m] -> ic [A] (minus sign included, no delay), each section discretised by Tustin."""
    ss = None
    for a, b, c, d in _sections(p):
        sec = StateSpace(*bilinear_section(a, b, c, d, dt), dt)
        ss = sec if ss is None else series(ss, sec)
    return ss._replace(c=-ss.c, d=-ss.d)


def structured_axis_frf(p: StructuredAxis, freq_hz: np.ndarray, dt: float) -> np.ndarray:
    """Frequency response of :func:`structured_axis` with the computational delay of ``delay_samples`` = 1,
    (L,) complex [A/m]: each section at s = j 2/dt tan(pi f dt) (Tustin's exact map), times -z^-1.

    Examples
    --------
    >>> import numpy as np
    >>> p = StructuredAxis(kp_a_per_m=12000.0)
    >>> f = np.array([50.0, 400.0])
    >>> k = structured_controller([p], 1e-4, Layout(("a_x",)))
    >>> bool(np.allclose(structured_axis_frf(p, f, 1e-4), k.freqresp(f)[:, 0, 0]))
    True
    """
    f = np.asarray(freq_hz, dtype=float)
    s = 1j * (2.0 / dt) * np.tan(np.pi * f * dt)
    h = np.ones(f.shape, dtype=complex)
    for a, b, c, d in _sections(p):
        if a.shape[0] == 1:
            h *= d[0, 0] + c[0, 0] * b[0, 0] / (s - a[0, 0])
        else:   # 2 x 2: C (sI - A)^-1 B by the adjugate
            det = (s - a[0, 0]) * (s - a[1, 1]) - a[0, 1] * a[1, 0]
            x0 = ((s - a[1, 1]) * b[0, 0] + a[0, 1] * b[1, 0]) / det
            x1 = (a[1, 0] * b[0, 0] + (s - a[0, 0]) * b[1, 0]) / det
            h *= d[0, 0] + c[0, 0] * x0 + c[0, 1] * x1
    return -h * np.exp(-2j * np.pi * f * dt)


def structured_controller(axes: list[StructuredAxis] | tuple[StructuredAxis, ...], dt: float,
                          layout: Layout = RADIAL, delay_samples: int = 1) -> StateSpace:
    """The decentralised controller, one :class:`StructuredAxis` per axis of ``layout``, with
    ``delay_samples`` of computational delay: y (na) [m] -> ic (na) [A]."""
    if len(axes) != len(layout):
        raise ValueError(f"structured_controller: {len(axes)} axes given for the layout's {len(layout)} "
                         f"({' '.join(layout.axes)})")
    built: dict[StructuredAxis, StateSpace] = {}   # axes that share their parameters share one realisation
    parts = []
    for p in axes:
        if p not in built:
            built[p] = structured_axis(p, dt)
        parts.append(built[p])
    k = series(block_diag(*parts), delay(len(layout), delay_samples, dt))
    return k._replace(input_names=layout.outputs, output_names=layout.controls,
                      input_units=layout.units("y"), output_units=layout.units("ic"))
