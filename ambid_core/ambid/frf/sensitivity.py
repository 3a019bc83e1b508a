"""Input sensitivity of the AMB control loop and its ISO 14839-3 zone.

Sign convention: ``u = r - C y`` (the control current is ``ic = -C y``), the
plant is ``y = P u``, so ``u = (I + C P)^-1 r``: the input sensitivity
``S = (I + C P)^-1`` maps the excitation r to the applied current u. It is
measured as ``S = U R^-1`` per line over the experiments, i.e. the pooled
``S_ur S_rr^-1`` (r is noise-free, so noise does not bias it).

ISO 14839-3 judges each control axis by the peak magnitude of its
sensitivity over frequency, as an absolute gain (not dB): zone A if
peak < 3 (9.5 dB), B if < 4 (12 dB), C if < 5 (14 dB), else D. Each axis is
the diagonal element S_ii measured with the other loops closed; the
machine's zone is that of the worst axis.
"""

from __future__ import annotations

import numpy as np

from ambid.frf.estimators import _cross, _matched, _right_divide

__all__ = ["input_sensitivity", "sensitivity_diagonal", "sensitivity_peak", "iso14839_zone", "zone_probabilities",
           "input_sensitivity_from_models", "ZONE_LIMITS", "ZONES"]

# Upper peak-gain limits of zones A, B, C (ISO 14839-3); above the last is D.
ZONE_LIMITS: tuple[tuple[str, float], ...] = (("A", 3.0), ("B", 4.0), ("C", 5.0))
#: The zones, best first.
ZONES: tuple[str, ...] = ("A", "B", "C", "D")


def input_sensitivity(u: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Measured input sensitivity ``S = S_ur S_rr^-1`` (r -> u), per line.

    Args:
        u: applied-input spectra (M, Ne, P, L, Nu).
        r: excitation spectra (M, Ne, P or 1, L, Nu), Ne >= Nu with an
            invertible reference matrix at every line.

    Returns:
        S (L, Nu, Nu), dimensionless (A/A).
    """
    s = _matched(u=u, r=r)
    return _right_divide(_cross(s["u"], s["r"]), _cross(s["r"], s["r"]), "S_rr")


def sensitivity_diagonal(s: np.ndarray) -> np.ndarray:
    """Per-axis SISO view: the diagonal elements S_ii, shape (L, Nu) from (L, Nu, Nu)."""
    s = np.asarray(s)
    if s.ndim != 3 or s.shape[1] != s.shape[2]:
        raise ValueError(f"s must have shape (L, Nu, Nu), got {s.shape}")
    return np.diagonal(s, axis1=1, axis2=2).copy()


def sensitivity_peak(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak magnitude of each axis's sensitivity over the lines.

    Args:
        s: sensitivity matrices (L, Nu, Nu), or diagonal (L, Nu).

    Returns:
        (peak, index): peak |S_ii| per axis (Nu,) as absolute gain, and the
        line index (Nu,) where it occurs.
    """
    s = np.asarray(s)
    diag = sensitivity_diagonal(s) if s.ndim == 3 else s
    if diag.ndim != 2 or diag.shape[0] == 0:
        raise ValueError(f"s must have shape (L, Nu, Nu) or (L, Nu) with L >= 1, got {s.shape}")
    if not np.all(np.isfinite(diag)):
        raise ValueError("s contains NaN or inf")
    mag = np.abs(diag)
    idx = mag.argmax(axis=0)
    return mag[idx, np.arange(mag.shape[1])], idx


def iso14839_zone(peak: float) -> str:
    """ISO 14839-3 zone of a peak sensitivity (absolute gain): A < 3 <= B < 4 <= C < 5 <= D."""
    peak = float(peak)
    if not np.isfinite(peak) or peak < 0:
        raise ValueError(f"peak must be a finite gain >= 0 (absolute, not dB), got {peak}")
    for zone, limit in ZONE_LIMITS:
        if peak < limit:
            return zone
    return "D"


def zone_probabilities(peaks: np.ndarray) -> dict[str, float]:
    """The probability of each ISO 14839-3 zone, the share of ``peaks`` (draws of a peak's distribution,
    absolute gain) in it: the zone of :func:`iso14839_zone` with its confidence.

    Examples:
        >>> zone_probabilities(np.array([2.5, 2.9, 3.1, 4.2]))
        {'A': 0.5, 'B': 0.25, 'C': 0.25, 'D': 0.0}
    """
    x = np.asarray(peaks, dtype=float).ravel()
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError("zone_probabilities needs finite peak draws")
    edges = [limit for _, limit in ZONE_LIMITS]
    counts = np.bincount(np.searchsorted(edges, x, side="right"), minlength=len(ZONES))
    return {z: float(c) / x.size for z, c in zip(ZONES, counts)}


def input_sensitivity_from_models(p_jw: np.ndarray, c_jw: np.ndarray) -> np.ndarray:
    """True input sensitivity ``S = (I + C P)^-1`` from plant and controller FRFs.

    Args:
        p_jw: plant FRF (L, Ny, Nu) [m/A], u -> y.
        c_jw: controller FRF (L, Nu, Ny) [A/m], y -> -ic (``u = r - C y``).

    Returns:
        S (L, Nu, Nu).
    """
    p_jw, c_jw = np.asarray(p_jw), np.asarray(c_jw)
    if p_jw.ndim != 3 or c_jw.ndim != 3 or c_jw.shape != (p_jw.shape[0], p_jw.shape[2], p_jw.shape[1]):
        raise ValueError(f"need p_jw (L, Ny, Nu) and c_jw (L, Nu, Ny), got {p_jw.shape} and {c_jw.shape}")
    eye = np.eye(p_jw.shape[2])
    return np.linalg.inv(eye + c_jw @ p_jw)
