"""H-infinity mixed-sensitivity position controller for a discrete plant model, and its order reduction.

The problem (discrete time, the plant's own sampling and delays exact): the controller's output ``v`` reaches
the coils one sample later (the computational delay), ``u = z^-1 v + d``, the sensors read
``y_m = y + sigma n``; minimise the H-infinity norm from ``[d; n]`` to

* ``z1 = u / s_max``: the input sensitivity (``d -> u`` is ``S = (I - K G)^-1``), against the peak asked for;
* ``z2 = W_e(z) v / i_e``: the controller's current where the high-pass ``W_e`` (unit gain below
  ``effort_corner_hz``, ``effort_rolloff`` times above) says it must roll off, against the current ``i_e``
  allowed (the sensor noise through the controller, and the unmodelled dynamics beyond the band);
* ``z3 = W_c(z) y``: the displacement per current at low frequency (``W_c`` a first-order lag of dc gain
  ``1 / compliance_m_per_a`` and corner ``compliance_corner_hz``): the bearing's stiffness.

The weights are discretised by Tustin; displacements are scaled to micrometres inside the synthesis, so
its matrices are of like size. The synthesis is SLICOT's SB10DD (slycot) at a fixed gamma, with a
bisection of gamma between bounds the caller gives: never the unbounded search of ``control.hinfsyn``,
which can hang (python-control issue #152). The controller (``y -> ic``, minus sign included, one sample of
delay: D = 0) is typically of the plant's order plus the weights'; :func:`reduce_controller` truncates it
by balanced truncation of its stable part (SLICOT AB09MD), its unstable part kept.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import linalg

from ambid.statespace import StateSpace, delay, series

__all__ = ["MixedSensitivityWeights", "generalized_plant", "mixed_sensitivity", "with_delay", "reduce_controller"]

_MICRO = 1e6   # displacements in micrometres inside the synthesis


@dataclass(frozen=True)
class MixedSensitivityWeights:
    """The weights of the mixed-sensitivity problem (module docstring); the same on every axis.

    Attributes
    ----------
    sensitivity_peak
        the input-sensitivity peak the design asks for, s_max [-].
    effort_a
        the controller current the noise and the roll-off weight may cost, i_e [A].
    effort_corner_hz
        where the controller must start to roll off [Hz].
    effort_rolloff
        W_e's gain far above the corner [-].
    compliance_m_per_a
        the displacement per current allowed at low frequency [m/A].
    compliance_corner_hz
        above it the compliance weight falls off [Hz].
    noise_m
        the sensors' noise std per sample, sigma [m].
    """

    sensitivity_peak: float = 2.0
    effort_a: float = 1.0
    effort_corner_hz: float = 800.0
    effort_rolloff: float = 100.0
    compliance_m_per_a: float = 50e-6
    compliance_corner_hz: float = 20.0
    noise_m: float = 0.2e-6

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"mixed-sensitivity weight {name} = {value!r} must be finite and > 0")
        if self.effort_rolloff < 1:
            raise ValueError(f"effort_rolloff = {self.effort_rolloff!r} must be >= 1 (a high-pass)")


def _first_order(num: tuple[float, float], den: tuple[float, float], dt: float) -> tuple[float, float, float, float]:
    """Tustin discretisation of (n1 s + n0) / (d1 s + d0), ``num = (n1, n0)``, ``den = (d1, d0)``: the scalar
    (a, b, c, d) of x+ = a x + b u, y = c x + d u."""
    k = 2.0 / dt
    scale = den[0] * k + den[1]
    b0, b1 = (num[0] * k + num[1]) / scale, (num[1] - num[0] * k) / scale
    a1 = (den[1] - den[0] * k) / scale
    return -a1, 1.0, b1 - b0 * a1, b0   # (b0 z + b1) / (z + a1)


def generalized_plant(plant: StateSpace, w: MixedSensitivityWeights) -> tuple[StateSpace, int, int]:
    """The discrete generalised plant of the module docstring, inputs [d; n; v], outputs [z1; z2; z3; y_m].

    Parameters
    ----------
    plant
        discrete u (na) [A] -> y (na) [m], D = 0.
    w
        the weights.

    Returns
    -------
    (P, number of control inputs, number of measurements).
    """
    if plant.dt <= 0 or np.any(plant.d):
        raise ValueError("mixed_sensitivity needs a discrete, strictly proper plant")
    dt = plant.dt
    na = plant.n_inputs
    ap, bp, cp = plant.a, plant.b, plant.c * _MICRO
    nx = ap.shape[0]
    we, wc = 2 * np.pi * w.effort_corner_hz, 2 * np.pi * w.compliance_corner_hz
    # W_e = (s / we + 1) / (s / (we rolloff) + 1): 1 at dc, rolloff far above
    a2, b2, c2, d2 = _first_order((1 / we, 1.0), (1 / (we * w.effort_rolloff), 1.0), dt)
    # W_c = g / (s / wc + 1), g in A/um
    g = 1.0 / (w.compliance_m_per_a * _MICRO)
    a3, b3, c3, d3 = _first_order((0.0, g), (1 / wc, 1.0), dt)
    eye, zero = np.eye(na), np.zeros((na, na))
    n = nx + 3 * na
    sx, sd, s2, s3 = slice(0, nx), slice(nx, nx + na), slice(nx + na, nx + 2 * na), slice(nx + 2 * na, n)
    a = np.zeros((n, n))
    a[sx, sx], a[sx, sd] = ap, bp
    a[s2, s2] = a2 * eye
    a[s3, sx], a[s3, s3] = b3 * cp, a3 * eye
    b = np.zeros((n, 3 * na))                                  # [d, n, v]
    b[sx, :na] = bp
    b[sd, 2 * na:] = eye
    b[s2, 2 * na:] = b2 * eye
    c = np.zeros((4 * na, n))
    d = np.zeros((4 * na, 3 * na))
    c[:na, sd] = eye / w.sensitivity_peak                       # z1 = u / s_max
    d[:na, :na] = eye / w.sensitivity_peak
    c[na:2 * na, s2] = c2 * eye / w.effort_a                    # z2 = W_e v / i_e
    d[na:2 * na, 2 * na:] = d2 * eye / w.effort_a
    c[2 * na:3 * na, sx], c[2 * na:3 * na, s3] = d3 * cp, c3 * eye   # z3 = W_c y
    c[3 * na:, sx] = cp                                         # y_m = y + sigma n
    d[3 * na:, na:2 * na] = w.noise_m * _MICRO * eye
    return StateSpace(a, b, c, d, dt), na, na


def _balanced(p: StateSpace) -> StateSpace:
    """``p`` in states scaled so that A's rows and columns are of like size (its entries span 20 decades:
    metres, metres per second and amperes); the controller's realisation is its own, so nothing maps back."""
    _, scale = linalg.matrix_balance(p.a, permute=False, separate=True)
    t = scale[0] if isinstance(scale, tuple) else scale
    return p._replace(a=p.a * t[None, :] / t[:, None], b=p.b / t[:, None], c=p.c * t[None, :])


