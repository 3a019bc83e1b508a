"""The whole offline identification of a recorded session, in one call: the stages in their order.

:func:`identify_session` runs, on one experiment of a session MCAP file:

1. the inputs (:func:`ambid.identification.inputs.read_session_inputs`): the FRF matrix u -> y with its
   noise (and, with M >= 2 realisations, total) variance, the design, the rig and the controller recorded;
2. the FRF's variances and directional form (:func:`ambid.identification.session_frf.session_frf`);
3. the fit (:func:`ambid.identification.model_fit.fit_frf`): order selection on a stabilisation diagram
   and the common-denominator fit at that order, with a known delay of half a sample; modes (frequency,
   damping) and real poles, the state-space export (``model.npz``, ``model.json``);
4. the update (:func:`ambid.identification.update.update_rig`): the MAP estimate with the nominal rig's
   values and tolerances as priors, started from the data; the nominal and the updated model's loop with
   the recorded controller are checked and said; where the rig model covers the FRF's channels (a note
   says so where it does not: channels are data, a record of one axis or one plane is fitted all the same);
5. the truth, when the session is simulated (rig facts recorded, plant source 'sim') or a true model is
   given (:func:`ambid.identification.truth.truth_of`): the FRF error and the modes against it;
6. the sensitivity (:func:`ambid.identification.sensitivity.sensitivity_figures`);
7. the report (``out_dir/report/index.html``, :mod:`ambid.identification.report`) and
   ``identification.json``: the :class:`ambid.identification.result.Identification` returned.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from ambid.fit import save_model_json, save_model_npz
from ambid.frf.streaming import FrfResult
from ambid.identification.inputs import SessionInputs, read_session_inputs
from ambid.identification.model_fit import FrfFit, fit_frf
from ambid.identification.quality import experiment_samples, quality_figures
from ambid.identification.references import ReferenceModels, reference_key, reference_models
from ambid.identification.report import write_identification_report
from ambid.identification.result import (ExcitationFacts, FitFigures, Identification, OutputFiles, UpdateFigures,
                                         session_intervals)
from ambid.identification.sensitivity import sensitivity_figures
from ambid.identification.session_frf import SessionFrf, session_frf
from ambid.identification.truth import Truth, frf_error_figures, truth_of
from ambid.identification.update import RigUpdate, loop_notes, update_figures, update_rig
from ambid.plant.rig import Rig, load_rig, make_rig
from ambid.statespace import StateSpace

__all__ = ["identify_session"]


def identify_session(mcap_path: str | os.PathLike, out_dir: str | os.PathLike, estimator: str = "indirect",
                     order: int | None = None, *, experiment_id: str | None = None,
                     rig: Rig | str | os.PathLike | Mapping | None = None, max_order: int = 32,
                     order_penalty: float = 2.0, update: bool = True,
                     nominal: Mapping[str, float] | None = None,
                     update_free: Sequence[str] | None = None, report: bool | str = True,
                     recover: bool = False, true_model: StateSpace | None = None,
                     inputs: SessionInputs | None = None,
                     references: ReferenceModels | Callable[[], ReferenceModels | None] | None = None,
                     on_summary: Callable[[Identification], None] | None = None) -> Identification:
    """Identify the rig from one experiment of a recorded session (module docstring).

    Args:
        mcap_path: session .mcap file.
        out_dir: folder for model.npz, model.json, frf.npz, identification.json
            and report/ (created).
        estimator: FRF estimator (:data:`ambid.frf.streaming.ESTIMATORS`).
        order: model order; None selects it (:func:`ambid.identification.model_fit.select_order`).
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
        report: write the HTML report; ``"background"``: have a detached process write it
            (:mod:`ambid.background`, its state in ``report/status.json``) and return without waiting for it.
        recover: read a session file a killed recorder left.
        true_model: the plant the session measured, u [A] -> y [m], when it is
            known from elsewhere (a hardware session against the C reference
            target, whose model file says what it runs): the FRF error and the
            modes are compared with it, as with a simulated session's true rig.
        inputs: what the session holds (:func:`ambid.identification.inputs.read_session_inputs`), when the
            caller has it already (e.g. from the running graph, before the recording is closed); default read
            from ``mcap_path``.
        references: :func:`ambid.identification.references.reference_models` computed ahead (e.g. while the
            session ran), or a function returning them, called once the fit and the update are done (so they
            can still be in the making meanwhile); used when their key matches these inputs, else computed
            here: the numbers are the same.
        on_summary: called with the result before the report is written, so that a caller can show it
            without waiting for the figures.

    Returns:
        The :class:`ambid.identification.result.Identification` (also written to ``identification.json``):
        the experiment, the FRF's noise, the fit and its modes, the update, the sensitivity, against the
        truth where there is one, the files, the notes (what could not be done and why) and the wall time.
    """
    t0 = time.perf_counter()
    out, path = Path(out_dir), os.fspath(mcap_path)
    if inputs is None:
        inputs = read_session_inputs(path, estimator, experiment_id, recover)
    frf, design = inputs.frf, inputs.design
    out.mkdir(parents=True, exist_ok=True)  # only once the session gave an FRF: a refusal leaves nothing behind
    dt_s = design.dt_s
    measured = session_frf(frf)
    notes = list(measured.notes)
    fitted = fit_frf(frf, design.fs_hz, order, max_order=max_order, order_penalty=order_penalty,
                     units=inputs.units, variances=measured.variances)
    save_model_npz(out / "model.npz", fitted.fit.model)
    save_model_json(out / "model.json", fitted.fit.model)
    the_rig, updated = _update_stage(rig, inputs, true_model, update, fitted, dt_s, nominal, update_free, notes)
    # the truths, after the fit and the update: reference models still in the making meanwhile are waited for
    # only now
    refs = _references(references, inputs, frf)
    truth = truth_of(inputs.simulated, refs, true_model, fitted, frf.freq_hz, design.fs_hz / design.n_per_period)
    measured.save(out / "frf.npz", truth.g, truth.g_at_excitation)
    recorded = None if inputs.controller is None else inputs.controller[0]
    if the_rig is not None and recorded is not None and update:
        notes += loop_notes(the_rig, nominal, updated.update, recorded, dt_s)
    figures = None if updated.error is None else UpdateFigures(error=updated.error)
    if updated.update is not None:
        figures, update_notes = update_figures(updated.update, the_rig, nominal, truth.parameters)
        notes += update_notes
    # the experiment's samples, read once: what spoils them (said in the result) and the report's figures
    samples = experiment_samples(path, inputs, recover)
    result = _result(path, out, inputs, measured, fitted, truth, figures, notes,
                     frf_error_figures(truth, frf, fitted, the_rig, updated.update, dt_s),
                     quality_figures(samples, inputs),
                     sensitivity_figures(frf, inputs, fitted.fit.model, refs, the_rig, updated.update, recorded,
                                         dt_s))
    if on_summary is not None:
        on_summary(replace(result, wall_s=time.perf_counter() - t0))
    if report:
        result = replace(result, files=replace(result.files, report=str(out / "report" / "index.html")),
                         wall_s=time.perf_counter() - t0)
        _report(report, out / "report", result, inputs, fitted, the_rig, updated.update, truth.g,
                measured.directional, samples)
    result = replace(result, wall_s=time.perf_counter() - t0)
    (out / "identification.json").write_text(json.dumps(result.to_json(), indent=1))
    return result


def _report(how: bool | str, folder: Path, *what) -> None:
    """:func:`write_identification_report` into ``folder``, here, or (``how`` "background") by a detached
    process: the caller answers now, the page follows (``folder/status.json`` says when)."""
    if how == "background":
        from ambid.background import start

        start(folder / "status.json", write_identification_report, folder, *what, nice=5)
    else:
        write_identification_report(folder, *what)


def _update_stage(rig, inputs: SessionInputs, true_model: StateSpace | None, update: bool, fitted, dt_s: float,
                  nominal: Mapping[str, float] | None, update_free: Sequence[str] | None,
                  notes: list[str]) -> tuple[Rig | None, RigUpdate]:
    """The rig (given or recorded) and its physical-model update; what could not be done goes to ``notes``."""
    the_rig = _rig_of(rig, inputs.rig_facts)
    if the_rig is None:
        notes.append("no rig in the session and none given: no nominal model, no updating")
    if true_model is None and the_rig is not None and not inputs.simulated:
        notes.append("not a simulated session: no true model to compare with")
    updated = RigUpdate(None)
    if update and the_rig is not None:
        updated = update_rig(the_rig, inputs.frf, fitted, dt_s, nominal, update_free)
        notes += updated.notes + ([f"model updating failed: {updated.error}"] if updated.error else [])
    return the_rig, updated

def _rig_of(rig: Rig | str | os.PathLike | Mapping | None, facts: dict | None) -> Rig | None:
    """The rig given (a Rig, a file or parameters), else the one the session recorded, else None."""
    if isinstance(rig, Rig):
        return rig
    if isinstance(rig, Mapping):
        return make_rig(dict(rig))
    if rig is not None:
        return load_rig(rig)
    return make_rig(facts) if facts else None


def _references(references: ReferenceModels | Callable[[], ReferenceModels | None] | None,
                inputs: SessionInputs, frf: FrfResult) -> ReferenceModels:
    """The reference models handed over, where they were made for these inputs; else made here."""
    chans = (frf.output_names, frf.input_names)
    given = references() if callable(references) else references
    if given is not None and given.key == reference_key(inputs, frf.freq_hz, *chans):
        return given
    return reference_models(inputs, frf.freq_hz, *chans)


def _result(path: str, out: Path, inputs: SessionInputs, measured: SessionFrf, fitted: FrfFit, truth: Truth,
            update: UpdateFigures | None, notes: list[str], frf_error, quality, sensitivity) -> Identification:
    """The stages' results as one :class:`Identification` (no report yet, no wall time)."""
    frf, fit, v = measured.frf, fitted.fit, measured.variances
    rows = list(truth.modes_vs_true)
    return Identification(
        session=path, experiment_id=inputs.experiment["experiment_id"], estimator=frf.estimator,
        excitation=ExcitationFacts.of(inputs.design), band_hz=list(fitted.band_hz), inputs=list(frf.input_names),
        outputs=list(frf.output_names), input_units=list(fit.model.input_units),
        output_units=list(fit.model.output_units), controller=(inputs.controller or (None, None))[1],
        simulated=inputs.simulated, frf_error=frf_error, noise=measured.noise_figures(truth.noise),
        fit=FitFigures(order=int(fitted.order), order_rule=fitted.order_rule, chi2_per_dof=fit.chi2_per_dof,
                       delay_s=fitted.delay_s, weights=v.weights_kind, orders_tried=fitted.diagram.orders,
                       chi2_per_dof_by_order=fitted.diagram.chi2_per_dof, modes=fitted.mode_rows,
                       computational_poles=fitted.computational, real_poles=fitted.real_rows,
                       refine_message=fit.message),
        intervals=session_intervals(v.var_kind, v.weights_kind, v.var is not None and
                                    v.var_kind.startswith("var_total")),
        modes_vs_true=rows, synchronous=measured.synchronous_figures(),
        max_mode_freq_error=max((abs(r.freq_error) for r in rows), default=None),
        max_mode_damping_error=max((abs(r.damping_error) for r in rows), default=None),
        update=update, quality=quality, sensitivity=sensitivity,
        files=OutputFiles(model_npz=str(out / "model.npz"), model_json=str(out / "model.json"),
                          frf_npz=str(out / "frf.npz"), summary_json=str(out / "identification.json")),
        notes=notes)
