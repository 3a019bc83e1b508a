"""The whole offline identification of a recorded session, in one call.

:func:`identify_session` runs, on one experiment of a session MCAP file:

1. the FRF matrix u -> y with its noise (and, with M >= 2 realisations,
   total) variance (:func:`ambid.frf.offline.frf_from_session`);
2. order selection on a stabilisation diagram (:func:`select_order`) and the
   common-denominator fit at that order, with a known delay of half a sample
   (the zero-order hold of a sampled measurement), weighted by the FRF's
   variance (total with M >= 2, else noise) averaged over the inputs of each
   output;
3. modes (frequency, damping) and real poles, the state-space export
   (``model.npz``, ``model.json``) and the FRF (``frf.npz``) in ``out_dir``;
4. physical-model updating (:mod:`ambid.fit.model_update`): the MAP estimate
   with the nominal rig's values and tolerances as priors, started from the
   data (the fitted modes, the FRF's level and phase), with an extra support
   mode when the fit shows a mode the nominal model lacks; the nominal and the
   updated model's loop with the recorded controller are checked and said;
   where the rig model covers the FRF's channels (a note says so where it does
   not: channels are data, a record of one axis or one plane is fitted all the same);
5. when the session is simulated (rig facts recorded, plant source 'sim'):
   the comparison against the true rig's sampled linear model
   (:func:`ambid.plant.true_rig.true_linear_model`) and its parameters;
6. the report (``out_dir/report/index.html``) and ``identification.json``.

Order-selection rule (:func:`select_order`): the order with the smallest
information criterion ``2 V + penalty * p`` (Akaike's for penalty 2; 2 V is
chi^2 = chi^2/dof * (N - p), N real residuals, p real parameters) among the
orders whose in-band lightly damped complex poles (damping ratio below
``max_damping`` in magnitude) all have positive damping and are stable in
frequency in the diagram (found again within its tol_freq at the next lower
order fitted); if no order qualifies, the smallest criterion of all. The
plant's only unstable poles are real (the magnets' negative stiffness), so
a lightly damped unstable pair marks a spurious pole.

Modes against the true rig (:func:`compare_modes`): true modes closer than
the frequency resolution form one cluster, compared by mean frequency and
damping with the fitted modes near it.

FRF error figures: per line the relative matrix error
``||G - G_true||_F / ||G_true||_F`` (Frobenius norm over the Ny x Nu matrix,
so structurally zero cross-plane entries do not divide by zero), its median
and worst value over the excited lines.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from ambid.channels import split_name
from ambid.control.closed_loop import close_loop, loop_robustness
from ambid.excitation.design import ExcitationDesign
from ambid.fit import (FitResult, StabilisationDiagram, fit_common_denominator, modal_summary, save_model_json,
                       save_model_npz, stabilisation_diagram)
from ambid.fit.model_update import (PhysicalUpdate, bending_keys, closed_loop_noise_std, covers, excitation_slopes,
                                    rig_channels,
                                    match_modes, nominal_parameters, nominal_update_parameters, parameter_prior,
                                    physical_discrete, physical_frf, physical_statespace, slopes_as_parameters,
                                    start_from_data, total_lag, true_parameters, unmodelled_mode,
                                    update_physical_model)
from ambid.fit.physical_modes import judge_poles
from ambid.fit.updating import NotIdentifiable, Prior
from ambid.plant.tolerances import Z95
from ambid.frf.directional import directional_frf, has_planes, whirl_of_residue
from ambid.frf.levels import LineLevels, line_levels
from ambid.frf.offline import frf_from_session, session_designs
from ambid.frf.quality import record_quality
from ambid.frf.sensitivity import iso14839_zone, sensitivity_shown
from ambid.frf.uncertainty import fit_weight_variance, row_covariance
from ambid.frf.streaming import FrfResult, axis_tag
from ambid.jsonable import to_jsonable
from ambid.plant.rig import Rig, load_rig, make_rig
from ambid.plant.true_rig import true_linear_model, true_plant
from ambid.report.html import write_report
from ambid.report.rotor_figures import directional_frf_figure
from ambid.session import iter_decoded, read_metadata
from ambid.session.blocks import read_samples
from ambid.session.facts import controller_facts, controller_model, plant_facts
from ambid.statespace import StateSpace

__all__ = ["select_order", "split_modes", "frf_relative_error", "recorded_controller", "session_rig", "true_modes",
           "compare_modes", "FrfFit", "fit_frf", "update_rig", "identify_session", "SessionInputs",
           "read_session_inputs", "inputs_from_messages", "ReferenceModels", "reference_key", "reference_models"]

_PLANT_TOPIC = "plant/description"
_DESIGN_TOPIC = "excitation/design"
_MEASUREMENT_TOPIC = "measurement"


def select_order(diagram: StabilisationDiagram, band_hz: tuple[float, float], n_lines: int, n_entries: int,
                 weighted: bool = True, penalty: float = 2.0, max_damping: float = 0.3) -> int:
    """The model order by the rule of the module docstring.

    Args:
        diagram: from :func:`ambid.fit.stabilisation_diagram`, fitted with
            relative degree 0 (a feed-through term).
        band_hz: (low, high) band whose poles count [Hz].
        n_lines: L lines of the data; n_entries: Ny * Nu.
        weighted: the fits were weighted by the noise variance (then
            ``diagram.chi2_per_dof`` is chi^2/dof); False when unweighted
            (then it holds the cost V, scaled here by the smallest V / dof).
        penalty: criterion weight per parameter (2: AIC, ln N: MDL/BIC).
        max_damping: complex poles more damped than this are not checked [-].

    Returns:
        The chosen order.
    """
    if not (penalty >= 0 and n_lines >= 1 and n_entries >= 1):
        raise ValueError(f"need penalty >= 0, n_lines >= 1, n_entries >= 1; got {penalty}, {n_lines}, {n_entries}")
    orders = np.asarray(diagram.orders)
    n_res = 2 * n_lines * n_entries
    n_par = orders + n_entries * (orders + 1)  # poles + numerators and feed-through (fit_common_denominator)
    dof = np.maximum(n_res - n_par, 1)
    chi = np.asarray(diagram.chi2_per_dof, dtype=float)
    chi2 = chi * dof if weighted else 2 * chi
    if not weighted:
        chi2 = chi2 / np.nanmin(chi2 / dof)   # noise level from the best fit per degree of freedom
    crit = np.where(np.isfinite(chi2), chi2 + penalty * n_par, np.inf)
    if not np.any(np.isfinite(crit)):
        raise ValueError("the stabilisation diagram has no finite cost values")
    lo, hi = band_hz
    clean = []
    for n in orders:
        sel = diagram.order == n
        p, status, f, z = diagram.pole_rad_s[sel], diagram.status[sel], diagram.freq_hz[sel], diagram.damping[sel]
        checked = (p.imag > 0) & (f >= lo) & (f <= hi) & (np.abs(z) < max_damping)
        clean.append(n != orders[0] and bool(np.all(z[checked] > 0) and np.all(np.isin(status[checked], (1, 3)))))
    clean = np.array(clean)
    pick = np.where(clean, crit, np.inf) if np.any(clean & np.isfinite(crit)) else crit
    return int(orders[int(np.argmin(pick))])


def frf_relative_error(G: np.ndarray, G_ref: np.ndarray) -> np.ndarray:
    """Per line ||G - G_ref||_F / ||G_ref||_F over the (Ny, Nu) matrix, (L,) [-]."""
    g, r = np.asarray(G), np.asarray(G_ref)
    if g.shape != r.shape or g.ndim != 3:
        raise ValueError(f"G and G_ref must both be (L, Ny, Nu), got {g.shape} and {r.shape}")
    return np.linalg.norm(g - r, axis=(1, 2)) / np.linalg.norm(r, axis=(1, 2))


def session_rig(path: str | os.PathLike, plant_topic: str = "/amb/plant/description",
                recover: bool = False) -> tuple[dict | None, str | None]:
    """The rig parameters and plant source ('sim' | 'hardware') recorded in a session.

    From the ``ambid.session`` metadata the recorder writes, else from the
    first PlantDescription message on ``plant_topic``.

    Returns:
        (rig dict for :func:`ambid.plant.rig.make_rig` or None, source or None).
    """

    def parsed(value: Any) -> Any:
        if isinstance(value, str):
            try:
                return json.loads(value)
            except json.JSONDecodeError:
                return None
        return value

    facts = read_metadata(path, recover=recover).get("ambid.session", {})
    plant = parsed(facts.get("plant"))
    plant = plant if isinstance(plant, dict) else {}
    rig = parsed(facts.get("rig")) or parsed(plant.get("rig"))
    source = plant.get("source")
    if not isinstance(rig, dict) or not rig:
        rig = None
        for _, msg in iter_decoded(path, [plant_topic], recover=recover):
            pf = plant_facts(msg)
            rig = pf["rig"] if isinstance(pf["rig"], dict) and pf["rig"] else None
            source = pf["source"]
            break
    return rig, (str(source) if source else None)


def true_modes(poles_rad_s: np.ndarray, band_hz: tuple[float, float],
               rel_tol: float = 1e-4) -> list[tuple[float, float]]:
    """Distinct lightly damped pole pairs in a band: [(frequency [Hz], damping ratio [-])], ascending.

    Pairs within ``rel_tol`` of each other in frequency and damping (the x
    and y planes of a symmetric rotor) count once.
    """
    p = np.asarray(poles_rad_s, dtype=complex)
    p = p[(p.imag > 0)]
    f, z = np.abs(p) / (2 * np.pi), -p.real / np.abs(p)
    keep = (f >= band_hz[0]) & (f <= band_hz[1]) & (z > 0) & (z < 0.3)
    out: list[tuple[float, float]] = []
    for fi, zi in sorted(zip(f[keep], z[keep])):
        if out and abs(fi - out[-1][0]) <= rel_tol * fi and abs(zi - out[-1][1]) <= rel_tol * max(zi, 1e-12) + 1e-9:
            continue
        out.append((float(fi), float(zi)))
    return out


def compare_modes(fitted: Sequence[tuple[float, float]], true: Sequence[tuple[float, float]],
                  resolution_hz: float) -> list[dict]:
    """Fitted modes against true ones, closely spaced modes as clusters.

    Modes closer than the frequency resolution cannot be told apart by the
    data, so true modes less than ``resolution_hz`` apart form a cluster,
    compared by its mean frequency and damping with the mean of the fitted
    modes within ``resolution_hz`` of the cluster (the nearest fitted mode
    when none is).

    Args:
        fitted, true: [(frequency [Hz], damping ratio [-])].
        resolution_hz: frequency resolution fs / N of the measurement [Hz].

    Returns:
        One dict per true cluster: true_freq_hz, true_damping, freq_hz,
        damping, freq_error, damping_error (relative), n_true, n_fitted.
    """
    if not resolution_hz > 0:
        raise ValueError(f"resolution_hz must be > 0, got {resolution_hz}")
    clusters: list[list[tuple[float, float]]] = []
    for f, z in sorted(true):
        if clusters and f - clusters[-1][-1][0] < resolution_hz:
            clusters[-1].append((f, z))
        else:
            clusters.append([(f, z)])
    out = []
    if not fitted:
        return out
    fit_f = np.array([f for f, _ in fitted])
    fit_z = np.array([z for _, z in fitted])
    for c in clusters:
        lo, hi = c[0][0] - resolution_hz, c[-1][0] + resolution_hz
        inside = (fit_f >= lo) & (fit_f <= hi)
        if not np.any(inside):
            inside = np.arange(fit_f.size) == np.argmin(np.abs(fit_f - np.mean([f for f, _ in c])))
        ft, zt = float(np.mean([f for f, _ in c])), float(np.mean([z for _, z in c]))
        ff, zf = float(fit_f[inside].mean()), float(fit_z[inside].mean())
        out.append(dict(true_freq_hz=ft, true_damping=zt, freq_hz=ff, damping=zf, freq_error=ff / ft - 1,
                        damping_error=zf / zt - 1, n_true=len(c), n_fitted=int(inside.sum())))
    return out


def _fit_variance(frf: FrfResult, pool: bool = True) -> tuple[np.ndarray | None, str]:
    """The FRF's variance, for the printed band and the fits' line covariance (the fits weight by
    :func:`_weight_variance`): total (BLA) where known, else noise; floored.

    With ``pool``, each output's variances are averaged over the inputs (one
    row of G carries the same output noise): an estimate from P periods has
    only 2 (P - 1) degrees of freedom.
    """
    for name in ("var_total", "var_noise"):
        v = np.asarray(getattr(frf, name), dtype=float)
        if np.all(np.isfinite(v)) and np.any(v > 0):
            if pool:
                v = np.broadcast_to(v.mean(axis=2, keepdims=True), v.shape)
            return _floored(v), name + (", pooled over the inputs" if pool else "")
    return None, "none (equal weights)"


def _weight_variance(frf: FrfResult, var: np.ndarray | None, var_kind: str) -> tuple[np.ndarray | None, str]:
    """The variance the fits weight by: the noise scaled by the distortion's share averaged over the
    neighbouring lines (:func:`ambid.frf.uncertainty.fit_weight_variance`), where both are known; else ``var``."""
    vn, vt = (np.asarray(getattr(frf, k), dtype=float) for k in ("var_noise", "var_total"))
    if var is None or not (np.all(np.isfinite(vn)) and np.all(np.isfinite(vt)) and np.any(vn > 0)):
        return var, var_kind
    return (_floored(fit_weight_variance(vn, vt)),
            "var_noise x (var_total / var_noise averaged over +-3 lines), pooled over the inputs")


def _floored(v: np.ndarray) -> np.ndarray:
    """A weighting variance floored at 1e-6 of its median positive value (no line weighs without bound)."""
    return np.maximum(v, 1e-6 * np.median(v[v > 0]))


def _session_fact(path: str, key: str, recover: bool) -> dict:
    """One entry of the session's facts (``ambid.session`` metadata) as a dict; {} when it is not there."""
    value = read_metadata(path, recover=recover).get("ambid.session", {}).get(key)
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except json.JSONDecodeError:
            value = None
    return value if isinstance(value, dict) else {}


