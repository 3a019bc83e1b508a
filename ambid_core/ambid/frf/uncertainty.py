"""Noise and nonlinear-distortion analysis of periodic experiments.

The "robust method" of Pintelon & Schoukens (System Identification: A
Frequency Domain Approach, 2nd ed., 2012, ch. 3-4) for M realisations of a
random-phase multisine, each measured over P steady-state periods:

* per realisation m: ``G_m = Ybar_m Ubar_m^+`` (EIV ratio of the period
  means; the indirect ``(Ybar R^H)(Ubar R^H)^-1`` when r is given) and the
  noise variance of G_m from the period-to-period scatter of the per-period
  solutions G_mp (:func:`ambid.frf.estimators.per_period_frf`)::

      var_n(G_m) = sum_p |G_mp - mean_p G_mp|^2 / (P (P - 1))

  (sample variance over P divided by P; the per-period solutions propagate
  the input and output noise, and their correlation, to G to first order);
* best linear approximation ``G_bla = mean_m G_m`` with::

      var_noise = mean_m var_n(G_m) / M               (noise only)
      var_total = sum_m |G_m - G_bla|^2 / (M (M - 1))  (noise + stochastic NL)
      var_bla_nl = max(var_total - var_noise, 0)       (NL part of var(G_bla))
      var_stochastic_nl = M * var_bla_nl               (var of G_s, one realisation)

  The stochastic nonlinear contribution G_s of one realisation is what
  changes with the random phases; ``var_stochastic_nl`` is its variance,
  ``var G_s = M (var_BLA - var_BLA,n)`` as in the robust method.

All variances are of complex quantities, ``E|X - E X|^2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ambid.frf.estimators import _matched, _records, _right_divide, per_period_frf

__all__ = [
    "fit_weights", "floored_variance",
    "fit_weight_variance", "period_mean_variance", "frf_noise_variance", "BlaEstimate", "bla_robust",
    "DistortionLevels", "distortion_levels", "noise_std_interval", "output_noise_std", "row_covariance",
]


def period_mean_variance(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over the periods and the variance of that mean.

    Parameters
    ----------
    x
        period spectra (M, Ne, P, L, n_ch), P >= 2.

    Returns
    -------
    (mean, var_of_mean), each (M, Ne, L, n_ch); ``var_of_mean`` is the
    sample variance over P (ddof 1) divided by P, in unit of x squared.
    """
    x = _matched(x=x)["x"]
    p = x.shape[2]
    if p < 2:
        raise ValueError(f"period-to-period scatter needs P >= 2 periods, got P = {p}")
    return x.mean(axis=2), x.var(axis=2, ddof=1) / p


