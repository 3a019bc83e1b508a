"""Stage 4, the update: the rig's physical model updated to the FRF, and what it says about the loop.

:func:`update_rig` makes the MAP estimate (:mod:`ambid.fit.model_update`) with the nominal rig's values
and tolerances as priors, started from the data (the fitted modes, the FRF's level and phase), with an
extra support mode when the fit shows a mode the nominal model lacks. :func:`update_figures` joins the
nominal values and, for a simulated session, the truths; :func:`loop_notes` says whether the nominal and
the updated model are stable with the controller that ran (which was: it was measured).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ambid.control.closed_loop import close_loop
from ambid.fit.model_update import (PhysicalUpdate, bending_keys, covers, match_modes, nominal_update_parameters,
                                    parameter_prior, physical_discrete, physical_statespace, rig_channels,
                                    start_from_data, total_lag, unmodelled_mode, update_physical_model)
from ambid.fit.updating import NotIdentifiable, Prior
from ambid.frf.streaming import FrfResult
from ambid.identification.model_fit import FrfFit
from ambid.identification.session_frf import FrfVariances
from ambid.identification.result import (Identification, ParameterPrior, ParameterRow, TotalLag,
                                         UpdateFigures)
from ambid.plant.rig import Rig
from ambid.plant.tolerances import Z95
from ambid.statespace import StateSpace

__all__ = ["RigUpdate", "update_rig", "update_figures", "loop_notes", "nominal_values", "refit_parameters",
           "DEFAULT_FREE"]

#: what identify updates by default (those the rig has), besides the bending modes in the band and a support mode
DEFAULT_FREE = ("ki_n_per_a", "ks_n_per_m", "ks_b_over_a", "amplifier_bandwidth_hz", "sensor_bandwidth_hz",
                "delay_s", "axial_ki_n_per_a", "axial_ks_n_per_m", "axial_amplifier_bandwidth_hz")
_SUPPORT_KEYS = ("support_freq_hz", "support_damping_ratio", "support_gain_per_kg")


@dataclass(frozen=True)
class RigUpdate:
    """The outcome of :func:`update_rig`.

    Attributes
    ----------
    update
        the physical-model update, or None (not covered, failed, nothing free).
    error
        why it failed, or None.
    notes
        what was done differently and why (parameters kept fixed, channels not covered, ...).
    """

    update: PhysicalUpdate | None
    error: str | None = None
    notes: list[str] = field(default_factory=list)


def nominal_values(rig: Rig, nominal: Mapping[str, float] | None) -> dict[str, float]:
    """The rig's values of the updatable parameters, ``nominal`` replacing some."""
    return {**nominal_update_parameters(rig), **{k: float(v) for k, v in (nominal or {}).items()}}


def update_rig(rig: Rig, frf: FrfResult, fitted: FrfFit, dt_s: float, nominal: Mapping[str, float] | None = None,
               free: Sequence[str] | None = None) -> RigUpdate:
    """The physical-model update of ``rig`` to an FRF, weighted as the fit ``fitted`` was: the MAP estimate
    with ``rig``'s values (``nominal`` replacing some) and tolerances as priors, started from the data and
    ``fitted``'s stable modes, a support mode at a stable fitted mode the rig lacks.

    The nominal values (:func:`ambid.fit.model_update.nominal_update_parameters`, with ``nominal``) and the
    rig's tolerances make the prior; the bending modes start at the fitted modes, the gains and lags start
    from the FRF (:func:`ambid.fit.model_update.start_from_data`). Nothing is fixed because the data cannot
    tell it: such a direction keeps its prior's width.

    Parameters
    ----------
    rig
        the rig whose physical model is updated.
    frf
        the measured FRF.
    fitted
        its fit (:func:`ambid.identification.model_fit.fit_frf`): weights, band, stable modes.
    dt_s
        the sample period [s].
    nominal
        nominal values replacing the rig's (parameter name -> value).
    free
        parameters to update; default :data:`DEFAULT_FREE` (those the rig has), the bending modes in
        the band and a support mode where the fit shows one.
    """
    rotor = rig.rotor_model()
    part = _on_the_rigs_channels(rotor, frf, fitted.variances)
    if isinstance(part, str):
        return RigUpdate(None, None, [f"no physical model updating: {part}"])
    frf, v, sub_notes = part
    values = nominal_values(rig, nominal)
    modes = fitted.stable_modes()
    chosen = free is not None
    free = list(free) if chosen else _default_free(values, fitted.band_hz)
    known = [k for k in free if k in values]
    bending, used, notes = match_modes(rotor, values, known, parameter_prior(rig, known, values)[0],
                                       [(m.freq_hz, m.damping) for m in modes])
    notes = sub_notes + notes
    _add_support_mode(rig, rotor, values, bending, [m for k, m in enumerate(modes) if k not in used],
                      fitted.band_hz)
    if not chosen and all(k in values for k in _SUPPORT_KEYS):
        free += [k for k in _SUPPORT_KEYS if k not in free]
    prior, fixed = parameter_prior(rig, free, values)
    if fixed:
        keep = [k for k, name in enumerate(free) if name not in fixed]
        free = [free[k] for k in keep]
        prior = Prior(prior.mean[keep], prior.std[keep], prior.log[keep])
        notes.append(f"{', '.join(fixed)} kept at the nominal value (tolerance 'fixed' in the rig file)")
    if not free:
        return RigUpdate(None, "every parameter is fixed; nothing to update", notes)
    # the prior's centre where a range replaced the nominal value (the delay's 0..1 sample)
    centre = dict(values)
    centre.update({name: float(prior.mean[k]) for k, name in enumerate(free) if np.isfinite(prior.std[k])})
    centre.update(bending)
    try:
        start = start_from_data(rotor, frf.freq_hz, frf.frf, v.weights, centre, free, prior, dt_s)
        return RigUpdate(update_physical_model(rotor, frf.freq_hz, frf.frf, v.weights, start, free, dt_s,
                                               prior=prior, row_covariance=v.row_cov,
                                               realisations=v.realisations), None, notes)
    except NotIdentifiable as exc:
        return RigUpdate(None, (f"{exc}; the parameters {', '.join(exc.parameters)} have no tolerance here: give "
                                "them one under tolerances: in the rig file"), notes)
    except ValueError as exc:
        return RigUpdate(None, str(exc), notes)