def _nonlinear_magnets(path: str, recover: bool) -> bool:
    """Whether the simulated session ran the nonlinear magnets (the session config identify records; the
    plant node's default, linear, when the session does not say)."""
    return bool(_session_fact(path, "config", recover).get("nonlinear_magnets", False))


def _mode_interval(fit: FitResult, freq_hz: float, damping: float) -> dict:
    """freq_hz_std, freq_hz_ci95, damping_std, damping_ci95 of a fitted mode, or {}: normal (1.96 sigma), or
    Student's t where the variance came from the realisations' scatter (few degrees of freedom)."""
    sd = fit.mode_interval(freq_hz, damping)
    if sd is None:
        return {}
    q = float(stats.t.ppf(0.975, sd[2])) if np.isfinite(sd[2]) else 1.96
    return dict(freq_hz_std=sd[0], freq_hz_ci95=[freq_hz - q * sd[0], freq_hz + q * sd[0]],
                damping_std=sd[1], damping_ci95=[damping - q * sd[1], damping + q * sd[1]],
                ci_dof=sd[2] if np.isfinite(sd[2]) else None, noise_only=False)


def _band_kind(var_kind: str) -> str:
    kind = "total (noise + nonlinear)" if var_kind.startswith("var_total") else "noise only"
    return kind + (", pooled over the inputs" if "pooled" in var_kind else "")


def _load_rig(rig: Rig | str | os.PathLike | Mapping | None, facts: dict | None) -> Rig | None:
    if isinstance(rig, Rig):
        return rig
    if isinstance(rig, Mapping):
        return make_rig(dict(rig))
    if rig is not None:
        return load_rig(rig)
    return make_rig(facts) if facts else None


def _update(rig: Rig, frf: FrfResult, var, band, modes, dt_s, nominal_overrides, free, row_cov=None,
            realisations=None) -> tuple[PhysicalUpdate | None, str | None, list[str]]:
    """Model updating: the MAP estimate from the nominal rig's priors, started from the data.

    The nominal values (:func:`ambid.fit.model_update.nominal_update_parameters`, with
    ``nominal_overrides``) and the rig's tolerances make the prior; the bending modes start at the
    fitted modes, a support mode is added at the strongest fitted mode the nominal model lacks, the
    gains and lags start from the FRF (:func:`ambid.fit.model_update.start_from_data`). Nothing is
    fixed because the data cannot tell it: such a direction keeps its prior's width.

    Returns (update or None, error or None, notes).
    """
    rotor = rig.rotor_model()
    not_covered = covers(rotor, frf.output_names, frf.input_names)
    sub_notes = []
    if not_covered:
        picked = rig_channels(rotor, frf.output_names, frf.input_names)
        if picked is None:
            return None, None, [f"no physical model updating: {not_covered}"]
        # the channels the rig model describes; the others (accelerometers, probes along the shaft) left out
        rows, cols, left = picked
        frf = dataclasses.replace(frf, frf=frf.frf[:, rows][:, :, cols],
                                  output_names=tuple(frf.output_names[i] for i in rows),
                                  input_names=tuple(frf.input_names[j] for j in cols))
        var = None if var is None else var[:, rows][:, :, cols]
        row_cov = None if row_cov is None else row_cov[:, rows][:, :, cols][:, :, :, cols]
        realisations = None if realisations is None else realisations[:, :, rows][:, :, :, cols]
        sub_notes.append(f"physical model updating on the channels the rig model describes "
                         f"({', '.join(frf.output_names)} / {', '.join(frf.input_names)}); left out: "
                         f"{', '.join(left)} (not in the rig model)")
    nominal = nominal_update_parameters(rig)
    nominal.update({k: float(v) for k, v in (nominal_overrides or {}).items()})
    fitted = [(m.freq_hz, m.damping) for m in modes]
    chosen = free is not None
    if free is None:
        free = [k for k in ("ki_n_per_a", "ks_n_per_m", "ks_b_over_a", "amplifier_bandwidth_hz",
                            "sensor_bandwidth_hz", "delay_s", "axial_ki_n_per_a", "axial_ks_n_per_m",
                            "axial_amplifier_bandwidth_hz") if k in nominal]
        # the bending modes within the measured band (one outside it cannot be identified from it)
        for mode in range(1, 9):
            fk, zk = bending_keys(mode)
            if fk in nominal and band[0] <= nominal[fk] <= band[1]:
                free += [fk, zk]
    free = list(free)
    known = [k for k in free if k in nominal]
    bending, used, notes = match_modes(rotor, nominal, known, parameter_prior(rig, known, nominal)[0], fitted)
    notes = sub_notes + notes
    # a support mode where the fit shows a mode that neither the nominal model nor its bending modes explain
    rest = [m for k, m in enumerate(modes) if k not in used]
    # resonance peak height of R / (s - p) is |R| / (zeta omega)
    strength = [m.residue_singular_values[0] / (max(m.damping, 1e-6) * 2 * np.pi * m.freq_hz) for m in rest]
    extra = unmodelled_mode([m.freq_hz for m in rest], [m.damping for m in rest], strength,
                            physical_statespace(rotor, {**nominal, **bending}), band)
    if extra is not None and not all(k in nominal for k in _SUPPORT_KEYS):
        # no data sheet: its nominal is the fitted mode; its prior only keeps the problem well posed
        nominal.update(support_freq_hz=extra[0], support_damping_ratio=extra[1],
                       support_gain_per_kg=2.0 / rig.rotor_mass_kg)
    if not chosen and all(k in nominal for k in _SUPPORT_KEYS):
        free += [k for k in _SUPPORT_KEYS if k not in free]
    prior, fixed = parameter_prior(rig, free, nominal)
    if fixed:
        keep = [k for k, name in enumerate(free) if name not in fixed]
        free = [free[k] for k in keep]
        prior = Prior(prior.mean[keep], prior.std[keep], prior.log[keep])
        notes.append(f"{', '.join(fixed)} kept at the nominal value (tolerance 'fixed' in the rig file)")
    if not free:
        return None, "every parameter is fixed; nothing to update", notes
    # the prior's centre where a range replaced the nominal value (the delay's 0..1 sample)
    centre = dict(nominal)
    centre.update({name: float(prior.mean[k]) for k, name in enumerate(free) if np.isfinite(prior.std[k])})
    centre.update(bending)
    try:
        start = start_from_data(rotor, frf.freq_hz, frf.frf, var, centre, free, prior, dt_s)
        return update_physical_model(rotor, frf.freq_hz, frf.frf, var, start, free, dt_s, prior=prior,
                                     row_covariance=row_cov, realisations=realisations), None, notes
    except NotIdentifiable as exc:
        return None, (f"{exc}; the parameters {', '.join(exc.parameters)} have no tolerance here: give them one "
                      "under tolerances: in the rig file"), notes
    except ValueError as exc:
        return None, str(exc), notes


