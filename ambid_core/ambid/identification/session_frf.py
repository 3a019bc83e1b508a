"""Stage 2, the FRF: a session's FRF, its variances, its directional form and its noise figures.

The FRF itself is the inputs' (:func:`ambid.frf.offline.frf_from_session`, the stream the FRF consumer
runs). Here it gets what the fit and the printed band need: the variance the intervals are read from
(total where the realisations' scatter gives it, else noise; pooled over the inputs of an output), the
variance the fit is weighted by, the covariance of a row's entries (the indirect estimator) and the
realisations whose scatter joins the intervals; forward and backward whirl where the channels hold a
bearing's x and y; and ``frf.npz``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ambid.frf.directional import DirectionalFrf, directional_frf, has_planes
from ambid.frf.streaming import FrfResult
from ambid.frf.uncertainty import fit_weights, floored_variance, row_covariance
from ambid.identification.result import Harmonic, NoiseFigures, SynchronousFigures

__all__ = ["FrfVariances", "frf_variances", "SessionFrf", "session_frf", "band_kind"]


@dataclass(frozen=True)
class FrfVariances:
    """What an FRF's fit is weighted by and its intervals are read from.

    Attributes
    ----------
    var, var_kind
        the line variance the intervals are read from, and what it is (None: no variance).
    band_var
        the variance of the printed +-2 sigma band.
    weights, weights_kind
        the variance the fit is weighted by, and what it is.
    row_cov
        the covariance of a row's entries (the indirect estimator), or None.
    realisations
        (M, L, Ny, Nu) the realisations' FRFs whose scatter joins the intervals, or None.
    """

    var: np.ndarray | None
    var_kind: str
    band_var: np.ndarray
    weights: np.ndarray | None
    weights_kind: str
    row_cov: np.ndarray | None
    realisations: np.ndarray | None


def frf_variances(frf: FrfResult) -> FrfVariances:
    """The variances of ``frf`` for its fit and its printed band (module docstring)."""
    var, var_kind = _fit_variance(frf)
    # the printed +-2 sigma band: the same variance, pooled over the inputs of an output (one output's
    # noise and distortion reach every input's column alike): 2 (M - 1) Nu degrees of freedom instead of
    # 2 (M - 1), so that with M = 3 the band covers 96 % of the lines, not 89 %
    band_var = frf.var_total if var is None else var
    # the indirect estimator's errors are correlated along a row (U^-1 mixes the experiments); the
    # intervals of the modes and parameters take that in (a sandwich with this covariance)
    row_cov = (row_covariance(var, frf.sensitivity) if var is not None and frf.estimator == "indirect"
               and np.all(np.isfinite(frf.sensitivity)) else None)
    # and the realisations' own scatter, where it is wider (distortion coherent over the lines)
    realisations = (frf.frf_realisations if row_cov is not None and frf.frf_realisations is not None
                    and len(frf.frf_realisations) >= 2 else None)
    # the fits weight by a variance that does not follow the realisations' scatter their intervals are read from
    w_var, w_kind = _weight_variance(frf, var, var_kind)
    return FrfVariances(var, var_kind, band_var, w_var, w_kind, row_cov, realisations)


def _fit_variance(frf: FrfResult, pool: bool = True) -> tuple[np.ndarray | None, str]:
    """The FRF's variance, for the printed band and the fits' line covariance (the fits weight by
    :func:`_weight_variance`): total (BLA) where known, else noise; floored.

    With ``pool``, each output's variances are averaged over the inputs (one
    row of G carries the same output noise): an estimate from P periods has
    only 2 (P - 1) degrees of freedom.
    """
    for name in ("var_total", "var_noise"):
        v = np.asarray(getattr(frf, name), dtype=float)
        if np.all(np.isfinite(v)) and np.any(v > 0):
            if pool:
                v = np.broadcast_to(v.mean(axis=2, keepdims=True), v.shape)
            return floored_variance(v), name + (", pooled over the inputs" if pool else "")
    return None, "none (equal weights)"


def _weight_variance(frf: FrfResult, var: np.ndarray | None, var_kind: str) -> tuple[np.ndarray | None, str]:
    """The variance the fits weight by: the noise scaled by the distortion's share averaged over the
    neighbouring lines (:func:`ambid.frf.uncertainty.fit_weight_variance`), where both are known; else ``var``."""
    vn, vt = (np.asarray(getattr(frf, k), dtype=float) for k in ("var_noise", "var_total"))
    if var is None or not (np.all(np.isfinite(vn)) and np.all(np.isfinite(vt)) and np.any(vn > 0)):
        return var, var_kind
    return fit_weights(vn, vt), "var_noise x (var_total / var_noise averaged over +-3 lines), pooled over the inputs"



def band_kind(var_kind: str) -> str:
    """What the printed band's variance holds, in words."""
    kind = "total (noise + nonlinear)" if var_kind.startswith("var_total") else "noise only"
    return kind + (", pooled over the inputs" if "pooled" in var_kind else "")


