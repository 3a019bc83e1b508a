"""Stage 5, the sensitivity: the loop's sensitivity, measured at the lines and modelled between them.

Each excitation channel shows the sensitivity its injection point allows (at the current: the input
sensitivity u / r; elsewhere what :func:`ambid.frf.sensitivity.sensitivity_shown` finds, or why none). The
measured S is known only at the excited lines, which can straddle a sharp peak; the fitted plant with the
recorded controller K(z) gives it in between, and the updated physical model with K gives its own peak;
each peak with its ISO 14839-3 zone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ambid.control.closed_loop import loop_robustness
from ambid.fit.model_update import PhysicalUpdate, physical_discrete
from ambid.frf.sensitivity import iso14839_zone, sensitivity_shown
from ambid.frf.streaming import FrfResult
from ambid.identification.inputs import SessionInputs
from ambid.identification.references import ReferenceModels, axis_of
from ambid.identification.result import LoopSensitivity, SensitivityChannel, SensitivityFigures
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace

__all__ = ["sensitivity_figures"]


def sensitivity_figures(frf: FrfResult, inputs: SessionInputs, model: StateSpace, refs: ReferenceModels,
                        rig: Rig | None, upd: PhysicalUpdate | None, controller: StateSpace | None, dt_s: float
                        ) -> SensitivityFigures:
    """The loop sensitivity the session shows, per excitation channel by where it was injected
    (:func:`ambid.frf.sensitivity.sensitivity_shown`), and the headline: the worst peak over the measured lines
    and the fitted ``model`` between them (with the recorded ``controller``, on ``refs``' dense grid), its
    frequency and which of the two it came from, and its ISO 14839-3 zone; one line per channel that shows none,
    saying why. Where every channel is injected at the current (ambid's own sessions), the input sensitivity
    at the lines, of the fitted model between them, of the true loop and of the updated model too."""
    channels = _channels(frf, inputs)
    with_peak = [c for c in channels if c.peak is not None]
    if all(c.injected_at == "current" for c in channels):
        # ambid's own sessions: the input sensitivity at the lines, as before
        worst = int(np.argmax(frf.sensitivity_peak))
        figures = SensitivityFigures(channels, peak=frf.sensitivity_peak, peak_hz=frf.sensitivity_peak_hz,
                                     worst_input=frf.input_names[worst], worst_peak=float(frf.sensitivity_peak[worst]),
                                     iso_zone=frf.iso_zone, **_model_sensitivity(model, refs),
                                     **_updated_sensitivity(rig, upd, controller, dt_s))
    elif with_peak:
        w = max(with_peak, key=lambda c: c.peak)
        figures = SensitivityFigures(channels, worst_input=w.excitation, worst_peak=w.peak, peak_hz_worst=w.peak_hz,
                                     iso_zone=w.iso_zone)
    else:
        figures = SensitivityFigures(channels)
    return replace(figures, none=[c.why for c in channels if c.peak is None],
                   loop=_loop_peak(with_peak, figures, frf.input_names))


def _channels(frf: FrfResult, inputs: SessionInputs) -> list[SensitivityChannel]:
    """Per excitation channel, the sensitivity it shows by where it was injected, with its peak."""
    units = inputs.units
    shown = sensitivity_shown(frf.frf, frf.sensitivity, frf.output_names, frf.input_names, inputs.injected_at,
                              [units.get(n, "m") for n in frf.output_names],
                              [units.get(f"r_{axis_of(n)}", "A") for n in frf.input_names])
    f = frf.freq_hz
    channels = []
    for sh in shown:
        peak = {}
        if sh.values is not None:
            mag = np.abs(sh.values)
            k = int(np.argmax(mag))
            peak = dict(peak=float(mag[k]), peak_hz=float(f[k]), iso_zone=iso14839_zone(float(mag[k])))
        channels.append(SensitivityChannel(excitation=sh.excitation, injected_at=sh.injected_at,
                                           kind=sh.kind or None, why=sh.why, **peak))
    return channels


def _loop_peak(with_peak: list[SensitivityChannel], figures: SensitivityFigures,
               input_names: Sequence[str]) -> LoopSensitivity | None:
    """The loop's worst peak, over the measured lines and the fitted model between them (with the recorded
    controller)."""
    cands = [(c.peak, c.peak_hz, "the measured lines", c.excitation) for c in with_peak]
    if figures.model_peak is not None:
        mp = np.asarray(figures.model_peak, dtype=float)
        k = int(np.argmax(mp))
        cands.append((float(mp[k]), float(np.asarray(figures.model_peak_hz)[k]),
                      "the fitted model between the lines (with the recorded controller)", input_names[k]))
    if not cands:
        return None
    peak, hz, source, chan = max(cands, key=lambda c: c[0])
    return LoopSensitivity(peak=peak, peak_hz=hz, source=source, channel=chan, iso_zone=iso14839_zone(peak))


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