def _synthesise(p: StateSpace, ncon: int, nmeas: int, gamma: float):
    """SB10DD at ``gamma``: (ak, bk, ck, dk), or None where it finds no admissible controller or only one whose
    Riccati equations are too ill conditioned to trust (a gamma just above the optimum) or whose loop is
    not stable."""
    from slycot import sb10dd   # optional dependency (ambid[control]); only the synthesis needs it
    from slycot.exceptions import SlycotArithmeticError

    n, m, np_ = p.n_states, p.n_inputs, p.n_outputs
    try:
        _, ak, bk, ck, dk, _, _, rcond = sb10dd(n, m, np_, ncon, nmeas, gamma, p.a, p.b, p.c, p.d)
    except SlycotArithmeticError as exc:
        if exc.info in (1, 2):
            raise ValueError(f"mixed_sensitivity: the problem is ill posed (SB10DD info {exc.info}: a plant "
                             "pole or zero on the unit circle the weights cannot see)") from None
        return None
    if np.min(rcond[6:]) < 1e-9:
        return None
    m1, p1 = m - ncon, np_ - nmeas
    b2, c2 = p.b[:, m1:], p.c[p1:]
    acl = np.block([[p.a + b2 @ dk @ c2, b2 @ ck], [bk @ c2, ak]])
    if np.max(np.abs(np.linalg.eigvals(acl))) >= 1.0:
        return None
    return ak, bk, ck, dk


