"""Fit a measured FRF handed over as a file (:mod:`ambid.frf.frf_file`): order, model, modes with intervals, report.

The same common-denominator fit as a session's identification
(:mod:`ambid.identification.model_fit`): the stabilisation diagram, the order
by :func:`ambid.identification.model_fit.select_order`, the fit at that order,
the modes in the band with their 95 % intervals, the state-space export and
a report. What differs is what a file can say about its noise:

* with ``var`` (each entry's variance ``E|H - H0|^2``): the fit is weighted by
  it, and the modes' intervals propagate it (a sandwich with the entries'
  covariance, the entries of a line taken as independent);
* without: each line is weighted by its own level (the mean |H|^2 of its
  entries: relative accuracy, as an analyser's FRF has), and the intervals
  come from the scatter of the fit's residuals about the model, line by line
  (the noise as the misfit shows it, any model error included, the lines
  taken as independent; a smoothed FRF, whose lines are not, gets intervals
  too narrow).

There is no physical updating and no comparison with a truth: a file holds
neither a rig nor a simulation.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from ambid.fit import fit_common_denominator, save_model_json, save_model_npz, stabilisation_diagram
from ambid.frf.frf_file import MeasuredFrf
from ambid.frf.quality import record_quality
from ambid.identification.model_fit import select_order, split_modes
from ambid.identification.result import FitFigures, IntervalNotes, MeasuredFrfFit, OutputFiles, QualityFigures

__all__ = ["identify_frf", "INTERVALS_WITH_VAR", "INTERVALS_WITHOUT_VAR"]

INTERVALS_WITH_VAR = ("95 % intervals of the modes propagated from the file's variance of each entry (var): the "
                      "fit weighted by it, a sandwich covariance with the entries of a line independent, Student t "
                      "where its degrees of freedom are few")
INTERVALS_WITHOUT_VAR = ("the file gives no variance: the fit weighs each line by its own level, and the 95 % "
                         "intervals come from the scatter of its residuals about the model, line by line; they hold "
                         "the noise as the misfit shows it and any model error, and assume the lines' errors "
                         "independent (an FRF smoothed over frequency gets intervals too narrow)")


def identify_frf(measured: MeasuredFrf, out_dir: str | os.PathLike, *, order: int | None = None,
                 max_order: int = 32, order_penalty: float = 2.0, delay_s: float = 0.0,
                 report: bool = True, on_summary: Callable[[MeasuredFrfFit], None] | None = None) -> MeasuredFrfFit:
    """Fit the FRF of a file and write model.npz, model.json, frf.npz, identification.json and report/.

    Args:
        measured: from :func:`ambid.frf.frf_file.read_frf_file`.
        out_dir: output folder (created).
        order: model order; None selects it from the stabilisation diagram.
        max_order: highest order tried.
        order_penalty: the order rule's weight per parameter (2: Akaike).
        delay_s: a known pure delay of the measurement [s] (0 for an analyser's FRF).
        report: write the HTML report.
        on_summary: called with the result before the report is written (its ``files.report`` already
            names the page to come), so a caller can show the figures at once.

    Returns:
        The :class:`ambid.identification.result.MeasuredFrfFit` (also ``identification.json``): source,
        format, outputs, inputs, n_lines, band_hz, var_given, fit (order, order_rule, chi2_per_dof, delay_s,
        weights, modes with their 95 % intervals, real_poles), intervals, files, notes, wall_s.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    f, g, var = measured.freq_hz, measured.frf, measured.var
    ny, nu = g.shape[1:]
    band = (float(f[0]), float(f[-1]))
    notes = list(measured.notes)
    if var is None:
        # no variance: each line weighted by its own level (the mean |H|^2 of its entries), so that a resonance
        # a decade down counts as much as one at the top (an analyser's FRF is as accurate, relatively, there)
        level = np.mean(np.abs(g) ** 2, axis=(1, 2), keepdims=True)
        w_var = np.broadcast_to(np.maximum(level, 1e-12 * np.max(level)), g.shape).copy()
    else:
        w_var = np.maximum(var, 1e-12 * np.median(var))
    top = min(max_order, f.size - 1)
    orders = list(range(2, top + 1, 2))
    if not orders:
        raise ValueError(f"{measured.path}: {f.size} frequencies are too few for a parametric fit; give more")
    out.mkdir(parents=True, exist_ok=True)
    diagram = stabilisation_diagram(f, g, w_var, orders=orders, delay_s=delay_s)
    rule = (f"smallest chi2 + {order_penalty:g} p N/(N - p - 1) (AICc) among orders with stable, positively damped "
            "in-band modes")
    if order is None:
        order = select_order(diagram, band, f.size, ny * nu, var is not None, order_penalty)
    else:
        rule = "given"
    # the file's variance as the entries' covariance (independent within a line): the intervals follow it
    row_cov = None if var is None else np.einsum("lij,jk->lijk", var, np.eye(nu)).astype(complex)
    labels = dict(input_names=measured.input_names, output_names=measured.output_names,
                  input_units=measured.input_units, output_units=measured.output_units)
    fit = fit_common_denominator(f, g, w_var, order=int(order), delay_s=delay_s, row_covariance=row_cov, **labels)
    # the modes the data shows, the computational poles apart with their reasons: as for a session
    _, rows, real, computational = split_modes(fit, diagram, int(order), f, g, var)
    # the intervals hold the file's variance alone where it gave one
    rows = [r if r.interval is None or r.interval.freq_hz_std is None else
            replace(r, interval=replace(r.interval, noise_only=var is not None)) for r in rows]
    quality = []
    if measured.coherence is not None:   # the analyser's coherence: its low lines said, one line per pair
        pairs = [f"{o}/{u}" for o in measured.output_names for u in measured.input_names]
        quality = [q.to_dict() for q in record_quality(None, (), 1.0, f, measured.coherence.reshape(f.size, -1),
                                                       pairs)]
    save_model_npz(out / "model.npz", fit.model)
    save_model_json(out / "model.json", fit.model)
    np.savez(out / "frf.npz", freq_hz=f, H=g, **({} if var is None else dict(var=var)),
             **({} if measured.coherence is None else dict(coherence=measured.coherence)),
             outputs=np.array(measured.output_names), inputs=np.array(measured.input_names))
    result = MeasuredFrfFit(
        source=measured.path, format=measured.kind, form=measured.form, unit=measured.unit,
        output_units=list(measured.output_units), input_units=list(measured.input_units),
        outputs=list(measured.output_names), inputs=list(measured.input_names), n_lines=int(f.size),
        band_hz=list(band), var_given=var is not None,
        fit=FitFigures(order=int(order), order_rule=rule, chi2_per_dof=fit.chi2_per_dof, delay_s=delay_s,
                       weights="the file's var" if var is not None else "each line by its mean |H|^2 (relative)",
                       orders_tried=diagram.orders, chi2_per_dof_by_order=diagram.chi2_per_dof, modes=rows,
                       computational_poles=computational, real_poles=real, refine_message=fit.message),
        quality=QualityFigures(findings=quality),
        intervals=IntervalNotes(modes=INTERVALS_WITH_VAR if var is not None else INTERVALS_WITHOUT_VAR),
        files=OutputFiles(model_npz=str(out / "model.npz"), model_json=str(out / "model.json"),
                          frf_npz=str(out / "frf.npz"), summary_json=str(out / "identification.json")),
        notes=notes)
    if report:
        result = replace(result, files=replace(result.files, report=str(out / "report" / "index.html")))
    if on_summary is not None:
        on_summary(replace(result, wall_s=time.perf_counter() - t0))
    if report:
        from ambid.report.measured import write_measured_report

        dense = np.geomspace(max(band[0] / 1.2, 1e-3), band[1] * 1.2, 400)
        write_measured_report(out / "report", result.to_json(), f, g, None if var is None else np.sqrt(var),
                              diagram, int(order), {"fitted model": (dense, fit.model.freqresp(dense))},
                              measured.output_names, measured.input_names)
    result = replace(result, wall_s=time.perf_counter() - t0)
    (out / "identification.json").write_text(json.dumps(result.to_json(), indent=1))
    return result
