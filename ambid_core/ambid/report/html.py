"""The identification report: ``DIR/index.html`` with the headline numbers and the figures (PNGs beside it)."""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ambid.report import figures

if TYPE_CHECKING:
    from ambid.excitation.design import ExcitationDesign
    from ambid.fit.order_selection import StabilisationDiagram
    from ambid.frf.levels import LineLevels
    from ambid.frf.streaming import FrfResult

__all__ = ["write_report", "render_index", "frf_row_units", "frf_column_units"]

_CSS = """
body { font-family: sans-serif; max-width: 1200px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em 0; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: left; font-size: 0.92em; }
th { background: #eee; }
td.num { text-align: right; font-family: monospace; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.92em; color: #333; margin-top: 0.3em; }
.note { color: #a40; }
"""


def _fmt(x: Any, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, float, np.floating, np.integer)):
        return "-" if not math.isfinite(float(x)) else format(float(x), spec)
    if isinstance(x, (list, tuple)):
        return ", ".join(_fmt(v, spec) for v in x)
    return str(x)


def _pct(x: Any) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{100 * float(x):.3g} %"


def _table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _controller(c: Mapping[str, Any] | None) -> str:
    if not c:
        return "not recorded"
    params = c.get("parameters") or {}
    what = f" {params['file']}" if c.get("kind") == "file" and "file" in params else ""
    return (f"{c.get('kind')}{what}: {c.get('n_states')} states, delay {c.get('delay_samples')} sample(s), "
            f"current limit {_fmt((c.get('current_limit_a') or [None])[0])} A")


def _headline(s: Mapping[str, Any]) -> list[list[str]]:
    ex, fit, sens, noise = s["excitation"], s["fit"], s["sensitivity"], s["noise"]
    rows = [
        ["session", f"{s['session']} (experiment {s['experiment_id']})"],
        ["estimator", s["estimator"]],
        ["controller", _controller(s.get("controller"))],
        ["excitation", f"{ex['kind']} ({ex.get('mimo') or '-'}, {ex.get('grid') or '-'}), {ex['n_excited_lines']} "
                       f"lines, N = {ex['samples_per_period']}, P = {ex['n_periods']} + {ex['n_transient_periods']} "
                       f"transient, M = {ex['n_realisations']}, Ne = {ex['n_experiments']}, "
                       f"{_fmt(ex['measurement_time_s'])} s at {_fmt(ex['sample_rate_hz'])} Hz"],
        ["crest factor per input [-]", _fmt(ex["crest_factor"], ".3g")],
        ["band (excited lines) [Hz]", _fmt(s["band_hz"])],
        ["inputs / outputs", f"{', '.join(s['inputs'])} / {', '.join(s['outputs'])}"],
    ]
    err = s.get("frf_error")
    if err:
        rows.append(["FRF error vs true rig, measured: median / worst",
                     f"{_pct(err['median'])} / {_pct(err['worst'])} (at {_fmt(err['worst_at_hz'])} Hz)"])
        rows.append(["FRF error vs true rig, fitted model: median / worst",
                     f"{_pct(err['fitted_median'])} / {_pct(err['fitted_worst'])}"])
        if "updated_median" in err:
            rows.append(["FRF error vs true rig, updated physical model: median / worst",
                         f"{_pct(err['updated_median'])} / {_pct(err['updated_worst'])}"])
    std = noise.get("output_noise_std_m")
    rows += [
        ["output noise std [um] (95 % interval)", _noise_text(std, noise.get("output_noise_std_ci95_m"))],
        ["relative FRF noise (median sigma/|G|)", _pct(noise.get("relative_frf_noise_std"))],
        ["var_total / var_noise (median; ~1 if linear)", _fmt(noise.get("nonlinear_variance_ratio"), ".3g")],
        ["odd / even detection lines above noise [dB]",
         f"{_fmt(noise.get('distortion_odd_db'), '+.1f')} / {_fmt(noise.get('distortion_even_db'), '+.1f')}"],
        ["model order (rule)", f"{fit['order']} ({fit['order_rule']})"],
        ["fit chi2 / dof", _fmt(fit["chi2_per_dof"], ".3g")],
    ]
    loop = sens.get("loop")
    if loop:
        rows += [["loop sensitivity peak (the worst over the measured lines and the fitted model between them)",
                  f"{_fmt(loop['peak'], '.3g')} ({_fmt(20 * math.log10(loop['peak']), '.1f')} dB) at "
                  f"{_fmt(loop['peak_hz'], '.4g')} Hz, {loop['channel']}, from {loop['source']}"]]
    if sens.get("worst_peak") is not None:
        rows += [["peak sensitivity at the measured lines", f"{_fmt(sens['worst_peak'], '.3g')} on "
                  f"{sens['worst_input']} ({_fmt(20 * math.log10(sens['worst_peak']), '.1f')} dB)"]]
    zone = (loop or {}).get("iso_zone", sens.get("iso_zone") if "loop" not in sens else None)
    if zone is not None:
        rows += [["ISO 14839-3 zone", zone]]
    probs = (loop or {}).get("zone_probabilities")
    if probs:
        rows += [["ISO 14839-3 zone probabilities (from the measured and fitted sensitivity's uncertainty)",
                  ", ".join(f"{z} {p:.2f}" for z, p in probs.items())]]
    rows += [["no sensitivity", why] for why in sens.get("none") or []]
    rows += [["data quality", q["text"]] for q in (s.get("quality") or {}).get("findings", [])]
    if s.get("max_mode_freq_error") is not None:
        rows.append(["worst mode frequency / damping error vs true",
                     f"{_pct(s['max_mode_freq_error'])} / {_pct(s['max_mode_damping_error'])}"])
    return rows