def mixed_sensitivity(plant: StateSpace, weights: MixedSensitivityWeights, gamma_max: float = 50.0,
                      gamma_tol: float = 0.02, max_steps: int = 30, backoff: float = 1.05
                      ) -> tuple[StateSpace, float]:
    """The H-infinity mixed-sensitivity controller of ``plant`` (module docstring), gamma bisected.

    Parameters
    ----------
    plant
        discrete u (na) [A] -> y (na) [m], D = 0 (e.g. :func:`ambid.fit.model_update.physical_discrete`).
    weights
        the problem's weights.
    gamma_max
        the largest gamma tried; no controller there is a refusal.
    gamma_tol
        the bisection stops when the bracket is this narrow (relative).
    max_steps
        most synthesis calls of the bisection.
    backoff
        the controller is synthesised at this factor above the smallest gamma found.

    Returns
    -------
    (controller y (na) [m] -> v (na) [A] before the computational delay, D != 0 in general: it runs as
    :func:`with_delay`; the gamma achieved).

    Raises
    ------
    ValueError
        no controller up to ``gamma_max`` (the weights ask too much of this plant), or the
        problem is ill posed (a weight or the plant violates the synthesis' rank conditions).
    """
    from slycot.exceptions import SlycotParameterError

    p, ncon, nmeas = generalized_plant(plant, weights)
    p = _balanced(p)
    best = None
    lo, hi = 0.05, float(gamma_max)
    steps = 0
    while steps < max_steps and (best is None or hi - lo > gamma_tol * hi):
        gamma = hi if best is None else float(np.sqrt(lo * hi))   # gamma spans decades: halve its logarithm
        steps += 1
        try:
            out = _synthesise(p, ncon, nmeas, gamma)
        except SlycotParameterError as exc:
            raise ValueError(f"mixed_sensitivity: SB10DD refused the problem ({exc})") from None
        if out is None:
            if best is None:
                raise ValueError(f"mixed_sensitivity: no controller reaches gamma {gamma_max:g} with these "
                                 "weights; relax them")
            lo = gamma
            continue
        best = (out, gamma)
        hi = gamma
    # a little above the optimum: the controller there is better conditioned (its poles not pushed to
    # the edge) at a cost in the norm the bisection's tolerance already allows for
    final = _synthesise(p, ncon, nmeas, backoff * best[1]) if backoff > 1 else None
    (ak, bk, ck, dk), gamma = (final, backoff * best[1]) if final is not None else best
    # the synthesis saw micrometres: the controller takes metres
    return StateSpace(ak, bk * _MICRO, ck, dk * _MICRO, plant.dt, plant.output_names, tuple(
        "ic" + n[1:] if n.startswith("u_") else n for n in plant.input_names), plant.output_units,
        plant.input_units), gamma


def with_delay(k0: StateSpace, samples: int = 1) -> StateSpace:
    """The controller as it runs: ``k0``'s output ``samples`` samples later (D = 0 for one or more)."""
    return series(k0, delay(k0.n_outputs, samples, k0.dt))._replace(
        input_names=k0.input_names, output_names=k0.output_names, input_units=k0.input_units,
        output_units=k0.output_units)


def reduce_controller(k: StateSpace, order: int) -> StateSpace:
    """Balanced truncation of ``k``'s stable part to ``order`` states in all (its unstable part kept whole;
    SLICOT AB09MD, square root, with equilibration).

    Raises
    ------
    ValueError
        ``order`` is below the number of unstable poles.
    """
    from slycot import ab09md

    n_unstable = int(np.sum(np.abs(k.poles()) >= 1.0))
    if order < n_unstable:
        raise ValueError(f"reduce_controller: the controller has {n_unstable} unstable poles; keep at least that many")
    if order >= k.n_states:
        return k
    nr, ar, br, cr, _, _ = ab09md("D", "B", "S", k.n_states, k.n_inputs, k.n_outputs, k.a, k.b, k.c,
                                  alpha=1.0, nr=order)
    return k._replace(a=ar[:nr, :nr], b=br[:nr], c=cr[:, :nr])