_SUPPORT_KEYS = ("support_freq_hz", "support_damping_ratio", "support_gain_per_kg")


def refit_parameters(summary: Mapping[str, Any], rig: Rig, freq_hz: np.ndarray, G: np.ndarray,
                     var: np.ndarray | None) -> dict[str, float]:
    """The updated parameters of ``summary`` fitted again to another FRF at the same lines.

    E.g. a noise-free twin of the session (:mod:`ambid_cli.commands.validate`): started at the summary's
    estimates, the same parameters free, the same priors and weights ``var``.

    Args:
        summary: :func:`identify_session`'s summary, with ``update.parameters``.
        rig: the rig the session updated.
        freq_hz: (L,) lines [Hz].
        G: (L, na, na) FRF u -> y [m/A] on the rig's axes.
        var: (L, na, na) the session's fit variance [(m/A)^2], or None.

    Returns:
        free parameter name -> estimate; {} without an update in the summary.
    """
    params = ((summary.get("update") or {}).get("parameters")) or {}
    start = {k: float(v["value"]) for k, v in params.items()}
    free = [k for k, v in params.items() if v.get("free")]
    if not free:
        return {}
    mean, sd, log = [], [], []
    for k in free:
        pr = params[k].get("prior")
        if pr is None:
            mean.append(start[k])
            sd.append(np.inf)
            log.append(False)
            continue
        hi = float(pr["ci95"][1])
        mean.append(float(pr["mean"]))
        sd.append(np.log(hi / pr["mean"]) / Z95 if pr["log"] else (hi - pr["mean"]) / Z95)
        log.append(bool(pr["log"]))
    prior = Prior(np.array(mean), np.array(sd), np.array(log, dtype=bool))
    upd = update_physical_model(rig.rotor_model(), freq_hz, G, var, start, free, rig.dt, prior=prior)
    return {k: float(upd.parameters[k]) for k in free}


@dataclass(frozen=True)
class FrfFit:
    """The common-denominator model of an FRF as identify fits it, and what the fit was weighted by.

    Attributes:
        fit: the fit at the chosen order (:class:`ambid.fit.FitResult`).
        order, order_rule: the order and how it was chosen.
        diagram: the stabilisation diagram the order was chosen on.
        band_hz: (low, high) of the FRF's lines [Hz].
        delay_s: the known delay fitted with the model: half a sample (the zero-order hold) [s].
        modes: the in-band complex pole pairs (:class:`ambid.fit.Mode`), by frequency.
        mode_rows: per mode, what identify prints and records: freq_hz, damping, stable (found again
            within 1 % at the next lower order), their 95 % intervals (freq_hz_ci95, damping_ci95, ...),
            and, where the channels hold a radial bearing's x and y, whirl and forward_share.
        real_rows: the real poles: pole_hz (signed, > 0 unstable), unstable.
        var, var_kind: the line variance the intervals are read from, and what it is (None: no variance).
        band_var: the variance of the printed +-2 sigma band.
        weights, weights_kind: the variance the fit is weighted by, and what it is.
        row_cov: the covariance of a row's entries (the indirect estimator), or None.
        realisations: (M, L, Ny, Nu) the realisations' FRFs whose scatter joins the intervals, or None.
        computational: the fit's complex poles that are not modes of the data, each with its reason
            (:func:`split_modes`).
    """

    fit: FitResult
    order: int
    order_rule: str
    diagram: StabilisationDiagram
    band_hz: tuple[float, float]
    delay_s: float
    modes: list
    mode_rows: list[dict]
    real_rows: list[dict]
    var: np.ndarray | None
    var_kind: str
    band_var: np.ndarray
    weights: np.ndarray | None
    weights_kind: str
    row_cov: np.ndarray | None
    realisations: np.ndarray | None
    computational: list[dict] = dataclasses.field(default_factory=list)


def split_modes(fit: FitResult, diagram: StabilisationDiagram, order: int, freq_hz: np.ndarray, G: np.ndarray,
                noise_var: np.ndarray | None, *, plant_input_current: bool = False
                ) -> tuple[list, list[dict], list[dict], list[dict]]:
    """The fit's poles parted into the modes the data shows and the computational ones
    (:func:`ambid.fit.physical_modes.judge_poles`), for ``ambid fit`` of a session and of an FRF file alike.

    Returns:
        (modes: the physical :class:`ambid.fit.Mode` by frequency; their rows: freq_hz, damping, stable (found
        again within 1 % at the next lower order), the 95 % intervals; the real poles' rows: pole_hz (signed,
        > 0 unstable), unstable, reason; the computational complex poles' rows: freq_hz, damping, reason).
    """
    summary_modes = modal_summary(fit.model)
    prev = diagram.orders[diagram.orders < order]
    prev_poles = diagram.poles_of(int(prev[-1])) if prev.size else np.zeros(0, complex)
    verdicts = {v.index: v for v in judge_poles(fit.model, diagram, order, freq_hz, G, noise_var,
                                                plant_input_current=plant_input_current)}
    poles = fit.model.poles

    def index(pole: complex) -> int:   # the model's pole the summary's is (real poles: their real part)
        return int(np.argmin(np.abs(poles - pole)))

    modes, rows, computational = [], [], []
    for m in summary_modes.modes:
        v = verdicts[index(m.pole_rad_s)]
        if not v.physical:
            computational.append(dict(freq_hz=m.freq_hz, damping=m.damping, reason=v.reason,
                                      stable_share=v.stable_share, snr=v.snr))
            continue
        modes.append(m)
        rows.append(dict(freq_hz=m.freq_hz, damping=m.damping,
                         stable=bool(prev_poles.size and np.min(np.abs(np.abs(prev_poles) / (2 * np.pi) - m.freq_hz))
                                     <= 0.01 * m.freq_hz), **_mode_interval(fit, m.freq_hz, m.damping)))
    real_rows = []
    for r in summary_modes.real_poles:
        v = verdicts[index(r.pole_rad_s)]
        real_rows.append(dict(pole_hz=r.pole_rad_s / (2 * np.pi), unstable=r.unstable, physical=v.physical,
                              reason=v.reason))
    return modes, rows, real_rows, computational


def _is_current(name: str) -> bool:
    """A channel of the applied current (``u_<axis>``)."""
    try:
        return split_name(name)[0] == "u"
    except ValueError:
        return False