def frf_noise_variance(y: np.ndarray, u: np.ndarray,
                       r: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """FRF of each realisation and its noise variance from period scatter.

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny), P >= 2.
    u
        input spectra (M, Ne, P, L, Nu).
    r
        excitation spectra (M, Ne, P or 1, L, Nu), optional; if given
        ``G_m = (Ybar R^H)(Ubar R^H)^-1`` else ``G_m = Ybar Ubar^+``.

    Returns
    -------
    (G_m, var_n): each (M, L, Ny, Nu); var_n is the noise variance of G_m.
    """
    s = _matched(y=y, u=u) if r is None else _matched(y=y, u=u, r=r)
    p = s["y"].shape[2]
    if p < 2:
        raise ValueError(f"period-to-period scatter needs P >= 2 periods, got P = {p}")
    gk = per_period_frf(y, u, r)                       # (M, P, L, Ny, Nu)
    var_n = gk.var(axis=1, ddof=1) / p
    ybar = _records(s["y"].mean(axis=2, keepdims=True))[:, 0]
    ubar = _records(s["u"].mean(axis=2, keepdims=True))[:, 0]
    ref = _records(s["r"].mean(axis=2, keepdims=True))[:, 0] if r is not None else ubar
    ref_h = np.conj(np.swapaxes(ref, -1, -2))
    g_m = _right_divide(ybar @ ref_h, ubar @ ref_h, "Ubar R^H")
    return g_m, var_n


@dataclass(frozen=True)
class BlaEstimate:
    """Best linear approximation with noise and nonlinear variances.

    Attributes (arrays (L, Ny, Nu), unit of G, variances in unit of G squared):
        frf: G_bla, mean over realisations.
        frf_realisations: G_m per realisation (M, L, Ny, Nu).
        var_noise: noise variance of G_bla (period scatter).
        var_total: total variance of G_bla (realisation scatter).
        var_bla_nl: max(var_total - var_noise, 0), NL part of var(G_bla).
        var_stochastic_nl: M * var_bla_nl, variance of the stochastic
            nonlinear contribution of one realisation.
        n_realisations: M.
        n_periods: P.
    """

    frf: np.ndarray
    frf_realisations: np.ndarray
    var_noise: np.ndarray
    var_total: np.ndarray
    var_bla_nl: np.ndarray
    var_stochastic_nl: np.ndarray
    n_realisations: int
    n_periods: int


def bla_robust(y: np.ndarray, u: np.ndarray, r: np.ndarray | None = None) -> BlaEstimate:
    """Robust-method BLA from M >= 2 realisations of P >= 2 periods (see module doc).

    Parameters
    ----------
    y
        output spectra at the excited lines (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).
    r
        excitation spectra (M, Ne, P or 1, L, Nu), optional (use it in
        closed loop).

    Returns
    -------
    :class:`BlaEstimate`.
    """
    g_m, var_n = frf_noise_variance(y, u, r)
    m = g_m.shape[0]
    if m < 2:
        raise ValueError(f"the total (realisation-to-realisation) variance needs M >= 2 realisations, "
                         f"got M = {m}; use frf_noise_variance for a single realisation")
    g = g_m.mean(axis=0)
    var_noise = var_n.mean(axis=0) / m
    var_total = g_m.var(axis=0, ddof=1) / m
    var_bla_nl = np.clip(var_total - var_noise, 0.0, None)
    return BlaEstimate(frf=g, frf_realisations=g_m, var_noise=var_noise, var_total=var_total,
                       var_bla_nl=var_bla_nl, var_stochastic_nl=m * var_bla_nl,
                       n_realisations=m, n_periods=int(np.shape(y)[2]))


@dataclass(frozen=True)
class DistortionLevels:
    """Output levels at non-excited (detection) lines against the noise floor.

    At each detection line the period mean Ybar is coherent over the
    periods (nonlinear distortion of a periodic signal is periodic) while the
    noise averages down, so ``E|Ybar|^2 = |Y_nl|^2 + var(Ybar)``; var(Ybar) is
    estimated from the period scatter at that same line. Without distortion
    the ratio is ~1 (0 dB).

    Attributes
    ----------
    odd_power
        mean over realisations and experiments of |Ybar|^2 at the
        odd detection lines (L_odd, Ny) [unit of y squared].
    odd_noise_power
        var(Ybar) there, same shape.
    even_power, even_noise_power
        the same at even lines (L_even, Ny).
    odd_db, even_db
        per output (Ny,), ``10 log10(sum power / sum
        noise_power)`` over the lines of that kind [dB above the noise
        floor]; NaN when there are no such lines.
    """

    odd_power: np.ndarray
    odd_noise_power: np.ndarray
    even_power: np.ndarray
    even_noise_power: np.ndarray
    odd_db: np.ndarray
    even_db: np.ndarray


def _levels(y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mean, var = period_mean_variance(y)
    power = (np.abs(mean) ** 2).mean(axis=(0, 1))
    noise = var.real.mean(axis=(0, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        db = 10 * np.log10(power.sum(axis=0) / noise.sum(axis=0))
    if power.shape[0] == 0:
        db = np.full(power.shape[1], np.nan)
    return power, noise, db


def distortion_levels(y_odd: np.ndarray, y_even: np.ndarray) -> DistortionLevels:
    """Even and odd nonlinear-distortion levels from detection lines.

    Odd (e.g. cubic) nonlinearities of an odd multisine show at the odd
    detection lines, even ones (e.g. quadratic) at the even lines.

    Parameters
    ----------
    y_odd
        output spectra at the odd non-excited lines (M, Ne, P, L_odd, Ny), P >= 2.
    y_even
        output spectra at the even non-excited lines (M, Ne, P, L_even, Ny).

    Returns
    -------
    :class:`DistortionLevels`.
    """
    odd = _levels(y_odd)
    even = _levels(y_even)
    if odd[0].shape[1] != even[0].shape[1]:
        raise ValueError(f"y_odd has {odd[0].shape[1]} outputs but y_even has {even[0].shape[1]}")
    return DistortionLevels(odd_power=odd[0], odd_noise_power=odd[1], odd_db=odd[2],
                            even_power=even[0], even_noise_power=even[1], even_db=even[2])


def output_noise_std(periods: np.ndarray) -> np.ndarray:
    """Time-domain noise standard deviation from period-to-period scatter.

    ``sigma^2 = mean over (m, e, n) of the sample variance over p (ddof 1)``
    of the steady-state samples: the periodic part (response to the
    excitation and its nonlinear distortion) cancels, the noise stays.

    Parameters
    ----------
    periods
        time samples (M, Ne, P, N, n_ch) from
        :func:`ambid.frf.periods.split_periods`, P >= 2.

    Returns
    -------
    Noise standard deviation per channel (n_ch,), unit of the samples.
    """
    periods = np.asarray(periods, dtype=float)
    if periods.ndim != 5:
        raise ValueError(f"periods must have shape (M, Ne, P, N, n_ch), got shape {periods.shape}")
    if periods.shape[2] < 2:
        raise ValueError(f"period-to-period scatter needs P >= 2 periods, got P = {periods.shape[2]}")
    if not np.all(np.isfinite(periods)):
        raise ValueError("periods contain NaN or inf; clean the time data first")
    return np.sqrt(periods.var(axis=2, ddof=1).mean(axis=(0, 1, 2)))


def noise_std_interval(segment_variances: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviation and interval of the noise std sqrt(mean over segments of v_s).

    Each segment's period-to-period variance v_s averages N (P - 1) squared
    deviations, but of a coloured process (the sensor noise through the
    closed loop), so the chi^2 law with N (P - 1) degrees of freedom would
    be too narrow by the noise's correlation length. The segments are
    independent records: the scatter of the S values v_s gives the variance
    of their mean, and Student's t with S - 1 degrees of freedom the
    interval, which the square root carries to the std (its standard
    deviation by the delta method, sd(v_mean) / (2 sqrt(v_mean))).

    Parameters
    ----------
    segment_variances
        (S, n_ch) each segment's mean period-to-period
        variance [unit^2].
    level
        the interval's level.

    Returns
    -------
    (sd (n_ch,), interval (n_ch, 2)) in the unit of the samples; NaN
    with S < 2.
    """
    v = np.asarray(segment_variances, dtype=float)
    s, n_ch = v.shape
    if s < 2:
        return np.full(n_ch, np.nan), np.full((n_ch, 2), np.nan)
    mean = v.mean(axis=0)
    sd_mean = v.std(axis=0, ddof=1) / np.sqrt(s)
    # Student's t quantile from scipy.special, not scipy.stats: that one's import (~0.9 s of CPU) came in the
    # middle of a session in the live view, at its first estimate, and in every command that reads an FRF
    from scipy import special

    half = special.stdtrit(s - 1, 0.5 + level / 2) * sd_mean
    ci = np.sqrt(np.clip(np.stack([mean - half, mean + half], axis=1), 0.0, None))
    return sd_mean / (2 * np.sqrt(mean)), ci


def row_covariance(var: np.ndarray, sensitivity: np.ndarray) -> np.ndarray:
    """Covariance of the entries of each row of a closed-loop FRF estimated with orthogonal excitations.

    With the indirect estimator ``G = (Y R^H)(U R^H)^-1`` (Ne = Nu) the error
    of output row i is ``n_i U^-1``, n_i that output's noise (or stochastic
    distortion) over the experiments, so within a row
    ``E[e_j e_k*] = sigma_i^2 ((U U^H)^-1)_kj``; the rows are independent.
    An orthogonal design has ``R R^H = c I``, and ``U = S R`` with S the
    input sensitivity, so the shape is ``conj((S S^H)^-1)``: where the loop
    couples the inputs (S far from diagonal, near a lightly damped mode) the
    entries of a row are strongly correlated, and a fit that takes them as
    independent misjudges its own uncertainty.

    Parameters
    ----------
    var
        (L, Ny, Nu) variance of each entry (e.g. pooled over the inputs);
        each row's covariance is scaled so that its mean diagonal is the
        mean of ``var`` over that row.
    sensitivity
        (L, Nu, Nu) input sensitivity S (r -> u).

    Returns
    -------
    (L, Ny, Nu, Nu) complex Hermitian row covariances [unit of G squared].
    """
    v = np.asarray(var, dtype=float)
    s = np.asarray(sensitivity, dtype=complex)
    if v.ndim != 3 or s.shape != (v.shape[0], v.shape[2], v.shape[2]):
        raise ValueError(f"var must be (L, Ny, Nu) and sensitivity (L, Nu, Nu); got {v.shape}, {s.shape}")
    shape = np.conj(np.linalg.inv(s @ np.conj(np.swapaxes(s, -1, -2))))
    shape = (shape + np.conj(np.swapaxes(shape, -1, -2))) / 2
    shape = shape / np.real(np.trace(shape, axis1=-2, axis2=-1))[:, None, None] * v.shape[2]
    return v.mean(axis=2)[:, :, None, None] * shape[:, None]


def fit_weight_variance(var_noise: np.ndarray, var_total: np.ndarray, window: int = 3) -> np.ndarray:
    """The variance to weight a fit by, not read from the realisations' scatter it is judged by.

    Weights taken from ``var_total`` (the scatter of M realisations) follow
    that scatter: a line whose few realisations happen to disagree gets a small
    weight, and the scatter of the fitted parameters, measured with those
    weights, reads too small (with M = 3 the bending-mode damping's variance
    came out 1.7 times too small, and the estimate was less accurate). Here
    each line's level is its noise variance (the period-to-period scatter,
    independent of the realisation means for Gaussian noise), scaled by the
    stochastic distortion's share ``var_total / var_noise``, which varies
    slowly over the lines, averaged over the ``window`` lines either side
    with the line itself left out: no weight owes anything to its own
    line's realisations. Both
    variances are pooled over the inputs of an output first (one output's
    noise and distortion reach every input's column alike).

    Parameters
    ----------
    var_noise
        (L, Ny, Nu) noise variance of G [unit of G squared].
    var_total
        (L, Ny, Nu) total variance of G (noise and stochastic
        nonlinear distortion, from the realisations' scatter).
    window
        lines either side the distortion share is averaged over.

    Returns
    -------
    (L, Ny, Nu) variance, the same for every input of an output; the
    share is floored at 1 (the total holds the noise).
    """
    vn = np.asarray(var_noise, dtype=float).mean(axis=2, keepdims=True)
    vt = np.asarray(var_total, dtype=float).mean(axis=2, keepdims=True)
    share = np.where(vn > 0, vt / np.where(vn > 0, vn, 1.0), 1.0)
    n_lines = share.shape[0]
    csum = np.cumsum(np.concatenate([np.zeros((1,) + share.shape[1:]), share]), axis=0)
    lo = np.clip(np.arange(n_lines) - window, 0, n_lines)
    hi = np.clip(np.arange(n_lines) + window + 1, 0, n_lines)
    # the neighbours' mean, the line itself left out: its weight owes nothing to its own realisations
    count = (hi - lo - 1)[:, None, None]
    mean_share = np.where(count > 0, (csum[hi] - csum[lo] - share) / np.maximum(count, 1), share)
    return np.broadcast_to(vn * np.maximum(mean_share, 1.0), np.shape(var_noise)).copy()


def floored_variance(v: np.ndarray) -> np.ndarray:
    """A weighting variance floored at 1e-6 of its median positive value (no line weighs without bound)."""
    return np.maximum(v, 1e-6 * np.median(v[v > 0]))


def fit_weights(var_noise: np.ndarray, var_total: np.ndarray) -> np.ndarray:
    """(L, Ny, Nu) the variance identify weights its fit by, from the FRF's noise and total variances
    (L, Ny, Nu) [unit of G squared]: :func:`fit_weight_variance`, floored (:func:`floored_variance`).
    The commissioning's simulated verifying measurement weights its fit by the same rule."""
    return floored_variance(fit_weight_variance(var_noise, var_total))