def _on_the_rigs_channels(rotor, frf: FrfResult, v: FrfVariances) -> tuple[FrfResult, FrfVariances, list[str]] | str:
    """The FRF and its variances on the channels the rig model describes (the others, accelerometers or probes
    along the shaft, left out and said in a note), or why none can be updated."""
    not_covered = covers(rotor, frf.output_names, frf.input_names)
    if not not_covered:
        return frf, v, []
    picked = rig_channels(rotor, frf.output_names, frf.input_names)
    if picked is None:
        return not_covered
    rows, cols, left = picked
    frf = replace(frf, frf=frf.frf[:, rows][:, :, cols], output_names=tuple(frf.output_names[i] for i in rows),
                  input_names=tuple(frf.input_names[j] for j in cols))
    v = replace(v, weights=None if v.weights is None else v.weights[:, rows][:, :, cols],
                row_cov=None if v.row_cov is None else v.row_cov[:, rows][:, :, cols][:, :, :, cols],
                realisations=None if v.realisations is None else v.realisations[:, :, rows][:, :, :, cols])
    return frf, v, [f"physical model updating on the channels the rig model describes "
                    f"({', '.join(frf.output_names)} / {', '.join(frf.input_names)}); left out: "
                    f"{', '.join(left)} (not in the rig model)"]


def _default_free(values: Mapping[str, float], band_hz: tuple[float, float]) -> list[str]:
    """:data:`DEFAULT_FREE` that the rig has, and the bending modes within the measured band (one outside it
    cannot be identified from it)."""
    free = [k for k in DEFAULT_FREE if k in values]
    for mode in range(1, 9):
        fk, zk = bending_keys(mode)
        if fk in values and band_hz[0] <= values[fk] <= band_hz[1]:
            free += [fk, zk]
    return free


def _add_support_mode(rig: Rig, rotor, values: dict[str, float], bending: Mapping[str, float], rest: list,
                      band_hz: tuple[float, float]) -> None:
    """A support mode in ``values`` where the fit shows a mode (of ``rest``) that neither the nominal model nor
    its bending modes explain, unless the rig has one: its nominal is the fitted mode (no data sheet; its
    prior only keeps the problem well posed)."""
    # resonance peak height of R / (s - p) is |R| / (zeta omega)
    strength = [m.residue_singular_values[0] / (max(m.damping, 1e-6) * 2 * np.pi * m.freq_hz) for m in rest]
    extra = unmodelled_mode([m.freq_hz for m in rest], [m.damping for m in rest], strength,
                            physical_statespace(rotor, {**values, **bending}), band_hz)
    if extra is not None and not all(k in values for k in _SUPPORT_KEYS):
        values.update(support_freq_hz=extra[0], support_damping_ratio=extra[1],
                      support_gain_per_kg=2.0 / rig.rotor_mass_kg)


