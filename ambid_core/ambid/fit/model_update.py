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
* the bending modes of the rotor: the first one's free-free frequency
  ``bending_freq_hz`` [Hz] (the modal stiffness omega^2 of the mass-normalised
  mode) and damping ratio ``bending_damping_ratio`` [-], both planes; mode k >= 2
  as ``bending_<k>_freq_hz``, ``bending_<k>_damping_ratio``;
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

Priors (:func:`parameter_prior`): each parameter's nominal value
(:func:`nominal_update_parameters`) and the rig's tolerance of it
(:mod:`ambid.plant.tolerances`) make a normal prior; the update is their
maximum a posteriori estimate. It starts from the data (:func:`start_from_data`:
the bending modes at the fitted modes, ki and ks fitted to the FRF with the
rest held, the lags moved by the phase's slope), not from the nominal values.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import linalg, special  # not scipy.stats: ~0.6 s to import

from ambid.channels import FIVE_AXIS, RADIAL, Layout, bearing_of
from ambid.fit.updating import Prior, UpdateResult, update_parameters
from ambid.plant.rig import Rig
from ambid.plant.tolerances import Z95, tolerance_for
from ambid.plant.rotor_model import RotorModel
from ambid.plant.sensors import noise_std
from ambid.excitation.design import ExcitationDesign
from ambid.plant.true_rig import TruePlant, delayed_zoh, levitated_plant, true_linear_model
from ambid.statespace import StateSpace

__all__ = ["ParameterInfo", "PARAMETERS", "DEFAULT_FREE", "PhysicalUpdate", "bending_coordinates", "bending_keys",
           "covers", "nominal_parameters", "nominal_update_parameters", "rig_values_for", "parameter_prior",
           "true_parameters",
           "excitation_slopes", "slopes_as_parameters", "closed_loop_noise_std", "physical_statespace", "physical_frf",
           "physical_discrete",
           "update_physical_model",
           "match_modes", "start_from_data", "total_lag", "unmodelled_mode"]


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
    **{f"bending_{k}_{q}": ParameterInfo(*info[:4], f"{info[4]} (bending mode {k})")
       for k in range(2, 9) for q, info in (("freq_hz", ("Hz", 1e-3, 1e6, 100.0, "free-free frequency")),
                                            ("damping_ratio", ("-", 0.0, 1.0, 0.01, "damping ratio")))},
}

#: Parameters freed by default (the support ones too when the start holds them).
DEFAULT_FREE: tuple[str, ...] = ("ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz", "bending_freq_hz",
                                 "bending_damping_ratio", "delay_s", "axial_ki_n_per_a", "axial_ks_n_per_m",
                                 "axial_amplifier_bandwidth_hz")
_SUPPORT = ("support_freq_hz", "support_damping_ratio", "support_gain_per_kg")
_REQUIRED = ("ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz")
_AXIAL = ("axial_ki_n_per_a", "axial_ks_n_per_m", "axial_amplifier_bandwidth_hz")


def bending_keys(mode: int) -> tuple[str, str]:
    """The frequency and damping parameter names of bending mode ``mode`` (1: the first)."""
    return ("bending_freq_hz", "bending_damping_ratio") if mode == 1 else \
        (f"bending_{mode}_freq_hz", f"bending_{mode}_damping_ratio")


def bending_coordinates(rotor: RotorModel, mode: int = 1) -> np.ndarray:
    """Modal coordinates (both planes) of the rotor's bending mode ``mode`` (1: the first), (k,) int; empty
    if none.

    Needs the modal layout of :func:`ambid.plant.modal.modal_state_space`
    (x = [eta, eta'], A = [[0, I], [-K, -C]] with K diagonal); an imported
    rotor of another layout has no adjustable bending mode here.
    """
    a = rotor.a
    n = a.shape[0]
    if rotor.flexible_freq_hz.size < mode or mode < 1 or n % 2:
        return np.zeros(0, dtype=int)
    r = n // 2
    k = -a[r:, :r]
    if not (np.allclose(a[:r, :r], 0.0) and np.allclose(a[:r, r:], np.eye(r))
            and np.allclose(k - np.diag(np.diag(k)), 0.0, atol=1e-9 * max(np.abs(k).max(), 1.0))):
        return np.zeros(0, dtype=int)
    w1 = 2 * np.pi * rotor.flexible_freq_hz[mode - 1]
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


