"""The report of a measured FRF fitted from a file (:func:`ambid.identification.frf_file_fit.identify_frf`): ``DIR/index.html``."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ambid.report import figures
from ambid.report.html import _CSS, frf_column_units, _fmt, _modes_rows, frf_row_units, _table, computational_section

if TYPE_CHECKING:
    from ambid.fit.order_selection import StabilisationDiagram

__all__ = ["write_measured_report"]


def write_measured_report(report_dir: str | Path, summary: Mapping[str, Any], freq_hz: np.ndarray, frf: np.ndarray,
                          std: np.ndarray | None, diagram: StabilisationDiagram, order: int,
                          curves: Mapping[str, tuple[np.ndarray, np.ndarray]], output_names: Sequence[str],
                          input_names: Sequence[str]) -> Path:
    """Bode matrices (measured with +-2 sigma where the file gives var, and the fit), the stabilisation diagram,
    the headline table and the modes; returns the path of index.html.

    Parameters
    ----------
    report_dir
        folder (created).
    summary
        :func:`ambid.identification.frf_file_fit.identify_frf`'s summary.
    freq_hz, frf
        (L,), (L, Ny, Nu) the file's FRF [its unit].
    std
        (L, Ny, Nu) its standard deviation, or None.
    diagram, order
        the stabilisation diagram and the chosen order.
    curves
        label -> (freq (K,), FRF (K, Ny, Nu)) of the models.
    output_names, input_names
        labels.
    """
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = dict(input_names=tuple(input_names), output_names=tuple(output_names))
    shown = []
    band = "with its +-2 sigma band from the file's var, " if std is not None else "(the file gives no variance), "
    for quantity, name in (("magnitude", "bode_magnitude.png"), ("phase", "bode_phase.png")):
        figures.bode_matrix(freq_hz, frf, std, curves, quantity, out / name, **names,
                            row_units=frf_row_units(summary), col_units=frf_column_units(summary))
        shown.append((name, f"FRF matrix {quantity} from {summary['source']} (dots) {band}and the fitted model "
                            "(the axis label's unit is the file's)."))
    figures.stabilisation(diagram, freq_hz, frf, order, out / "stabilisation.png",
                          mode_ci95=[m["freq_hz_ci95"] for m in summary["fit"]["modes"] if m.get("freq_hz_ci95")])
    shown.append(("stabilisation.png", f"Stabilisation diagram over the CMIF; the dashed line marks the chosen order "
                                       f"{order}; its modes carry their 95 % frequency intervals."))
    fit = summary["fit"]
    rows = [["file", f"{summary['source']} ({summary['format']})"],
            ["outputs / inputs", f"{', '.join(summary['outputs'])} / {', '.join(summary['inputs'])}"],
            ["frequencies", f"{summary['n_lines']} in {_fmt(summary['band_hz'])} Hz"],
            ["variance given", _fmt(summary["var_given"])],
            ["model order (rule)", f"{fit['order']} ({fit['order_rule']})"],
            ["fit chi2 / dof", _fmt(fit["chi2_per_dof"], ".3g")],
            ["known delay [s]", _fmt(fit["delay_s"])]]
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>ambid fit of a measured FRF</title>"
             f"<style>{_CSS}</style></head><body>", "<h1>ambid fit of a measured FRF</h1>",
             "<h2>Headline figures</h2>", _table(["quantity", "value"], rows)]
    parts += [f"<p class='note'>Note: {html.escape(str(n))}</p>" for n in summary.get("notes") or []]
    parts += ["<h2>Fitted modes</h2>",
              _table(["frequency [Hz]", "95 % CI", "damping ratio [-]", "95 % CI", "stable in diagram"],
                     _modes_rows(summary)),
              "<p>" + html.escape(str(summary["intervals"]["modes"])) + "</p>"]
    parts += computational_section(summary)
    reals = fit.get("real_poles") or []
    if reals:
        parts.append("<p>Real poles [Hz] (positive: unstable): "
                     + html.escape(", ".join(_fmt(r["pole_hz"], ".4g") for r in reals)) + "</p>")
    parts.append("<h2>Figures</h2>")
    parts += [f"<figure><img src='{html.escape(n)}' alt='{html.escape(c)}'><figcaption>{html.escape(c)}"
              "</figcaption></figure>" for n, c in shown]
    parts.append("</body></html>")
    index = out / "index.html"
    index.write_text("\n".join(parts))
    return index
