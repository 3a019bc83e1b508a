"""Stage 5, the sensitivity: the loop's sensitivity, measured at the lines and modelled between them.

Each excitation channel shows the sensitivity its injection point allows (at the current: the input
sensitivity u / r; elsewhere what :func:`ambid.frf.sensitivity.sensitivity_shown` finds, or why none). The
measured S is known only at the excited lines, which can straddle a sharp peak; the fitted plant with the
recorded controller K(z) gives it in between, and the updated physical model with K gives its own peak;
each peak with its ISO 14839-3 zone, and the loop's worst peak with the probability of each zone
(:func:`loop_zone_probabilities`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ambid.control.closed_loop import loop_robustness
from ambid.fit.model_update import PhysicalUpdate, physical_discrete
from ambid.frf.sensitivity import iso14839_zone, sensitivity_peak_draws, sensitivity_shown, zone_probabilities
from ambid.frf.streaming import FrfResult
from ambid.identification.inputs import SessionInputs
from ambid.identification.references import ReferenceModels, axis_of
from ambid.identification.result import LoopSensitivity, SensitivityChannel, SensitivityFigures
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace

__all__ = ["sensitivity_figures", "loop_zone_probabilities"]

#: Draws of the loop's worst peak behind its zone probabilities, and the lines they are taken at.
N_DRAWS = 1000
N_LINES = 24


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
    loop = _loop_peak(with_peak, figures, frf.input_names)
    if loop is not None and all(c.injected_at == "current" for c in channels):
        seed = getattr(inputs.design, "seed", None)
        loop = replace(loop, zone_probabilities=loop_zone_probabilities(frf, model, refs, figures,
                                                                        0 if seed is None else int(seed)))
    return replace(figures, none=[c.why for c in channels if c.peak is None], loop=loop)


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


def loop_zone_probabilities(frf: FrfResult, model: StateSpace, refs: ReferenceModels, figures: SensitivityFigures,
                            seed: int, n_draws: int = N_DRAWS) -> dict[str, float] | None:
    """The probability of each ISO 14839-3 zone for the loop's worst input-sensitivity peak, the share of
    ``n_draws`` draws of that peak in each (:func:`ambid.frf.sensitivity.zone_probabilities`).

    Each draw is the worst ``|S_ii|`` over (:func:`ambid.frf.sensitivity.sensitivity_peak_draws`):

    * the measured lines (the ``N_LINES`` with the highest measured peak, where the worst one can be): the
      measured u / r moved as the loop closed on a plant drawn from the FRF's own per-line variance
      (``var_total``, noise and stochastic nonlinear scatter; ``var_noise`` where that is unknown) moves it;
    * the fitted model's peak of each input between the lines (``figures.model_peak_hz``): the fitted plant
      there, drawn with the variance of the nearest measured line plus that line's squared fit residual.

    The draws are reflected about the estimated peak (the basic bootstrap): a largest of noisy values is
    biased up by the noise, and the draws above the estimate show by how much.

    What it does not cover: the fit's parameter covariance is not propagated (the fit does not expose one
    for G between the lines cheaply), so a fitted peak's spread is that of the data around it, not of the
    mode's damping the fit chose; correlation between lines and elements is ignored; a bias common to every
    period (e.g. the magnets' level dependence) is not in the variance. Deterministic: the draws come from
    ``seed`` (the session's).

    Returns
    -------
    ``{zone: probability}`` over 'A'..'D', summing to 1; None without the recorded controller on the lines'
    band (the propagation needs it) or without any variance.
    """
    if refs.controller_frf is None or refs.sens_freq_hz is None:
        return None
    var = np.where(np.isfinite(frf.var_total), frf.var_total, frf.var_noise)
    if not np.any(np.isfinite(var)):
        return None
    var = np.nan_to_num(var, nan=0.0)
    grid, kz = refs.sens_freq_hz, refs.controller_frf      # kz: y -> ic = -C
    mag = np.abs(np.diagonal(frf.sensitivity, axis1=1, axis2=2)).max(axis=1)
    lines = np.sort(np.argsort(mag)[::-1][:N_LINES])
    f = frf.freq_hz[lines]
    # the controller at the lines, linear between the dense grid's points
    k = np.clip(np.searchsorted(grid, f), 1, grid.size - 1)
    w = ((f - grid[k - 1]) / (grid[k] - grid[k - 1]))[:, None, None]
    s, g, v, c = frf.sensitivity[lines], frf.frf[lines], var[lines], -((1 - w) * kz[k - 1] + w * kz[k])
    if figures.model_peak_hz is not None:
        fm = np.unique(np.asarray(figures.model_peak_hz, dtype=float))
        # one point per mode: peaks of several inputs within half a line spacing are one peak (each point
        # gives every input's S), not independent draws of it, which would push the largest up
        half = 0.5 * float(np.median(np.diff(frf.freq_hz))) if frf.freq_hz.size > 1 else 0.0
        fm = fm[np.concatenate([[True], np.diff(fm) > half])]
        near = np.abs(frf.freq_hz[None, :] - fm[:, None]).argmin(axis=1)
        resid2 = np.abs(frf.frf[near] - model.freqresp(frf.freq_hz[near])) ** 2
        gm = model.freqresp(fm)
        cm = -kz[np.abs(grid[None, :] - fm[:, None]).argmin(axis=1)]
        sm = np.linalg.inv(np.eye(gm.shape[2])[None] + cm @ gm)
        s, g, v, c = (np.concatenate(p) for p in ((s, sm), (g, gm), (v, var[near] + resid2), (c, cm)))
    draws = sensitivity_peak_draws(s, g, v, c, n_draws, np.random.default_rng([seed, 14839]))
    # the basic bootstrap: the estimated peak is itself a largest of noisy values, biased up by the noise as
    # much as the draws are above it, so the truth's draws are the draws reflected about the estimate
    peak = float(np.abs(np.diagonal(s, axis1=1, axis2=2)).max())
    return zone_probabilities(np.maximum(2.0 * peak - draws, 0.0))


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
