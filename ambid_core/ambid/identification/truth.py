"""The identification against the truth, where there is one: a simulated session's true rig, or a plant
model given from elsewhere (the C reference target's model file).

Modes against the true rig (:func:`compare_modes`): true modes closer than
the frequency resolution form one cluster, compared by mean frequency and
damping with the fitted modes near it.

FRF error figures: per line the relative matrix error
``||G - G_true||_F / ||G_true||_F`` (:func:`ambid.frf.accuracy.frf_relative_error`:
the Frobenius norm over the Ny x Nu matrix, so structurally zero cross-plane
entries do not divide by zero), its median and worst value over the excited lines.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ambid.fit.model_update import PhysicalUpdate, physical_frf
from ambid.frf.accuracy import frf_relative_error
from ambid.frf.streaming import FrfResult
from ambid.identification.model_fit import FrfFit, mode_interval
from ambid.identification.references import ReferenceModels
from ambid.identification.result import FrfErrorFigures, ModeComparison
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace

__all__ = ["true_modes", "compare_modes", "Truth", "truth_of", "frf_error_figures"]


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
                  resolution_hz: float) -> list[ModeComparison]:
    """Fitted modes against true ones, closely spaced modes as clusters.

    Modes closer than the frequency resolution cannot be told apart by the
    data, so true modes less than ``resolution_hz`` apart form a cluster,
    compared by its mean frequency and damping with the mean of the fitted
    modes within ``resolution_hz`` of the cluster (the nearest fitted mode
    when none is).

    Parameters
    ----------
    fitted, true
        [(frequency [Hz], damping ratio [-])].
    resolution_hz
        frequency resolution fs / N of the measurement [Hz].

    Returns
    -------
    One :class:`ambid.identification.result.ModeComparison` per true cluster: true_freq_hz,
    true_damping, freq_hz, damping, freq_error, damping_error (relative), n_true, n_fitted.
    """
    if not resolution_hz > 0:
        raise ValueError(f"resolution_hz must be > 0, got {resolution_hz}")
    clusters: list[list[tuple[float, float]]] = []
    for f, z in sorted(true):
        if clusters and f - clusters[-1][-1][0] < resolution_hz:
            clusters[-1].append((f, z))
        else:
            clusters.append([(f, z)])
    out: list[ModeComparison] = []
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
        out.append(ModeComparison(true_freq_hz=ft, true_damping=zt, freq_hz=ff, damping=zf, freq_error=ff / ft - 1,
                                  damping_error=zf / zt - 1, n_true=len(c), n_fitted=int(inside.sum())))
    return out


@dataclass(frozen=True)
class Truth:
    """What the identification is measured against, where there is a truth.

    Attributes
    ----------
    g
        (L, Ny, Nu) the true FRF at the lines, or None (no truth).
    g_at_excitation
        (L, Ny, Nu) the true rig linearised at this excitation's level, or None.
    noise
        (Ny,) the sensor noise through the true loop [m], or None.
    parameters
        the true rig's physical parameters, or None.
    modes_vs_true
        the fitted modes against the true ones (intervals where one meets one).
    reference
        what the truth is, in words.
    """

    g: np.ndarray | None = None
    g_at_excitation: np.ndarray | None = None
    noise: np.ndarray | None = None
    parameters: dict | None = None
    modes_vs_true: list[ModeComparison] = ()
    reference: str = ""


def truth_of(simulated: bool, refs: ReferenceModels, true_model: StateSpace | None, fitted: FrfFit,
             freq_hz: np.ndarray, resolution_hz: float) -> Truth:
    """The truth of a session: the simulated rig's (``refs``), or ``true_model`` where given (it is the truth,
    whatever the session's source), or none; the fitted modes compared with its modes.

    Parameters
    ----------
    simulated
        the session ran the simulated rig (and a rig is known).
    refs
        :func:`ambid.identification.references.reference_models` of the session.
    true_model
        the plant the session measured, u [A] -> y [m], known from elsewhere, or None.
    fitted
        the fit (:func:`ambid.identification.model_fit.fit_frf`).
    freq_hz
        (L,) the FRF's lines [Hz].
    resolution_hz
        the measurement's frequency resolution fs / N [Hz].
    """
    truth = Truth()
    if simulated:
        truth = Truth(refs.true_g, refs.true_g_x, refs.true_noise, refs.true_params,
                      compare_modes(fitted.physical_modes(), true_modes(refs.true_poles, fitted.band_hz),
                                    resolution_hz), "true rig, small-signal model sampled with zero-order hold")
    if true_model is not None:
        z = true_model.poles()
        s_poles = np.log(z[np.abs(z) > 0]) / true_model.dt if true_model.dt > 0 else true_model.poles()
        truth = replace(truth, g=true_model.freqresp(freq_hz), reference="the given plant model",
                        modes_vs_true=compare_modes(fitted.physical_modes(), true_modes(s_poles, fitted.band_hz),
                                                    resolution_hz))
    # one true and one fitted mode: the fitted mode's interval against the truth (a cluster's mean has none:
    # its members' covariance is not kept)
    rows = [replace(r, interval=mode_interval(fitted.fit, r.freq_hz, r.damping)) if r.n_true == r.n_fitted == 1
            else r for r in truth.modes_vs_true]
    return replace(truth, modes_vs_true=rows)


def frf_error_figures(truth: Truth, frf: FrfResult, fitted: FrfFit, rig: Rig | None, upd: PhysicalUpdate | None,
                      dt_s: float) -> FrfErrorFigures | None:
    """The measured, fitted and updated FRFs' relative errors against the truth; None without one."""
    if truth.g is None:
        return None
    f = frf.freq_hz
    e_meas = frf_relative_error(frf.frf, truth.g)
    e_fit = frf_relative_error(fitted.fit.model.freqresp(f), truth.g)
    e_upd = (None if upd is None else
             frf_relative_error(physical_frf(rig.rotor_model(), upd.parameters, f, dt_s), truth.g))
    return FrfErrorFigures(reference=truth.reference, median=float(np.median(e_meas)), worst=float(np.max(e_meas)),
                           worst_at_hz=float(f[np.argmax(e_meas)]), fitted_median=float(np.median(e_fit)),
                           fitted_worst=float(np.max(e_fit)),
                           updated_median=None if e_upd is None else float(np.median(e_upd)),
                           updated_worst=None if e_upd is None else float(np.max(e_upd)))
