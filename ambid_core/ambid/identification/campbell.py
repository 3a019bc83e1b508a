"""A measured Campbell diagram: identified modes against rotor speed, beside the model's prediction.

One identification per speed (``ambid identify``'s summaries, as summary.json holds them) is
gathered here into ``campbell.json``: per speed the identified modes with their whirl direction, the
true rig's (simulated sessions), the first bending mode's forward and backward frequencies identified
against true, with identify's 95 % intervals and whether they hold the truth; over a dense speed grid the analytical model's whirl branches and the critical speeds
where a branch crosses the 1X line.

Whirl of a model's modes: from the residue of each eigenvalue (:func:`ambid.frf.directional.whirl_of_residue`),
coincident eigenvalues (the x and y planes at standstill) merged, so a standing mode reads as standing.
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ambid.frf.directional import whirl_of_residue
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import Rig, make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.report.rotor_figures import campbell_figure
from ambid.statespace import StateSpace

__all__ = ["model_modes", "predicted_branches", "critical_speeds", "first_bending", "campbell_summary"]

# modes within this relative frequency of each other are one (coincident x and y modes)
_MERGE_REL = 1e-4
# the first bending pair is sought within this fraction of the rotor's free-free first bending frequency
_BENDING_WINDOW = 0.08
# a fitted mode's intervals in identify's summary, carried into campbell.json
_INTERVAL_KEYS = ("freq_hz_std", "freq_hz_ci95", "damping_std", "damping_ci95")


def model_modes(model: StateSpace, band_hz: tuple[float, float], max_damping: float = 0.3) -> list[dict]:
    """Lightly damped modes of a continuous model in a band, with their whirl.

    Parameters
    ----------
    model
        continuous StateSpace whose named inputs and outputs hold the bearing planes' x and y
        channels (``u_a_x``, ``y_a_x``, ...; any other axis, e.g. the axial one, is left out).
    band_hz
        (f_lo, f_hi) [Hz].
    max_damping
        modes with damping ratio in (0, max_damping) count.

    Returns
    -------
    [{freq_hz, damping, whirl, forward_share}] ascending in frequency.
    """
    s, v = np.linalg.eig(model.a)
    w = np.linalg.inv(v)
    f = s.imag / (2 * np.pi)
    zeta = -s.real / np.maximum(np.abs(s), 1e-300)
    keep = np.flatnonzero((s.imag > 0) & (f >= band_hz[0]) & (f <= band_hz[1]) & (zeta > 0) & (zeta < max_damping))
    keep = keep[np.argsort(f[keep])]
    groups: list[list[int]] = []
    for i in keep:
        if groups and f[i] - f[groups[-1][-1]] <= _MERGE_REL * f[i]:
            groups[-1].append(int(i))
        else:
            groups.append([int(i)])
    out = []
    for g in groups:
        residue = sum(np.outer(model.c @ v[:, i], w[i] @ model.b) for i in g)
        kind, share = whirl_of_residue(residue, model.output_names, model.input_names)
        wn = float(np.mean(np.abs(s[g])))
        out.append(dict(freq_hz=wn / (2 * np.pi), damping=float(np.mean(zeta[g])), whirl=kind,
                        forward_share=share))
    return out


def _at_speed(rig: Rig, speed_rpm: float) -> Rig:
    return make_rig({**rig.to_dict(), "rotor_speed_rpm": float(speed_rpm)})


def predicted_branches(rig: Rig, speeds_rpm: np.ndarray, band_hz: tuple[float, float]) -> dict[str, np.ndarray]:
    """The analytical model's whirl branches over speed: label -> (S,) frequency [Hz] (NaN where absent).

    At each speed the forward modes, ascending, are branches 'mode j forward', the backward ones
    'mode j backward'; a standing mode (standstill) starts both branches of its rank.
    """
    rows = []
    for rpm in speeds_rpm:
        modes = model_modes(analytical_model(_at_speed(rig, rpm)), band_hz)
        fw = [m["freq_hz"] for m in modes if m["whirl"] in ("forward", "standing")]
        bw = [m["freq_hz"] for m in modes if m["whirl"] in ("backward", "standing")]
        rows.append((fw, bw))
    n = max((max(len(fw), len(bw)) for fw, bw in rows), default=0)
    out: dict[str, np.ndarray] = {}
    for j in range(n):
        for k, name in ((1, "backward"), (0, "forward")):
            out[f"mode {j + 1} {name}"] = np.array([r[k][j] if j < len(r[k]) else np.nan for r in rows])
    return out


def critical_speeds(speeds_rpm: np.ndarray, branches: Mapping[str, np.ndarray]) -> list[dict]:
    """Where each branch crosses the 1X line f = rpm / 60 (linear interpolation on the grid).

    Returns
    -------
    [{label, speed_rpm, freq_hz}].
    """
    out = []
    rpm = np.asarray(speeds_rpm, dtype=float)
    for label, f in branches.items():
        d = np.asarray(f) - rpm / 60.0
        for i in range(rpm.size - 1):
            if np.isfinite(d[i]) and np.isfinite(d[i + 1]) and d[i] * d[i + 1] < 0:
                t = d[i] / (d[i] - d[i + 1])
                r = rpm[i] + t * (rpm[i + 1] - rpm[i])
                out.append(dict(label=label, speed_rpm=float(r), freq_hz=float(r / 60.0)))
    return out


def first_bending(modes: Sequence[Mapping], reference_hz: float) -> dict:
    """The first bending mode's backward and forward frequency among ``modes`` near ``reference_hz``.

    A standing mode (standstill) gives both; whirl is 'split' when a backward and a forward mode are
    there, else the one direction found.

    Returns
    -------
    {backward_hz, forward_hz, backward_damping, forward_damping, whirl} (None where missing), and
    ``<side>_hz_ci95`` / ``<side>_damping_ci95`` (95 % intervals, None where the mode has none).
    """
    near = [m for m in modes if abs(m["freq_hz"] / reference_hz - 1) <= _BENDING_WINDOW]
    out: dict[str, Any] = {f"{side}_{q}": None for side in ("backward", "forward")
                           for q in ("hz", "damping", "hz_ci95", "damping_ci95")}
    for side in ("backward", "forward"):
        cand = [m for m in near if m["whirl"] in (side, "standing")]
        if cand:
            best = max(cand, key=lambda m: abs(m["forward_share"] - 0.5))  # the clearest of its kind
            out[f"{side}_hz"], out[f"{side}_damping"] = best["freq_hz"], best["damping"]
            out[f"{side}_hz_ci95"] = best.get("freq_hz_ci95")
            out[f"{side}_damping_ci95"] = best.get("damping_ci95")
    kinds = {m["whirl"] for m in near}
    out["whirl"] = "split" if {"forward", "backward"} <= kinds else ("standing" if "standing" in kinds else
                                                                       "/".join(sorted(kinds)) or None)
    return out


def _truth_at_excitation(summary: Mapping[str, Any], freq_hz: float | None) -> float | None:
    """The true frequency at the excitation level of the fitted mode at ``freq_hz`` (identify's
    ``modes_vs_true``, one true and one fitted mode), or None."""
    if freq_hz is None:
        return None
    for row in summary.get("modes_vs_true") or []:
        if row.get("n_true") == 1 and row.get("n_fitted") == 1 and abs(row["freq_hz"] - freq_hz) <= 1e-9 * freq_hz:
            return float(row["true_freq_hz"])
    return None


def campbell_summary(rig: Rig, runs: Sequence[tuple[float, Mapping[str, Any]]], band_hz: tuple[float, float],
                     n_grid: int = 25) -> dict:
    """campbell.json: per speed the identified and true modes and the first bending mode, the predicted
    branches and the critical speeds.

    Parameters
    ----------
    rig
        the rig at any speed (its speed is replaced).
    runs
        (speed [rpm], identification summary) per speed, ascending.
    band_hz
        band of the modes [Hz].
    n_grid
        speeds of the predicted branches, from 0 to 1.25 x the highest, at least past the first
        bending mode's critical speed.
    """
    ref_hz = float(_at_speed(rig, 0.0).rotor_model().flexible_freq_hz[0])
    # the first bending mode as the levitated rotor has it at standstill (the magnets lower it a little)
    standstill = model_modes(true_linear_model(_at_speed(rig, 0.0)), band_hz)
    ref_hz = min((m["freq_hz"] for m in standstill), key=lambda f: abs(f - ref_hz), default=ref_hz)
    per_speed = []
    for rpm, s in runs:
        # each mode with the 95 % intervals the identification gives it (fit.modes[*].freq_hz_ci95, ...)
        identified = [dict(freq_hz=m["freq_hz"], damping=m["damping"], whirl=m.get("whirl", "standing"),
                           forward_share=m.get("forward_share", 0.5), stable=m.get("stable", True),
                           **{k: m[k] for k in _INTERVAL_KEYS if m.get(k) is not None})
                      for m in (s.get("fit") or {}).get("modes", [])]
        physical = [m for m in identified if m["stable"] and m["damping"] > 0]
        true = model_modes(true_linear_model(_at_speed(rig, rpm)), band_hz) if s.get("simulated") else []
        fb_id = first_bending(physical, ref_hz)
        row: dict[str, Any] = dict(speed_rpm=float(rpm), identified=identified, true=true,
                                   first_bending=dict(identified=fb_id), frf_error=s.get("frf_error"),
                                   session=(s.get("recording") or {}).get("path"))
        if true:
            fb_true = first_bending(true, ref_hz)
            err = {}
            for side in ("backward", "forward"):
                a, b = fb_id[f"{side}_hz"], fb_true[f"{side}_hz"]
                err[f"{side}_error"] = None if a is None or b is None else a / b - 1
                # an interval claims the loop this excitation linearises (the magnets' slopes averaged over
                # its excursions): identify's modes_vs_true has that truth for a mode it matched alone
                bx = _truth_at_excitation(s, a)
                err[f"{side}_true_at_excitation_hz"] = bx
                ci, t = fb_id[f"{side}_hz_ci95"], b if bx is None else bx
                err[f"{side}_covered"] = None if ci is None or t is None else bool(ci[0] <= t <= ci[1])
            row["first_bending"].update(true=fb_true, **err, whirl_right=fb_id["whirl"] == fb_true["whirl"])
        per_speed.append(row)
    # far enough to show where the first bending mode meets 1X (its critical speed)
    top = max([1.25 * rpm for rpm, _ in runs] + [1.15 * 60.0 * ref_hz])
    grid = np.linspace(0.0, top, n_grid)
    branches = predicted_branches(rig, grid, band_hz)
    fb = [r["first_bending"] for r in per_speed if "true" in r["first_bending"]]
    errors = [abs(e) for r in fb for e in (r["backward_error"], r["forward_error"]) if e is not None]
    covered = [c for r in fb for c in (r["backward_covered"], r["forward_covered"]) if c is not None]
    return dict(rig=rig.name, band_hz=list(band_hz), first_bending_reference_hz=ref_hz, speeds=per_speed,
                predicted=dict(model="analytical (nominal) model", speeds_rpm=grid.tolist(),
                               branches={k: v.tolist() for k, v in branches.items()}),
                critical_speeds=critical_speeds(grid, branches),
                first_bending_max_error=max(errors) if errors else None,
                # how many of the first bending frequencies' 95 % intervals hold the true rig's (at the
                # excitation level where identify matched the mode alone, else the small-signal model's)
                first_bending_ci_covered=[sum(covered), len(covered)] if covered else None,
                first_bending_whirl_right=all(r["whirl_right"] for r in fb) if fb else None)


def campbell_table(summary: Mapping[str, Any]) -> str:
    """The first bending mode identified against true per speed, as a Markdown table."""
    lines = ["| speed [rpm] | backward true [Hz] | backward identified [Hz] (95 % CI) | error | forward true [Hz] | "
             "forward identified [Hz] (95 % CI) | error | whirl (true / identified) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]

    def hz(x: float | None, ci: Sequence[float] | None = None) -> str:
        return "-" if x is None else f"{x:.3f}" + ("" if ci is None else f" ({ci[0]:.3f}..{ci[1]:.3f})")

    def pct(x: float | None) -> str:
        return "-" if x is None else f"{100 * x:+.3f} %"

    for r in summary["speeds"]:
        fb = r["first_bending"]
        t, i = fb.get("true") or {}, fb["identified"]
        lines.append(f"| {r['speed_rpm']:.0f} | {hz(t.get('backward_hz'))} | "
                     f"{hz(i['backward_hz'], i.get('backward_hz_ci95'))} | "
                     f"{pct(fb.get('backward_error'))} | {hz(t.get('forward_hz'))} | "
                     f"{hz(i['forward_hz'], i.get('forward_hz_ci95'))} | "
                     f"{pct(fb.get('forward_error'))} | {t.get('whirl', '-')} / {i['whirl']} |")
    return "\n".join(lines)


def campbell_figure_data(summary: Mapping[str, Any]) -> dict:
    """Arguments of :func:`ambid.report.rotor_figures.campbell_figure` from a campbell summary."""
    identified = [dict(speed_rpm=r["speed_rpm"], **m) for r in summary["speeds"] for m in r["identified"]
                  if m["stable"] and m["damping"] > 0]
    pred = summary["predicted"]
    return dict(speeds_rpm=np.array([r["speed_rpm"] for r in summary["speeds"]]), identified=identified,
                predicted_rpm=np.array(pred["speeds_rpm"]),
                predicted={k: np.array(v, dtype=float) for k, v in pred["branches"].items()},
                critical=summary["critical_speeds"], f_max_hz=summary["band_hz"][1])


def write_campbell_report(summary: Mapping[str, Any], report_dir: str | Path) -> Path:
    """DIR/report: campbell.png and an index.html with the first-bending table."""
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    campbell_figure(**campbell_figure_data(summary), path=out / "campbell.png")
    rows = "".join(f"<li>{html.escape(c['label'])}: {c['speed_rpm']:.0f} rpm ({c['freq_hz']:.1f} Hz)</li>"
                   for c in summary["critical_speeds"])
    table = campbell_table(summary).splitlines()
    head = [c.strip() for c in table[0].strip("|").split("|")]
    body = [[c.strip() for c in ln.strip("|").split("|")] for ln in table[2:]]
    t = ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
         + "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in body)
         + "</table>")
    links = "".join(f"<li>{r['speed_rpm']:.0f} rpm: <a href='../{html.escape(Path(r['session']).parent.name)}/"
                    f"report/index.html'>identification report</a></li>"
                    for r in summary["speeds"] if r.get("session"))
    index = out / "index.html"
    index.write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>ambid Campbell diagram</title></head><body>"
        f"<h1>Campbell diagram: {html.escape(str(summary['rig']))}</h1>"
        "<figure><img src='campbell.png' alt='Campbell diagram'><figcaption>Identified modes per speed (triangles "
        "up: forward whirl, down: backward, circles: standing; bars: their 95 % intervals) beside the "
        "analytical model's whirl branches "
        "(dashed), the 1X line and the critical speeds (x) where a branch crosses it; right: identified "
        "damping.</figcaption></figure>"
        f"<h2>First bending mode, identified against the true rig</h2>{t}"
        f"<h2>Critical speeds (analytical model)</h2><ul>{rows or '<li>none in range</li>'}</ul>"
        f"<h2>Sessions</h2><ul>{links}</ul></body></html>", encoding="utf-8")
    return index
