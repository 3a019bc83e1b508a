"""What the verifying identification will measure: the input-sensitivity peak of a new controller's loop,
as an interval and ISO 14839-3 zone probabilities.

The claim. ``identify`` run again with the new controller and the same experiment measures the input
sensitivity and reports its headline peak: the worst ``|S_jj|`` over the axes, at the excited lines
(``S = U R^-1``) and between them (the fitted model with the controller). That number is what the
interval claims to hold 95 % of the time. It differs from the loop's own peak by

* the plant the data allow: the updated physical model's posterior (:mod:`ambid.commissioning.plants`);
* the verifying measurement's own noise: its indirect estimate is ``G + E S^-1`` and its sensitivity
  ``S + S K E`` with ``E = V R^-1`` the sensor noise (and the magnets' stochastic distortion) over the
  excitation; ``E``'s variance per output and line is read off the run's own FRF variance,
  ``var(G_ij) = e_i^2 sum_k |(S^-1)_kj|^2`` with the run's sensitivity, so the new loop's ``S`` sets how
  much of it reaches the new estimate;
* the verifying fit: the common-denominator model of that noisy estimate, at the run's order, between the
  lines, weighted as identify weights it: by the noise and total variances the verifying run estimates from
  its own periods and realisations (:func:`ambid.frf.uncertainty.fit_weights`). Those estimates
  scatter from line to line (a few degrees of freedom each), and the fitted model between the lines, where
  the headline peak usually lies, moves with its weights: each simulated measurement draws its variance
  estimates by resampling the run's own line-to-line scatter (each line's level over its neighbours').

:func:`predict_peak` simulates the verifying measurement this way for plants drawn from the posterior
(a parametric bootstrap of the measurement and its fit), and reads the interval off the order statistics
of those samples (ranks (n + 1) 0.025 and (n + 1) 0.975: a prediction interval whatever their
distribution): the samples' spread holds both the plant's uncertainty and the measurement's. The loop's peak (all frequencies, no measurement) is given beside it.
Nothing here reads the simulated truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ambid.commissioning.loops import input_sensitivity_frf, worst_peak
from ambid.commissioning.plants import PlantUncertainty, draw_parameters, peak_grid, plant_set
from ambid.control.closed_loop import close_loop, closed_loop_patches, residue_freqresp
from ambid.fit import fit_common_denominator
from ambid.frf.sensitivity import zone_probabilities
from ambid.frf.uncertainty import fit_weights
from ambid.statespace import StateSpace

__all__ = ["MeasurementModel", "measurement_model", "verify_fit_weights", "PeakPrediction", "predict_peak"]


@dataclass(frozen=True)
class MeasurementModel:
    """How the run measured, which the verifying identification repeats.

    Attributes
    ----------
    freq_hz
        (L,) the excited lines [Hz].
    noise_var
        (L, ny) variance of each output's error over the excitation, ``E = V R^-1``
        [(m/A)^2] (module docstring).
    order
        the fitted model's order.
    delay_s
        the delay the fit takes as known [s] (half a sample).
    poles
        (order,) the run's fitted poles [rad/s]: the verifying fit's start.
    n_dense
        lines of the dense grid between the excited ones where identify looks for the peak.
    noise_only_var
        (L, ny) like ``noise_var``, of the noise alone (the periods' scatter), or None: the fit is then
        weighted by ``noise_var`` itself.
    scatter
        (N, 2) the run's estimated noise and total levels of a line (an output's) over the mean of its
        neighbours', the pairs each simulated measurement's variance estimates are resampled from; None: no
        scatter.
    """

    freq_hz: np.ndarray
    noise_var: np.ndarray
    order: int
    delay_s: float
    poles: np.ndarray
    n_dense: int = 8000
    noise_only_var: np.ndarray | None = None
    scatter: np.ndarray | None = None

    @property
    def dense_hz(self) -> np.ndarray:
        """The dense grid over the band [Hz], identify's (``np.linspace(lo, hi, n_dense)``)."""
        return np.linspace(float(self.freq_hz.min()), float(self.freq_hz.max()), self.n_dense)


