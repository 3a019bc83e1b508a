"""The rotordynamic figures: directional FRFs (forward and backward whirl) and the Campbell diagram.

Like :mod:`ambid.report.figures`: one matplotlib Figure per function, no pyplot state, a PNG when
``path`` is given. Frequencies in Hz, speeds in rpm, FRFs in m/A.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ambid.report.figures import _figure, _log_x, _save

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ambid.frf.directional import DirectionalFrf

__all__ = ["directional_frf_figure", "campbell_figure"]

_WHIRL_COLOUR = {"forward": "tab:blue", "backward": "tab:red", "standing": "0.4"}


def directional_frf_figure(measured: DirectionalFrf, curves: Mapping[str, DirectionalFrf],
                           modes: Sequence[tuple[float, str]] = (), path: str | Path | None = None) -> Figure:
    """Forward and backward directional FRFs of each bearing plane (diagonal elements, p per f).

    Parameters
    ----------
    measured
        the measured directional FRF (dots).
    curves
        label -> model directional FRF on a dense grid (lines).
    modes
        (frequency [Hz], whirl) of the fitted modes, marked by whirl colour.
    path
        PNG to write.
    """
    n_planes = measured.forward.shape[1]
    names = [p.upper() for p in measured.planes] or [str(j + 1) for j in range(n_planes)]
    fig = _figure((max(5.0 * n_planes, 9.0), 5.2))
    axes = fig.subplots(1, n_planes, sharey=True, squeeze=False)[0]
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.12, top=0.9, wspace=0.06)
    for j, (ax, plane) in enumerate(zip(axes, names)):
        for name, attr, colour in (("forward", "forward", "tab:blue"), ("backward", "backward", "tab:red")):
            g = getattr(measured, attr)[:, j, j]
            ax.plot(measured.freq_hz, 20 * np.log10(np.abs(g)), "o", ms=2.2, color=colour,
                    label=f"measured, {name}")
            for k, (label, model) in enumerate(curves.items()):
                gm = getattr(model, attr)[:, j, j]
                ax.plot(model.freq_hz, 20 * np.log10(np.abs(gm)), color=colour, lw=1.0,
                        ls=("-", ":", "--")[k % 3], label=f"{label}, {name}")
        for f, kind in modes:
            ax.axvline(f, color=_WHIRL_COLOUR.get(kind, "0.4"), lw=0.7, alpha=0.6)
        _log_x(ax)
        ax.set_title(f"plane {plane}: p_{plane} / f_{plane}")
        ax.set_xlabel("frequency [Hz]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("|H| [dB re 1 m/A]")
    axes[-1].legend(fontsize=7, loc="lower left")
    fig.suptitle("Directional FRFs: forward whirl (blue) and backward whirl (red); vertical lines: fitted modes "
                 "by whirl", fontsize=9)
    return _save(fig, path)


def campbell_figure(speeds_rpm: np.ndarray, identified: Sequence[Mapping], predicted_rpm: np.ndarray,
                    predicted: Mapping[str, np.ndarray], critical: Sequence[Mapping] = (),
                    f_max_hz: float | None = None, path: str | Path | None = None) -> Figure:
    """Campbell diagram: identified modes against speed beside the model's predicted whirl curves and 1X.

    Parameters
    ----------
    speeds_rpm
        (S,) measured speeds [rpm].
    identified
        dicts with speed_rpm, freq_hz, damping, whirl and, where known, freq_hz_ci95
        [lo, hi] (95 % interval, drawn as a bar).
    predicted_rpm
        (K,) dense speeds of the predicted curves [rpm].
    predicted
        label -> (K,) frequency [Hz] of each predicted branch; labels ending in
        'forward' / 'backward' take the whirl colours.
    critical
        dicts with speed_rpm, freq_hz, label (crossings of 1X).
    f_max_hz
        top of the frequency axis, or None.
    path
        PNG to write.
    """
    fig = _figure((10.0, 6.0))
    ax_f, ax_z = fig.subplots(1, 2, gridspec_kw={"width_ratios": (2.2, 1.0)})
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.1, top=0.9, wspace=0.25)
    for label, f in predicted.items():
        kind = "forward" if label.endswith("forward") else "backward" if label.endswith("backward") else "standing"
        ax_f.plot(predicted_rpm, f, color=_WHIRL_COLOUR[kind], lw=0.9, alpha=0.6, ls="--")
    rpm_line = np.array([0.0, predicted_rpm.max() if predicted_rpm.size else speeds_rpm.max()])
    ax_f.plot(rpm_line, rpm_line / 60.0, color="k", lw=1.0, label="1X (rotation)")
    for kind, marker in (("forward", "^"), ("backward", "v"), ("standing", "o")):
        rows = [r for r in identified if r["whirl"] == kind]
        if rows:
            ci = [r.get("freq_hz_ci95") or (r["freq_hz"], r["freq_hz"]) for r in rows]
            ax_f.errorbar([r["speed_rpm"] for r in rows], [r["freq_hz"] for r in rows],
                          yerr=[[r["freq_hz"] - c[0] for r, c in zip(rows, ci)],
                                [c[1] - r["freq_hz"] for r, c in zip(rows, ci)]], fmt=marker, ms=6,
                          color=_WHIRL_COLOUR[kind], label=f"identified, {kind} whirl")
            ax_z.plot([r["speed_rpm"] for r in rows], [100 * r["damping"] for r in rows], marker, ms=6,
                      color=_WHIRL_COLOUR[kind], label=kind)
    for i, c in enumerate(critical):
        ax_f.plot(c["speed_rpm"], c["freq_hz"], "kx", ms=8)
        ax_f.annotate(f"{c['label']}\n{c['speed_rpm']:.0f} rpm", (c["speed_rpm"], c["freq_hz"]), fontsize=7,
                      xytext=(-70, 14 + 22 * (i % 3)), textcoords="offset points", ha="left",
                      arrowprops=dict(arrowstyle="-", lw=0.5, color="0.3"))
    ax_f.plot([], [], color="0.4", ls="--", label="predicted (model), by whirl colour")
    ax_f.plot([], [], "kx", label="critical speed (mode crosses 1X)")
    if f_max_hz:
        ax_f.set_ylim(0, f_max_hz)
    ax_f.set_xlim(left=min(0.0, float(np.min(speeds_rpm))))
    ax_f.set_xlabel("rotor speed [rpm]")
    ax_f.set_ylabel("frequency [Hz]")
    ax_f.set_title("Campbell diagram")
    ax_f.grid(True, alpha=0.3)
    ax_f.legend(fontsize=7, loc="center left", bbox_to_anchor=(0.0, 0.62))
    ax_z.set_xlabel("rotor speed [rpm]")
    ax_z.set_ylabel("damping ratio [%]")
    ax_z.set_title("identified damping")
    ax_z.grid(True, alpha=0.3)
    ax_z.legend(fontsize=7)
    return _save(fig, path)