def rig_channels(rotor: RotorModel, output_names: Sequence[str], input_names: Sequence[str]
                 ) -> tuple[list[int], list[int], list[str]] | None:
    """Where the rig model's channels are in an FRF that holds them all (and perhaps more: accelerometers,
    probes along the shaft): (rows, columns) in the model's order, and the FRF's channels it leaves out; None
    when the FRF lacks one of the model's channels."""
    lay = rotor.layout
    outs, ins = list(output_names), list(input_names)
    if not (set(lay.outputs) <= set(outs) and set(lay.inputs) <= set(ins)):
        return None
    rows, cols = [outs.index(n) for n in lay.outputs], [ins.index(n) for n in lay.inputs]
    left = [n for n in outs if n not in lay.outputs] + [n for n in ins if n not in lay.inputs]
    return rows, cols, left


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
    for k in range(1, rotor.flexible_freq_hz.size + 1):
        if bending_coordinates(rotor, k).size:
            fk, zk = bending_keys(k)
            p[fk] = float(rotor.flexible_freq_hz[k - 1])
            p[zk] = float(rig.modal_damping_ratio)
    return p


def nominal_update_parameters(rig: Rig) -> dict[str, float]:
    """Every updating parameter's nominal value, the centre of its prior: the analytical model's
    (:func:`nominal_parameters`) with the data sheet's sensor bandwidth and delay (``sensor_bandwidth_hz``,
    ``extra_delay_s`` of the rig)."""
    p = nominal_parameters(rig)
    p.update(sensor_bandwidth_hz=float(rig.values["sensor_bandwidth_hz"]),
             delay_s=float(rig.values["extra_delay_s"]))
    if rig.layout.axial:
        p["axial_sensor_bandwidth_hz"] = float(rig.values["axial_sensor_bandwidth_hz"])
    return p


def rig_values_for(rig: Rig, targets: Mapping[str, float]) -> dict[str, float]:
    """The rig-file values that move ``rig``'s nominal updating parameters (:func:`nominal_update_parameters`)
    to ``targets``: ki and ks through the air gap and pole area, the amplifier bandwidth through the dc link
    voltage, the sensor bandwidth, the bending modes through Young's modulus, the modal damping and the extra
    delay; a parameter ``targets`` does not name keeps its value.

    Parameters
    ----------
    rig
        the rig.
    targets
        updating parameter name -> value (e.g. an update's estimates, or a nominal value drawn from the
        tolerances).

    Returns
    -------
    name -> value of the rig fields that change (``{**rig.values, **returned}`` is the moved rig).

    Examples
    --------
    >>> from dataclasses import replace
    >>> from ambid.plant.rig import make_rig
    >>> rig = make_rig()
    >>> ki = nominal_update_parameters(rig)["ki_n_per_a"]
    >>> moved = replace(rig, values={**rig.values, **rig_values_for(rig, {"ki_n_per_a": 1.02 * ki})})
    >>> round(nominal_update_parameters(moved)["ki_n_per_a"] / ki, 6)
    1.02
    """
    v, nom = rig.values, nominal_update_parameters(rig)

    def factor(name: str) -> float:
        return float(targets[name]) / nom[name] if name in targets and name in nom else 1.0

    f_ki, f_ks = factor("ki_n_per_a"), factor("ks_n_per_m")
    gap = f_ki / f_ks                                   # ki ~ A / s0^2, ks ~ A / s0^3, L ~ A / s0
    over = dict(air_gap_m=v["air_gap_m"] * gap, pole_area_m2=v["pole_area_m2"] * f_ki * gap**2,
                dc_link_voltage_v=v["dc_link_voltage_v"] * factor("amplifier_bandwidth_hz") * f_ki * gap)
    if "sensor_bandwidth_hz" in targets:
        over["sensor_bandwidth_hz"] = max(float(targets["sensor_bandwidth_hz"]), 10.0)
    if "bending_freq_hz" in nom:
        over["youngs_modulus_pa"] = v["youngs_modulus_pa"] * factor("bending_freq_hz") ** 2
        if "bending_damping_ratio" in targets:
            over["modal_damping_ratio"] = min(float(targets["bending_damping_ratio"]), 0.2)
    if "delay_s" in targets:
        over["extra_delay_s"] = float(min(max(float(targets["delay_s"]), 0.0), rig.dt))
    return {k: float(x) for k, x in over.items()}