def fit_frf(frf: FrfResult, sample_rate_hz: float, order: int | None = None, *, max_order: int = 32,
            order_penalty: float = 2.0, units: Mapping[str, str] | None = None) -> FrfFit:
    """The common-denominator fit of an FRF, as :func:`identify_session` makes it (steps 2-3 of the module
    docstring): order selection on the stabilisation diagram unless ``order`` is given, a known delay of
    half a sample, the weights and interval covariance of the FRF's variance.

    Args:
        frf: the estimate (:func:`ambid.frf.offline.frf_from_session`).
        sample_rate_hz: the measurement's sample rate [Hz].
        order: model order; None selects it (:func:`select_order`).
        max_order: highest order in the stabilisation diagram.
        order_penalty: criterion weight per parameter of the order rule (2: Akaike).
        units: channel -> unit where the record says (an imported record's outputs of any kind); default m
            for outputs, A for inputs.

    Raises:
        ValueError: too few lines for a parametric fit.
    """
    f = frf.freq_hz
    band = (float(f.min()), float(f.max()))
    var, var_kind = _fit_variance(frf)
    # the printed +-2 sigma band: the same variance, pooled over the inputs of an output (one output's
    # noise and distortion reach every input's column alike): 2 (M - 1) Nu degrees of freedom instead of
    # 2 (M - 1), so that with M = 3 the band covers 96 % of the lines, not 89 %
    band_var = frf.var_total if var is None else var
    # the indirect estimator's errors are correlated along a row (U^-1 mixes the experiments); the
    # intervals of the modes and parameters take that in (a sandwich with this covariance)
    row_cov = (row_covariance(var, frf.sensitivity) if var is not None and frf.estimator == "indirect"
               and np.all(np.isfinite(frf.sensitivity)) else None)
    # and the realisations' own scatter, where it is wider (distortion coherent over the lines)
    realisations = (frf.frf_realisations if row_cov is not None and frf.frf_realisations is not None
                    and len(frf.frf_realisations) >= 2 else None)
    # the fits weight by a variance that does not follow the realisations' scatter their intervals are read from
    w_var, w_kind = _weight_variance(frf, var, var_kind)

    # --- parametric fit ---------------------------------------------------------------
    fit_delay = (1.0 / sample_rate_hz) / 2  # the zero-order hold: half a sample
    units = dict(units or {})
    labels = dict(input_names=frf.input_names, output_names=frf.output_names,
                  input_units=tuple(units.get(n, "A") for n in frf.input_names),
                  output_units=tuple(units.get(n, "m") for n in frf.output_names))
    top = min(max_order, f.size - 1)
    orders = list(range(2, top + 1, 2))
    if not orders:
        raise ValueError(f"{f.size} lines are too few for a parametric fit; excite more lines")
    diagram = stabilisation_diagram(f, frf.frf, w_var, orders=orders, delay_s=fit_delay)
    rule = (f"smallest chi2 + {order_penalty:g} p among orders with stable, positively damped in-band modes")
    if order is None:
        order = select_order(diagram, band, f.size, frf.frf.shape[1] * frf.frf.shape[2], w_var is not None,
                             order_penalty)
    else:
        rule = "given"
    fit: FitResult = fit_common_denominator(f, frf.frf, w_var, order=int(order), delay_s=fit_delay,
                                            row_covariance=row_cov, realisations=realisations, **labels)
    current_in = all(_is_current(n) for n in frf.input_names)
    modes, mode_rows, real_rows, computational = split_modes(fit, diagram, int(order), f, frf.frf, var,
                                                             plant_input_current=current_in)
    # the radial bearing planes among the channels (x and y of a bearing): forward and backward whirl told apart
    if has_planes(frf.output_names, frf.input_names):
        for m, row in zip(modes, mode_rows):
            k = int(np.argmin(np.abs(fit.model.poles - m.pole_rad_s)))
            row["whirl"], row["forward_share"] = whirl_of_residue(fit.model.residues[k], frf.output_names,
                                                                  frf.input_names)
    return FrfFit(fit, int(order), rule, diagram, band, fit_delay, modes, mode_rows, real_rows, var, var_kind,
                  band_var, w_var, w_kind, row_cov, realisations, computational)


def update_rig(rig: Rig, frf: FrfResult, fitted: FrfFit, dt_s: float, nominal: Mapping[str, float] | None = None,
               free: Sequence[str] | None = None) -> tuple[PhysicalUpdate | None, str | None, list[str]]:
    """The physical-model update of ``rig`` to an FRF (step 4 of the module docstring), weighted as the fit
    ``fitted`` was: the MAP estimate with ``rig``'s values (``nominal`` replacing some) and tolerances as
    priors, started from the data and ``fitted``'s stable modes, a support mode at a stable fitted mode the
    rig lacks.

    Returns:
        (the update or None, why not or None, notes).
    """
    stable = [m for m, row in zip(fitted.modes, fitted.mode_rows) if row["stable"]]
    return _update(rig, frf, fitted.weights, fitted.band_hz, stable, dt_s, nominal, free, fitted.row_cov,
                   fitted.realisations)


