"""What an updated parameter's interval claims on a nonlinear rig, computed without the session's estimate.

A linear model fitted to data taken with an excitation describes the rig's *best linear approximation*
(BLA) at that excitation level (Pintelon & Schoukens, System Identification, ch. 3), not its small-signal
model at rest. For the magnets of eq. 2.14 the difference is mostly their slopes averaged over the
excursions the excitation causes (Bussgang; :func:`ambid.fit.model_update.excitation_slopes`), but not
only: the BLA's phase at the top of the band departs from the linear lags too (by 0.1 % of their sum on
the default session), and the physical model carries that into its lags. No variance holds such a shift;
what the interval claims has to say it.

The estimand here, the *BLA parameters* of a session: the MAP update of the physical model
(:func:`ambid.fit.model_update.update_physical_model`) fitted to the FRFs of noise-free twins of the
session (the same rig without sensor noise, the same controller and excitation level, random phases
whose stochastic nonlinear distortion averages out over the twins), each twin weighted by the variance
the session weighted its data with, their information scaled to one session's, and the prior centred on
the simulated rig at rest with the tolerances' widths. Where the data decide, that is the physical model
that best describes the rig at this excitation; where the tolerance decides, it stays near the rig at
rest. For a linear-Gaussian model, a session's MAP interval from a nominal model drawn from the
tolerances about the rig at rest covers exactly this point 95 % of the time: the data's part of the
error has the noise's and the distortion's scatter, the prior's part the nominal draw's. The simulated
truth is used only to measure ambid (``ambid validate``, the nominal-model test), never by an update.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ambid.channels import RADIAL
from ambid.excitation.design import ExcitationDesign
from ambid.fit.model_update import PARAMETERS, parameter_prior, total_lag, true_parameters, update_physical_model
from ambid.fit.updating import Prior
from ambid.frf.streaming import FrfResult, FrfStream
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace
from ambid.control.simulated_loop import levitate, run_loop

__all__ = ["SLOPES", "Twin", "noise_free_twin", "variance_on", "bla_parameters", "at_own_excitation"]

#: the updated parameters whose value at a session's own excitation ambid computes (the magnets' slopes
#: averaged over the excursions it causes, :func:`ambid.fit.model_update.excitation_slopes`)
SLOPES = ("ki_n_per_a", "ks_n_per_m", "ks_b_over_a")


@dataclass(frozen=True)
class Twin:
    """One noise-free twin's FRF and the variance the session's fit weighted such data with.

    Attributes
    ----------
    freq_hz
        (L,) excited lines [Hz].
    frf
        (L, 4, 4) FRF u -> y [m/A] of the noise-free nonlinear rig.
    var
        (L, 4, 4) the session's fit variance at these lines [(m/A)^2].
    """

    freq_hz: np.ndarray
    frf: np.ndarray
    var: np.ndarray


def noise_free_twin(rig: Rig, controller: StateSpace, current_limit_a: float, design: ExcitationDesign,
                    nonlinear_magnets: bool = True, estimator: str = "indirect") -> FrfResult:
    """The FRF of ``rig`` without sensor noise under ``controller`` and ``design``, simulated here.

    The loop of :func:`ambid.control.simulated_loop.run_loop` (the plant node's simulator and the controller
    node's stepper, sample by sample): what ``ambid identify`` measures on the same rig and design without
    noise, to the last bit, in seconds instead of a ROS session.

    Parameters
    ----------
    rig
        the simulated rig (its ``sensor_noise_m`` is set to 0 here).
    controller
        the discrete controller y -> ic that runs (dt = rig.dt).
    current_limit_a
        its output saturation [A].
    design
        the periodic excitation design.
    nonlinear_magnets
        the magnets' full law (eq. 2.14), as identify simulates them.
    estimator
        the FRF estimator (:data:`ambid.frf.streaming.ESTIMATORS`).

    Returns
    -------
    :class:`ambid.frf.streaming.FrfResult` of the twin.
    """
    quiet = replace(rig, values={**rig.values, "sensor_noise_m": 0.0})
    start = levitate(quiet, nonlinear_magnets=nonlinear_magnets, controller=(controller, current_limit_a))
    record = run_loop(start, design.samples(0, design.total_samples))
    stream = FrfStream(design, RADIAL.outputs, RADIAL.inputs, RADIAL.excitations, total_samples=design.total_samples)
    stream.add(0, record.columns())
    return stream.estimate(estimator)


def variance_on(freq_ref_hz: np.ndarray, var_ref: np.ndarray, freq_hz: np.ndarray) -> np.ndarray:
    """A line variance carried to other lines of the same band: per entry, linear in log f and log var
    (the fit variance is smooth over frequency), held beyond the ends.

    Parameters
    ----------
    freq_ref_hz
        (L,) lines of ``var_ref`` [Hz], ascending.
    var_ref
        (L, Ny, Nu) variance > 0.
    freq_hz
        (K,) lines wanted [Hz].

    Returns
    -------
    (K, Ny, Nu) variance.
    """
    lf = np.log(np.asarray(freq_ref_hz, dtype=float))
    lv = np.log(np.asarray(var_ref, dtype=float)).reshape(lf.size, -1)
    x = np.log(np.asarray(freq_hz, dtype=float))
    out = np.column_stack([np.interp(x, lf, lv[:, j]) for j in range(lv.shape[1])])
    return np.exp(out).reshape((x.size,) + np.shape(var_ref)[1:])


def bla_parameters(rig: Rig, twins: Sequence[Twin], names: Sequence[str], free: Sequence[str],
                   max_evaluations: int = 300) -> dict[str, float]:
    """The BLA parameters (module docstring) of a session's physical model on ``rig``.

    Parameters
    ----------
    rig
        the simulated (true) rig, with its tolerances.
    twins
        noise-free twins of the session at the same excitation level (several random-phase
        designs: their stochastic distortion averages out; 16 or more leave it below a quarter of a
        session's standard deviation).
    names
        every parameter of the session's physical model (its structure: which bending modes,
        sensor bandwidth, support mode).
    free
        those the session updated.
    max_evaluations
        most model evaluations of the fit.

    Returns
    -------
    name -> value for every name in ``names`` (the fixed ones at the rig's values at rest), and
    ``total_lag_s`` (:func:`ambid.fit.model_update.total_lag`) where the lags are in ``names``.
    """
    if not twins:
        raise ValueError("bla_parameters: give at least one noise-free twin")
    truth = true_parameters(rig)
    missing = [k for k in names if k not in truth]
    if missing:
        raise ValueError(f"bla_parameters: the rig has no value at rest of {missing}")
    start = {k: float(truth[k]) for k in names if k in PARAMETERS}
    prior, _ = parameter_prior(rig, free, start)
    # centred on the rig at rest (a range tolerance, the delay's, would move it to the range's middle)
    prior = Prior(np.array([start[k] for k in free]), prior.std, prior.log)
    f = np.concatenate([t.freq_hz for t in twins])
    g = np.concatenate([t.frf for t in twins])
    # K twins carry K sessions' information: scaled to one session's, the prior keeps a session's weight
    var = np.concatenate([t.var for t in twins]) * len(twins)
    upd = update_physical_model(rig.rotor_model(), f, g, var, start, free, rig.dt, prior=prior,
                                covariance="jacobian", max_evaluations=max_evaluations)
    out = {k: float(upd.parameters[k]) for k in names if k in upd.parameters}
    if "amplifier_bandwidth_hz" in out:
        out["total_lag_s"] = total_lag(out)
    return out



def at_own_excitation(bla: Mapping[str, float], own: Mapping[str, float],
                      pooled: Mapping[str, float]) -> dict[str, float]:
    """One session's BLA parameters: ``bla`` (:func:`bla_parameters`, pooled over the twins of sessions
    whose excitations differ) with each of :data:`SLOPES` moved by its session's own excitation-level value
    less the mean of those values over the pooled sessions (Bussgang: the magnets' slopes its grid and
    amplitudes cause, :func:`ambid.fit.model_update.excitation_slopes`).

    Parameters
    ----------
    bla
        name -> value, the pooled estimand.
    own
        name -> this session's value at its own excitation, for some of :data:`SLOPES`.
    pooled
        name -> the mean of those values over the sessions whose twins gave ``bla``.

    Returns
    -------
    name -> value: ``bla`` with the slopes it and ``own`` and ``pooled`` share moved.
    """
    out = dict(bla)
    for k in SLOPES:
        if k in out and k in own and k in pooled:
            out[k] = float(out[k] + own[k] - pooled[k])
    return out
