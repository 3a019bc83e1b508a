"""Output levels at a periodic experiment's excited and detection lines (the noise and
distortion figure of the report)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ambid.excitation.design import ExcitationDesign
from ambid.frf.periods import period_spectra


@dataclass(frozen=True)
class LineLevels:
    """Output levels of a periodic experiment at its lines, for the noise / distortion figure.

    Each ``*_amp`` is sqrt of the mean over realisations and experiments of
    |Ybar|^2 (Ybar the period mean of the output line spectrum, amplitude
    scaling of :func:`ambid.frf.periods.period_spectra`), each ``*_noise``
    the standard deviation of Ybar from the period scatter [unit of y].

    Attributes
    ----------
    excited_hz, odd_hz, even_hz
        (L,), (Lo,), (Le,) line frequencies [Hz].
    excited_amp, odd_amp, even_amp
        (L, Ny), (Lo, Ny), (Le, Ny) [m].
    excited_noise, odd_noise, even_noise
        same shapes [m].
    """

    excited_hz: np.ndarray
    odd_hz: np.ndarray
    even_hz: np.ndarray
    excited_amp: np.ndarray
    odd_amp: np.ndarray
    even_amp: np.ndarray
    excited_noise: np.ndarray
    odd_noise: np.ndarray
    even_noise: np.ndarray


def line_levels(y: np.ndarray, design: ExcitationDesign) -> LineLevels | None:
    """Output levels at the excited and detection lines of a periodic experiment (P >= 2).

    Parameters
    ----------
    y
        (total_samples, Ny) outputs over the experiment [m]; NaN where
        samples are missing (those periods are left out).
    design
        the experiment's design.

    Returns
    -------
    :class:`LineLevels`, or None when the design is not periodic with
    one period length, or has fewer than two steady-state periods.
    """
    d = design
    if not d.is_periodic or d.kind == "stepped_sine" or d.n_periods < 2:
        return None
    y = np.asarray(y, dtype=float)
    if y.ndim != 2:
        raise ValueError(f"y must be (n_samples, Ny), got shape {y.shape}")
    n, pt, p, ne = d.n_per_period, d.n_transient_periods, d.n_periods, d.n_experiments
    seg = (pt + p) * n
    m = min(y.shape[0] // (seg * ne), d.n_realisations)
    if m < 1:
        return None
    x = y[:m * ne * seg].reshape(m, ne, pt + p, n, y.shape[1])[:, :, pt:]
    valid = np.all(np.isfinite(x), axis=(3, 4))                   # (M, Ne, P)

    def levels(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if lines.size == 0:
            return np.zeros((0, y.shape[1])), np.zeros((0, y.shape[1]))
        spec = period_spectra(np.where(np.isfinite(x), x, 0.0), lines)   # (M, Ne, P, L, Ny)
        spec = np.where(valid[..., None, None], spec, np.nan)
        mean = np.nanmean(spec, axis=2)
        count = valid.sum(axis=2)[..., None, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            var = np.nansum(np.abs(spec - mean[:, :, None]) ** 2, axis=2) / (count * (count - 1))
        var = np.where(count >= 2, var, np.nan)
        return np.sqrt(np.nanmean(np.abs(mean) ** 2, axis=(0, 1))), np.sqrt(np.nanmean(var, axis=(0, 1)))

    res = d.fs_hz / n
    ex, odd, even = (levels(lines) for lines in (d.excited_lines, d.detection_lines_odd, d.detection_lines_even))
    return LineLevels(d.excited_lines * res, d.detection_lines_odd * res, d.detection_lines_even * res,
                      ex[0], odd[0], even[0], ex[1], odd[1], even[1])