def identify_session(mcap_path: str | os.PathLike, out_dir: str | os.PathLike, estimator: str = "indirect",
                     order: int | None = None, *, experiment_id: str | None = None,
                     rig: Rig | str | os.PathLike | Mapping | None = None, max_order: int = 32,
                     order_penalty: float = 2.0, update: bool = True,
                     nominal: Mapping[str, float] | None = None,
                     update_free: Sequence[str] | None = None, report: bool = True,
                     recover: bool = False, true_model: StateSpace | None = None,
                     inputs: SessionInputs | None = None,
                     references: ReferenceModels | Callable[[], ReferenceModels | None] | None = None,
                     on_summary: Callable[[dict], None] | None = None) -> dict:
    """Identify the rig from one experiment of a recorded session (module docstring).

    Args:
        mcap_path: session .mcap file.
        out_dir: folder for model.npz, model.json, frf.npz, identification.json
            and report/ (created).
        estimator: FRF estimator (:data:`ambid.frf.streaming.ESTIMATORS`).
        order: model order; None selects it (:func:`select_order`).
        experiment_id: which experiment; default the last recorded.
        rig: the rig for the nominal model and the updating (a Rig, a YAML
            file or a parameter dict); default the rig recorded in the
            session. Without one, no updating and no nominal model.
        max_order: highest order in the stabilisation diagram.
        order_penalty: criterion weight per parameter of the order rule
            (2: Akaike; larger values choose lower orders).
        update: run the physical-model updating.
        nominal: nominal values replacing the rig's (parameter name ->
            value, :data:`ambid.fit.model_update.PARAMETERS`): the centres of
            the priors. The update starts from the data, not from these.
        update_free: parameters to update; default ki, ks, ks_b_over_a, the
            amplifier and sensor bandwidths, the delay, the bending modes in
            the band and a support mode (when the fit shows one).
        report: write the HTML report.
        recover: read a session file a killed recorder left.
        true_model: the plant the session measured, u [A] -> y [m], when it is
            known from elsewhere (a hardware session against the C reference
            target, whose model file says what it runs): the FRF error and the
            modes are compared with it, as with a simulated session's true rig.
        inputs: what the session holds (:func:`read_session_inputs`), when the caller has it already (e.g.
            from the running graph, before the recording is closed); default read from ``mcap_path``.
        references: :func:`reference_models` computed ahead (e.g. while the session ran), or a function
            returning them, called once the fit and the update are done (so they can still be in the making
            meanwhile); used when their key matches these inputs, else computed here: the numbers are the same.
        on_summary: called with the summary before the report is written, so that a caller can show the
            results without waiting for the figures.

    Returns:
        JSON-safe summary dict (also written to ``identification.json``):

        * ``estimator, experiment_id, session, simulated``;
        * ``excitation``: kind, mimo, grid, sample rate [Hz], N, P, Pt, M,
          Ne, lines, design band [Hz], rms, peak [A], crest factor,
          measurement time [s];
        * ``band_hz`` (excited lines), ``inputs``, ``outputs``;
        * ``frf_error`` (None unless simulated): median, worst (and
          worst_at_hz) relative error of the measured FRF, fitted_* and
          updated_* of the models, against the true sampled model;
        * ``noise``: output_noise_std_m (Ny,), relative_frf_noise_std,
          nonlinear_variance_ratio, distortion_odd_db / even_db (Ny,) [dB
          above the noise], fit_weights;
        * ``fit``: order, order_rule, chi2_per_dof, delay_s, orders_tried,
          chi2_per_dof_by_order, modes [{freq_hz, damping, stable (found
          within 1 % at the next lower order fitted)}], real_poles
          [{pole_hz (signed, > 0 unstable), unstable}];
        * ``modes_vs_true`` (:func:`compare_modes`), max_mode_freq_error,
          max_mode_damping_error;
        * ``update``: :meth:`ambid.fit.model_update.PhysicalUpdate.to_dict` with
          nominal, true and error (relative to true) per parameter, or
          {error}; None without a rig;
        * ``sensitivity``: peak (Nu,), peak_hz, worst_input, worst_peak,
          iso_zone;
        * ``files``, ``wall_s`` and ``notes`` (what could not be done and why).
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    path = os.fspath(mcap_path)
    notes: list[str] = []
    if inputs is None:
        inputs = read_session_inputs(path, estimator, experiment_id, recover)
    frf = inputs.frf
    out.mkdir(parents=True, exist_ok=True)  # only once the session gave an FRF: a refusal leaves nothing behind
    chosen = inputs.experiment
    design: ExcitationDesign = chosen["design"]
    dt_s = 1.0 / design.fs_hz
    f = frf.freq_hz
    if frf.gaps:
        notes.append(f"{len(frf.gaps)} gap(s) in the measurement; the periods they touch were left out")
    mf = fit_frf(frf, design.fs_hz, order, max_order=max_order, order_penalty=order_penalty, units=inputs.units)
    var, var_kind, band_var, w_var, w_kind = mf.var, mf.var_kind, mf.band_var, mf.weights, mf.weights_kind
    order, fit, modes, mode_rows, band, diagram = mf.order, mf.fit, mf.modes, mf.mode_rows, mf.band_hz, mf.diagram
    # the radial bearing planes among the channels (x and y of a bearing): forward and backward whirl told apart
    dfrf = (directional_frf(f, frf.frf, var, frf.output_names, frf.input_names)
            if has_planes(frf.output_names, frf.input_names) else None)
    save_model_npz(out / "model.npz", fit.model)
    save_model_json(out / "model.json", fit.model)

    # --- rig: nominal, truth, updating --------------------------------------------------
    facts, source = inputs.rig_facts, inputs.plant_source
    the_rig = _load_rig(rig, facts)
    simulated = facts is not None and source == "sim"
    true_g = true_params = true_g_x = true_noise = None
    true_rig = make_rig(facts) if simulated else None
    recorded = inputs.controller
    modes_vs_true: list[dict] = []
    if the_rig is None:
        notes.append("no rig in the session and none given: no nominal model, no updating")
    if true_model is None and the_rig is not None and not simulated:
        notes.append("not a simulated session: no true model to compare with")
    upd: PhysicalUpdate | None = None
    update_error = None
    if update and the_rig is not None:
        upd, update_error, update_notes = update_rig(the_rig, frf, mf, dt_s, nominal, update_free)
        notes.extend(update_notes)
        if update_error:
            notes.append(f"model updating failed: {update_error}")

    # the truths, after the fit and the update: reference models still in the making meanwhile are waited for
    # only now
    chans = (frf.output_names, frf.input_names)
    given = references() if callable(references) else references
    refs = (given if given is not None and given.key == reference_key(inputs, f, *chans)
            else reference_models(inputs, f, *chans))
    if simulated and the_rig is not None:
        true_g, true_params, true_g_x, true_noise = refs.true_g, refs.true_params, refs.true_g_x, refs.true_noise
        # physical-looking fitted modes: positively damped and found again at the next lower order
        physical = [(m.freq_hz, m.damping) for m, row in zip(modes, mode_rows) if row["stable"] and m.damping > 0]
        modes_vs_true = compare_modes(physical or [(m.freq_hz, m.damping) for m in modes],
                                      true_modes(refs.true_poles, band), design.fs_hz / design.n_per_period)
    if true_model is not None:  # given: it is the truth, whatever the session's source
        true_g = true_model.freqresp(f)
        z = true_model.poles()
        s_poles = np.log(z[np.abs(z) > 0]) / true_model.dt if true_model.dt > 0 else true_model.poles()
        physical = [(m.freq_hz, m.damping) for m, row in zip(modes, mode_rows) if row["stable"] and m.damping > 0]
        modes_vs_true = compare_modes(physical or [(m.freq_hz, m.damping) for m in modes], true_modes(s_poles, band),
                                      design.fs_hz / design.n_per_period)
    for row in modes_vs_true:
        # one true and one fitted mode: the fitted mode's interval against the truth (a cluster's
        # mean has none: its members' covariance is not kept)
        if row["n_true"] == 1 and row["n_fitted"] == 1:
            row.update(_mode_interval(fit, row["freq_hz"], row["damping"]))

    truths = {} if true_g is None else {"true_frf": true_g}
    if true_g_x is not None:
        truths["true_frf_at_excitation"] = true_g_x
    np.savez(out / "frf.npz", freq_hz=f, frf=frf.frf, var_noise=frf.var_noise, var_total=frf.var_total,
             var_band=band_var, **({} if w_var is None else dict(var_fit=w_var)),
             coherence=frf.coherence, sensitivity=frf.sensitivity,
             input_names=np.array(frf.input_names), output_names=np.array(frf.output_names), **truths,
             **({} if dfrf is None else dict(forward=dfrf.forward, backward=dfrf.backward)))

    # --- figures of merit -----------------------------------------------------------------
    frf_error = None
    if true_g is not None:
        e_meas = frf_relative_error(frf.frf, true_g)
        e_fit = frf_relative_error(fit.model.freqresp(f), true_g)
        frf_error = dict(reference="the given plant model" if true_model is not None else
                         "true rig, small-signal model sampled with zero-order hold",
                         median=float(np.median(e_meas)), worst=float(np.max(e_meas)),
                         worst_at_hz=float(f[np.argmax(e_meas)]), fitted_median=float(np.median(e_fit)),
                         fitted_worst=float(np.max(e_fit)))
        if upd is not None:
            e_upd = frf_relative_error(physical_frf(the_rig.rotor_model(), upd.parameters, f, dt_s), true_g)
            frf_error.update(updated_median=float(np.median(e_upd)), updated_worst=float(np.max(e_upd)))
    dist = frf.distortion
    noise = dict(output_noise_std_m=frf.noise_std, output_noise_std_ci95_m=frf.noise_std_ci95,
                 output_noise_std_sd_m=frf.noise_std_sd, true_output_noise_std_m=true_noise,
                 relative_frf_noise_std=frf.relative_noise_std,
                 nonlinear_variance_ratio=frf.nonlinear_ratio,
                 distortion_odd_db=None if dist is None else dist.odd_db,
                 distortion_even_db=None if dist is None else dist.even_db, fit_weights=w_kind)
    update_dict = None
    if the_rig is not None and recorded is not None and update:
        notes.extend(_loop_notes(the_rig, nominal, upd, recorded[0], dt_s))
    if upd is not None:
        update_dict = upd.to_dict()
        nominal_values = {**nominal_update_parameters(the_rig), **{k: float(v) for k, v in (nominal or {}).items()}}
        for name, row in update_dict["parameters"].items():
            row["nominal"] = (row.get("prior") or {}).get("mean", nominal_values.get(name))
            row["true"] = None if true_params is None else true_params.get(name)
            short = name.split("_n_per")[0]
            if true_params is not None and f"{short}_at_excitation" in true_params:
                # ki, ks: a linear model fitted to data taken with an excitation estimates the slopes that
                # excitation sees (excitation_slopes), not the small-signal ones at rest
                row["true_small_signal"] = row["true"]
                row["true"] = true_params[f"{short}_at_excitation"]
            row["error"] = None if row["true"] in (None, 0) else row["value"] / row["true"] - 1
        if true_params is not None:
            update_dict["true_centre"] = dict(ki_n_per_a=true_params["ki_centre_n_per_a"],
                                              ks_n_per_m=true_params["ks_centre_n_per_m"])
        lag = update_dict.get("total_lag")
        if lag is not None and true_params is not None:
            lag["true"] = total_lag({k: true_params[k] for k in ("amplifier_bandwidth_hz", "sensor_bandwidth_hz",
                                                                  "delay_s") if k in true_params})
        if update_dict["prior_dominated"]:
            notes.append(f"the data tell little about {', '.join(update_dict['prior_dominated'])}: their intervals "
                         "are mostly their tolerances (posterior / prior width above 0.71); "
                         + ("the total lag, which the data do tell, is in update.total_lag"
                            if lag is not None else "see update.parameters"))
    elif update_error:
        update_dict = dict(error=update_error)
    # the experiment's samples, read once: what spoils them (said in the summary) and the report's figures
    samples = _experiment_samples(path, chosen, design, frf, recover)
    quality = _quality(samples, chosen, design, frf)
    summary: dict[str, Any] = dict(
        session=path, experiment_id=chosen["experiment_id"], estimator=frf.estimator,
        excitation=dict(kind=design.kind, mimo=design.options.get("mimo"), grid=design.options.get("grid"),
                        sample_rate_hz=design.fs_hz, samples_per_period=design.n_per_period,
                        n_periods=design.n_periods, n_transient_periods=design.n_transient_periods,
                        n_realisations=design.n_realisations, n_experiments=design.n_experiments,
                        n_excited_lines=int(design.excited_lines.size), design_band_hz=list(design.band_hz),
                        rms_a=design.rms_a, peak_a=design.peak_a, crest_factor=design.crest_factor,
                        measurement_time_s=design.measurement_time_s,
                        synchronous=design.options.get("synchronous")),
        band_hz=list(band), inputs=list(frf.input_names), outputs=list(frf.output_names),
        input_units=list(fit.model.input_units), output_units=list(fit.model.output_units),
        controller=(recorded or (None, None))[1],
        simulated=simulated, frf_error=frf_error, noise=noise,
        fit=dict(order=int(order), order_rule=mf.order_rule, chi2_per_dof=fit.chi2_per_dof, delay_s=mf.delay_s,
                 weights=w_kind, orders_tried=diagram.orders, chi2_per_dof_by_order=diagram.chi2_per_dof,
                 modes=mode_rows, computational_poles=mf.computational, real_poles=mf.real_rows,
                 refine_message=fit.message),
        intervals=dict(
            noise_only=[] if var is not None and var_kind.startswith("var_total") else
            ["frf band", "parameters", "modes"],
            frf_band=f"+-2 sigma with sigma^2 = {var_kind} (total: noise and the stochastic nonlinear "
                     "distortion, from the realisation-to-realisation scatter; noise only with one realisation). "
                     "It covers the best linear approximation at this excitation level (the magnets' slopes "
                     "averaged over the excursions the excitation causes), not the small-signal model at rest: "
                     "the magnets' nonlinearity shifts the low lines by about 0.5-1 %, a bias no variance holds",
            noise_std="95 % interval (Student t) of each output's noise std from the scatter of the segments' "
                      "period-to-period variances (the noise is coloured by the loop, so the samples' chi2 "
                      "degrees of freedom would be too many); the truth is the sensor noise through the loop",
            parameters="95 % intervals (Student t) of the physical parameters of the linear model that best "
                       "describes the rig at this excitation level (its best linear approximation), the data and "
                       "each parameter's tolerance together (maximum a posteriori; where prior_dominated, mostly "
                       "the tolerance about the nominal value). On a nonlinear rig these differ from the "
                       "parameters at rest by a bias no variance holds: ki and ks by the magnets' slopes averaged "
                       "over the excursions (true: those slopes, true_small_signal: at rest), the lags by the "
                       "approximation's phase (the total lag by about 0.1 % on the default rig; true: at rest). "
                       "From a sandwich covariance pooled with the realisations' scatter "
                       "(ambid.fit.correlated.realisation_inflation): the Jacobian of the fit weighted "
                       f"by {w_kind}, the line covariance {var_kind}, the errors of a line correlated (within a "
                       "row through U^-1, between rows as the residuals show), scaled by the generalised "
                       "chi2/dof, so they hold the misfit too. The sensor bandwidth, amplifier bandwidth and "
                       "delay are strongly correlated; their sum is update.total_lag. ambid validate measures "
                       "the coverage against the parameters of the best linear approximation (docs/uncertainty.md)",
            modes="95 % intervals (Student t of 2 + M - 1 degrees of freedom where M >= 2 realisations' scatter "
                  "joins the sandwich in the variance; else 1.96 sigma) of the "
                  "fitted modes from the variable-projection sandwich "
                  "covariance of the common denominator's factors (the same line covariance as the parameters); "
                  "a cluster of true modes closer than the resolution has none"),
        modes_vs_true=modes_vs_true,
        synchronous=_synchronous_dict(frf),
        max_mode_freq_error=max((abs(r["freq_error"]) for r in modes_vs_true), default=None),
        max_mode_damping_error=max((abs(r["damping_error"]) for r in modes_vs_true), default=None),
        update=update_dict,
        quality=dict(findings=quality, coherence=dict(
            min=float(np.nanmin(frf.coherence)) if np.size(frf.coherence) else None,
            median=float(np.nanmedian(frf.coherence)) if np.size(frf.coherence) else None,
            per_line="frf.npz: coherence (L, Ny), each output's multiple coherence with the excitation")),
        sensitivity=_sensitivity_summary(frf, inputs, fit, refs, the_rig, upd, recorded, dt_s),
        files=dict(model_npz=str(out / "model.npz"), model_json=str(out / "model.json"),
                   frf_npz=str(out / "frf.npz"), summary_json=str(out / "identification.json")),
        notes=notes)
    if on_summary is not None:
        on_summary(to_jsonable({**summary, "wall_s": time.perf_counter() - t0}))
    if report:

        levels, window = _samples_for_report(samples, design, frf, int(chosen["start_index"]))
        dense = np.geomspace(max(band[0] / 1.5, 1e-3), min(band[1] * 1.5, 0.499 * design.fs_hz), 400)
        curves = {"fitted model": (dense, fit.model.freqresp(dense))}
        if the_rig is not None and not covers(the_rig.rotor_model(), frf.output_names, frf.input_names):
            curves["analytical (nominal) model"] = (dense, physical_frf(the_rig.rotor_model(),
                                                                        nominal_parameters(the_rig), dense, dt_s))
        if upd is not None:
            curves["updated physical model"] = (dense, physical_frf(the_rig.rotor_model(), upd.parameters,
                                                                     dense, dt_s))
        if true_rig is not None:
            curves["true rig (simulated)"] = (dense, _on_channels(true_linear_model(true_rig, discrete=True), dense,
                                                                  frf.output_names, frf.input_names))
        line_models = {"fitted model": fit.model.freqresp(f)}
        if upd is not None:
            line_models["updated physical model"] = physical_frf(the_rig.rotor_model(), upd.parameters, f, dt_s)
        summary["files"]["report"] = str(out / "report" / "index.html")
        summary["wall_s"] = time.perf_counter() - t0
        extra = []
        if dfrf is not None:
            d_curves = {label: directional_frf(fc, gc, None, frf.output_names, frf.input_names)
                        for label, (fc, gc) in curves.items() if label in ("fitted model", "true rig (simulated)")}
            whirls = [(row["freq_hz"], row["whirl"]) for row in mode_rows]
            extra.append(("directional_frf.png", "Directional FRFs p / f (p = x + j y, f = u_x + j u_y per bearing "
                          "plane): forward whirl (blue) and backward whirl (red), measured (dots) and models; a "
                          "forward mode peaks in the forward FRF, a backward one in the backward FRF.",
                          lambda p: directional_frf_figure(dfrf, d_curves, whirls, p)))
        write_report(out / "report", to_jsonable(summary), frf=frf, design=design, diagram=diagram, order=int(order),
                     curves=curves, levels=levels, window=window, true_frf=true_g, line_models=line_models,
                     extra_figures=extra, band_variance=band_var, band_kind=_band_kind(var_kind))
    summary["wall_s"] = time.perf_counter() - t0
    summary = to_jsonable(summary)
    (out / "identification.json").write_text(json.dumps(summary, indent=1))
    return summary


def _on_channels(model: StateSpace, freq_hz: np.ndarray, output_names: Sequence[str],
                 input_names: Sequence[str]) -> np.ndarray:
    """A model's FRF at ``freq_hz`` on the measured FRF's channels: its rows and columns picked by name, so a
    session that excited some of the rig's inputs is compared with the same entries of the truth."""
    g = model.freqresp(freq_hz)
    rows = [model.output_names.index(n) for n in output_names]
    cols = [model.input_names.index(n) for n in input_names]
    # C order, as freqresp gives it: the error norms sum in memory order, the default rig's to the last bit
    return np.ascontiguousarray(g[:, rows][:, :, cols])


