"""Split a periodic experiment into periods and take their spectra.

Sample layout (fixed by the excitation design): the record is a sequence of
segments, realisation-major::

    for m in range(M):            # realisations (independent random phases)
        for e in range(Ne):       # experiments (e.g. orthogonal multisines)
            Pt transient periods, then P steady-state periods, N samples each

so it holds exactly ``M * Ne * (Pt + P) * N`` samples. The transient periods
are dropped: only the steady state is used by the estimators.
"""

from __future__ import annotations

import numpy as np

__all__ = ["layout_length", "split_periods", "period_spectra"]


def _positive_int(name: str, value: int, minimum: int = 1) -> int:
    if isinstance(value, bool) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def layout_length(n_per_period: int, n_periods: int, n_transient: int,
                  n_realisations: int, n_experiments: int) -> int:
    """Number of samples of a record with the layout above, ``M*Ne*(Pt+P)*N``."""
    n = _positive_int("n_per_period", n_per_period)
    p = _positive_int("n_periods", n_periods)
    pt = _positive_int("n_transient", n_transient, minimum=0)
    m = _positive_int("n_realisations", n_realisations)
    ne = _positive_int("n_experiments", n_experiments)
    return m * ne * (pt + p) * n


def split_periods(x: np.ndarray, n_per_period: int, n_periods: int, n_transient: int,
                  n_realisations: int, n_experiments: int) -> np.ndarray:
    """Cut a record into steady-state periods, dropping the transient periods.

    Parameters
    ----------
    x
        samples, shape (n_samples, n_ch) (a 1-D array is one channel),
        any unit; n_samples must equal ``M * Ne * (Pt + P) * N``.
    n_per_period
        samples per period N.
    n_periods
        steady-state periods per segment P.
    n_transient
        transient periods per segment Pt (dropped), >= 0.
    n_realisations
        realisations M.
    n_experiments
        experiments per realisation Ne.

    Returns
    -------
    Array (M, Ne, P, N, n_ch), a copy in the unit of ``x``.
    """
    x = np.asarray(x)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"x must have shape (n_samples, n_ch), got shape {x.shape}")
    expected = layout_length(n_per_period, n_periods, n_transient, n_realisations, n_experiments)
    if x.shape[0] != expected:
        raise ValueError(
            f"x has {x.shape[0]} samples but the layout M*Ne*(Pt+P)*N = {n_realisations}*"
            f"{n_experiments}*({n_transient}+{n_periods})*{n_per_period} = {expected} needs exactly "
            "that many; check the layout against the excitation design, or transpose x if "
            "channels are on axis 0")
    segments = x.reshape(n_realisations, n_experiments, n_transient + n_periods,
                         n_per_period, x.shape[1])
    return segments[:, :, n_transient:].copy()


def period_spectra(periods: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """DFT of every period at the given bins.

    Scaling: ``X[k] = (2/N) sum_n x[n] exp(-2j pi k n / N)`` for 0 < k < N/2,
    so ``A cos(2 pi k n / N + phi)`` gives ``X[k] = A exp(j phi)``, |X| = A; for
    k = 0 and k = N/2 the factor is 1/N (a constant c gives X[0] = c). White
    noise of variance s^2 then has ``E|X[k]|^2 = 4 s^2 / N`` at interior bins.

    Parameters
    ----------
    periods
        array (M, Ne, P, N, n_ch) from :func:`split_periods`.
    lines
        DFT bin indices, int array (L,), each in [0, N/2].

    Returns
    -------
    Complex array (M, Ne, P, L, n_ch), in the unit of ``periods``.
    """
    periods = np.asarray(periods)
    if periods.ndim != 5:
        raise ValueError(
            f"periods must have shape (M, Ne, P, N, n_ch) as returned by split_periods, "
            f"got shape {periods.shape}")
    if np.iscomplexobj(periods):
        raise ValueError("periods must be real time samples, got a complex array")
    n = periods.shape[3]
    lines = np.asarray(lines)
    if lines.ndim != 1 or not np.issubdtype(lines.dtype, np.integer):
        raise ValueError(f"lines must be a 1-D integer array of DFT bins, got {lines!r}")
    if lines.size and (lines.min() < 0 or lines.max() > n // 2):
        raise ValueError(f"lines must lie in [0, N/2] = [0, {n // 2}] for N = {n}, "
                         f"got range [{lines.min()}, {lines.max()}]")
    spectrum = np.fft.rfft(periods, axis=3)[:, :, :, lines, :]
    scale = np.full(lines.shape, 2.0 / n)
    scale[lines == 0] = 1.0 / n
    if n % 2 == 0:
        scale[lines == n // 2] = 1.0 / n
    return spectrum * scale[:, None]