def measurement_model(freq_hz: np.ndarray, var_g: np.ndarray, sensitivity: np.ndarray, order: int,
                      delay_s: float, poles: np.ndarray, window: int = 3,
                      var_noise: np.ndarray | None = None) -> MeasurementModel:
    """The run's :class:`MeasurementModel` from its FRF's variance and measured sensitivity.

    Parameters
    ----------
    freq_hz
        (L,) lines [Hz].
    var_g
        (L, ny, nu) the FRF's variance (noise and stochastic distortion; identify's band variance).
    sensitivity
        (L, nu, nu) the sensitivity the run measured.
    order, delay_s, poles
        the run's fit.
    window
        lines either side each output's noise level is averaged over.
    var_noise
        (L, ny, nu) the FRF's noise variance (the periods' scatter), or None.
    """
    sinv = np.linalg.inv(np.asarray(sensitivity))
    gain = np.sum(np.abs(sinv) ** 2, axis=1)                       # (L, nu): sum_k |Sinv_kj|^2
    kernel = np.ones(2 * window + 1)
    count = np.convolve(np.ones(gain.shape[0]), kernel, mode="same")

    def level(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each output's level over the excitation (L, ny), smoothed, and each line's over its neighbours'."""
        e2 = np.mean(np.asarray(v, dtype=float) / gain[:, None, :], axis=2)
        total = np.stack([np.convolve(e2[:, i], kernel, mode="same") for i in range(e2.shape[1])], axis=1)
        neighbours = (total - e2) / (count - 1)[:, None]            # the line itself left out
        return total / count[:, None], e2 / neighbours

    smooth, scatter_total = level(var_g)
    noise_only = scatter = None
    if var_noise is not None:
        noise_only, scatter_noise = level(var_noise)
        scatter = np.stack([scatter_noise.ravel(), scatter_total.ravel()], axis=1)
    return MeasurementModel(np.asarray(freq_hz, dtype=float), smooth, int(order), float(delay_s),
                            np.asarray(poles, dtype=complex), noise_only_var=noise_only, scatter=scatter)


@dataclass(frozen=True)
class PeakPrediction:
    """A controller's predicted input-sensitivity peak.

    Attributes
    ----------
    value
        the predicted headline peak of the verifying identification (median of the samples) [-].
    ci95
        its 95 % prediction interval [lo, hi] [-].
    freq_hz
        where the loop's peak lies at the estimate [Hz].
    axis
        the axis of that peak.
    zones
        probability of each ISO 14839-3 zone of the verifying measurement's peak.
    samples
        (B,) the simulated verifying measurements' peaks.
    loop_peak
        the loop's own peak at the estimate (all frequencies) [-].
    loop_ci95
        the 2.5 and 97.5 % quantiles of the loop's peak over the drawn plants [-].
    loop_samples
        (B,) the loop's peak of each drawn plant.
    stable_share
        share of the drawn plants whose loop is stable [-].
    """

    value: float
    ci95: tuple[float, float]
    freq_hz: float
    axis: str
    zones: dict[str, float]
    samples: np.ndarray
    loop_peak: float
    loop_ci95: tuple[float, float]
    loop_samples: np.ndarray
    stable_share: float

    def to_dict(self) -> dict:
        """``{value, ci95, freq_hz, axis, zones, loop: {...}, ...}`` for tune.json."""
        return dict(value=self.value, ci95=list(self.ci95), freq_hz=self.freq_hz, axis=self.axis,
                    zones=self.zones, n_samples=int(self.samples.size),
                    loop=dict(value=self.loop_peak, ci95=list(self.loop_ci95)), stable_share=self.stable_share)


def _measured_peak(k_lines: np.ndarray, k_dense: np.ndarray, g_lines: np.ndarray, model: MeasurementModel,
                   rng: np.random.Generator) -> float:
    """One simulated verifying measurement's headline peak of the plant ``g_lines`` (L, ny, nu)."""
    f = model.freq_hz
    s = input_sensitivity_frf(k_lines, g_lines)                      # (L, nu, nu)
    ny, nu = g_lines.shape[1:]
    sd = np.sqrt(model.noise_var / 2)[:, :, None]
    e = sd * (rng.standard_normal((f.size, ny, nu)) + 1j * rng.standard_normal((f.size, ny, nu)))
    sinv = np.linalg.inv(s)
    g_meas = g_lines + e @ sinv
    kf = np.einsum("li,ij->lij", k_lines, np.eye(nu)) if k_lines.ndim == 2 else k_lines
    s_meas = s + s @ kf @ e
    fit = fit_common_denominator(f, g_meas, verify_fit_weights(model, sinv, rng), order=model.order,
                                 delay_s=model.delay_s,
                                 initial_poles=model.poles, n_vf_iterations=5, max_refine_evaluations=40)
    dense = model.dense_hz
    model_peak = float(worst_peak(k_dense, fit.model.freqresp(dense)[None])[0])
    line_peak = float(np.abs(np.diagonal(s_meas, axis1=1, axis2=2)).max())
    return max(model_peak, line_peak)


def verify_fit_weights(model: MeasurementModel, sinv: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(L, ny, nu) the variance the simulated verifying fit is weighted by (module docstring): the new loop's
    noise and total variances, each line's estimates scattered by a resampled pair of the run's, combined as
    identify combines them; pooled over the inputs."""
    gain = np.sum(np.abs(sinv) ** 2, axis=1)[:, None, :]             # (L, 1, nu)
    if model.noise_only_var is None or model.scatter is None:
        var = model.noise_var[:, :, None] * gain
        return np.broadcast_to(var.mean(axis=2, keepdims=True), var.shape)
    pick = model.scatter[rng.integers(0, model.scatter.shape[0], size=model.noise_var.shape)]   # (L, ny, 2)
    noise = (model.noise_only_var * pick[..., 0])[:, :, None] * gain
    total = (model.noise_var * pick[..., 1])[:, :, None] * gain
    return fit_weights(noise, total)


def predict_peak(unc: PlantUncertainty, controller: StateSpace, model: MeasurementModel, *, n_samples: int = 100,
                 seed: int = 0, axes: Sequence[str] = ()) -> PeakPrediction:
    """The verifying identification's headline peak with ``controller`` (module docstring).

    Parameters
    ----------
    unc
        the run's updated physical model and its posterior.
    controller
        discrete y -> ic at the loop's sample period.
    model
        how the run measured (:func:`measurement_model`).
    n_samples
        simulated verifying measurements (plants drawn from the posterior).
    seed
        the random draws' seed.
    axes
        the axes' names, for the peak's axis.

    Raises
    ------
    ValueError
        the loop is unstable at the estimate.
    """
    rng = np.random.default_rng([seed, 36])
    params = draw_parameters(unc, n_samples, rng)
    est = plant_set(unc, params[:1], model.freq_hz)
    grid = peak_grid(est.models)
    k_grid = residue_freqresp(controller, grid)
    k_lines = residue_freqresp(controller, model.freq_hz)
    k_dense = residue_freqresp(controller, model.dense_hz)
    samples, loops, stable = [], [], 0
    at_estimate = None
    for i, p in enumerate(params):
        ps = plant_set(unc, [p], model.freq_hz)
        plant = ps.models[0]
        loop = close_loop(plant, controller)
        ok = bool(np.all(np.abs(loop.poles()) < 1.0))
        if i == 0 and not ok:
            raise ValueError("the loop with this controller is unstable on the updated model: no peak to predict")
        stable += ok
        if not ok:
            continue
        # the plant's modes and this loop's own: a closed-loop peak can be far narrower than the plant's mode
        own = np.setdiff1d(closed_loop_patches(loop), grid)
        f_all = np.concatenate([grid, own])
        k_all = np.concatenate([k_grid, residue_freqresp(controller, own)])
        s = input_sensitivity_frf(k_all, residue_freqresp(plant, f_all))
        mag = np.abs(np.diagonal(s, axis1=1, axis2=2))
        loops.append(float(mag.max()))
        if i == 0:
            j = np.unravel_index(np.argmax(mag), mag.shape)
            at_estimate = (float(mag.max()), float(f_all[j[0]]), axes[j[1]] if axes else str(j[1]))
        samples.append(_measured_peak(k_lines, k_dense, ps.frf[0], model, rng))
    x = np.array(samples)
    # a new draw lies between the order statistics at ranks (n + 1) p with probability p2 - p1, whatever the
    # distribution (numpy's "weibull" positions): the interval is a distribution-free prediction interval
    lo, hi = np.quantile(x, [0.025, 0.975], method="weibull")
    loops_a = np.array(loops)
    return PeakPrediction(value=float(np.median(x)), ci95=(float(lo), float(hi)), freq_hz=at_estimate[1],
                          axis=at_estimate[2], zones=zone_probabilities(x), samples=x,
                          loop_peak=at_estimate[0], loop_ci95=(float(np.quantile(loops_a, 0.025)),
                                                                 float(np.quantile(loops_a, 0.975))),
                          loop_samples=loops_a, stable_share=stable / len(params))