def parameter_prior(rig: Rig, names: Sequence[str], centre: Mapping[str, float]) -> tuple[Prior, tuple[str, ...]]:
    """The normal prior of each parameter in ``names`` from the rig's tolerances.

    Parameters
    ----------
    rig
        the nominal rig (its ``tolerances``, else the defaults of :mod:`ambid.plant.tolerances`).
    names
        the updated parameters.
    centre
        each one's nominal value (a range tolerance replaces it by its middle).

    Returns
    -------
    (prior, fixed): the :class:`ambid.fit.updating.Prior` over ``names`` (a parameter without a
    tolerance gets none: flat), and the names whose tolerance is ``fixed``.
    """
    mean, sd, log, fixed = [], [], [], []
    for name in names:
        tol = tolerance_for(name, rig.tolerances)
        if tol is None:
            mean.append(float(centre[name]))
            sd.append(np.inf)
            log.append(False)
            continue
        m, s, lg = tol.centre_and_sd(float(centre[name]), rig.dt)
        if s == 0:
            fixed.append(name)
        mean.append(m)
        sd.append(s if s > 0 else np.inf)
        log.append(lg)
    return Prior(np.array(mean), np.array(sd), np.array(log, dtype=bool)), tuple(fixed)


def total_lag(params: Mapping[str, float]) -> float:
    """The input-to-output lag the data tell best [s]: 1 / (2 pi f_amp) + 1 / (2 pi f_sens) + delay
    (each first-order lag's group delay at low frequency; a missing sensor bandwidth adds none)."""
    lag = 1.0 / (2 * np.pi * params["amplifier_bandwidth_hz"]) + float(params.get("delay_s", 0.0))
    if "sensor_bandwidth_hz" in params:
        lag += 1.0 / (2 * np.pi * params["sensor_bandwidth_hz"])
    return float(lag)


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

    Returns
    -------
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


def closed_loop_noise_std(rig: Rig, controller: StateSpace, plant: TruePlant | None = None) -> np.ndarray:
    """Standard deviation of the measured outputs' noise in the true linear closed loop [m], (na,).

    The sensors' white noise v (std ``sensor_noise_m`` per sample, ``axial_sensor_noise_m`` axially,
    Sigma = diag(sigma^2)) reaches the outputs as y = (I - G K)^-1 v (positive feedback u = K y + r): with
    the loop's states x (plant, then controller), x[k+1] = A_cl x[k] + B_v v[k]
    and y = C x + v, so var(y) = diag(C P C^T + Sigma) with P the state
    covariance, P = A_cl P A_cl^T + B_v Sigma B_v^T (the discrete Lyapunov
    equation: exact, and milliseconds where a Parseval sum over the unit
    circle fine enough for the lightly damped modes took seconds). What the
    period-to-period scatter of a periodic measurement estimates.

    Parameters
    ----------
    rig
        the true rig.
    controller
        the discrete controller y -> ic that ran (dt = rig.dt).
    plant
        the affine model to linearise (default the levitated one), e.g.
        the magnets' slopes at the excitation level.

    Returns
    -------
    (na,) std per sensor, in the rig layout's output order [m].
    """
    g = true_linear_model(rig, discrete=True, plant=plant)
    k = controller
    acl = np.block([[g.a + g.b @ k.d @ g.c, g.b @ k.c], [k.b @ g.c, k.a]])
    bv = np.vstack([g.b @ k.d, k.b])
    c = np.hstack([g.c, np.zeros((g.c.shape[0], k.a.shape[0]))])
    sigma = noise_std(rig.axis_sensors())
    if np.all(sigma == sigma[0]):   # one noise level (the radial rig): sigma times the unit-noise loop's
        p = linalg.solve_discrete_lyapunov(acl, bv @ bv.T)
        return float(sigma[0]) * np.sqrt(np.diag(c @ p @ c.T) + 1.0)
    p = linalg.solve_discrete_lyapunov(acl, (bv * sigma**2) @ bv.T)
    return np.sqrt(np.diag(c @ p @ c.T) + sigma**2)


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

    Parameters
    ----------
    rig, controller
        as :func:`closed_loop_noise_std`'s.
    design
        the periodic excitation design that ran.

    Returns
    -------
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


