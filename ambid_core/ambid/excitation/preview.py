"""Preview of a design: a figure (amplitude spectrum and time signal) and a text summary."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .design import ExcitationDesign


def _experiment_of(design: ExcitationDesign, i: int) -> int:
    """An experiment in which input i is excited (its own one when one at a time)."""
    return i if design.options.get("mimo") == "one_at_a_time" else 0


def _one_period(design: ExcitationDesign, m: int, i: int) -> np.ndarray:
    """(N,) one period (noise: the first steady-state block) of input i [A]."""
    e = _experiment_of(design, i)
    if design.kind == "stepped_sine":
        p = design.period(m, i)[:, i]
        return np.tile(p, design.n_per_period // p.size)
    start = design.segment_start(m, e) + design.n_transient_periods * design.n_per_period
    return design.samples(start, design.n_per_period)[:, i]


def plot_design(design: ExcitationDesign, path: str | Path, realisation: int = 0) -> Path:
    """Write a PNG: amplitude spectrum of one period per input and its time signal.

    Top: |X_k| [A] of one period (N samples) of each input, excited lines
    marked; odd and even detection lines marked along the bottom. For the
    stepped sine the top panel shows each line's amplitude instead (lines are
    measured one by one). Bottom: the same period in time [s].

    Parameters
    ----------
    design
        the design.
    path
        PNG file to write.
    realisation
        realisation m shown (stepped sine: the line shown in time).

    Returns
    -------
    The path written.
    """
    # optional (ambid[report]): only the figure needs it. A Figure without pyplot (its import alone costs
    # ~0.5 s) and fixed margins, not constrained layout (its text-extent passes cost more than the drawing)
    from matplotlib.figure import Figure

    path = Path(path)
    d = design
    n, fs = d.n_per_period, d.fs_hz
    res = fs / n
    fig = Figure(figsize=(9, 7))
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.07, top=0.95, hspace=0.32)
    ax_f, ax_t = fig.subplots(2, 1)
    k_max = int(min(n // 2, max(d.excited_lines.max() * 1.25, d.excited_lines.max() + 5)))
    floor = 1e-6 * float(np.max(d.amplitudes_a))
    t = np.arange(n) / fs
    for i, name in enumerate(d.input_names):
        if d.kind == "stepped_sine":
            line, = ax_f.plot(d.freq_hz, d.amplitudes_a[i], "o-", ms=3, label=f"{name}")
            x = _one_period(d, realisation, i)
        else:
            x = _one_period(d, realisation, i)
            spec = np.abs(np.fft.rfft(x))[: k_max + 1] * (2 / n)
            line, = ax_f.plot(np.arange(k_max + 1) * res, np.maximum(spec, floor), lw=0.6,
                              label=f"{name}: all lines")
            ax_f.plot(d.freq_hz, np.maximum(spec[d.excited_lines], floor), "o", ms=3,
                      color=line.get_color(), label=f"{name}: excited lines")
        ax_t.plot(t, x, lw=0.8, label=name)
    if d.detection_lines_odd.size:
        ax_f.plot(d.detection_lines_odd * res, np.full(d.detection_lines_odd.size, floor), "v",
                  color="tab:red", ms=4, label="odd detection lines")
    if d.detection_lines_even.size:
        ax_f.plot(d.detection_lines_even * res, np.full(d.detection_lines_even.size, floor), "^",
                  color="tab:green", ms=3, label="even detection lines")
    if d.kind != "stepped_sine":
        ax_f.set_yscale("log")
    if d.options.get("spacing") == "log":
        ax_f.set_xscale("log")
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("line amplitude [A]")
    what = "one N-sample block (no window)" if d.kind == "noise" else "one period"
    ax_f.set_title(f"{d.kind}: amplitude spectrum of {what} "
                   f"(N = {n}, resolution {res:.4g} Hz, realisation {realisation})")
    ax_f.grid(True, which="both", alpha=0.3)
    ax_f.legend(fontsize=7, ncol=2)
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("excitation current [A]")
    ax_t.set_title(what + (f" of line {realisation}" if d.kind == "stepped_sine" else "")
                   + f"; measurement time {d.measurement_time_s:.4g} s")
    ax_t.grid(True, alpha=0.3)
    ax_t.legend(fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(path.name + ".part")   # whole or not at all: a reader never sees half a PNG
    fig.savefig(part, dpi=110, format="png")
    os.replace(part, path)
    return path


def describe(design: ExcitationDesign) -> str:
    """Multi-line text summary: lines, N, crest factor, RMS/peak per input, time."""
    d = design
    res = d.fs_hz / d.n_per_period
    opts = ", ".join(f"{k}={v}" for k, v in d.options.items() if k not in ("power_fraction", "synchronous"))
    lines = [
        f"excitation: {d.kind} ({opts})",
        f"sample rate {d.fs_hz:g} Hz, N = {d.n_per_period} samples per period, "
        f"resolution {res:.6g} Hz",
        f"band {d.band_hz[0]:g}-{d.band_hz[1]:g} Hz: {d.excited_lines.size} excited lines "
        f"({d.freq_hz[0]:.6g}-{d.freq_hz[-1]:.6g} Hz), detection lines: "
        f"{d.detection_lines_odd.size} odd, {d.detection_lines_even.size} even",
        f"layout: M = {d.n_realisations} realisations x Ne = {d.n_experiments} experiments"
        + ("" if d.kind == "stepped_sine" else
           f" x (Pt = {d.n_transient_periods} + P = {d.n_periods}) periods"),
    ]
    if "power_fraction" in d.options:
        pf = np.asarray(d.options["power_fraction"])
        lines.append(f"power on the excited lines: {pf.min():.1%} to {pf.max():.1%}")
    for name, pk, rms, cf in zip(d.input_names, d.peak_a, d.rms_a, d.crest_factor):
        lines.append(f"  input {name!r}: peak {pk:.4g} A, RMS {rms:.4g} A, crest factor {cf:.3f}")
    lines.append(f"measurement time {d.measurement_time_s:.6g} s ({d.total_samples} samples)")
    return "\n".join(lines)
