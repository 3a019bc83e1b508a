"""Excitation lines that steer clear of a spinning rotor's synchronous harmonics.

A rotor spinning at f_rot = rpm / 60 carries disturbances at k f_rot
(unbalance at 1X, runout at 1X, 2X, ...), present whatever the excitation.
On a line the multisine excites they bias the FRF; leaking from a
harmonic that falls between lines they raise the scatter of the lines
around it. Two measures, both here:

* the period: a period of N samples puts harmonic k on bin
  k f_rot N / fs; :func:`commensurate_period` picks the N nearest the
  requested one (within ``max_change``) for which that is an integer, so
  the harmonics fall exactly on lines and do not leak;
* the lines: excited lines within ``guard_bins`` of a harmonic's bin are
  moved to the nearest free line of the same parity outside every guard
  (:func:`steer_lines`), detection lines there are dropped, and the
  harmonics' own bins become *disturbance lines*, where the FRF code
  estimates the synchronous response instead of an FRF.

What was done is kept in the design's ``options["synchronous"]``
(:func:`synchronous_options`), which the FRF code reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

DEFAULT_HARMONICS = 6
DEFAULT_GUARD_BINS = 1
DEFAULT_MAX_PERIOD_CHANGE = 0.25


def harmonic_bins(speed_rpm: float, fs_hz: float, n: int, n_harmonics: int) -> np.ndarray:
    """Bin positions k f_rot N / fs of the harmonics k = 1..n_harmonics, (n_harmonics,) float [bins].

    Examples
    --------
    >>> harmonic_bins(6000.0, 10_000.0, 2000, 3)   # 100 Hz and its harmonics, bins of 5 Hz
    array([20., 40., 60.])
    """
    return np.arange(1, int(n_harmonics) + 1) * (float(speed_rpm) / 60.0) * int(n) / float(fs_hz)


def commensurate_period(speed_rpm: float, fs_hz: float, n: int,
                        max_change: float = DEFAULT_MAX_PERIOD_CHANGE) -> int | None:
    """The period N' nearest n [samples] on which the rotation frequency falls on a bin, or None.

    N' f_rot / fs must be an integer; with f_rot / fs = p / q in lowest
    terms (the speed taken to 1e-6 rpm) that makes N' a multiple of q.

    Parameters
    ----------
    speed_rpm
        spin speed [rpm], > 0.
    fs_hz
        sample rate [Hz].
    n
        requested period [samples].
    max_change
        largest relative change |N' - n| / n accepted.

    Returns
    -------
    N', or None when no multiple of q lies within max_change of n.
    """
    ratio = Fraction(round(float(speed_rpm) * 1e6), 60_000_000) / Fraction(float(fs_hz)).limit_denominator(10**9)
    q = ratio.denominator
    best = None
    for cand in ((n // q) * q, (n // q + 1) * q):
        if cand >= 4 and abs(cand - n) <= max_change * n and (best is None or abs(cand - n) < abs(best - n)):
            best = cand
    return best


@dataclass(frozen=True)
class SteeredLines:
    """Lines after steering (:func:`steer_lines`).

    Attributes
    ----------
    excited
        (L,) excited lines, sorted.
    detection_odd, detection_even
        non-excited lines of the band outside every guard.
    disturbance
        (K,) bins nearest each harmonic inside [1, N/2), one per harmonic that has one.
    disturbance_harmonic
        (K,) the harmonic number k of each disturbance line.
    moved
        ((from, to, k), ...): excited line ``from`` was within the guard of harmonic k and went to
        ``to`` (-1: no free line left, dropped).
    """

    excited: np.ndarray
    detection_odd: np.ndarray
    detection_even: np.ndarray
    disturbance: np.ndarray
    disturbance_harmonic: np.ndarray
    moved: tuple[tuple[int, int, int], ...]


def guarded(bins: np.ndarray, harmonics: np.ndarray, guard_bins: int) -> np.ndarray:
    """Which of ``bins`` lie within guard_bins (plus the half bin a harmonic between lines leaks into) of a
    harmonic bin position, (len(bins),) bool.

    Examples
    --------
    >>> import numpy as np
    >>> guarded(np.array([18, 19, 20, 21, 25]), np.array([20.0]), 1)   # within one bin of the harmonic
    array([False,  True,  True,  True, False])
    """
    b = np.asarray(bins, dtype=float)[:, None]
    h = np.asarray(harmonics, dtype=float)[None, :]
    on_bin = np.abs(h - np.round(h)) < 1e-6
    reach = np.where(on_bin, guard_bins, guard_bins + 0.5)
    return np.any(np.abs(b - h) <= reach + 1e-9, axis=1) if h.size else np.zeros(b.shape[0], bool)


def steer_lines(excited: np.ndarray, k_lo: int, k_hi: int, n: int, harmonics: np.ndarray,
                guard_bins: int = DEFAULT_GUARD_BINS) -> SteeredLines:
    """Move excited lines off the guarded bins around the synchronous harmonics.

    Parameters
    ----------
    excited
        (L,) excited lines of the unsteered design.
    k_lo, k_hi
        the band's bins.
    n
        period [samples].
    harmonics
        (K,) harmonic bin positions (:func:`harmonic_bins`).
    guard_bins
        bins kept free on each side of a harmonic.

    Returns
    -------
    :class:`SteeredLines`; an excited line goes to the nearest line of its parity in the band that is
    neither excited nor guarded (the grid's odd/even character stays), else it is dropped.
    """
    exc = np.asarray(excited, dtype=np.int64)
    harmonics = np.asarray(harmonics, dtype=float)
    band = np.arange(k_lo, k_hi + 1, dtype=np.int64)
    blocked = set(band[guarded(band, harmonics, guard_bins)].tolist())
    keep = set(exc.tolist())
    moved = []
    for line in exc.tolist():
        if line not in blocked:
            continue
        keep.discard(line)
        k = int(np.argmin(np.abs(harmonics - line))) + 1
        to = -1
        for step in range(2, k_hi - k_lo + 2, 2):  # same parity, nearest first, below before above
            for cand in (line - step, line + step):
                if k_lo <= cand <= k_hi and cand not in blocked and cand not in keep:
                    to = cand
                    break
            if to >= 0:
                break
        if to >= 0:
            keep.add(to)
        moved.append((line, to, k))
    new = np.array(sorted(keep), dtype=np.int64)
    rest = np.setdiff1d(band, new)
    rest = rest[~guarded(rest, harmonics, guard_bins)] if rest.size else rest
    near = np.round(harmonics).astype(np.int64)
    inside = (near >= 1) & (2 * near < n)
    return SteeredLines(new, rest[rest % 2 == 1], rest[rest % 2 == 0], near[inside],
                        np.flatnonzero(inside) + 1, tuple(moved))


def synchronous_options(speed_rpm: float, n_harmonics: int, guard_bins: int, harmonics: np.ndarray,
                        steered: SteeredLines, requested_n: int, n: int) -> dict:
    """The JSON-safe record a design keeps in ``options["synchronous"]``."""
    return {"speed_rpm": float(speed_rpm), "n_harmonics": int(n_harmonics), "guard_bins": int(guard_bins),
            "harmonic_bins": [float(h) for h in harmonics],
            "on_lines": bool(np.all(np.abs(harmonics - np.round(harmonics)) < 1e-6)),
            "disturbance_lines": steered.disturbance.tolist(),
            "disturbance_harmonics": steered.disturbance_harmonic.tolist(),
            "moved": [list(m) for m in steered.moved],
            "requested_n_per_period": int(requested_n), "n_per_period": int(n)}


def describe_steering(options: dict, fs_hz: float) -> list[str]:
    """Lines for a person: what the steering did and why (empty without steering)."""
    sync = options.get("synchronous")
    if not sync:
        return []
    n = sync["n_per_period"]
    res = fs_hz / n
    f_rot = sync["speed_rpm"] / 60.0
    out = [f"at {sync['speed_rpm']:.0f} rpm (1X = {f_rot:.3f} Hz): harmonics 1..{sync['n_harmonics']} kept "
           f"{sync['guard_bins']} bin(s) clear"]
    if sync["requested_n_per_period"] != n:
        out.append(f"  period {sync['requested_n_per_period']} -> {n} samples (resolution "
                   f"{fs_hz / sync['requested_n_per_period']:.4g} -> {res:.4g} Hz), so that every harmonic falls "
                   "exactly on a line and does not leak")
    elif sync["on_lines"]:
        out.append(f"  period {n} samples: every harmonic already falls exactly on a line")
    else:
        out.append(f"  period {n} samples: the harmonics fall between lines (no period within reach puts them "
                   "on lines); the guard takes the half bin they leak into as well")
    for frm, to, k in sync["moved"]:
        where = f"{to * res:.2f} Hz" if to >= 0 else "dropped (no free line left)"
        out.append(f"  line {frm * res:.2f} Hz -> {where}: within the guard of {k}X ({k * f_rot:.2f} Hz)")
    if not sync["moved"]:
        out.append("  no excited line was within a guard; none moved")
    dl = ", ".join(f"{k}X {b * res:.2f} Hz" for b, k in zip(sync["disturbance_lines"], sync["disturbance_harmonics"]))
    out.append(f"  disturbance lines (synchronous response estimated there, kept out of the FRF): {dl}")
    return out