def slopes_as_parameters(ki: np.ndarray, ks: np.ndarray, layout: Layout = RADIAL) -> dict[str, float]:
    """The magnets' slopes per axis (:func:`excitation_slopes`) as the updating model's parameters.

    Parameters
    ----------
    ki
        (na,) [N/A], ks: (na,) [N/m], in ``layout``'s axis order (the rig's; default the four radial axes).
    layout
        the axes the slopes belong to.

    Returns
    -------
    ``ki_n_per_a`` and ``ks_n_per_m`` (means over the radial axes) and ``ks_b_over_a`` (bearing B's ks over
    A's); with an axial axis also ``axial_ki_n_per_a`` and ``axial_ks_n_per_m``.
    """
    ki, ks = np.asarray(ki, dtype=float), np.asarray(ks, dtype=float)
    axial = list(layout.axial)
    radial = [j for j in range(len(layout)) if j not in axial]
    a_axes = [j for j in radial if bearing_of(layout.axes[j]) == "a"]
    b_axes = [j for j in radial if bearing_of(layout.axes[j]) == "b"]
    out = dict(ki_n_per_a=float(np.mean(ki[radial])), ks_n_per_m=float(np.mean(ks[radial])),
               ks_b_over_a=float(np.mean(ks[b_axes]) / np.mean(ks[a_axes])))
    if axial:
        out.update(axial_ki_n_per_a=float(np.mean(ki[axial])), axial_ks_n_per_m=float(np.mean(ks[axial])))
    return out


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
    if (min(p.get(k, 1.0) for k in ("sensor_bandwidth_hz", "axial_sensor_bandwidth_hz")) <= 0
            or any(v <= 0 for k, v in p.items() if k.endswith("freq_hz"))):
        raise ValueError("physical model: sensor_bandwidth_hz, axial_sensor_bandwidth_hz and the mode frequencies "
                         "must be > 0")
    support = [k for k in _SUPPORT if k in p]
    if support and len(support) != len(_SUPPORT):
        raise ValueError(f"physical model: a support mode needs all of {list(_SUPPORT)}, got {support}")
    if support and (p["support_freq_hz"] <= 0 or p["support_gain_per_kg"] < 0):
        raise ValueError("physical model: support_freq_hz must be > 0 and support_gain_per_kg >= 0")
    return p


def physical_statespace(rotor: RotorModel, params: Mapping[str, float]) -> StateSpace:
    """Continuous model u [A] -> y [m] of the parametrised rig, without the delay.

    Parameters
    ----------
    rotor
        the rig's rotor model (``rig.rotor_model()``).
    params
        parameter name -> value (:data:`PARAMETERS`); ki, ks and the
        amplifier bandwidth are required, the others optional (missing
        sensor gains are 1, a missing bending mode keeps the rotor's, no
        support or sensor-bandwidth parameters means none).

    Returns
    -------
    StateSpace (dt = 0), the rotor layout's na inputs (u) and na outputs (y).
    """
    p = _check_params(params)
    a_r = rotor.a.copy()
    r = a_r.shape[0] // 2
    for mode in range(1, 9):
        fk, zk = bending_keys(mode)
        if fk not in p and zk not in p:
            continue
        idx = bending_coordinates(rotor, mode)
        if idx.size == 0:
            raise ValueError(f"physical model: this rotor has no adjustable bending mode {mode} (not kept, or not "
                             f"in modal layout); drop {fk} and {zk}")
        w_old = 2 * np.pi * rotor.flexible_freq_hz[mode - 1]
        w = 2 * np.pi * p.get(fk, rotor.flexible_freq_hz[mode - 1])
        a_r[r + idx, idx] = -w * w
        if zk in p:
            a_r[r + idx, r + idx] = -2 * p[zk] * w
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

    Parameters
    ----------
    rotor
        the rig's rotor model.
    params
        as for :func:`physical_statespace` (``delay_s`` default 0).
    freq_hz
        (L,) lines [Hz].
    dt_s
        sample period [s] of the measurement: the zero-order-hold
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