def _synchronous_dict(frf: FrfResult) -> dict | None:
    """The synchronous response at the disturbance lines of a run at speed (None at standstill)."""
    s = frf.synchronous
    if s is None:
        return None
    return dict(on_lines=s.on_lines, n_records=s.n_records, channels=list(s.channel_names),
                harmonics=[dict(harmonic=int(k), freq_hz=float(fq), amplitude=a, phase_deg=np.degrees(ph),
                                amplitude_std=sd)
                           for k, fq, a, ph, sd in zip(s.harmonic, s.freq_hz, s.amplitude, s.phase_rad,
                                                       s.amplitude_std)])


def _experiment_samples(path: str, chosen: dict, design: ExcitationDesign, frf: FrfResult, recover: bool):
    """The experiment's samples of the FRF's outputs, inputs and excitation (a SampleRange), or None."""
    topic = chosen["topic"].rstrip("/")[:-len(_DESIGN_TOPIC)] + _MEASUREMENT_TOPIC
    refs = [("r_" + n[2:]) if n.startswith("u_") else "r_" + n for n in frf.input_names]
    names = list(frf.output_names) + list(frf.input_names) + refs
    start = chosen["start_index"]
    total = min(chosen["total_samples"], design.total_samples)
    try:
        return read_samples(path, topic, start, start + total, names, recover=recover)
    except ValueError:
        return None


def _quality(data, chosen: dict, design: ExcitationDesign, frf: FrfResult) -> list[dict]:
    """What spoils the record (:func:`ambid.frf.quality.record_quality`), one finding each; [] without samples."""
    if data is None:
        return []
    ny, nu = len(frf.output_names), len(frf.input_names)
    names = list(frf.output_names) + list(frf.input_names) + [f"r_{_axis(n)}" for n in frf.input_names]
    found = record_quality(data.data, names, design.fs_hz, frf.freq_hz, frf.coherence, frf.output_names,
                           names[ny + nu:], first_row=int(chosen["start_index"]))
    return [q.to_dict() for q in found]


def _samples_for_report(data, design: ExcitationDesign, frf: FrfResult, start: int
                        ) -> tuple[LineLevels | None, dict | None]:
    """Line levels of the whole experiment and a short time window of y, u, r."""
    if data is None:
        return None, None
    total = data.data.shape[0]
    ny, nu = len(frf.output_names), len(frf.input_names)
    levels = line_levels(data.data[:, :ny], design)
    w0 = design.n_transient_periods * design.n_per_period if design.kind != "stepped_sine" else 0
    n_win = int(min(design.n_per_period, round(0.05 * design.fs_hz), total - w0))
    window = None
    if n_win > 1:
        x = data.data[w0:w0 + n_win]
        window = dict(t_s=(start + w0 + np.arange(n_win)) / design.fs_hz, y=x[:, :ny], u=x[:, ny:ny + nu],
                      r=x[:, ny + nu:], output_names=frf.output_names, input_names=frf.input_names)
    return levels, window



def recorded_controller(path: str | os.PathLike, recover: bool = False) -> tuple[StateSpace, dict] | None:
    """The controller that ran: its discrete state space and its facts (kind, delay, parameters, ...) from
    the session's ControllerDescription, or None when the session has none."""
    for msg, dec in iter_decoded(path, recover=recover):
        if msg.topic.endswith("controller/description"):
            return controller_model(dec), controller_facts(dec)
    return None


def _axis(name: str) -> str:
    """The axis of a channel name (``y_a_x``, ``ic_a_x``, ``u_a_x`` -> ``a_x``); another name as it is."""
    try:
        return split_name(name)[1]
    except ValueError:
        return axis_tag(name)


