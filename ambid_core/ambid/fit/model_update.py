"""Updating the physical (chapter-2) model of the rig against a measured FRF matrix.

The updating model is the analytical model of :func:`ambid.plant.analytical.analytical_model`
with its physical parameters exposed, plus the two things a real rig adds
most often, each switched on by giving its parameters:

* magnets: ``ki_n_per_a`` [N/A], ``ks_n_per_m`` [N/m], one value for all four
  radial axes (F = ki i + ks g, eq. 2.18), optionally ``ks_b_over_a`` [-],
  bearing B's ks over bearing A's (their mean stays ks_n_per_m); an axial
  bearing (axis ``z``) has its own ``axial_ki_n_per_a``, ``axial_ks_n_per_m``;
* amplifiers: first-order current loops of ``amplifier_bandwidth_hz`` [Hz]
  (eq. 2.21), the axial one's ``axial_amplifier_bandwidth_hz``;
* sensors: gains ``sensor_gain_<axis>`` [m/m], and optionally a first-order
  low-pass ``sensor_bandwidth_hz`` [Hz] (``axial_sensor_bandwidth_hz`` the
  axial probe's, the radial one's when not given);
* the first bending mode of the rotor: its free-free frequency
  ``bending_freq_hz`` [Hz] (the modal stiffness omega^2 of the mass-normalised
  mode) and damping ratio ``bending_damping_ratio`` [-], both planes;
* an extra, unmodelled mode, taken as a support (housing or foundation)
  mode: each radial bearing stator with its sensor sits on a mass-spring-damper of
  uncoupled frequency ``support_freq_hz`` [Hz], damping ratio
  ``support_damping_ratio`` [-] and gain ``support_gain_per_kg`` = 1 / modal
  mass [1/kg]; the magnet force reacts on it and the sensor measures rotor
  minus stator (Schweitzer & Maslen, Magnetic Bearings, ch. 12);
* ``delay_s`` [s]: extra input delay (conversion, PWM update).

The FRF is taken the way the rig is measured: with ``dt_s > 0`` the exact
zero-order-hold sampled model, u[k] held over a sample and delayed by
``delay_s`` (:func:`ambid.plant.true_rig.delayed_zoh`), at z = exp(j 2 pi f dt);
with ``dt_s = 0`` the continuous model times exp(-j 2 pi f delay_s).

The axes are the rotor model's (``rotor.layout``: the rig's); a rig model
covers the four radial axes, or five with the axial bearing, and the FRF to
update against must have those channels (:func:`covers`).

States of :func:`physical_statespace`: rotor (n_r), then (with a support
mode) the radial stator displacements h (nh) [m] and velocities (nh) [m/s],
the coil control currents i (na) [A] and (with a sensor bandwidth) the
sensor filter states (na) [m].

Ki and the sensor gains enter the FRF only as their product (the force per
ampere is seen through the sensors); free either ki or the gains, not both
(:func:`ambid.fit.update_parameters` names the combination otherwise).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ambid.channels import FIVE_AXIS, bearing_of
from ambid.fit.updating import UpdateResult, update_parameters
from ambid.plant.rig import Rig
from ambid.plant.rotor_model import RotorModel
from ambid.plant.sensors import noise_std
from ambid.excitation.design import ExcitationDesign
from ambid.plant.true_rig import TruePlant, delayed_zoh, levitated_plant, true_linear_model
from ambid.statespace import StateSpace

__all__ = ["ParameterInfo", "PARAMETERS", "DEFAULT_FREE", "PhysicalUpdate", "bending_coordinates", "covers",
           "nominal_parameters", "true_parameters", "excitation_slopes", "closed_loop_noise_std", "physical_statespace",
           "physical_frf", "update_physical_model", "unmodelled_mode"]


@dataclass(frozen=True)
class ParameterInfo:
    """One updating parameter: SI unit, allowed [low, high] range, typical size, meaning."""

    unit: str
    low: float
    high: float
    typical: float
    description: str


PARAMETERS: dict[str, ParameterInfo] = {
    "ki_n_per_a": ParameterInfo("N/A", 1e-6, 1e6, 100.0, "current gain of each magnet pair"),
    "ks_n_per_m": ParameterInfo("N/m", 0.0, 1e10, 1e5, "negative stiffness of each magnet pair (mean of A and B)"),
    "ks_b_over_a": ParameterInfo("-", 0.5, 2.0, 1.0, "ks of bearing B over bearing A (an excitation stiffens "
                                 "the two bearings' magnets unequally)"),
    "amplifier_bandwidth_hz": ParameterInfo("Hz", 1.0, 1e6, 1e3, "closed current-loop bandwidth"),
    # every axis a rig model can have (the five-axis machine's); a rotor uses those of its layout
    **{f"sensor_gain_{a}": ParameterInfo("m/m", 0.01, 100.0, 1.0, f"gain of sensor {a}") for a in FIVE_AXIS.axes},
    "sensor_bandwidth_hz": ParameterInfo("Hz", 1.0, 1e7, 1e4, "first-order sensor low-pass (optional)"),
    "axial_ki_n_per_a": ParameterInfo("N/A", 1e-6, 1e6, 100.0, "current gain of the axial magnet pair"),
    "axial_ks_n_per_m": ParameterInfo("N/m", 0.0, 1e10, 1e5, "negative stiffness of the axial magnet pair"),
    "axial_amplifier_bandwidth_hz": ParameterInfo("Hz", 1.0, 1e6, 1e3, "the axial coils' current-loop bandwidth"),
    "axial_sensor_bandwidth_hz": ParameterInfo("Hz", 1.0, 1e7, 1e4, "the axial probe's first-order low-pass "
                                               "(optional; default sensor_bandwidth_hz)"),
    "bending_freq_hz": ParameterInfo("Hz", 1e-3, 1e6, 100.0, "free-free frequency of the first bending mode"),
    "bending_damping_ratio": ParameterInfo("-", 0.0, 1.0, 0.01, "damping ratio of the first bending mode"),
    "support_freq_hz": ParameterInfo("Hz", 0.1, 1e6, 100.0, "uncoupled frequency of the support mode"),
    "support_damping_ratio": ParameterInfo("-", 0.0, 1.0, 0.02, "damping ratio of the support mode"),
    "support_gain_per_kg": ParameterInfo("1/kg", 0.0, 1e3, 0.05, "1 / modal mass of the support mode"),
    "delay_s": ParameterInfo("s", -0.01, 0.01, 1e-4, "extra input delay"),
}

#: Parameters freed by default (the support ones too when the start holds them).
DEFAULT_FREE: tuple[str, ...] = ("ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz", "bending_freq_hz",
                                 "bending_damping_ratio", "delay_s", "axial_ki_n_per_a", "axial_ks_n_per_m",
                                 "axial_amplifier_bandwidth_hz")
_SUPPORT = ("support_freq_hz", "support_damping_ratio", "support_gain_per_kg")
_REQUIRED = ("ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz")
_AXIAL = ("axial_ki_n_per_a", "axial_ks_n_per_m", "axial_amplifier_bandwidth_hz")


def bending_coordinates(rotor: RotorModel) -> np.ndarray:
    """Modal coordinates (both planes) of the rotor's first bending mode, (k,) int; empty if none.

    Needs the modal layout of :func:`ambid.plant.modal.modal_state_space`
    (x = [eta, eta'], A = [[0, I], [-K, -C]] with K diagonal); an imported
    rotor of another layout has no adjustable bending mode here.
    """
    a = rotor.a
    n = a.shape[0]
    if rotor.flexible_freq_hz.size == 0 or n % 2:
        return np.zeros(0, dtype=int)
    r = n // 2
    k = -a[r:, :r]
    if not (np.allclose(a[:r, :r], 0.0) and np.allclose(a[:r, r:], np.eye(r))
            and np.allclose(k - np.diag(np.diag(k)), 0.0, atol=1e-9 * max(np.abs(k).max(), 1.0))):
        return np.zeros(0, dtype=int)
    w1 = 2 * np.pi * rotor.flexible_freq_hz[0]
    w = np.sqrt(np.maximum(np.diag(k), 0.0))
    return np.flatnonzero(np.abs(w - w1) <= 1e-6 * w1)


def covers(rotor: RotorModel, output_names: Sequence[str], input_names: Sequence[str]) -> str | None:
    """None when the physical model of ``rotor`` (its layout) has exactly the FRF's channels, in order; else
    one sentence saying why the model cannot be updated against it."""
    lay = rotor.layout
    if tuple(output_names) == lay.outputs and tuple(input_names) == lay.inputs:
        return None
    return (f"the rig model covers the axes {' '.join(lay.axes)} (outputs {', '.join(lay.outputs)}), not this FRF's "
            f"{len(output_names)} x {len(input_names)} channels ({', '.join(output_names)} / {', '.join(input_names)})")


def nominal_parameters(rig: Rig) -> dict[str, float]:
    """The analytical model's parameter values (nominal ki, ks, ideal sensors, no support mode, no delay).

    With these, :func:`physical_statespace` equals :func:`ambid.plant.analytical.analytical_model`.
    """
    p = {"ki_n_per_a": float(rig.magnet.ki), "ks_n_per_m": float(rig.magnet.ks), "ks_b_over_a": 1.0,
         "amplifier_bandwidth_hz": float(rig.current_loop_bandwidth_hz),
         **{f"sensor_gain_{a}": 1.0 for a in rig.layout.axes}, "delay_s": 0.0}
    if rig.layout.axial:
        p.update(axial_ki_n_per_a=float(rig.axial_magnet.ki), axial_ks_n_per_m=float(rig.axial_magnet.ks),
                 axial_amplifier_bandwidth_hz=float(rig.axial_amplifier.bandwidth_hz))
    rotor = rig.rotor_model()
    if bending_coordinates(rotor).size:
        p["bending_freq_hz"] = float(rotor.flexible_freq_hz[0])
        p["bending_damping_ratio"] = float(rig.modal_damping_ratio)
    return p


def true_parameters(rig: Rig) -> dict[str, float]:
    """The true (simulated) rig's values of the same parameters.

    ki, ks are the small-signal slopes of the true magnets at the levitated
    operating point (averaged over the axes, which carry the same gravity
    share): what a measured FRF determines. The centre values of the true
    magnet are under ``ki_centre_n_per_a``, ``ks_centre_n_per_m``.
    """
    _, op = levitated_plant(rig)
    v = rig.values
    p = nominal_parameters(rig)
    a_axes, b_axes, radial, axial = _bearing_axes(rig.layout)
    p.update({"ki_n_per_a": float(np.mean(op.ki_n_per_a[radial])), "ks_n_per_m": float(np.mean(op.ks_n_per_m[radial])),
              "ks_b_over_a": float(np.mean(op.ks_n_per_m[b_axes]) / np.mean(op.ks_n_per_m[a_axes])),
              **{f"sensor_gain_{a}": float(v["axial_sensor_gain" if j in axial else "sensor_gain"])
                 for j, a in enumerate(rig.layout.axes)},
              "sensor_bandwidth_hz": float(v["sensor_bandwidth_hz"]),
              "support_freq_hz": float(v["housing_freq_hz"]),
              "support_damping_ratio": float(v["housing_damping_ratio"]),
              "support_gain_per_kg": 1.0 / float(v["housing_mass_kg"]), "delay_s": float(v["extra_delay_s"]),
              "ki_centre_n_per_a": float(rig.true_magnet.ki), "ks_centre_n_per_m": float(rig.true_magnet.ks)})
    if axial:
        p.update(axial_ki_n_per_a=float(np.mean(op.ki_n_per_a[axial])),
                 axial_ks_n_per_m=float(np.mean(op.ks_n_per_m[axial])),
                 axial_sensor_bandwidth_hz=float(v["axial_sensor_bandwidth_hz"]))
    return p


def _bearing_axes(layout) -> tuple[list[int], list[int], list[int], list[int]]:
    """Indices of the axes of radial bearing A, of radial bearing B, of every radial axis, of the axial ones."""
    axial = list(layout.axial)
    radial = [j for j in range(len(layout)) if j not in axial]
    a_axes = [j for j in radial if bearing_of(layout.axes[j]) == "a"]
    b_axes = [j for j in radial if bearing_of(layout.axes[j]) == "b"]
    return a_axes, b_axes, radial, axial


def _loop_moments(rig: Rig, controller: StateSpace, design: ExcitationDesign,
                  n_noise_lines: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of [coil current, gap] per axis in the true linear closed loop under the design.

    The excitation's part from the design's line amplitudes (mean over its
    segments, sum over lines of Re(X Y*) / 2), the sensor noise's part from
    Parseval over ``n_noise_lines`` lines of the unit circle.

    Returns:
        (cov (na, 2, 2) [[A^2, A m], [A m, m^2]], the plant the moments were taken on).
    """
    p, _ = levitated_plant(rig)
    na = p.n_axes
    rows = np.vstack([p.c_y, p.c_current, p.c_gap])
    loop = true_linear_model(rig, discrete=True, plant=p, outputs=rows)
    order = [design.input_names.index(n) for n in rig.layout.inputs]

    def parts(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = loop.freqresp(f)
        s_in = np.linalg.inv(np.eye(na) - controller.freqresp(f) @ h[:, :na])      # r -> u
        return s_in, h[:, na:2 * na] @ s_in, h[:, 2 * na:3 * na] @ s_in

    f = design.freq_hz
    _, ri, rg = parts(f)
    cov = np.zeros((na, 2, 2))
    segs = [(m, e) for m in range(design.n_realisations) for e in range(design.n_experiments)]
    for m, e in segs:
        r = design.reference_spectrum(m, e)[order].T[:, :, None]                   # (L, na, 1)
        x = np.stack([(ri @ r)[:, :, 0], (rg @ r)[:, :, 0]], axis=-1)              # (L, na axes, 2)
        cov += np.einsum("lai,laj->aij", x, x.conj()).real / 2 / len(segs)
    sigma = noise_std(rig.axis_sensors())  # per sensor [m]
    if np.any(sigma > 0):
        fn = (np.arange(n_noise_lines) + 0.5) / n_noise_lines / rig.dt   # off z = 1: the integrator
        _, ni, ng = parts(fn)
        k = controller.freqresp(fn)
        xn = np.stack([ni @ k, ng @ k], axis=1)                                    # (L, 2, na axes, na noises)
        cov += _noise_weighted(np.einsum, "liaj,lkaj->aik", xn, sigma) / n_noise_lines
    return cov, p


def _noise_weighted(einsum, spec: str, x: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Re einsum(spec, x, conj x) with the last axis (the sensors) weighted by sigma^2: one factor when every
    sensor has the same noise (the radial rig), else per sensor."""
    if np.all(sigma == sigma[0]):
        return sigma[0] ** 2 * einsum(spec, x, x.conj()).real
    xs = x * sigma
    return einsum(spec, xs, xs.conj()).real


def closed_loop_noise_std(rig: Rig, controller: StateSpace, plant: TruePlant | None = None,
                          n_lines: int = 1 << 15) -> np.ndarray:
    """Standard deviation of the measured outputs' noise in the true linear closed loop [m], (na,).

    The sensors' white noise v (std ``sensor_noise_m`` per sample, ``axial_sensor_noise_m`` axially) reaches
    the outputs as y = (I - G K)^-1 v (positive feedback u = K y + r), so
    var(y_i) = sigma^2 mean over the unit circle of sum_j |S_ij|^2
    (Parseval, midpoint rule over ``n_lines`` lines of 0..fs/2: fine enough
    for the lightly damped closed-loop modes). What the period-to-period
    scatter of a periodic measurement estimates.

    Args:
        rig: the true rig.
        controller: the discrete controller y -> ic that ran (dt = rig.dt).
        plant: the affine model to linearise (default the levitated one), e.g.
            the magnets' slopes at the excitation level.

    Returns:
        (na,) std per sensor, in the rig layout's output order [m].
    """
    g = true_linear_model(rig, discrete=True, plant=plant)
    f = (np.arange(n_lines) + 0.5) / n_lines / (2 * rig.dt)
    with warnings.catch_warnings():  # the controller's integrators near z = 1 at the lowest lines: S ~ 0 there
        warnings.simplefilter("ignore", linalg.LinAlgWarning)
        k = controller.freqresp(f)
    s_out = np.linalg.inv(np.eye(g.n_outputs) - g.freqresp(f) @ k)
    sigma = noise_std(rig.axis_sensors())
    if np.all(sigma == sigma[0]):
        return float(sigma[0]) * np.sqrt((np.abs(s_out) ** 2).sum(axis=2).mean(axis=0))
    return np.sqrt((np.abs(s_out * sigma) ** 2).sum(axis=2).mean(axis=0))


def excitation_slopes(rig: Rig, controller: StateSpace, design: ExcitationDesign,
                      n_points: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """The true magnets' ki, ks per axis as a linear model measured with this excitation sees them.

    A best linear approximation of the force F(i, g) of eq. 2.14 under
    jointly Gaussian current and gap excursions is the expected slope
    (Bussgang; Price's theorem): ki = E[dF/di], ks = E[dF/dg] at the
    levitated operating point. The excursions' covariance is that of the
    true linear closed loop (``controller``, positive feedback u = K y + r)
    driven by the design and the sensor noise; the expectation is a
    Gauss-Hermite quadrature of ``n_points``^2 nodes. Since ks grows with the
    square of the current (ks (1 + i^2 / ib^2) at the centre), an excitation
    stiffens the magnets: a 0.4 A multisine raises ks by about 0.6 %, far
    more than a 16.8 s measurement's noise.

    Args:
        rig: the true rig.
        controller: the discrete controller y -> ic that ran (dt = rig.dt).
        design: the periodic excitation design that ran.

    Returns:
        (ki (na,) [N/A], ks (na,) [N/m]), in the rig layout's input order.
    """
    cov, p = _loop_moments(rig, controller, design)
    op = levitated_plant(rig)[1]
    i0, g0 = p.c_current @ op.state, op.gap_m
    x, w = np.polynomial.hermite_e.hermegauss(n_points)
    w = w / w.sum()
    zi, zg = np.meshgrid(x, x, indexing="ij")
    ww = np.outer(w, w)
    mags = rig.axis_magnets(true=True)
    ki, ks = np.zeros(len(mags)), np.zeros(len(mags))
    for a, mag in enumerate(mags):
        chol = np.linalg.cholesky(cov[a] + 1e-30 * np.eye(2))
        di = chol[0, 0] * zi
        dg = chol[1, 0] * zi + chol[1, 1] * zg
        dfdi, dfdg = mag.slopes(i0[a] + di, g0[a] + dg)
        ki[a], ks[a] = np.sum(ww * dfdi), np.sum(ww * dfdg)
    return ki, ks


def _check_params(params: Mapping[str, float]) -> dict[str, float]:
    p = {k: float(v) for k, v in params.items() if k in PARAMETERS}
    missing = [k for k in _REQUIRED if k not in p]
    if missing:
        raise ValueError(f"physical model: parameters {missing} are missing; start from nominal_parameters(rig)")
    for k, v in p.items():
        if not math.isfinite(v):
            raise ValueError(f"physical model: {k} = {v} must be finite")
    for k in ("amplifier_bandwidth_hz", "axial_amplifier_bandwidth_hz"):
        if p.get(k, 1.0) <= 0:
            raise ValueError(f"physical model: {k} must be > 0, got {p[k]}")
    if min(p.get(k, 1.0) for k in ("sensor_bandwidth_hz", "axial_sensor_bandwidth_hz", "bending_freq_hz")) <= 0:
        raise ValueError("physical model: sensor_bandwidth_hz, axial_sensor_bandwidth_hz and bending_freq_hz "
                         "must be > 0")
    support = [k for k in _SUPPORT if k in p]
    if support and len(support) != len(_SUPPORT):
        raise ValueError(f"physical model: a support mode needs all of {list(_SUPPORT)}, got {support}")
    if support and (p["support_freq_hz"] <= 0 or p["support_gain_per_kg"] < 0):
        raise ValueError("physical model: support_freq_hz must be > 0 and support_gain_per_kg >= 0")
    return p


def physical_statespace(rotor: RotorModel, params: Mapping[str, float]) -> StateSpace:
    """Continuous model u [A] -> y [m] of the parametrised rig, without the delay.

    Args:
        rotor: the rig's rotor model (``rig.rotor_model()``).
        params: parameter name -> value (:data:`PARAMETERS`); ki, ks and the
            amplifier bandwidth are required, the others optional (missing
            sensor gains are 1, a missing bending mode keeps the rotor's, no
            support or sensor-bandwidth parameters means none).

    Returns:
        StateSpace (dt = 0), the rotor layout's na inputs (u) and na outputs (y).
    """
    p = _check_params(params)
    a_r = rotor.a.copy()
    if "bending_freq_hz" in p or "bending_damping_ratio" in p:
        idx = bending_coordinates(rotor)
        if idx.size == 0:
            raise ValueError("physical model: this rotor has no adjustable bending mode (none kept, or not in "
                             "modal layout); drop bending_freq_hz and bending_damping_ratio")
        r = a_r.shape[0] // 2
        w_old = 2 * np.pi * rotor.flexible_freq_hz[0]
        w = 2 * np.pi * p.get("bending_freq_hz", rotor.flexible_freq_hz[0])
        a_r[r + idx, idx] = -w * w
        if "bending_damping_ratio" in p:
            a_r[r + idx, r + idx] = -2 * p["bending_damping_ratio"] * w
        else:  # keep the rotor's damping ratio
            a_r[r + idx, r + idx] *= w / w_old
    layout = rotor.layout
    na = len(layout)
    a_axes, b_axes, radial, axial = _bearing_axes(layout)
    if axial and not all(k in p for k in _AXIAL):
        raise ValueError(f"physical model: the rotor has an axial axis; give {', '.join(_AXIAL)} "
                         "(nominal_parameters(rig) has them)")
    gains = np.array([p.get(f"sensor_gain_{a}", 1.0) for a in layout.axes])
    has_support = "support_gain_per_kg" in p and p["support_gain_per_kg"] > 0
    has_filter = "sensor_bandwidth_hz" in p
    nr, nh = rotor.n_states, len(radial)
    blocks = [("r", nr)] + ([("h", nh), ("hv", nh)] if has_support else []) + [("i", na)] + \
        ([("s", na)] if has_filter else [])
    sl, start = {}, 0
    for name, size in blocks:
        sl[name] = slice(start, start + size)
        start += size
    n = start
    c_gap = np.zeros((na, n))
    c_gap[:, sl["r"]] = rotor.c_bearing
    c_rel = np.zeros((na, n))  # rotor minus stator at the sensor planes
    c_rel[:, sl["r"]] = rotor.c_sensor
    if has_support:  # the radial stators on their pedestals
        c_gap[radial, sl["h"]] = -np.eye(nh)
        c_rel[radial, sl["h"]] = -np.eye(nh)
    rho = p.get("ks_b_over_a", 1.0)
    ks_a = 2 * p["ks_n_per_m"] / (1 + rho)
    ks = np.full(na, ks_a)
    ks[b_axes] = rho * ks_a
    ki = np.full(na, p["ki_n_per_a"])
    bandwidth = np.full(na, p["amplifier_bandwidth_hz"])
    if axial:
        ks[axial], ki[axial] = p["axial_ks_n_per_m"], p["axial_ki_n_per_a"]
        bandwidth[axial] = p["axial_amplifier_bandwidth_hz"]
    force = ks[:, None] * c_gap
    force[:, sl["i"]] += np.diag(ki)
    a = np.zeros((n, n))
    a[sl["r"], sl["r"]] = a_r
    a[sl["r"]] += rotor.b @ force
    if has_support:
        mh = 1.0 / p["support_gain_per_kg"]
        wh = 2 * np.pi * p["support_freq_hz"]
        eye = np.eye(nh)
        a[sl["h"], sl["hv"]] = eye
        a[sl["hv"]] = -force[radial] / mh
        a[sl["hv"], sl["h"]] += -wh * wh * eye
        a[sl["hv"], sl["hv"]] += -2 * p["support_damping_ratio"] * wh * eye
    inv_tau = 1.0 / (1.0 / (2 * np.pi * bandwidth))
    a[sl["i"], sl["i"]] = -np.diag(inv_tau)
    b = np.zeros((n, na))
    b[sl["i"]] = np.diag(inv_tau)
    if has_filter:
        wc = np.full(na, 2 * np.pi * p["sensor_bandwidth_hz"])
        if axial:
            wc[axial] = 2 * np.pi * p.get("axial_sensor_bandwidth_hz", p["sensor_bandwidth_hz"])
        a[sl["s"]] = wc[:, None] * c_rel
        a[sl["s"], sl["s"]] += -np.diag(wc)
        c = np.zeros((na, n))
        c[:, sl["s"]] = np.diag(gains)
    else:
        c = gains[:, None] * c_rel
    return StateSpace(a, b, c, np.zeros((na, na)), 0.0, layout.inputs, layout.outputs, layout.units("u"),
                      layout.units("y"))


def physical_frf(rotor: RotorModel, params: Mapping[str, float], freq_hz: np.ndarray, dt_s: float) -> np.ndarray:
    """FRF of the parametrised rig as measured, (L, na, na) complex [m/A].

    Args:
        rotor: the rig's rotor model.
        params: as for :func:`physical_statespace` (``delay_s`` default 0).
        freq_hz: (L,) lines [Hz].
        dt_s: sample period [s] of the measurement: the zero-order-hold
            sampled model at z = exp(j 2 pi f dt); 0 for the continuous one.
    """
    if not (math.isfinite(dt_s) and dt_s >= 0):
        raise ValueError(f"dt_s must be >= 0 [s] (0 = continuous), got {dt_s}")
    ss = physical_statespace(rotor, params)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    d = float(params.get("delay_s", 0.0))
    if not math.isfinite(d):
        raise ValueError(f"delay_s must be finite, got {d}")
    if dt_s == 0:
        return _resolvent(ss.a, ss.b, ss.c, 2j * np.pi * f) * np.exp(-2j * np.pi * f * d)[:, None, None]
    # delay = k dt + frac, 0 <= frac < dt: z^-k times the fractional-delay ZOH model
    k = math.floor(d / dt_s)
    frac = min(max(d - k * dt_s, 0.0), dt_s)
    phi, g1, g0 = delayed_zoh(ss.a, ss.b, dt_s, frac)
    z = np.exp(2j * np.pi * f * dt_s)
    g = _resolvent(phi, np.hstack([g1, g0]), ss.c, z)
    na = ss.n_inputs
    return (g[:, :, :na] + g[:, :, na:] / z[:, None, None]) * (z ** -k)[:, None, None]


def _resolvent(a: np.ndarray, b: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """C (s I - A)^-1 B at every s (L,), (L, p, m); one batched solve (the model is evaluated
    hundreds of times in an update, a per-line loop costs 20x more)."""
    n = a.shape[0]
    m = np.empty((s.size, n, n), dtype=complex)
    m[:] = -a
    i = np.arange(n)
    m[:, i, i] += s[:, None]
    x = np.linalg.solve(m, np.broadcast_to(b.astype(complex), (s.size,) + b.shape))
    return np.einsum("pn,lnm->lpm", c, x)


@dataclass(frozen=True)
class PhysicalUpdate:
    """Updated physical parameters.

    Attributes:
        result: the :class:`ambid.fit.UpdateResult` of the free parameters
            (estimates, standard deviations, 95 % intervals, correlation).
        start: every parameter's start value.
        parameters: every parameter after the update (fixed ones as started).
        free: names of the parameters updated.
        dt_s: sample period the FRF was modelled at [s].
    """

    result: UpdateResult
    start: dict[str, float]
    parameters: dict[str, float]
    free: tuple[str, ...]
    dt_s: float

    def to_dict(self) -> dict:
        """JSON-safe: per parameter value, start, std, ci95, unit, free; plus the fit figures."""
        r = self.result
        std = dict(zip(r.names, r.std))
        ci = dict(zip(r.names, r.ci95))
        params = {name: dict(value=v, start=self.start[name], unit=PARAMETERS[name].unit, free=name in std,
                             std=float(std[name]) if name in std else None,
                             ci95=[float(c) for c in ci[name]] if name in ci else None)
                  for name, v in self.parameters.items()}
        return dict(parameters=params, chi2_per_dof=r.chi2_per_dof, dof=r.dof, success=r.success,
                    covariance_inflation=r.inflation,
                    message=r.message, n_evaluations=r.n_evaluations, correlation=r.correlation.tolist(),
                    free=list(self.free))


def update_physical_model(rotor: RotorModel, freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None,
                          start: Mapping[str, float], free: Sequence[str] | None = None, dt_s: float = 0.0,
                          max_evaluations: int = 300, covariance: str = "sandwich",
                          row_covariance: np.ndarray | None = None,
                          realisations: np.ndarray | None = None) -> PhysicalUpdate:
    """Fit the free physical parameters to a measured FRF (weighted least squares, CIs from the Jacobian).

    Args:
        rotor: the rig's rotor model.
        freq_hz: (L,) lines [Hz].
        G: (L, na, na) measured FRF u -> y [m/A], the rotor layout's channels (:func:`covers`).
        var: (L, na, na) variance of G [(m/A)^2], or None (equal weights).
        start: start values of every parameter of the model (e.g.
            :func:`nominal_parameters` with changes); fixed ones stay.
        free: parameters to update; default :data:`DEFAULT_FREE` (those in
            ``start``) plus the support ones when ``start`` has them.
        dt_s: sample period of the measurement [s] (0: continuous model).
        max_evaluations: most model evaluations of the optimiser.
        covariance: ``"sandwich"`` (default), ``"jacobian"`` or ``"rows"``
            (:func:`ambid.fit.update_parameters`); ``row_covariance`` given
            selects ``"rows"``.
        row_covariance: (L, na, na, na) covariance of the entries of each row of G
            (:func:`ambid.frf.uncertainty.row_covariance`).
        realisations: (M, L, na, na) the realisations' FRFs (their scatter may widen the intervals).

    Returns:
        :class:`PhysicalUpdate`.
    """
    st = _check_params(start)
    unknown = sorted(set(start) - set(PARAMETERS))
    if unknown:
        raise ValueError(f"update_physical_model: unknown parameters {unknown}; known: {list(PARAMETERS)}")
    if free is None:
        free = [k for k in DEFAULT_FREE + _SUPPORT if k in st]
    free = tuple(free)
    bad = [k for k in free if k not in st]
    if bad:
        raise ValueError(f"update_physical_model: free parameters {bad} have no start value; add them to start")
    if len(set(free)) != len(free) or not free:
        raise ValueError(f"update_physical_model: free must name distinct parameters, got {list(free)}")
    for k in free:
        info = PARAMETERS[k]
        if not info.low <= st[k] <= info.high:
            raise ValueError(f"update_physical_model: start {k} = {st[k]} is outside [{info.low:g}, {info.high:g}] "
                             f"{info.unit}")
    g = np.asarray(G)
    lay = rotor.layout
    if g.ndim != 3 or g.shape[1:] != (len(lay), len(lay)):
        raise ValueError(f"G must be (L, {len(lay)}, {len(lay)}) (outputs {list(lay.outputs)}, inputs "
                         f"{list(lay.inputs)}), got {g.shape}")
    f = np.asarray(freq_hz, dtype=float)

    def model(theta: np.ndarray) -> np.ndarray:
        p = dict(st)
        p.update(zip(free, theta))
        return physical_frf(rotor, p, f, dt_s)

    theta0 = np.array([st[k] for k in free])
    scales = np.array([abs(st[k]) if st[k] != 0 else (dt_s or PARAMETERS[k].typical) for k in free])
    lower = [PARAMETERS[k].low for k in free]
    upper = [PARAMETERS[k].high for k in free]
    # sandwich: in closed loop the entries of a line share their noise, and the model may miss some of the data
    res = update_parameters(model, theta0, f, g, var, names=free, scales=scales, bounds=(lower, upper),
                            covariance="rows" if row_covariance is not None else covariance,
                            row_covariance=row_covariance, realisations=realisations,
                            max_evaluations=max_evaluations)
    final = dict(st)
    final.update(zip(free, (float(v) for v in res.theta)))
    return PhysicalUpdate(result=res, start=st, parameters=final, free=free, dt_s=float(dt_s))


def unmodelled_mode(mode_freq_hz: np.ndarray, mode_damping: np.ndarray, mode_strength: np.ndarray,
                    nominal: StateSpace, band_hz: tuple[float, float], tol: float = 0.05) -> tuple[float, float] | None:
    """The strongest fitted mode the nominal model lacks: a start for the support mode.

    A fitted mode (in the band, damping in (0, 0.3)) is unmodelled when no
    lightly damped pole pair of the nominal model lies within ``tol``
    (relative) of its frequency.

    Args:
        mode_freq_hz, mode_damping, mode_strength: (K,) fitted modes'
            natural frequency [Hz], damping ratio [-] and a size measure
            (e.g. the largest residue singular value divided by the damping).
        nominal: the nominal continuous model.
        band_hz: (low, high) band of the data [Hz].
        tol: relative frequency distance that counts as the same mode.

    Returns:
        (frequency [Hz], damping ratio [-]) of that mode, or None.
    """
    fm, zm, sm = (np.asarray(x, dtype=float).ravel() for x in (mode_freq_hz, mode_damping, mode_strength))
    if not (fm.shape == zm.shape == sm.shape):
        raise ValueError("mode_freq_hz, mode_damping and mode_strength must have the same length")
    p = nominal.poles()
    p = p[(p.imag > 0) & (-p.real < 0.3 * np.abs(p))]
    f_nom = np.abs(p) / (2 * np.pi)
    best = None
    for f, z, s in zip(fm, zm, sm):
        if not (band_hz[0] <= f <= band_hz[1] and 0 < z < 0.3):
            continue
        if f_nom.size and np.min(np.abs(f_nom - f)) <= tol * f:
            continue
        if best is None or s > best[2]:
            best = (float(f), float(z), float(s))
    return None if best is None else best[:2]