def _noise_text(std: Sequence[float | None] | None, ci: Sequence[Sequence[float | None]] | None) -> str:
    """Each output's noise std [um] with its 95 % interval where there is one."""
    if not std:
        return "-"
    ci = ci or [None] * len(std)
    return ", ".join("-" if v is None else f"{v * 1e6:.4g}" + ("" if c is None or None in c else
                                                             f" ({c[0] * 1e6:.4g}..{c[1] * 1e6:.4g})")
                     for v, c in zip(std, ci))


def _pm(m: Mapping[str, Any], key: str, spec: str) -> str:
    """'+- half width' of a 95 % interval m[key + '_ci95'], or '-'."""
    ci = m.get(f"{key}_ci95")
    return "-" if ci is None else f"+- {_fmt((ci[1] - ci[0]) / 2, spec)}"


def frf_row_units(s: Mapping[str, Any]) -> list[str]:
    """Each FRF row's unit, for the Bode matrices' labels.

    Parameters
    ----------
    s : Mapping
        An identification summary (``output_units``, ``input_units``; a session without them: A in).

    Returns
    -------
    list of str
        (Ny,) ``'<output unit>/<input unit>'`` where every input shares one, else ''; '' too where both are
        dimensionless (a network's S parameters).
    """
    ins = set(s.get("input_units") or ["A"])
    return [(f"{u}/{next(iter(ins))}" if u or next(iter(ins)) else "") if len(ins) == 1 else ""
            for u in s.get("output_units") or []]


def frf_column_units(s: Mapping[str, Any]) -> list[str]:
    """Each FRF column's (input's) unit, for the Bode matrices' titles.

    Parameters
    ----------
    s : Mapping
        An identification summary (``input_units``, ``inputs``).

    Returns
    -------
    list of str
        (Nu,) A for a session's currents, the file's unit for an FRF file (N for a hammer, '' dimensionless).
    """
    return list(s.get("input_units") or ["A"] * len(s.get("inputs") or []))


def computational_section(s: Mapping[str, Any]) -> list[str]:
    """The fit's poles that are not modes, apart from them, each with its reason; and the plant's unstable pole."""
    fit = s["fit"]
    comp = fit.get("computational_poles") or []
    parts = []
    if comp:
        parts += ["<h3>Computational poles (not modes of the data)</h3>",
                  _table(["frequency [Hz]", "damping ratio [-]", "why not a mode"],
                         [[_fmt(c["freq_hz"], ".5g"), _fmt(c["damping"], ".4g"), html.escape(c["reason"])]
                          for c in comp])]
    plant = [r for r in fit.get("real_poles") or [] if r.get("physical")]
    parts += [f"<p>Unstable real pole at {_fmt(r['pole_hz'], '.4g')} Hz: {html.escape(r['reason'])}</p>"
              for r in plant]
    return parts


