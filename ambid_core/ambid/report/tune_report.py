"""The tuning's report: ``DIR/index.html`` with the predicted input sensitivity before and after, with bands,
and the tables of ``tune.json`` (the prediction, the zones, the margins, the candidates)."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ambid.report.figures import _ZONES, _figure, _log_x, _save
from ambid.report.html import _CSS, _fmt, _table

__all__ = ["sensitivity_bands_figure", "write_tune_report"]


def sensitivity_bands_figure(freq_hz: np.ndarray, bands: Mapping[str, np.ndarray], axes: Sequence[str],
                             measured: tuple[np.ndarray, np.ndarray] | None = None,
                             path: str | Path | None = None):
    """The worst axis's |S_jj| of each controller's loop: the median over the drawn plants and the band
    between their 2.5 and 97.5 % quantiles, with the ISO 14839-3 zones, and the run's measured |S_jj| at
    its lines.

    Parameters
    ----------
    freq_hz
        (L,) [Hz].
    bands
        label -> (3, L, na) quantiles of |S_jj| [-].
    axes
        (na,) the axes' names.
    measured
        (lines (K,), |S_jj| (K, na)) the run measured, or None.
    path
        PNG to write.
    """
    f = np.asarray(freq_hz, dtype=float)
    fig = _figure((9.0, 5.2))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.11, top=0.92)
    top = max(4.0, 1.15 * max(float(b[2].max()) for b in bands.values()))
    for zone, lo, hi, color in _ZONES:
        ax.axhspan(lo, min(hi, top), color=color, alpha=0.13, lw=0)
        ax.text(f.min(), (lo + min(hi, top)) / 2, f" zone {zone}", va="center", fontsize=9, color="0.3")
    for i, (label, b) in enumerate(bands.items()):
        j = int(np.argmax(b[1].max(axis=0)))   # the axis with the highest median peak
        ax.fill_between(f, b[0][:, j], b[2][:, j], color=f"C{i}", alpha=0.25, lw=0)
        k = int(np.argmax(b[1][:, j]))
        ax.plot(f, b[1][:, j], color=f"C{i}", lw=1.2,
                label=f"{label}, {axes[j]}: peak {b[1][k, j]:.2f} at {f[k]:.4g} Hz (median; band 2.5-97.5 %)")
    if measured is not None:
        lines, mag = measured
        j = int(np.argmax(mag.max(axis=0)))
        ax.plot(lines, mag[:, j], "k.", ms=4, label=f"measured by the run, {axes[j]}")
    _log_x(ax)
    ax.set_ylim(0, top)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("input sensitivity |S_jj| (r -> u) [A/A]")
    ax.set_title("Predicted input sensitivity over the plants the data allow, before and after")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    return _save(fig, path)


def _interval(d: Mapping[str, Any] | None) -> str:
    if not d:
        return "-"
    return f"{_fmt(d['value'], '.3f')} (95 % {_fmt(d['ci95'][0], '.3f')}..{_fmt(d['ci95'][1], '.3f')})"


def write_tune_report(report_dir: str | Path, doc: Mapping[str, Any], freq_hz: np.ndarray,
                      bands: Mapping[str, np.ndarray], axes: Sequence[str],
                      measured: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write ``report_dir/index.html`` and its figure; returns the page's path.

    Parameters
    ----------
    report_dir
        folder (created).
    doc
        tune.json's content.
    freq_hz, bands, axes, measured
        as :func:`sensitivity_bands_figure` takes them.
    """
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    sensitivity_bands_figure(freq_hz, bands, axes, measured, out / "sensitivity.png")
    before = doc.get("before") or {}
    zones = doc.get("zones") or {}
    head = [["controller", f"{doc['kind']} ({doc['order']} states): {doc['controller']}"],
            ["predicted peak (verifying measurement)", _interval(doc.get("predicted_peak"))
             + f" at {_fmt(doc.get('frequency_hz'), '.4g')} Hz ({doc.get('axis')})"],
            ["ISO 14839-3 zone probabilities", ", ".join(f"{z} {100 * p:.1f} %" for z, p in zones.items())],
            ["loop's own peak (no measurement)", _interval(doc.get("loop_peak"))],
            ["before: measured peak", f"{_fmt(before.get('measured_peak'), '.3f')} (zone "
             f"{before.get('measured_zone') or '-'})"],
            ["before: predicted for the running controller", _interval(before.get("predicted"))
             + ("" if before.get("measured_inside") is None else
                f"; the run's measurement {'inside' if before['measured_inside'] else 'outside'}")],
            ["stable on", f"{doc['stable_on']['plants']} drawn plants: {100 * doc['stable_on']['share']:.0f} %"],
            ["design time", f"{_fmt(doc.get('design_time_s'), '.1f')} s"]]
    m = doc.get("margins") or {}
    margin_rows = [[a, _fmt(m["sensitivity_peak"][j], ".3f"), _fmt(m["peak_freq_hz"][j], ".4g"),
                    _fmt(m["gain_margin_low"][j], ".3f"), _fmt(m["gain_margin_high"][j], ".3f"),
                    _fmt(m["phase_margin_deg"][j], ".1f")] for j, a in enumerate(axes)] if m else []
    cand_rows = [[c["kind"], str(c["order"]), _fmt(c["worst_peak"], ".3f"), f"{100 * c['stable_share']:.0f} %",
                  _fmt((c.get("current") or {}).get("noise_rms_a"), ".3g"), _fmt(c["design_s"], ".1f"),
                  "yes" if c["kind"] == doc["kind"] else ""] for c in doc.get("candidates", [])]
    notes = "".join(f"<p class='note'>{html.escape(n)}</p>" for n in doc.get("notes", []))
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>ambid tune</title><style>{_CSS}</style>"
            f"</head><body><h1>ambid tune: {html.escape(str(doc.get('run')))}</h1>{notes}"
            + _table(["", ""], head)
            + f"<p>{html.escape(doc.get('claim', ''))}</p>"
            + "<figure><img src='sensitivity.png'><figcaption>Predicted |S_jj| of the worst axis over the plants "
              "the run's data allow (median and 2.5-97.5 % band), before and after, and the run's measurement."
              "</figcaption></figure>"
            + "<h2>Margins (updated model at its estimate)</h2>"
            + _table(["axis", "peak |S_jj|", "at [Hz]", "gain margin low", "gain margin high", "phase margin [deg]"],
                     margin_rows)
            + "<h2>Candidates</h2>"
            + _table(["kind", "states", "worst peak (drawn plants)", "stable", "noise [A RMS]", "design [s]",
                      "chosen"], cand_rows)
            + "</body></html>")
    index = out / "index.html"
    index.write_text(page)
    return index
