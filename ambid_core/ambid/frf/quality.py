"""What spoils a measurement, found in its time records and its FRF, and said in one line each.

:func:`record_quality` looks at the samples of an experiment and at its FRF:

* clipping: a channel that sits at its largest or smallest value for runs
  of samples (a sensor or an ADC at its range); on a current channel
  (``u_``, ``ic_``) this is a saturated current or amplifier;
* dropouts: runs of samples held at one value (or at zero) inside a channel
  that otherwise moves (a logger or a link that lost data);
* too little excitation: lines where an excitation channel's spectrum is
  more than ``low_excitation_db`` below its median over the band;
* low coherence: lines where an output's coherence with the excitation is
  below ``min_coherence``.

A time-domain defect is not confined to some lines: a clipped or held sample
spreads over the whole spectrum, so its line names every line of the band;
the spectral ones name the lines (as frequency ranges) they affect.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["QualityFinding", "record_quality", "line_ranges"]


@dataclass(frozen=True)
class QualityFinding:
    """One thing that spoils the record.

    Attributes
    ----------
    kind
        'clipping', 'saturation', 'dropout', 'low excitation' or 'low coherence'.
    channel
        the channel it was found on.
    lines_hz
        (k,) the FRF lines it affects [Hz].
    text
        one line saying it, with the lines.
    """

    kind: str
    channel: str
    lines_hz: np.ndarray
    text: str

    def to_dict(self) -> dict:
        """JSON-safe dict."""
        return dict(kind=self.kind, channel=self.channel, n_lines=int(self.lines_hz.size), text=self.text)


def line_ranges(freq_hz: np.ndarray, mask: np.ndarray, all_freq_hz: np.ndarray | None = None) -> str:
    """Contiguous runs of the lines in ``mask`` as text, e.g. '5-12 Hz, 40 Hz' (runs of the line grid)."""
    f = np.asarray(freq_hz, dtype=float)
    m = np.asarray(mask, dtype=bool)
    parts, k = [], 0
    while k < f.size:
        if not m[k]:
            k += 1
            continue
        j = k
        while j + 1 < f.size and m[j + 1]:
            j += 1
        parts.append(f"{f[k]:.4g} Hz" if j == k else f"{f[k]:.4g}-{f[j]:.4g} Hz")
        k = j + 1
    if len(parts) > 6:
        parts = parts[:5] + [f"... ({len(parts) - 5} more ranges)"]
    return ", ".join(parts)


def _runs(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """(start, length) of the runs of True at least ``min_len`` long."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [(int(s), int(e - s)) for s, e in zip(starts, ends) if e - s >= min_len]