def physical_discrete(rotor: RotorModel, params: Mapping[str, float], dt_s: float) -> StateSpace:
    """The parametrised rig as a discrete state space at ``dt_s``, the delay exact (zero-order hold,
    ``delay_s`` >= 0 as whole samples of shift register plus the fraction :func:`delayed_zoh` holds): what a
    controller at that rate closes its loop around. Its FRF is :func:`physical_frf`'s.

    Returns
    -------
    StateSpace (dt = dt_s), 4 inputs, 4 outputs, D = 0; states: the continuous model's, then u[k-1] ... (4 each).
    """
    if not (math.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be > 0 [s], got {dt_s}")
    ss = physical_statespace(rotor, params)
    d = max(float(params.get("delay_s", 0.0)), 0.0)
    m = math.floor(d / dt_s)
    phi, g1, g0 = delayed_zoh(ss.a, ss.b, dt_s, min(max(d - m * dt_s, 0.0), dt_s))
    n, nu = ss.a.shape[0], ss.b.shape[1]
    nb = m + 1                                     # buffers u[k-1] ... u[k-m-1]
    a = np.zeros((n + nb * nu, n + nb * nu))
    b = np.zeros((n + nb * nu, nu))
    a[:n, :n] = phi
    buf = [slice(n + j * nu, n + (j + 1) * nu) for j in range(nb)]
    if m == 0:
        b[:n] = g1
    else:
        a[:n, buf[m - 1]] = g1
    a[:n, buf[m]] = g0
    b[buf[0]] = np.eye(nu)
    for j in range(1, nb):
        a[buf[j], buf[j - 1]] = np.eye(nu)
    c = np.hstack([ss.c, np.zeros((ss.c.shape[0], nb * nu))])
    return StateSpace(a, b, c, np.zeros((ss.c.shape[0], nu)), dt_s, ss.input_names, ss.output_names,
                      ss.input_units, ss.output_units)


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

    Attributes
    ----------
    result
        the :class:`ambid.fit.UpdateResult` of the free parameters
        (estimates, standard deviations, 95 % intervals, correlation).
    start
        every parameter's start value.
    parameters
        every parameter after the update (fixed ones as started).
    free
        names of the parameters updated.
    dt_s
        sample period the FRF was modelled at [s].
    prior
        the free parameters' prior (:class:`ambid.fit.updating.Prior`), or None.
    """

    result: UpdateResult
    start: dict[str, float]
    parameters: dict[str, float]
    free: tuple[str, ...]
    dt_s: float
    prior: Prior | None = None

    def total_lag(self) -> dict | None:
        """The total lag (:func:`total_lag`) with its std and 95 % interval, or None unless the amplifier
        bandwidth is free. Its parts trade the phase between them (strongly correlated); their sum is what
        the data tell."""
        r = self.result
        idx = {n: k for k, n in enumerate(r.names)}
        if "amplifier_bandwidth_hz" not in idx:
            return None
        grad = np.zeros(len(r.names))
        for name, d in (("amplifier_bandwidth_hz", -1.0 / (2 * np.pi * self.parameters["amplifier_bandwidth_hz"] ** 2)),
                        ("sensor_bandwidth_hz", -1.0 / (2 * np.pi * self.parameters.get("sensor_bandwidth_hz", 1.0) ** 2)),
                        ("delay_s", 1.0)):
            if name in idx:
                grad[idx[name]] = d
        var = float(grad @ r.covariance @ grad)
        contrib = grad**2 * np.diag(r.covariance)
        dof = r.variance_dof if r.variance_dof is not None else np.full(grad.size, np.inf)
        used = contrib > 0
        with np.errstate(divide="ignore"):
            nu = float(np.sum(contrib[used]) ** 2 / np.sum(contrib[used] ** 2 / dof[used])) if used.any() else np.inf
        value = total_lag(self.parameters)
        half = float(special.stdtrit(nu, 0.975)) * np.sqrt(var)
        return dict(value=value, std=float(np.sqrt(var)), ci95=[value - half, value + half], unit="s",
                    parts=[n for n in ("amplifier_bandwidth_hz", "sensor_bandwidth_hz", "delay_s") if n in idx])

    def to_dict(self) -> dict:
        """JSON-safe: per parameter value, start, std, ci95, unit, free, its prior (mean, 95 % interval,
        posterior/prior width) and whether the prior dominates it; the total lag; the fit figures."""
        r = self.result
        std = dict(zip(r.names, r.std))
        ci = dict(zip(r.names, r.ci95))
        ratio = dict(zip(r.names, r.prior_ratio if r.prior_ratio is not None else [np.nan] * len(r.names)))
        priors = {}
        if self.prior is not None:
            for k, name in enumerate(r.names):
                m, sd, lg = float(self.prior.mean[k]), float(self.prior.std[k]), bool(self.prior.log[k])
                if np.isfinite(sd):
                    lo, hi = (m * np.exp(-Z95 * sd), m * np.exp(Z95 * sd)) if lg else (m - Z95 * sd, m + Z95 * sd)
                    priors[name] = dict(mean=m, ci95=[float(lo), float(hi)], log=lg)
        params = {}
        for name, v in self.parameters.items():
            row = dict(value=v, start=self.start[name], unit=PARAMETERS[name].unit, free=name in std,
                       std=float(std[name]) if name in std else None,
                       ci95=[float(c) for c in ci[name]] if name in ci else None)
            if name in priors:
                rr = float(ratio[name])
                # posterior / prior width above 1/sqrt(2): the prior holds more information than the data
                row.update(prior=priors[name], prior_ratio=rr, prior_dominated=bool(rr > 1 / np.sqrt(2)))
            params[name] = row
        return dict(parameters=params, chi2_per_dof=r.chi2_per_dof, dof=r.dof, success=r.success,
                    covariance_inflation=r.inflation, total_lag=self.total_lag(),
                    prior_dominated=[n for n in r.names if params[n].get("prior_dominated")],
                    message=r.message, n_evaluations=r.n_evaluations, correlation=r.correlation.tolist(),
                    free=list(self.free))


def _bounds(free: Sequence[str]) -> tuple[list[float], list[float]]:
    return [PARAMETERS[k].low for k in free], [PARAMETERS[k].high for k in free]


def _scales(free: Sequence[str], start: Mapping[str, float], dt_s: float) -> np.ndarray:
    return np.array([abs(start[k]) if start[k] != 0 else (dt_s or PARAMETERS[k].typical) for k in free])


def update_physical_model(rotor: RotorModel, freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None,
                          start: Mapping[str, float], free: Sequence[str] | None = None, dt_s: float = 0.0,
                          max_evaluations: int = 300, covariance: str = "sandwich",
                          row_covariance: np.ndarray | None = None,
                          realisations: np.ndarray | None = None, prior: Prior | None = None,
                          covariance_only: bool = False) -> PhysicalUpdate:
    """Fit the free physical parameters to a measured FRF (MAP with ``prior``; intervals from the posterior).

    Parameters
    ----------
    rotor
        the rig's rotor model.
    freq_hz
        (L,) lines [Hz].
    G
        (L, na, na) measured FRF u -> y [m/A], the rotor layout's channels (:func:`covers`).
    var
        (L, na, na) variance of G [(m/A)^2], or None (equal weights).
    start
        start values of every parameter of the model (e.g.
        :func:`nominal_parameters` with changes); fixed ones stay.
    free
        parameters to update; default :data:`DEFAULT_FREE` (those in
        ``start``) plus the support ones when ``start`` has them.
    dt_s
        sample period of the measurement [s] (0: continuous model).
    max_evaluations
        most model evaluations of the optimiser.
    covariance
        ``"sandwich"`` (default), ``"jacobian"`` or ``"rows"``
        (:func:`ambid.fit.update_parameters`); ``row_covariance`` given
        selects ``"rows"``.
    row_covariance
        (L, na, na, na) covariance of the entries of each row of G
        (:func:`ambid.frf.uncertainty.row_covariance`).
    realisations
        (M, L, na, na) the realisations' FRFs (their scatter may widen the intervals).
    prior
        normal priors of the ``free`` parameters (:func:`parameter_prior`), or None.
    covariance_only
        keep ``start`` and give its covariance only.

    Returns
    -------
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
    # sandwich: in closed loop the entries of a line share their noise, and the model may miss some of the data
    res = update_parameters(model, theta0, f, g, var, names=free, scales=_scales(free, st, dt_s), bounds=_bounds(free),
                            prior=prior, covariance="rows" if row_covariance is not None else covariance,
                            row_covariance=row_covariance, realisations=realisations,
                            max_evaluations=max_evaluations, covariance_only=covariance_only)
    final = dict(st)
    final.update(zip(free, (float(v) for v in res.theta)))
    return PhysicalUpdate(result=res, start=st, parameters=final, free=free, dt_s=float(dt_s), prior=prior)


def _prior_of(prior: Prior | None, free: Sequence[str], names: Sequence[str]) -> Prior | None:
    """The prior of ``names`` (a subset of ``free``)."""
    if prior is None:
        return None
    k = [list(free).index(n) for n in names]
    return Prior(prior.mean[k], prior.std[k], prior.log[k])


def _lightly_damped_poles(ss: StateSpace) -> tuple[np.ndarray, np.ndarray]:
    p = ss.poles()
    p = p[(p.imag > 0) & (np.abs(p.real) < 0.3 * np.abs(p))]
    return np.abs(p) / (2 * np.pi), -p.real / np.abs(p)


def _sd_of(prior: Prior | None, free: Sequence[str]) -> dict[str, tuple[float, bool]]:
    """name -> (prior std, log) of the parameters with a prior."""
    if prior is None:
        return {}
    return {name: (float(prior.std[k]), bool(prior.log[k])) for k, name in enumerate(free)
            if np.isfinite(prior.std[k])}


def match_modes(rotor: RotorModel, nominal: Mapping[str, float], free: Sequence[str], prior: Prior | None,
                modes: Sequence[tuple[float, float]]) -> tuple[dict[str, float], list[int], list[str]]:
    """Start values of the free bending modes from the fitted modes.

    Each bending mode's frequency and damping start at the fitted mode
    nearest the nominal model's pole of it (within 3 prior standard
    deviations of its frequency, at least 2 %): the nominal value times the
    ratio of the fitted mode's to the nominal model's pole's.

    Parameters
    ----------
    rotor
        the rig's rotor model.
    nominal
        every parameter's nominal value.
    free
        the parameters to be updated (with their bending modes).
    prior
        their prior, or None (then +-5 % windows).
    modes
        fitted modes (frequency [Hz], damping ratio [-]).

    Returns
    -------
    (start values of the bending parameters, indices of the fitted modes used, notes).
    """
    sds = _sd_of(prior, free)
    fm = np.array([m[0] for m in modes], dtype=float)
    zm = np.array([m[1] for m in modes], dtype=float)
    ok = (zm > 0) & (zm < 0.3)
    out: dict[str, float] = {}
    used: list[int] = []
    notes: list[str] = []
    f_pole, z_pole = _lightly_damped_poles(physical_statespace(rotor, nominal))
    for mode in range(1, 9):
        fk, zk = bending_keys(mode)
        if fk not in free or f_pole.size == 0:
            continue
        j = int(np.argmin(np.abs(f_pole - nominal[fk])))
        sd, lg = sds.get(fk, (0.05 * nominal[fk], False))
        window = max(3 * (sd if lg else sd / nominal[fk]), 0.02) * f_pole[j]
        near = np.flatnonzero(ok & (np.abs(fm - f_pole[j]) <= window))
        near = near[~np.isin(near, used)]
        if near.size == 0:
            notes.append(f"bending mode {mode}: no fitted mode within {window:.3g} Hz of the nominal model's "
                         f"{f_pole[j]:.4g} Hz; its update starts at the nominal values")
            continue
        i = int(near[np.argmin(np.abs(fm[near] - f_pole[j]))])
        used.append(i)
        out[fk] = float(nominal[fk] * fm[i] / f_pole[j])
        if zk in free and z_pole[j] > 0:
            out[zk] = float(np.clip(nominal[zk] * zm[i] / z_pole[j], 1e-5, 0.5))
    return out, used, notes


def start_from_data(rotor: RotorModel, freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None,
                    start: Mapping[str, float], free: Sequence[str], prior: Prior | None,
                    dt_s: float) -> dict[str, float]:
    """Start values of the gains and lags from the FRF, the modes already placed (:func:`match_modes`).

    1. ki, ks (and ks_b_over_a) fitted to the FRF with everything else held
       (a small, well-posed problem: the FRF's level and its unstable poles).
    2. The lags from the phase: the weighted slope of the phase between the
       data and that model over frequency is the total lag's error; it is
       shared among the free lags (amplifier, sensor, delay) in proportion to
       their prior variances (the MAP split of one known sum).

    Parameters
    ----------
    rotor
        the rig's rotor model.
    freq_hz, G, var
        the FRF (L,), (L, ny, nu) and its variance (or None).
    start
        every parameter's value so far (the prior's centres, the modes from the data).
    free
        the parameters to be updated.
    prior
        their prior, or None.
    dt_s
        sample period [s] (0: continuous).

    Returns
    -------
    Start values of every parameter.
    """
    out = dict(start)
    free = list(free)
    sds = _sd_of(prior, free)
    f = np.asarray(freq_hz, dtype=float)
    g = np.asarray(G)
    # the support mode's frequency, damping and gain enter with ks (the housing sits at the cylindrical
    # mode's anti-resonance): fitted together
    gains = [k for k in ("ki_n_per_a", "ks_n_per_m", "ks_b_over_a") + _SUPPORT if k in free]
    if gains:
        try:
            up = update_physical_model(rotor, f, g, var, out, gains, dt_s, max_evaluations=60,
                                       covariance="jacobian", prior=_prior_of(prior, free, gains))
            out.update({k: up.parameters[k] for k in gains})
        except ValueError:
            pass   # the full update starts these at their nominal values then
    lags = [k for k in ("amplifier_bandwidth_hz", "sensor_bandwidth_hz", "delay_s") if k in free]
    if not lags:
        return out
    gm = physical_frf(rotor, out, f, dt_s)
    w2 = np.ones(g.shape) if var is None else 1.0 / np.asarray(var, dtype=float)
    num = np.sum(w2 * g * np.conj(gm), axis=(1, 2))
    info = np.sum(w2 * np.abs(gm) ** 2, axis=(1, 2))              # the phase's weight per line
    omega = 2 * np.pi * f
    d_lag = float(-np.sum(info * omega * np.angle(num)) / np.sum(info * omega**2))
    # each part's prior variance as a lag [s^2]: tau = 1 / (2 pi f) moves by tau times f's relative sd
    parts = {}
    for k in lags:
        sd, lg = sds.get(k, (0.0, False))
        if k == "delay_s":
            parts[k] = (sd * abs(out[k]) if lg else sd) ** 2
        else:
            parts[k] = ((sd if lg else sd / out[k]) / (2 * np.pi * out[k])) ** 2
    total = sum(parts.values())
    if total > 0 and np.isfinite(d_lag):
        for k, v in parts.items():
            share = d_lag * v / total
            if k == "delay_s":
                out[k] = float(out[k] + share)
            else:
                tau = 1.0 / (2 * np.pi * out[k])
                out[k] = float(1.0 / (2 * np.pi * max(tau + share, 0.2 * tau)))
    return out


def unmodelled_mode(mode_freq_hz: np.ndarray, mode_damping: np.ndarray, mode_strength: np.ndarray,
                    nominal: StateSpace, band_hz: tuple[float, float], tol: float = 0.05) -> tuple[float, float] | None:
    """The strongest fitted mode the nominal model lacks: a start for the support mode.

    A fitted mode (in the band, damping in (0, 0.3)) is unmodelled when no
    lightly damped pole pair of the nominal model lies within ``tol``
    (relative) of its frequency.

    Parameters
    ----------
    mode_freq_hz, mode_damping, mode_strength
        (K,) fitted modes'
        natural frequency [Hz], damping ratio [-] and a size measure
        (e.g. the largest residue singular value divided by the damping).
    nominal
        the nominal continuous model.
    band_hz
        (low, high) band of the data [Hz].
    tol
        relative frequency distance that counts as the same mode.

    Returns
    -------
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
