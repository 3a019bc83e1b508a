"""Stage 6, the report: the identification's HTML page (``report/index.html``) and its figures.

The measured FRF with its band, the fitted, nominal, updated and true models on a dense grid and at the
lines, the stabilisation diagram, the line levels of the whole experiment and a short window of y, u, r,
and, where the channels hold a bearing's x and y, the directional FRFs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ambid.fit.model_update import PhysicalUpdate, covers, nominal_parameters, physical_frf
from ambid.frf.directional import DirectionalFrf, directional_frf
from ambid.frf.levels import LineLevels, line_levels
from ambid.identification.inputs import SessionInputs
from ambid.identification.model_fit import FrfFit
from ambid.identification.session_frf import band_kind
from ambid.identification.references import on_channels
from ambid.identification.result import Identification
from ambid.plant.rig import Rig, make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.report.html import write_report
from ambid.report.rotor_figures import directional_frf_figure

__all__ = ["write_identification_report"]


def write_identification_report(folder: Path, result: Identification, inputs: SessionInputs, fitted: FrfFit,
                                rig: Rig | None, upd: PhysicalUpdate | None, true_g: np.ndarray | None,
                                dfrf: DirectionalFrf | None, samples) -> None:
    """Write the report of ``result`` into ``folder`` (``index.html`` and its figures).

    Parameters
    ----------
    folder
        the report's folder (created).
    result
        the identification, as recorded.
    inputs
        the session's inputs (its FRF, design, rig facts).
    fitted
        the fit.
    rig
        the rig of the nominal and updated models, or None.
    upd
        the update, or None.
    true_g
        (L, Ny, Nu) the true FRF at the lines, or None.
    dfrf
        the directional FRFs of the measurement, or None.
    samples
        the experiment's samples (:func:`ambid.identification.quality.experiment_samples`), or None.
    """
    frf, design = inputs.frf, inputs.design
    dt_s = design.dt_s
    band, f, fit = fitted.band_hz, frf.freq_hz, fitted.fit
    levels, window = _samples_for_report(samples, inputs)
    dense = np.geomspace(max(band[0] / 1.5, 1e-3), min(band[1] * 1.5, 0.499 * design.fs_hz), 400)
    curves = {"fitted model": (dense, fit.model.freqresp(dense))}
    if rig is not None and not covers(rig.rotor_model(), frf.output_names, frf.input_names):
        curves["analytical (nominal) model"] = (dense, physical_frf(rig.rotor_model(), nominal_parameters(rig),
                                                                    dense, dt_s))
    if upd is not None:
        curves["updated physical model"] = (dense, physical_frf(rig.rotor_model(), upd.parameters, dense, dt_s))
    if inputs.simulated:
        curves["true rig (simulated)"] = (dense, on_channels(true_linear_model(make_rig(inputs.rig_facts),
                                                                               discrete=True),
                                                             dense, frf.output_names, frf.input_names))
    line_models = {"fitted model": fit.model.freqresp(f)}
    if upd is not None:
        line_models["updated physical model"] = physical_frf(rig.rotor_model(), upd.parameters, f, dt_s)
    extra = []
    if dfrf is not None:
        d_curves = {label: directional_frf(fc, gc, None, frf.output_names, frf.input_names)
                    for label, (fc, gc) in curves.items() if label in ("fitted model", "true rig (simulated)")}
        whirls = [(row.freq_hz, row.whirl) for row in fitted.mode_rows]
        extra.append(("directional_frf.png", "Directional FRFs p / f (p = x + j y, f = u_x + j u_y per bearing "
                      "plane): forward whirl (blue) and backward whirl (red), measured (dots) and models; a "
                      "forward mode peaks in the forward FRF, a backward one in the backward FRF.",
                      lambda p: directional_frf_figure(dfrf, d_curves, whirls, p)))
    write_report(folder, result.to_json(), frf=frf, design=design, diagram=fitted.diagram, order=fitted.order,
                 curves=curves, levels=levels, window=window, true_frf=true_g, line_models=line_models,
                 extra_figures=extra, band_variance=fitted.variances.band_var,
                 band_kind=band_kind(fitted.variances.var_kind))


def _samples_for_report(data, inputs: SessionInputs) -> tuple[LineLevels | None, dict | None]:
    """Line levels of the whole experiment and a short time window of y, u, r."""
    if data is None:
        return None, None
    frf, design, start = inputs.frf, inputs.design, int(inputs.experiment["start_index"])
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