@dataclass(frozen=True)
class SessionFrf:
    """A session's FRF as the identification uses it.

    Attributes
    ----------
    frf
        the estimate.
    variances
        its variances (:func:`frf_variances`).
    directional
        its forward and backward whirl FRFs, where the channels hold a bearing's x and y; else None.
    notes
        what the measurement lacks (gaps).
    """

    frf: FrfResult
    variances: FrfVariances
    directional: DirectionalFrf | None
    notes: list[str]

    def noise_figures(self, true_noise: np.ndarray | None) -> NoiseFigures:
        """The FRF's noise and distortion figures, with the true noise through the loop where known."""
        frf, dist = self.frf, self.frf.distortion
        return NoiseFigures(output_noise_std_m=frf.noise_std, output_noise_std_ci95_m=frf.noise_std_ci95,
                            output_noise_std_sd_m=frf.noise_std_sd, true_output_noise_std_m=true_noise,
                            relative_frf_noise_std=frf.relative_noise_std,
                            nonlinear_variance_ratio=frf.nonlinear_ratio,
                            distortion_odd_db=None if dist is None else dist.odd_db,
                            distortion_even_db=None if dist is None else dist.even_db,
                            fit_weights=self.variances.weights_kind)

    def synchronous_figures(self) -> SynchronousFigures | None:
        """The synchronous response at the disturbance lines of a run at speed (None at standstill)."""
        s = self.frf.synchronous
        if s is None:
            return None
        return SynchronousFigures(
            on_lines=s.on_lines, n_records=s.n_records, channels=list(s.channel_names),
            harmonics=[Harmonic(harmonic=int(k), freq_hz=float(fq), amplitude=a, phase_deg=np.degrees(ph),
                                amplitude_std=sd)
                       for k, fq, a, ph, sd in zip(s.harmonic, s.freq_hz, s.amplitude, s.phase_rad,
                                                   s.amplitude_std)])

    def save(self, path: str | os.PathLike, true_g: np.ndarray | None = None,
             true_g_x: np.ndarray | None = None) -> None:
        """``frf.npz``: the FRF, its variances, coherence, sensitivity, channels, the truths where known and
        the directional FRFs."""
        frf, v, dfrf = self.frf, self.variances, self.directional
        truths = {} if true_g is None else {"true_frf": true_g}
        if true_g_x is not None:
            truths["true_frf_at_excitation"] = true_g_x
        np.savez(path, freq_hz=frf.freq_hz, frf=frf.frf, var_noise=frf.var_noise, var_total=frf.var_total,
                 var_band=v.band_var, **({} if v.weights is None else dict(var_fit=v.weights)),
                 coherence=frf.coherence, sensitivity=frf.sensitivity,
                 input_names=np.array(frf.input_names), output_names=np.array(frf.output_names), **truths,
                 **({} if dfrf is None else dict(forward=dfrf.forward, backward=dfrf.backward)))


def session_frf(frf: FrfResult) -> SessionFrf:
    """Stage 2: the FRF of a session's inputs (``inputs.frf``) with its variances and directional form."""
    v = frf_variances(frf)
    notes = [f"{len(frf.gaps)} gap(s) in the measurement; the periods they touch were left out"] if frf.gaps else []
    # the radial bearing planes among the channels (x and y of a bearing): forward and backward whirl told apart
    dfrf = (directional_frf(frf.freq_hz, frf.frf, v.var, frf.output_names, frf.input_names)
            if has_planes(frf.output_names, frf.input_names) else None)
    return SessionFrf(frf, v, dfrf, notes)