def _aligned_controller(k: StateSpace, output_names: Sequence[str],
                        input_names: Sequence[str]) -> StateSpace | None:
    """The controller y -> ic with its inputs in the FRF's output order and its outputs in the FRF's input
    order, matched by axis (``y_a_x`` <-> ``y_a_x``, ``u_a_x`` <-> ``ic_a_x``); as it is when its
    channels are unnamed and the sizes agree; None when the two do not close one loop."""
    if not (k.input_names and k.output_names and output_names and input_names):
        return k if (k.n_inputs, k.n_outputs) == (len(output_names), len(input_names)) else None
    ins, outs = [_axis(n) for n in k.input_names], [_axis(n) for n in k.output_names]
    want_in, want_out = [_axis(n) for n in output_names], [_axis(n) for n in input_names]
    if sorted(ins) != sorted(want_in) or sorted(outs) != sorted(want_out):
        return None
    rows, cols = [outs.index(a) for a in want_out], [ins.index(a) for a in want_in]
    if rows == sorted(rows) and cols == sorted(cols):
        return k  # already in order: the very matrices, so the figures do not move by a rounding
    return k._replace(b=np.ascontiguousarray(k.b[:, cols]), c=k.c[rows], d=k.d[np.ix_(rows, cols)],
                      input_names=tuple(k.input_names[i] for i in cols),
                      output_names=tuple(k.output_names[i] for i in rows))


def _model_sensitivity(model, refs: ReferenceModels) -> dict:
    """Input-sensitivity peak between the excited lines: S = (I - K G_fit)^-1 on a dense grid.

    The measured S is known only at the excited lines, which can straddle a
    sharp peak; the fitted plant with the recorded controller K(z) gives it in
    between (K on the grid: ``refs.controller_frf``). With a simulated rig, the
    true loop's peak is given beside it (``refs.true_loop``).
    """
    if refs.controller_frf is None:
        return {}
    f = refs.sens_freq_hz
    g = model.freqresp(f)
    kz = refs.controller_frf
    s = np.linalg.inv(np.eye(g.shape[2])[None] - kz @ g)
    diag = np.abs(np.diagonal(s, axis1=1, axis2=2))
    i = diag.argmax(axis=0)
    peak = diag[i, np.arange(diag.shape[1])]
    out = dict(model_peak=peak, model_peak_hz=f[i], model_iso_zone=iso14839_zone(float(peak.max())),
               model_note="fitted plant with the recorded controller, 8000 lines over the band")
    if refs.true_loop is not None:
        out.update(refs.true_loop)
    return out


def _sensitivity_summary(frf: FrfResult, inputs: SessionInputs, fit: FitResult, refs: ReferenceModels,
                         rig: Rig | None, upd: PhysicalUpdate | None, recorded, dt_s: float) -> dict:
    """The loop sensitivity the session shows, per excitation channel by where it was injected
    (:func:`ambid.frf.sensitivity.sensitivity_shown`), and the headline: the worst peak over the measured lines
    and the fitted model between them (with the recorded controller), its frequency and which of the two it came
    from, and its ISO 14839-3 zone; one line per channel that shows none, saying why."""
    units = inputs.units
    shown = sensitivity_shown(frf.frf, frf.sensitivity, frf.output_names, frf.input_names, inputs.injected_at,
                              [units.get(n, "m") for n in frf.output_names],
                              [units.get(f"r_{_axis(n)}", "A") for n in frf.input_names])
    f = frf.freq_hz
    channels = []
    for sh in shown:
        row = dict(excitation=sh.excitation, injected_at=sh.injected_at, kind=sh.kind or None, why=sh.why)
        if sh.values is not None:
            mag = np.abs(sh.values)
            k = int(np.argmax(mag))
            row.update(peak=float(mag[k]), peak_hz=float(f[k]), iso_zone=iso14839_zone(float(mag[k])))
        channels.append(row)
    with_peak = [c for c in channels if "peak" in c]
    out: dict[str, Any] = dict(channels=channels)
    if all(sh.injected_at == "current" for sh in shown):
        # ambid's own sessions: the input sensitivity at the lines, as before
        worst = int(np.argmax(frf.sensitivity_peak))
        out.update(peak=frf.sensitivity_peak, peak_hz=frf.sensitivity_peak_hz, worst_input=frf.input_names[worst],
                   worst_peak=float(frf.sensitivity_peak[worst]), iso_zone=frf.iso_zone,
                   **_model_sensitivity(fit.model, refs), **_updated_sensitivity(rig, upd, recorded, dt_s))
    elif with_peak:
        w = max(with_peak, key=lambda c: c["peak"])
        out.update(worst_input=w["excitation"], worst_peak=w["peak"], peak_hz_worst=w["peak_hz"],
                   iso_zone=w["iso_zone"])
    else:
        out.update(worst_input=None, worst_peak=None, iso_zone=None)
    out["none"] = [c["why"] for c in channels if "peak" not in c]
    # the headline: the loop's worst peak, over the measured lines and the fitted model between them
    cands = [(c["peak"], c["peak_hz"], "the measured lines", c["excitation"]) for c in with_peak]
    if out.get("model_peak") is not None:
        mp = np.asarray(out["model_peak"], dtype=float)
        k = int(np.argmax(mp))
        cands.append((float(mp[k]), float(np.asarray(out["model_peak_hz"])[k]),
                      "the fitted model between the lines (with the recorded controller)", frf.input_names[k]))
    if cands:
        peak, hz, source, chan = max(cands, key=lambda c: c[0])
        out["loop"] = dict(peak=peak, peak_hz=hz, source=source, channel=chan, iso_zone=iso14839_zone(peak))
    else:
        out["loop"] = None
    return out


def _nominal_values(rig: Rig, nominal: Mapping[str, float] | None) -> dict[str, float]:
    return {**nominal_update_parameters(rig), **{k: float(v) for k, v in (nominal or {}).items()}}


def _loop_notes(rig: Rig, nominal: Mapping[str, float] | None, upd: PhysicalUpdate | None, controller: StateSpace,
                dt_s: float) -> list[str]:
    """What the nominal and the updated model say about the loop that ran (which was stable: it was measured)."""
    notes = []
    rotor = rig.rotor_model()
    for label, params in (("the nominal model (the rig file's values)", _nominal_values(rig, nominal)),
                          ("the updated model", None if upd is None else upd.parameters)):
        if params is None:
            continue
        try:
            poles = close_loop(physical_discrete(rotor, params, dt_s), controller).poles()
        except ValueError:
            continue
        bad = poles[np.abs(poles) >= 1.0]
        if bad.size:
            s_bad = np.log(bad.astype(complex)) / dt_s
            hz = sorted({round(abs(v.imag) / (2 * np.pi), 1) for v in s_bad})
            notes.append(f"{label} is unstable with the controller that ran (closed-loop poles outside the unit "
                         f"circle at {', '.join(f'{h:g}' for h in hz)} Hz), although the measured loop was stable: "
                         + ("the FRF, the modes and the update come from the data and are kept; the sensitivity "
                            "is the updated model's" if upd is not None and label.startswith("the nominal") else
                            "its values are off; check the rig file"))
    return notes


def _updated_sensitivity(rig: Rig | None, upd: PhysicalUpdate | None, recorded, dt_s: float) -> dict:
    """Peak input sensitivity and ISO 14839-3 zone of the updated physical model with the recorded controller."""
    if rig is None or upd is None or recorded is None:
        return {}
    try:
        rob = loop_robustness(physical_discrete(rig.rotor_model(), upd.parameters, dt_s), recorded[0])
    except ValueError:
        return dict(updated_note="the updated model's loop with the recorded controller is unstable: no peak")
    return dict(updated_peak=rob.sensitivity_peak, updated_peak_hz=rob.peak_freq_hz, updated_iso_zone=rob.zone,
                updated_note="updated physical model with the recorded controller")


# ---------------------------------------------------------------------------------------------------------------
# What an identification reads from its session (read once), and what it compares the measurement with (the
# same whatever was measured): apart, so that a running session can have both before its recording is closed
# (ambid.studies.early_analysis).

@dataclass(frozen=True)
class SessionInputs:
    """What the identification of one experiment takes from its session.

    Attributes:
        path: the session file.
        experiment: the experiment's entry as :func:`ambid.frf.offline.session_designs` lists it
            (``topic``, ``experiment_id``, ``start_index``, ``total_samples``, ``design``).
        frf: its FRF (:func:`ambid.frf.offline.frf_from_session`); None before the measurement ends.
        rig_facts: the rig parameters the session recorded (:func:`session_rig`), or None.
        plant_source: ``'sim'``, ``'hardware'`` or None.
        controller: the controller that ran, (discrete StateSpace y -> ic, facts), or None.
        nonlinear_magnets: the simulated plant ran the nonlinear magnets.
        injected_at: excitation channel -> where the rig adds it ('current', 'reference', 'output'); an
            imported record's MAP.yaml says (ambid's own sessions: current, the default).
        units: channel -> unit, where an imported record says (outputs of any kind).
    """

    path: str
    experiment: dict
    frf: FrfResult | None
    rig_facts: dict | None
    plant_source: str | None
    controller: tuple[StateSpace, dict] | None
    nonlinear_magnets: bool
    injected_at: dict = dataclasses.field(default_factory=dict)
    units: dict = dataclasses.field(default_factory=dict)

    def digest(self) -> str:
        """A hash of everything the identification reads from these inputs (equal digests: equal numbers)."""
        e = self.experiment
        d = e["design"]
        return _digest([e["topic"], e["experiment_id"], e["start_index"], min(e["total_samples"], d.total_samples),
                        d.to_dict(), self.frf, self.rig_facts, self.plant_source, _controller_parts(self.controller),
                        self.nonlinear_magnets])