def _modes_rows(s: Mapping[str, Any]) -> list[list[str]]:
    return [[_fmt(m["freq_hz"], ".5g"), _pm(m, "freq_hz", ".2g"), _fmt(m["damping"], ".4g"), _pm(m, "damping", ".2g"),
             _fmt(m["stable"])] + ([f"{m['whirl']} ({_pct(m['forward_share'])} forward)"] if "whirl" in m else [])
            for m in s["fit"]["modes"]]


def _synchronous_rows(s: Mapping[str, Any]) -> list[list[str]]:
    sync = s.get("synchronous") or {}
    channels = sync.get("channels") or []
    ny = len(s.get("outputs") or [])
    return [[f"{h['harmonic']}X", _fmt(h["freq_hz"], ".5g")]
            + [f"{_fmt(a * 1e6, '.3g')} +- {_fmt(sd * 1e6, '.2g')} um, {_fmt(ph, '.0f')} deg"
               for a, sd, ph in zip(h["amplitude"][:ny], h["amplitude_std"][:ny], h["phase_deg"][:ny])]
            for h in sync.get("harmonics") or [] if channels]


def _true_mode_rows(s: Mapping[str, Any]) -> list[list[str]]:
    return [[_fmt(r["true_freq_hz"], ".5g"), _fmt(r["true_damping"], ".4g"), str(r["n_true"]),
             _fmt(r["freq_hz"], ".5g"), _fmt(r["damping"], ".4g"), str(r["n_fitted"]), _pct(r["freq_error"]),
             _pct(r["damping_error"])] for r in s.get("modes_vs_true") or []]


def _parameter_rows(s: Mapping[str, Any]) -> list[list[str]]:
    upd = s.get("update") or {}
    rows = []
    def span(ci) -> str:
        return "-" if ci is None else f"{_fmt(ci[0], '.5g')} .. {_fmt(ci[1], '.5g')}"

    for name, p in (upd.get("parameters") or {}).items():
        prior = p.get("prior")
        rows.append([name, p["unit"], _fmt(p.get("nominal"), ".6g"), span(prior["ci95"]) if prior else "-",
                     _fmt(p["value"], ".6g"), span(p.get("ci95")) if p.get("free") else "fixed",
                     _fmt(p.get("prior_ratio"), ".2f") + (" (prior)" if p.get("prior_dominated") else ""),
                     _fmt(p.get("true"), ".6g"), _pct(p.get("error"))])
    lag = upd.get("total_lag")
    if lag:
        rows.append(["total lag (amplifier + sensor + delay)", "s", "-", "-", _fmt(lag["value"], ".6g"),
                     span(lag["ci95"]), "-", _fmt(lag.get("true"), ".6g"),
                     _pct(None if lag.get("true") is None else lag["value"] / lag["true"] - 1)])
    return rows


