"""Stage 5, the sensitivity: the loop's input sensitivity, measured at the lines and modelled between them.

The measured S is known only at the excited lines, which can straddle a sharp peak; the fitted plant with
the recorded controller K(z) gives it in between, and the updated physical model with K gives its own
peak; each peak with its ISO 14839-3 zone.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ambid.control.closed_loop import loop_robustness
from ambid.fit.model_update import PhysicalUpdate, physical_discrete
from ambid.frf.sensitivity import iso14839_zone
from ambid.frf.streaming import FrfResult
from ambid.identification.references import ReferenceModels
from ambid.identification.result import SensitivityFigures
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace

__all__ = ["sensitivity_figures"]


def sensitivity_figures(frf: FrfResult, model: StateSpace, refs: ReferenceModels, rig: Rig | None,
                        upd: PhysicalUpdate | None, controller: StateSpace | None, dt_s: float
                        ) -> SensitivityFigures:
    """The input sensitivity's peaks: measured (``frf``), of the fitted ``model`` between the lines
    (with the recorded controller on ``refs``' dense grid), of the true loop (``refs.true_loop``) and of
    the updated physical model with ``controller``, where each is known."""
    worst = int(np.argmax(frf.sensitivity_peak))
    return SensitivityFigures(peak=frf.sensitivity_peak, peak_hz=frf.sensitivity_peak_hz,
                              worst_input=frf.input_names[worst], worst_peak=float(frf.sensitivity_peak[worst]),
                              iso_zone=frf.iso_zone, **_model_sensitivity(model, refs),
                              **_updated_sensitivity(rig, upd, controller, dt_s))


def _model_sensitivity(model: StateSpace, refs: ReferenceModels) -> dict[str, Any]:
    """Input-sensitivity peak between the excited lines: S = (I - K G_fit)^-1 on a dense grid (K on the grid:
    ``refs.controller_frf``). With a simulated rig, the true loop's peak is given beside it."""
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


def _updated_sensitivity(rig: Rig | None, upd: PhysicalUpdate | None, controller: StateSpace | None,
                         dt_s: float) -> dict[str, Any]:
    """Peak input sensitivity and ISO 14839-3 zone of the updated physical model with the recorded controller."""
    if rig is None or upd is None or controller is None:
        return {}
    try:
        rob = loop_robustness(physical_discrete(rig.rotor_model(), upd.parameters, dt_s), controller)
    except ValueError:
        return dict(updated_note="the updated model's loop with the recorded controller is unstable: no peak")
    return dict(updated_peak=rob.sensitivity_peak, updated_peak_hz=rob.peak_freq_hz, updated_iso_zone=rob.zone,
                updated_note="updated physical model with the recorded controller")