def update_figures(upd: PhysicalUpdate, rig: Rig, nominal: Mapping[str, float] | None,
                   true_params: Mapping[str, float] | None) -> tuple[UpdateFigures, list[str]]:
    """The update as identify records it: per parameter its nominal value (the prior's centre) and, where
    the truth is known, the true value and the relative error; the total lag's truth; and a note naming the
    parameters their tolerances set."""
    d = upd.to_dict()
    values = nominal_values(rig, nominal)
    rows = {}
    for name, row in d["parameters"].items():
        true = None if true_params is None else true_params.get(name)
        rest = None
        short = name.split("_n_per")[0]
        if true_params is not None and f"{short}_at_excitation" in true_params:
            # ki, ks: a linear model fitted to data taken with an excitation estimates the slopes that
            # excitation sees (excitation_slopes), not the small-signal ones at rest
            rest, true = true, true_params[f"{short}_at_excitation"]
        prior = row.get("prior")
        rows[name] = ParameterRow(
            value=row["value"], start=row["start"], unit=row["unit"], free=row["free"], std=row["std"],
            ci95=row["ci95"], prior=None if prior is None else ParameterPrior(**prior),
            prior_ratio=row.get("prior_ratio"), prior_dominated=row.get("prior_dominated"),
            nominal=(prior or {}).get("mean", values.get(name)), true=true, true_small_signal=rest,
            error=None if true in (None, 0) else row["value"] / true - 1)
    lag = d["total_lag"]
    if lag is not None:
        lag = TotalLag(**lag, true=None if true_params is None else total_lag(
            {k: true_params[k] for k in ("amplifier_bandwidth_hz", "sensor_bandwidth_hz", "delay_s")
             if k in true_params}))
    figures = UpdateFigures(
        parameters=rows, chi2_per_dof=d["chi2_per_dof"], dof=d["dof"], success=d["success"],
        covariance_inflation=d["covariance_inflation"], total_lag=lag, prior_dominated=d["prior_dominated"],
        message=d["message"], n_evaluations=d["n_evaluations"], correlation=d["correlation"], free=d["free"],
        true_centre=None if true_params is None else dict(ki_n_per_a=true_params["ki_centre_n_per_a"],
                                                         ks_n_per_m=true_params["ks_centre_n_per_m"]))
    notes = []
    if figures.prior_dominated:
        notes.append(f"the data tell little about {', '.join(figures.prior_dominated)}: their intervals "
                     "are mostly their tolerances (posterior / prior width above 0.71); "
                     + ("the total lag, which the data do tell, is in update.total_lag"
                        if lag is not None else "see update.parameters"))
    return figures, notes


def loop_notes(rig: Rig, nominal: Mapping[str, float] | None, upd: PhysicalUpdate | None, controller: StateSpace,
               dt_s: float) -> list[str]:
    """What the nominal and the updated model say about the loop that ran (which was stable: it was measured)."""
    notes = []
    rotor = rig.rotor_model()
    for label, params in (("the nominal model (the rig file's values)", nominal_values(rig, nominal)),
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


def refit_parameters(identification: Identification, rig: Rig, freq_hz: np.ndarray, G: np.ndarray,
                     var: np.ndarray | None) -> dict[str, float]:
    """The updated parameters of an identification fitted again to another FRF at the same lines.

    E.g. a noise-free twin of the session (``ambid validate``): started at the identification's
    estimates, the same parameters free, the same priors and weights ``var``.

    Parameters
    ----------
    identification
        :func:`ambid.identification.identify_session`'s result, with an update.
    rig
        the rig the session updated.
    freq_hz
        (L,) lines [Hz].
    G
        (L, na, na) FRF u -> y [m/A] on the rig's axes.
    var
        (L, na, na) the session's fit variance [(m/A)^2], or None.

    Returns
    -------
    free parameter name -> estimate; {} without an update.
    """
    params = ((identification.update.parameters if identification.update is not None else None) or {})
    start = {k: float(v.value) for k, v in params.items()}
    free = [k for k, v in params.items() if v.free]
    if not free:
        return {}
    mean, sd, log = [], [], []
    for k in free:
        pr = params[k].prior
        if pr is None:
            mean.append(start[k])
            sd.append(np.inf)
            log.append(False)
            continue
        hi = float(pr.ci95[1])
        mean.append(float(pr.mean))
        sd.append(np.log(hi / pr.mean) / Z95 if pr.log else (hi - pr.mean) / Z95)
        log.append(bool(pr.log))
    prior = Prior(np.array(mean), np.array(sd), np.array(log, dtype=bool))
    upd = update_physical_model(rig.rotor_model(), freq_hz, G, var, start, free, rig.dt, prior=prior)
    return {k: float(upd.parameters[k]) for k in free}
