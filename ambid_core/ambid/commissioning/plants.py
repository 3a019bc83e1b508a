"""The plants a run's data allow: the updated physical model and its parameters' posterior, as draws.

An identification's model update (``identification.json``'s ``update``,
:meth:`ambid.fit.model_update.PhysicalUpdate.to_dict`) holds every physical parameter's estimate, the
free ones' standard deviations, 95 % intervals (Student t) and correlation. The free parameters are
drawn from that posterior with their correlation and each its own Student t (the degrees of freedom its
interval was read with; a Gaussian copula), in ln theta where the prior was stated in the logarithm, as
the update estimated them;
the parameters the data could not reach (a bending mode above the band) from their tolerance about the
estimate (:mod:`ambid.plant.tolerances`): every plant a controller must hold. Nothing here reads the
simulated truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg, stats

from ambid.control.closed_loop import residue_freqresp
from ambid.fit.model_update import PARAMETERS, physical_discrete
from ambid.plant.rig import Rig
from ambid.plant.rotor_model import RotorModel
from ambid.plant.tolerances import tolerance_for
from ambid.statespace import StateSpace

__all__ = ["PlantUncertainty", "plant_uncertainty", "moved", "draw_parameters", "PlantSet", "plant_set", "peak_grid"]


@dataclass(frozen=True)
class PlantUncertainty:
    """An updated physical model as a distribution of plants.

    Attributes
    ----------
    rotor
        the rig's rotor model (its layout: the channels).
    dt_s
        the sample period of the loop [s].
    values
        every parameter's estimate (name -> value, :data:`ambid.fit.model_update.PARAMETERS`).
    free
        the parameters the data identified.
    log
        (k,) bool, those estimated in ln theta.
    cov
        (k, k) their covariance in the estimation's coordinates (theta, or ln theta where ``log``).
    dof
        (k,) each one's degrees of freedom (inf: normal).
    prior_only
        (name, mean, sd, log) of each parameter drawn from its tolerance alone.
    """

    rotor: RotorModel
    dt_s: float
    values: dict[str, float]
    free: tuple[str, ...]
    log: np.ndarray
    cov: np.ndarray
    dof: np.ndarray
    prior_only: tuple[tuple[str, float, float, bool], ...]


def _dof(q: float) -> float:
    """Degrees of freedom of a Student t whose 0.975 quantile is ``q`` (inf at or below the normal's)."""
    if not np.isfinite(q) or q <= stats.norm.ppf(0.975) * (1 + 1e-6):
        return np.inf
    lo, hi = 1.0, 1e6
    for _ in range(80):   # t.ppf(0.975, nu) falls with nu: bisection in log nu
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if stats.t.ppf(0.975, mid) > q else (lo, mid)
    return float(np.sqrt(lo * hi))


def plant_uncertainty(update: Mapping, rig: Rig) -> PlantUncertainty:
    """The posterior of identify's model update (``identification.json``'s ``update``) on ``rig``'s rotor.

    Parameters
    ----------
    update
        the update's dict: ``parameters`` (name -> value, std, ci95, free, prior), ``free`` and
        ``correlation`` (over ``free``, in their order).
    rig
        the nominal rig the update was made on (its rotor, sample period and tolerances).

    Raises
    ------
    ValueError
        the update failed or holds no free parameter.
    """
    params = (update or {}).get("parameters")
    if not params:
        why = (update or {}).get("error") or "the run has no physical model update"
        raise ValueError(f"no updated physical model to design on: {why}")
    values = {k: float(v["value"]) for k, v in params.items()}
    free = tuple(update.get("free") or [k for k, v in params.items() if v.get("free")])
    if not free:
        raise ValueError("the run's update has no free parameter: nothing was identified")
    corr = np.asarray(update.get("correlation") or np.eye(len(free)), dtype=float)
    log = np.array([bool((params[k].get("prior") or {}).get("log")) for k in free])
    sd = np.empty(len(free))
    dofs = []
    for i, k in enumerate(free):
        row, v = params[k], values[k]
        s = float(row["std"])
        sd[i] = s / v if log[i] else s
        hi = float(row["ci95"][1])
        half = np.log(hi / v) if log[i] else hi - v
        dofs.append(_dof(half / sd[i]) if sd[i] > 0 else np.inf)
    cov = corr * np.outer(sd, sd)
    prior_only = []
    for k, v in values.items():
        if k in free or k.startswith("sensor_gain"):   # a sensor gain trades with ki: identified through it
            continue
        tol = tolerance_for(k, rig.tolerances)
        if tol is None or tol.kind == "fixed":
            continue
        mean, s, lg = tol.centre_and_sd(v, rig.dt)
        if tol.kind == "range":
            mean = v   # the estimate stays the centre; the range's width is the spread
        if s > 0:
            prior_only.append((k, float(np.log(mean) if lg else mean), float(s), bool(lg)))
    return PlantUncertainty(rig.rotor_model(), float(rig.dt), values, free, log, cov, np.array(dofs),
                            tuple(prior_only))


def moved(unc: PlantUncertainty, ratios: Mapping[str, float]) -> PlantUncertainty:
    """``unc`` with the estimates of ``ratios``' parameters multiplied by them, the spread kept: the posterior
    carried to another operating point (the magnets' slopes under another loop,
    :func:`ambid.commissioning.from_run.operating_point`).

    Examples
    --------
    >>> from ambid.plant.rig import make_rig
    >>> update = {"free": ["ki_n_per_a"], "parameters": {
    ...     "ki_n_per_a": {"value": 175.0, "std": 0.5, "ci95": [174.0, 176.0], "free": True}}}
    >>> moved(plant_uncertainty(update, make_rig()), {"ki_n_per_a": 1.01}).values["ki_n_per_a"]
    176.75
    """
    values = {k: v * float(ratios.get(k, 1.0)) for k, v in unc.values.items()}
    return replace(unc, values=values)


def draw_parameters(unc: PlantUncertainty, n: int, rng: np.random.Generator) -> list[dict[str, float]]:
    """``n`` parameter sets from the posterior (module docstring); the first is the estimate itself.

    Examples
    --------
    >>> import numpy as np
    >>> from ambid.plant.rig import make_rig
    >>> rig = make_rig()
    >>> update = {"free": ["ki_n_per_a"], "correlation": [[1.0]], "parameters": {
    ...     "ki_n_per_a": {"value": 175.0, "std": 0.5, "ci95": [174.0, 176.0], "free": True},
    ...     "ks_n_per_m": {"value": 8.7e5, "free": False},
    ...     "amplifier_bandwidth_hz": {"value": 1700.0, "free": False}}}
    >>> draws = draw_parameters(plant_uncertainty(update, rig), 400, np.random.default_rng(1))
    >>> round(float(np.std([d["ki_n_per_a"] for d in draws])), 1)
    0.5
    """
    k = len(unc.free)
    x0 = np.array([np.log(unc.values[p]) if lg else unc.values[p] for p, lg in zip(unc.free, unc.log)])
    sd = np.sqrt(np.diag(unc.cov))
    corr = unc.cov / np.outer(np.where(sd > 0, sd, 1.0), np.where(sd > 0, sd, 1.0))
    # the correlation's square root by eigenvalues: a near-singular posterior (correlated lags) stays PSD
    w, v = linalg.eigh(corr)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    g = rng.standard_normal((n, k)) @ root.T
    g /= np.sqrt(np.clip(np.diag(root @ root.T), 1e-300, None))
    # each marginal its own Student t, the correlation kept through the normal scores (a Gaussian copula)
    heavy = np.isfinite(unc.dof)
    z = g.copy()
    if heavy.any():
        z[:, heavy] = stats.t.ppf(stats.norm.cdf(g[:, heavy]), unc.dof[heavy])
    z *= sd
    z[0] = 0.0
    x = x0 + z
    draws = []
    for i in range(n):
        p = dict(unc.values)
        for j, name in enumerate(unc.free):
            p[name] = float(np.exp(x[i, j]) if unc.log[j] else x[i, j])
        for name, mean, sd, lg in unc.prior_only:
            y = mean + (0.0 if i == 0 else sd * rng.standard_normal())
            p[name] = float(np.exp(y) if lg else y)
        for name, value in p.items():   # the model's ranges; a damping ratio or a gain stays positive
            info = PARAMETERS.get(name)
            if info is not None:
                low = info.low if info.low != 0 or name == "delay_s" else 1e-9 * info.typical
                p[name] = float(min(max(value, low), info.high))
        draws.append(p)
    return draws


@dataclass(frozen=True)
class PlantSet:
    """Discrete plants and their frequency responses on one grid.

    Attributes
    ----------
    parameters
        each plant's physical parameters.
    models
        each plant, discrete u (na) [A] -> y (na) [m] at the loop's sample period, its delay exact.
    freq_hz
        (L,) the grid [Hz].
    frf
        (D, L, na, na) each plant's frequency response there [m/A].
    """

    parameters: list[dict[str, float]]
    models: list[StateSpace]
    freq_hz: np.ndarray
    frf: np.ndarray


def plant_set(unc: PlantUncertainty, parameters: Sequence[Mapping[str, float]], freq_hz: np.ndarray) -> PlantSet:
    """The discrete plants of ``parameters`` and their responses at ``freq_hz``."""
    f = np.asarray(freq_hz, dtype=float)
    models = [physical_discrete(unc.rotor, p, unc.dt_s) for p in parameters]
    frf = np.stack([residue_freqresp(m, f) for m in models]) if models else np.zeros((0, f.size, 0, 0))
    return PlantSet([dict(p) for p in parameters], models, f, frf)


def peak_grid(models: Sequence[StateSpace], f_lo_hz: float = 1.0, n_log: int = 1500,
              per_mode: int = 121) -> np.ndarray:
    """A frequency grid [Hz] for sensitivity peaks of loops around ``models``: log-spaced from ``f_lo_hz`` to
    just below Nyquist, plus dense patches (+-4 half-power widths, at least +-3 %) about every lightly damped
    pole of the plants, where a closed loop's peak can be narrower than any affordable log grid."""
    dt = models[0].dt
    nyq = 0.5 / dt
    parts = [np.geomspace(f_lo_hz, 0.999 * nyq, n_log)]
    seen: list[float] = []
    for m in models:
        z = m.poles()
        z = z[np.abs(z) > 1e-12]
        s = np.log(z.astype(complex)) / dt
        for v in s:
            f0 = abs(v.imag) / (2 * np.pi)
            zeta = -v.real / max(abs(v), 1e-300)
            if not (f_lo_hz < f0 < nyq and v.imag > 0 and abs(zeta) < 0.1):
                continue
            if any(abs(f0 - g) < 0.002 * f0 for g in seen):
                continue
            seen.append(f0)
            half = max(4 * abs(zeta) * f0, 0.03 * f0)
            parts.append(np.linspace(max(f0 - half, f_lo_hz), min(f0 + half, 0.999 * nyq), per_mode))
    return np.unique(np.concatenate(parts))