def record_quality(samples: np.ndarray | None, names: Sequence[str], fs_hz: float, freq_hz: np.ndarray,
                   coherence: np.ndarray | None = None, output_names: Sequence[str] = (),
                   excitation_names: Sequence[str] = (), *, first_row: int = 0, min_clip_run: int = 3,
                   min_clip_share: float = 1e-3, min_hold_run: int = 8, low_excitation_db: float = 30.0,
                   min_coherence: float = 0.5) -> list[QualityFinding]:
    """The defects of an experiment's record and FRF (module docstring), one finding each.

    Args:
        samples: (n, k) the experiment's samples, columns ``names`` (None: an FRF without its records, the
            coherence alone is looked at).
        names: (k,) channel names (``y_...``, ``u_...``, ``ic_...``, ``r_...``).
        fs_hz: sample rate [Hz].
        freq_hz: (L,) the FRF's lines [Hz].
        coherence: (L, Ny) each output's coherence with the excitation, or None.
        output_names: (Ny,) the outputs ``coherence`` is of.
        excitation_names: the excitation channels among ``names`` (default: those named ``r_...``).
        first_row: the record row of ``samples[0]`` (rows in the text count from 1).
        min_clip_run: samples in a row at an extreme that make a clip [-].
        min_clip_share: share of the samples at clipped runs before it is said [-].
        min_hold_run: samples in a row at one value that make a dropout [-].
        low_excitation_db: how far below its median an excitation line is too little [dB].
        min_coherence: coherence below which a line is said [-].

    Returns:
        The findings, time-domain ones first, each with its one line.
    """
    x = np.zeros((0, 0)) if samples is None else np.asarray(samples, dtype=float)
    f = np.asarray(freq_hz, dtype=float)
    n = x.shape[0]
    every = f"all {f.size} lines ({f.min():.4g}-{f.max():.4g} Hz): a clipped or held sample spreads over the " \
            "spectrum" if f.size else "every line"
    out: list[QualityFinding] = []
    exc = list(excitation_names) or [c for c in names if c.startswith("r_")]
    for j, name in enumerate(names if x.size else ()):
        v = x[:, j]
        if n < 2 * min_hold_run or not np.any(v != v[0]):
            continue
        span = float(v.max() - v.min())
        tol = 1e-9 * max(span, 1e-300)
        current = name.startswith(("u_", "ic_"))
        for side, level in (("largest", v.max()), ("smallest", v.min())):
            runs = _runs(np.abs(v - level) <= tol, min_clip_run)
            held = sum(length for _, length in runs)
            if runs and held >= min_clip_share * n:
                kind = "saturation" if current else "clipping"
                what = "saturated (the current or its amplifier at its limit)" if current else "clipped"
                out.append(QualityFinding(kind, name, f, f"{name} {what} at {level:.6g}: {held} samples "
                                          f"({100 * held / n:.2g} %) in {len(runs)} run(s) at its {side} value, the "
                                          f"first from row {first_row + runs[0][0] + 1}; affects {every}"))
        # held samples away from the extremes: a dropout (a zero run where the channel otherwise moves, too)
        d = np.diff(v)
        still = np.concatenate([[False], d == 0])
        runs = [(s - 1, ln + 1) for s, ln in _runs(still, min_hold_run - 1)
                if not (abs(v[s] - v.max()) <= tol or abs(v[s] - v.min()) <= tol)]
        if runs and name not in exc:
            held = sum(length for _, length in runs)
            at = v[runs[0][0]]
            out.append(QualityFinding("dropout", name, f, f"{name} drops out: {len(runs)} run(s) of {held} samples "
                                      f"held at one value ({'zero' if at == 0 else f'{at:.6g}'} first), the first "
                                      f"from row {first_row + runs[0][0] + 1}; affects {every}"))
    # too little excitation in part of the band
    if f.size and n >= 16:
        win = np.hanning(n)
        spec = np.abs(np.fft.rfft(x * win[:, None], axis=0))
        bins = np.fft.rfftfreq(n, 1.0 / fs_hz)
        at = np.clip(np.searchsorted(bins, f), 0, bins.size - 1)
        for name in exc:
            if name not in names:
                continue
            j = list(names).index(name)
            # the excitation's level at each line: the spectrum's largest bin within half a line spacing
            half = max(1, int(round(0.5 * np.median(np.diff(f)) * n / fs_hz))) if f.size > 1 else 1
            level = np.array([spec[max(k - half, 0):k + half + 1, j].max() for k in at])
            med = float(np.median(level))
            low = level < med * 10 ** (-low_excitation_db / 20)
            if med > 0 and np.any(low):
                out.append(QualityFinding("low excitation", name, f[low], f"too little excitation on {name} at "
                                          f"{int(low.sum())} of {f.size} lines (more than {low_excitation_db:g} dB "
                                          f"below its median): {line_ranges(f, low)}"))
    if coherence is not None and f.size:
        c = np.asarray(coherence, dtype=float).reshape(f.size, -1)
        for i, name in enumerate(output_names[:c.shape[1]]):
            if not np.any(np.isfinite(c[:, i])):
                continue
            low = np.isfinite(c[:, i]) & (c[:, i] < min_coherence)
            if np.any(low):
                out.append(QualityFinding("low coherence", name, f[low], f"low coherence on {name} (below "
                                          f"{min_coherence:g}, lowest {np.nanmin(c[:, i]):.2g}) at {int(low.sum())} "
                                          f"of {f.size} lines: {line_ranges(f, low)}"))
    return out