def read_session_inputs(path: str | os.PathLike, estimator: str = "indirect", experiment_id: str | None = None,
                        recover: bool = False) -> SessionInputs:
    """:class:`SessionInputs` of one experiment (default the last) of a session file, each read once."""
    path = os.fspath(path)
    frf = frf_from_session(path, estimator=estimator, experiment_id=experiment_id, recover=recover)
    designs = session_designs(path, recover=recover)
    chosen = [d for d in designs if experiment_id is None or d["experiment_id"] == experiment_id][-1]
    namespace = chosen["topic"].rstrip("/")[:-len(_DESIGN_TOPIC)]
    facts, source = session_rig(path, namespace + _PLANT_TOPIC, recover=recover)
    injected_at, units = _import_facts(path, recover)
    return SessionInputs(path, chosen, frf, facts, source, recorded_controller(path, recover),
                         _nonlinear_magnets(path, recover), injected_at, units)


def _import_facts(path: str, recover: bool) -> tuple[dict, dict]:
    """(injected_at, units) an imported record's session facts carry ({} for ambid's own sessions)."""
    facts = _session_fact(path, "import", recover)
    injected, units = facts.get("injected_at"), facts.get("units")
    return (dict(injected) if isinstance(injected, dict) else {}), (dict(units) if isinstance(units, dict) else {})


def inputs_from_messages(path: str | os.PathLike, design_topic: str, design_msg: Any, plant_msg: Any,
                         controller_msg: Any, frf: FrfResult | None, nonlinear_magnets: bool) -> SessionInputs:
    """:class:`SessionInputs` from the messages a session publishes, read as the recording's are read.

    For a caller that has the session's messages before its recording is closed (the composed graph):
    ``design_msg`` (the experiment's last ExcitationDesign), ``plant_msg`` (PlantDescription) and
    ``controller_msg`` (ControllerDescription, or None) as rclpy messages or decoded ones, ``frf`` the
    estimate of the FRF consumer, which runs the stream :func:`ambid.frf.offline.frf_from_session` runs
    (None while the measurement runs).
    """
    design = ExcitationDesign.from_dict(json.loads(design_msg.design_json))
    experiment = {"topic": design_topic, "experiment_id": design_msg.experiment_id,
                  "start_index": int(design_msg.start_index), "total_samples": int(design_msg.total_samples),
                  "design": design}
    facts = json.loads(plant_msg.rig_json) if plant_msg is not None and plant_msg.rig_json else None
    source = plant_facts(plant_msg)["source"] if plant_msg is not None else None
    controller = (None if controller_msg is None else
                  (controller_model(controller_msg), controller_facts(controller_msg)))
    return SessionInputs(os.fspath(path), experiment, frf, facts if isinstance(facts, dict) and facts else None,
                         str(source) if source else None, controller, bool(nonlinear_magnets))


@dataclass(frozen=True)
class ReferenceModels:
    """What an identification compares the measurement with that the measurement does not change.

    Attributes:
        key: :func:`reference_key` of the inputs it was made for.
        true_g: (L, Ny, Nu) the simulated true rig's small-signal FRF at the lines (sampled), or None.
        true_params: its physical parameters (and the magnets' slopes at this excitation), or None.
        true_g_x: (L, Ny, Nu) the true rig linearised at this excitation's level, or None.
        true_noise: (Ny,) the sensor noise through the true loop [m], or None.
        true_poles: s-plane poles [rad/s] of the linear system this excitation measures, or None.
        sens_freq_hz: (8000,) the band's dense grid of the input-sensitivity check [Hz], or None.
        controller_frf: (8000, Nu, Ny) the recorded controller there, or None.
        true_loop: the true loop's input-sensitivity peak (true_peak, true_peak_hz, true_iso_zone), or None.
    """

    key: str
    true_g: np.ndarray | None = None
    true_params: dict | None = None
    true_g_x: np.ndarray | None = None
    true_noise: np.ndarray | None = None
    true_poles: np.ndarray | None = None
    sens_freq_hz: np.ndarray | None = None
    controller_frf: np.ndarray | None = None
    true_loop: dict | None = None


def reference_key(inputs: SessionInputs, freq_hz: np.ndarray, output_names: Sequence[str],
                  input_names: Sequence[str]) -> str:
    """What :func:`reference_models` depends on, hashed: the rig facts, the controller's model, the design,
    the magnets, the lines and the FRF's channels."""
    d = inputs.experiment["design"]
    k = None if inputs.controller is None else inputs.controller[0]
    return _digest([inputs.rig_facts, inputs.plant_source, None if k is None else [k.a, k.b, k.c, k.d, k.dt],
                    d.to_dict(), inputs.nonlinear_magnets, np.asarray(freq_hz, dtype=float), list(output_names),
                    list(input_names)])


def reference_models(inputs: SessionInputs, freq_hz: np.ndarray, output_names: Sequence[str],
                     input_names: Sequence[str]) -> ReferenceModels:
    """The models :func:`identify_session` compares with (:class:`ReferenceModels`), from what ``inputs``
    say of the session, none of what it measured (``inputs.frf`` is not read): so they can be computed while
    the session still runs.

    Args:
        inputs: the session's inputs.
        freq_hz: (L,) the FRF's lines [Hz].
        output_names, input_names: the FRF's channels (``y_<axis>``, ``u_<axis>``): the truths are picked on
            them, the controller aligned to them by axis; the noise through the loop needs every sensor of the rig.
    """
    f = np.asarray(freq_hz, dtype=float)
    refs: dict[str, Any] = {}
    facts, design = inputs.rig_facts, inputs.experiment["design"]
    recorded = inputs.controller
    if facts is not None and inputs.plant_source == "sim":
        true_rig = make_rig(facts)
        refs["true_g"] = _on_channels(true_linear_model(true_rig, discrete=True), f, output_names, input_names)
        true_params = true_parameters(true_rig)
        true_plant_x = None
        if recorded is not None and design.is_periodic and inputs.nonlinear_magnets:
            # what this excitation measures: the magnets' slopes averaged over the excursions it causes
            ki_x, ks_x = excitation_slopes(true_rig, recorded[0], design)
            true_params.update({f"{k.split('_n_per')[0]}_at_excitation": v
                                for k, v in slopes_as_parameters(ki_x, ks_x, true_rig.layout).items()})
            true_plant_x = true_plant(true_rig, ki_x, ks_x)
            refs["true_g_x"] = _on_channels(true_linear_model(true_rig, discrete=True, plant=true_plant_x), f,
                                            output_names, input_names)
        refs["true_params"] = true_params
        if recorded is not None and tuple(output_names) == true_rig.layout.outputs:
            # the sensor noise through the loop this excitation linearises
            refs["true_noise"] = closed_loop_noise_std(true_rig, recorded[0], true_plant_x)
        # the modes of the linear system this excitation measures (the magnets' stiffness moves them)
        refs["true_poles"] = true_linear_model(true_rig, plant=true_plant_x).poles()
    k = None if recorded is None else _aligned_controller(recorded[0], output_names, input_names)
    if k is not None and f.size:   # the loop needs the plant on the controller's channels
        refs["sens_freq_hz"] = grid = np.linspace(float(f.min()), float(f.max()), 8000)
        refs["controller_frf"] = k.freqresp(grid)
        if facts is not None and inputs.plant_source == "sim":
            truth = loop_robustness(true_linear_model(make_rig(facts)), recorded[0])
            refs["true_loop"] = dict(true_peak=truth.sensitivity_peak, true_peak_hz=truth.peak_freq_hz,
                                     true_iso_zone=truth.zone)
    return ReferenceModels(key=reference_key(inputs, f, output_names, input_names), **refs)


def _controller_parts(controller: tuple[StateSpace, dict] | None) -> list | None:
    if controller is None:
        return None
    k, facts = controller
    return [k.a, k.b, k.c, k.d, k.dt, facts]


def _digest(obj: Any) -> str:
    """A SHA-256 of nested values: arrays by dtype, shape and bytes, floats exactly, dataclasses by field."""
    h = hashlib.sha256()

    def feed(x: Any) -> None:
        if isinstance(x, np.ndarray):
            h.update(f"a{x.dtype.str}{x.shape}".encode())
            h.update(np.ascontiguousarray(x).tobytes())
        elif dataclasses.is_dataclass(x) and not isinstance(x, type):
            h.update(type(x).__name__.encode())
            for fld in dataclasses.fields(x):
                h.update(fld.name.encode())
                feed(getattr(x, fld.name))
        elif isinstance(x, Mapping):
            h.update(b"{")
            for k in sorted(x, key=str):
                feed(str(k))
                feed(x[k])
            h.update(b"}")
        elif isinstance(x, (list, tuple)):
            h.update(b"[")
            for v in x:
                feed(v)
            h.update(b"]")
        elif isinstance(x, (float, np.floating)):
            h.update(b"f" + float(x).hex().encode())
        else:
            h.update(f"{type(x).__name__}:{x!r}".encode())

    feed(obj)
    return h.hexdigest()
