"""Frequency line sets: grids, spacing, detection lines and amplitude shapes.

A *line* is a DFT bin index k of the period of N samples, i.e. the
frequency k * fs / N [Hz]. Grids follow Pintelon & Schoukens (2012), ch. 5:

- ``'full'``: every line of the band;
- ``'odd'``: odd lines only, so that even nonlinear distortions land on the
  unexcited even lines;
- ``'random_odd'``: odd lines, and in each group of ``group_size``
  consecutive odd lines one, chosen at random, is left out as an odd
  detection line (odd nonlinear distortions show there).

Spacing ``'linear'`` keeps every grid line; ``'log'`` keeps about
``n_lines`` quasi-logarithmically spaced unique integer lines of the grid.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Union

import numpy as np

GRIDS = ("full", "odd", "random_odd")
SPACINGS = ("linear", "log")

AmplitudeShape = Union[None, Callable[[np.ndarray], np.ndarray], Sequence[Sequence[float]],
                       np.ndarray]


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


def n_per_period(fs_hz: float, resolution_hz: float) -> int:
    """Samples per period N = fs / resolution, which must be an integer.

    Parameters
    ----------
    fs_hz
        sample rate [Hz], > 0.
    resolution_hz
        frequency resolution = line spacing fs/N [Hz], > 0.

    Returns
    -------
    N [samples].

    Raises
    ------
    ValueError
        if fs/resolution is not an integer (to 1e-9 relative); the
        message names resolutions that work.

    Examples
    --------
    >>> n_per_period(10_000.0, 5.0)    # 5 Hz resolution at 10 kHz
    2000
    """
    fs = _finite("fs_hz", fs_hz)
    res = _finite("resolution_hz", resolution_hz)
    if fs <= 0 or res <= 0:
        raise ValueError(f"fs_hz and resolution_hz must be > 0, got {fs!r} and {res!r}")
    ratio = fs / res
    n = int(round(ratio))
    if n < 4:
        raise ValueError(
            f"resolution_hz={res!r} gives only {ratio:.3g} samples per period at fs_hz={fs!r}; "
            f"use resolution_hz <= {fs / 4!r}")
    if abs(ratio - n) > 1e-9 * ratio:
        lo, hi = int(np.floor(ratio)), int(np.ceil(ratio))
        raise ValueError(
            f"fs_hz / resolution_hz = {ratio!r} is not an integer number of samples per period; "
            f"use resolution_hz = fs_hz/N for an integer N, e.g. {fs / hi!r} (N={hi}) "
            f"or {fs / lo!r} (N={lo})")
    return n


def band_bins(band_hz: tuple[float, float], fs_hz: float, n: int) -> tuple[int, int]:
    """First and last DFT bin inside a band.

    Parameters
    ----------
    band_hz
        (f_lo, f_hi) [Hz], 0 <= f_lo < f_hi < fs/2.
    fs_hz
        sample rate [Hz].
    n
        samples per period N.

    Returns
    -------
    (k_lo, k_hi): bins with f_lo <= k fs/N <= f_hi, k_lo >= 1, k_hi < N/2.

    Raises
    ------
    ValueError
        NaN, wrong order, band reaching Nyquist, or no bin inside.

    Examples
    --------
    >>> band_bins((10.0, 500.0), 10_000.0, 2000)   # bins of 5 Hz
    (2, 100)
    """
    if len(band_hz) != 2:
        raise ValueError(f"band_hz must be (f_lo, f_hi) in Hz, got {band_hz!r}")
    f_lo, f_hi = (_finite("band_hz", f) for f in band_hz)
    nyq = fs_hz / 2
    if not 0 <= f_lo < f_hi:
        raise ValueError(f"band_hz must satisfy 0 <= f_lo < f_hi, got {band_hz!r}")
    if f_hi >= nyq:
        raise ValueError(
            f"band_hz upper edge {f_hi!r} Hz is not below the Nyquist frequency fs/2 = {nyq!r} Hz; "
            "lower the band or raise fs_hz")
    res = fs_hz / n
    tol = 1e-9
    k_lo = max(1, int(np.ceil(f_lo / res - tol)))
    k_hi = min((n - 1) // 2, int(np.floor(f_hi / res + tol)))
    if k_hi < k_lo:
        raise ValueError(
            f"band_hz {band_hz!r} holds no frequency line at resolution {res!r} Hz; "
            "widen the band or refine the resolution")
    return k_lo, k_hi


def _greedy_log(cand: np.ndarray, ratio: float) -> np.ndarray:
    """Indices of candidates picked by: next = first candidate >= ratio * current."""
    chosen = [0]
    while True:
        nxt = int(np.searchsorted(cand, cand[chosen[-1]] * ratio - 1e-9))
        nxt = max(nxt, chosen[-1] + 1)
        if nxt >= cand.size:
            return np.array(chosen)
        chosen.append(nxt)


def log_lines(candidates: np.ndarray, n_lines: int) -> np.ndarray:
    """Quasi-logarithmic subset of candidate lines (unique integers).

    Each line is the first candidate at least a constant ratio above the
    previous one, so where the ratio step is less than one candidate apart
    (the low end) every candidate is taken and above that the lines are
    log-spaced. The ratio is the largest giving at least n_lines lines.

    Parameters
    ----------
    candidates
        (K,) sorted unique positive integer lines to choose from.
    n_lines
        wanted number of lines (>= 1).

    Returns
    -------
    (L,) sorted subset of ``candidates`` starting at its first, with
    L = min(n_lines, K) or slightly more (when no ratio gives exactly
    n_lines).

    Examples
    --------
    >>> import numpy as np
    >>> log_lines(np.arange(1, 100), 5)   # five of 1..99, about evenly spaced in log
    array([ 1,  3, 10, 31, 94])
    """
    cand = np.asarray(candidates, dtype=np.int64)
    if n_lines < 1:
        raise ValueError(f"n_lines must be >= 1, got {n_lines!r}")
    if n_lines >= cand.size:
        return cand.copy()
    lo, hi = 1.0, float(cand[-1]) / float(cand[0]) + 1.0  # counts: K at lo, 1 at hi
    for _ in range(60):  # bisection on the ratio: the count falls as the ratio grows
        mid = 0.5 * (lo + hi)
        if _greedy_log(cand, mid).size >= n_lines:
            lo = mid
        else:
            hi = mid
    return cand[_greedy_log(cand, lo)]


def line_set(k_lo: int, k_hi: int, grid: str = "random_odd", spacing: str = "linear",
             n_lines: int | None = None, group_size: int = 3,
             rng: np.random.Generator | None = None) -> np.ndarray:
    """Excited lines of a grid within bins [k_lo, k_hi].

    Parameters
    ----------
    k_lo, k_hi
        first and last admissible bin (1 <= k_lo <= k_hi).
    grid
        'full', 'odd' or 'random_odd'.
    spacing
        'linear' (all grid lines) or 'log' (about ``n_lines``
        quasi-log lines of the grid; default 100).
    n_lines
        number of lines for log spacing; must be None for linear.
    group_size
        random-odd group length (>= 2).
    rng
        random generator for the random-odd choice.

    Returns
    -------
    (L,) int64 sorted excited lines.

    Examples
    --------
    >>> line_set(2, 20, "full")
    array([ 2,  3,  4,  5,  6,  7,  8,  9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20])
    >>> line_set(2, 20, "odd")
    array([ 3,  5,  7,  9, 11, 13, 15, 17, 19])
    """
    if grid not in GRIDS:
        raise ValueError(f"grid must be one of {GRIDS}, got {grid!r}")
    if spacing not in SPACINGS:
        raise ValueError(f"spacing must be one of {SPACINGS}, got {spacing!r}")
    if spacing == "linear" and n_lines is not None:
        raise ValueError("n_lines applies to spacing='log' only; for linear spacing the "
                         "resolution and band set the lines")
    if grid == "random_odd" and group_size < 2:
        raise ValueError(f"group_size must be >= 2, got {group_size!r}")
    cand = np.arange(k_lo, k_hi + 1, dtype=np.int64)
    if grid != "full":
        cand = cand[cand % 2 == 1]
    if spacing == "log" and cand.size:
        cand = log_lines(cand, 100 if n_lines is None else int(n_lines))
    if grid == "random_odd":
        rng = np.random.default_rng(0) if rng is None else rng
        n_groups = cand.size // group_size
        drop = np.arange(n_groups) * group_size + rng.integers(0, group_size, n_groups)
        cand = np.delete(cand, drop)
    if cand.size == 0:
        raise ValueError(
            f"grid {grid!r} leaves no excited line in bins [{k_lo}, {k_hi}]; widen the band, "
            "refine the resolution or use grid='full'")
    return cand


def detection_lines(excited: np.ndarray, k_lo: int, k_hi: int) -> tuple[np.ndarray, np.ndarray]:
    """Unexcited lines within [k_lo, k_hi], split by parity.

    Parameters
    ----------
    excited
        (L,) excited lines.
    k_lo, k_hi
        band bins.

    Returns
    -------
    (odd, even): int64 arrays of the non-excited odd and even lines.

    Examples
    --------
    >>> import numpy as np
    >>> odd_free, even = detection_lines(np.array([3, 7, 9, 13, 15, 17]), 2, 20)
    >>> odd_free                          # odd bins left out: they show odd distortions
    array([ 5, 11, 19])
    >>> even                              # even bins: they show even distortions
    array([ 2,  4,  6,  8, 10, 12, 14, 16, 18, 20])
    """
    rest = np.setdiff1d(np.arange(k_lo, k_hi + 1, dtype=np.int64), excited)
    return rest[rest % 2 == 1], rest[rest % 2 == 0]


def shape_amplitudes(amplitude_shape: AmplitudeShape, freq_hz: np.ndarray) -> np.ndarray:
    """Relative amplitude of each line from a user shape.

    Parameters
    ----------
    amplitude_shape
        None (flat), a callable ``f(freq_hz) -> (L,)``, or a
        table ``(freq_hz, amplitude)`` of two equal-length sequences
        (linear interpolation, constant beyond its ends).
    freq_hz
        (L,) line frequencies [Hz].

    Returns
    -------
    (L,) amplitudes, max 1, all > 0 and finite.
    """
    f = np.asarray(freq_hz, dtype=float)
    if amplitude_shape is None:
        amp = np.ones_like(f)
    elif callable(amplitude_shape):
        amp = np.broadcast_to(np.asarray(amplitude_shape(f), dtype=float), f.shape).copy()
    else:
        table = np.asarray(amplitude_shape, dtype=float)
        if table.ndim != 2 or table.shape[0] != 2 or table.shape[1] < 1:
            raise ValueError("amplitude_shape table must be (freq_hz, amplitude): two sequences "
                             f"of equal length, got shape {table.shape}")
        if not np.all(np.isfinite(table)):
            raise ValueError("amplitude_shape table holds NaN or inf")
        order = np.argsort(table[0])
        amp = np.interp(f, table[0][order], table[1][order])
    if not np.all(np.isfinite(amp)):
        raise ValueError("amplitude_shape gives NaN or inf amplitudes")
    if np.any(amp <= 0):
        bad = f[amp <= 0][0]
        raise ValueError(
            f"amplitude_shape is <= 0 at {bad!r} Hz; every excited line needs a positive "
            "amplitude: narrow the band instead")
    return amp / amp.max()