def render_index(summary: Mapping[str, Any], figure_list: list[tuple[str, str]]) -> str:
    """The index.html text: headline table, modes, parameters, figures with captions.

    Parameters
    ----------
    summary
        the dict :func:`ambid.identification.identify_session` returns.
    figure_list
        [(PNG file name, caption)].
    """
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>ambid identification report</title>"
             f"<style>{_CSS}</style></head><body>",
             "<h1>ambid identification report</h1>",
             "<h2>Headline figures</h2>", _table(["quantity", "value"], _headline(summary))]
    for note in summary.get("notes") or []:
        parts.append(f"<p class='note'>Note: {html.escape(str(note))}</p>")
    whirl_col = ["whirl"] if any("whirl" in m for m in summary["fit"]["modes"]) else []
    parts += ["<h2>Fitted modes</h2>",
              _table(["frequency [Hz]", "95 % CI", "damping ratio [-]", "95 % CI", "stable in diagram"] + whirl_col,
                     _modes_rows(summary)),
              "<p>" + html.escape(str((summary.get("intervals") or {}).get("modes", ""))) + "</p>"]
    parts += computational_section(summary)
    if summary.get("synchronous"):
        parts += ["<h3>Synchronous response (disturbance lines at k x the rotation)</h3>",
                  _table(["harmonic", "frequency [Hz]"] + list(summary.get("outputs") or []),
                         _synchronous_rows(summary)),
                  "<p>Mean over every record of each output's line at the harmonic (amplitude +- its standard "
                  "uncertainty, phase at the experiment's first sample); these lines carry no excitation and "
                  "are kept out of the FRF and its noise estimate.</p>"]
    if summary.get("modes_vs_true"):
        parts += ["<h3>Modes against the true rig</h3>",
                  _table(["true frequency [Hz]", "true damping [-]", "true modes", "fitted frequency [Hz]",
                          "fitted damping [-]", "fitted modes", "frequency error", "damping error"],
                         _true_mode_rows(summary)),
                  "<p>True modes closer than the frequency resolution are one cluster (mean frequency and damping), "
                  "compared with the mean of the fitted modes near it.</p>"]
    reals = summary["fit"].get("real_poles") or []
    if reals:
        parts.append("<p>Real poles [Hz] (positive: unstable): "
                     + html.escape(", ".join(_fmt(r["pole_hz"], ".4g") for r in reals)) + "</p>")
    upd = summary.get("update")
    if upd and "parameters" in upd:
        parts += ["<h2>Updated physical parameters</h2>",
                  _table(["parameter", "unit", "nominal", "tolerance (prior 95 %)", "updated", "95 % interval",
                          "posterior / prior width", "true", "error vs true"], _parameter_rows(summary)),
                  f"<p>Updating chi2/dof {_fmt(upd.get('chi2_per_dof'), '.3g')}, "
                  f"{html.escape(str(upd.get('message')).rstrip('.'))}. "
                  + html.escape(str((summary.get("intervals") or {}).get("parameters", ""))) + "</p>"]
    elif upd and "error" in upd:
        parts.append(f"<p class='note'>Model updating failed: {html.escape(upd['error'])}</p>")
    parts.append("<h2>Figures</h2>")
    for name, caption in figure_list:
        parts.append(f"<figure><img src='{html.escape(name)}' alt='{html.escape(caption)}'>"
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _relative_error(g: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.linalg.norm(g - ref, axis=(1, 2)) / np.linalg.norm(ref, axis=(1, 2))


def write_report(report_dir: str | Path, summary: Mapping[str, Any], *, frf: FrfResult, design: ExcitationDesign,
                 diagram: StabilisationDiagram, order: int, curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
                 levels: LineLevels | None = None, window: Mapping[str, Any] | None = None,
                 true_frf: np.ndarray | None = None, line_models: Mapping[str, np.ndarray] | None = None,
                 extra_figures: Sequence[tuple[str, str, Callable[[Path], Any]]] = (),
                 band_variance: np.ndarray | None = None, band_kind: str = "") -> Path:
    """Draw every figure into ``report_dir`` and write ``report_dir/index.html``.

    Args:
        report_dir: output folder (created).
        summary: the identification summary (headline numbers).
        frf: the measured FRF result.
        design: the experiment's design.
        diagram, order: stabilisation diagram and the chosen order.
        curves: model label -> (freq (K,) [Hz], FRF (K, Ny, Nu) [m/A]).
        levels: line levels for the noise / distortion figure, or None.
        window: dict t_s, y, u, r, output_names, input_names for the time records, or None.
        true_frf: (L, Ny, Nu) true FRF at the lines, or None (no error figure).
        line_models: label -> (L, Ny, Nu) models at the lines, for the error figure.
        extra_figures: (file name, caption, draw(path)) of further figures, shown after the FRF error.

    Returns:
        Path of index.html.
    """
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    var = frf.var_total if np.all(np.isfinite(frf.var_total)) else frf.var_noise
    sigma_kind = "total (noise + nonlinear)" if var is frf.var_total else "noise only"
    if band_variance is not None:
        var, sigma_kind = np.asarray(band_variance), band_kind or sigma_kind
    std = np.sqrt(var) if np.all(np.isfinite(var)) else None
    names = dict(input_names=frf.input_names, output_names=frf.output_names)
    shown: list[tuple[str, str]] = []

    def add(name: str, caption: str, draw) -> None:
        draw(out / name)
        shown.append((name, caption))

    models = ", ".join(curves)
    add("bode_magnitude.png", f"FRF matrix magnitude [dB re 1 m/A], measured ({frf.estimator} estimator, dots) "
        f"with its +-2 sigma {sigma_kind} band, and {models}. The band covers the best linear approximation "
        "at this excitation level; the small-signal model at rest differs from it by the magnets' nonlinearity "
        "(the excitation stiffens them), a bias the band does not hold.",
        lambda p: figures.bode_matrix(frf.freq_hz, frf.frf, std, curves, "magnitude", p, **names,
                                      row_units=frf_row_units(summary), col_units=frf_column_units(summary)))
    add("bode_phase.png", f"FRF matrix phase [deg], measured (dots) and {models}.",
        lambda p: figures.bode_matrix(frf.freq_hz, frf.frf, std, curves, "phase", p, **names,
                                      col_units=frf_column_units(summary)))
    if true_frf is not None:
        errs = {"measured": _relative_error(frf.frf, true_frf)}
        errs.update({label: _relative_error(g, true_frf) for label, g in (line_models or {}).items()})
        noise = None
        if std is not None:
            noise = 2 * np.linalg.norm(std, axis=(1, 2)) / np.linalg.norm(true_frf, axis=(1, 2))
        add("frf_error.png", "Relative FRF-matrix error per line against the true rig's sampled small-signal model "
            "(Frobenius norm over the matrix); the dotted line is the measurement's 2 sigma noise level.",
            lambda p: figures.frf_error(frf.freq_hz, errs, noise, p))
    for name, caption, draw in extra_figures:
        add(name, caption, draw)
    if levels is not None:
        dist = frf.distortion
        add("noise_distortion.png", "Output line amplitudes (period means) at the excited lines, at the odd and "
            "even detection lines (where only nonlinear distortion and noise appear) and the noise floor (standard "
            "deviation of the period mean from the period-to-period scatter).",
            lambda p: figures.noise_distortion(levels, frf.output_names, p, None if dist is None else dist.odd_db,
                                               None if dist is None else dist.even_db))
    add("stabilisation.png", f"Stabilisation diagram (poles of the fits of each order; filled green squares are "
        f"stable in frequency and damping) over the CMIF (singular values of the measured FRF, grey); the dashed "
        f"line marks the chosen order {order}; the chosen order's modes carry their 95 % frequency intervals.",
        lambda p: figures.stabilisation(diagram, frf.freq_hz, frf.frf, order, p,
                                        mode_ci95=[m["freq_hz_ci95"] for m in summary["fit"]["modes"]
                                                   if m.get("freq_hz_ci95")]))
    if design.kind != "recorded":   # a recorded excitation has no design to draw: the time window shows it
        add("excitation.png", "Excitation design: line amplitudes of one period per input with its crest factor, "
            "the unexcited detection lines, and the period in time.",
            lambda p: figures.excitation(design, p))
    channels = (summary.get("sensitivity") or {}).get("channels") or []
    if all(c.get("injected_at", "current") == "current" for c in channels):
        # u / r is the input sensitivity only where r was added to the current (records.md, injection points)
        add("input_sensitivity.png", "Input sensitivity |S_ii| (r -> u) per axis, measured; ISO 14839-3 zones A "
            "(< 3), B (< 4), C (< 5) and D shaded.",
            lambda p: figures.input_sensitivity(frf.freq_hz, frf.sensitivity, frf.input_names, p))
    if window is not None:
        add("time_records.png", "A short window of the recorded displacements y and currents u (applied) and r "
            "(excitation) in steady state.",
            lambda p: figures.time_records(window["t_s"], window["y"], window["u"], window["r"],
                                           window["output_names"], window["input_names"], p))
    index = out / "index.html"
    index.write_text(render_index(summary, shown), encoding="utf-8")
    return index
