"""ambid compare: the thesis's comparisons of excitations and estimators (never imports rclpy).

Runs :func:`ambid.comparison.thesis.run_comparison` on the simulated rig and writes
to ``--out``: ``compare.json`` (every number), ``compare.md`` (one table per
comparison with a line of interpretation) and four PNG figures:
``measurement_time.png``, ``frf_error_methods.png``,
``frf_error_estimators.png`` and ``distortion_odd_full.png``.
The exit code is 0 when the run completed (the claim's verdict is in the
table, not in the exit code), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from ambid_cli.commands.inputs import output_dir, rig_file

HELP = "compare excitation methods, FRF estimators and odd/full multisines on the simulated rig"
PARTS = ("methods", "estimators", "odd_full")


def add_arguments(g: argparse.ArgumentParser) -> None:
    g.add_argument("--preset", choices=("quick", "full"), default="quick",
                   help="quick (about a minute, the CI run) or full (10-1000 Hz, several minutes)")
    g.add_argument("--out", default="compare", help="output directory (default compare/)")
    g.add_argument("--parts", default=",".join(PARTS),
                   help=f"comma-separated subset of {','.join(PARTS)} (default all)")
    g.add_argument("--rig", help="rig parameter YAML file (default: the built-in rig)")
    g.add_argument("--no-figures", action="store_true", help="skip the PNG figures")


def run(args: argparse.Namespace) -> int:
    from ambid.comparison.thesis import comparison_markdown, run_comparison

    parts = tuple(p.strip() for p in args.parts.split(",") if p.strip())
    bad = sorted(set(parts) - set(PARTS))
    if bad or not parts:
        print(f"ambid compare: --parts must name some of {', '.join(PARTS)}, got {args.parts!r}", file=sys.stderr)
        return 2
    rig = rig_file(args.rig)
    out = output_dir(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"ambid compare: {args.preset} preset, parts {', '.join(parts)}, rig {rig.name}", flush=True)
    result = run_comparison(args.preset, rig, parts)
    (out / "compare.json").write_text(json.dumps(_finite(result), indent=1, allow_nan=False))
    text = comparison_markdown(result)
    figures = [] if args.no_figures else write_figures(result, out)
    if figures:
        text += "\n## Figures\n\n" + "\n".join(f"![{p.stem}]({p.name})" for p in figures) + "\n"
    (out / "compare.md").write_text(text)
    print(text)
    print(f"written: {out / 'compare.json'}, {out / 'compare.md'}"
          + "".join(f", {p}" for p in figures))
    return 0


def _finite(x):
    """The result with NaN and inf as null, so compare.json is strict JSON."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# ---------------------------------------------------------------- figures

def write_figures(result: dict, out: Path) -> list[Path]:
    """The PNG figures of the parts present in ``result``; returns their paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    try:
        if "methods" in result:
            paths.append(_measurement_time(plt, result["methods"], out / "measurement_time.png"))
            paths.append(_method_errors(plt, result["methods"], out / "frf_error_methods.png"))
        if "estimators" in result:
            paths.append(_estimator_errors(plt, result["estimators"], out / "frf_error_estimators.png"))
        if "odd_full" in result:
            paths.append(_odd_full(plt, result["odd_full"], out / "distortion_odd_full.png"))
    finally:
        plt.close("all")
    return paths


def _measurement_time(plt, m: dict, path: Path) -> Path:
    target = 100 * m["target_error"]
    rows = []
    for e in m["methods"].values():
        extra = " (extrapolated)" if e["time_extrapolated"] else ""
        if e["reached_target"]:
            rows.append((e["label"] + extra, e["time_to_target_s"], True, e["error_at_target"]))
        else:
            rows.append((e["label"] + extra, e["best_time_s"], False, e["best_error"]))
    tuned = m["methods"].get("stepped_sine", {}).get("tuned_settle")
    if tuned and tuned["reached_target"]:
        rows.insert(1, ("stepped sine, wait tuned after the fact", tuned["time_to_target_s"], True,
                        tuned["error_at_target"]))
    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    y = range(len(rows))
    for i, (label, t, ok, err) in enumerate(rows):
        ax.barh(i, t, color="tab:blue" if ok else "lightgray", hatch=None if ok else "//", edgecolor="k")
        note = f"{t:.3g} s, {100 * err:.2f} %" if ok else f"target not reached: {100 * err:.1f} % after {t:.3g} s"
        ax.text(t * 1.08, i, note, va="center", fontsize=8)
    ax.set_yticks(list(y), [r[0] for r in rows])
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlim(min(r[1] for r in rows) / 2, max(r[1] for r in rows) * 8)
    ax.set_xlabel(f"measurement time to a {target:g} % median FRF error [s] (log scale)")
    ax.set_title("Measurement time per method\n(full FRF matrix, same lines, peak current and settling rule)",
                 fontsize=10)
    ax.legend(handles=[plt.Rectangle((0, 0), 1, 1, color="tab:blue", label="reached the target"),
                       plt.Rectangle((0, 0), 1, 1, facecolor="lightgray", hatch="//", edgecolor="k",
                                     label="not reached (longest run)")], loc="lower right", fontsize=8)
    fig.savefig(path, dpi=110)
    return path


def _method_errors(plt, m: dict, path: Path) -> Path:
    fig, (ax_t, ax_f) = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    target = 100 * m["target_error"]
    for e in m["methods"].values():
        steps = e["ladder"]
        if e["kind"] == "stepped_sine":
            steps = [s for s in steps if s["settle_s"] == e["settle_s"]]
        scale = len(m["lines"]) / e["lines_measured"]
        t = [s["measurement_time_s"] * scale for s in steps]
        line, = ax_t.plot(t, [100 * s["median_error"] for s in steps], "o-", ms=3, label=e["label"])
        per_line = e["error_per_line_at_target"]
        label = e["label"] + (" (at target)" if per_line is not None else " (longest run)")
        if per_line is None:
            per_line = e["ladder"][-1]["error_per_line"] if e["kind"] != "stepped_sine" else steps[-1]["error_per_line"]
        ax_f.plot(e["freq_hz"], [100 * v for v in per_line], "o-", ms=3, lw=0.8, color=line.get_color(), label=label)
    for ax in (ax_t, ax_f):
        ax.axhline(target, color="k", ls="--", lw=0.8, label=f"target {target:g} %")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    ax_t.set_xscale("log")
    ax_t.set_xlabel("measurement time [s] (prefixes of each run)")
    ax_t.set_ylabel("median relative FRF error [%]")
    ax_t.set_title("FRF error versus measurement time")
    ax_t.legend(fontsize=7)
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("relative FRF error ||G - G_true||_F / ||G_true||_F [%]")
    ax_f.set_title("FRF error per line")
    ax_f.legend(fontsize=7, loc="upper left")
    fig.savefig(path, dpi=110)
    return path


def _estimator_errors(plt, e: dict, path: Path) -> Path:
    fig, (ax_e, ax_b) = plt.subplots(2, 1, figsize=(9, 8), sharex=True, constrained_layout=True)
    f = e["freq_hz"]
    for v in e["estimators"].values():
        ax_e.plot(f, [100 * x for x in v["error_per_line"]], "o-", ms=3, lw=0.8,
                  label=f"{v['label']} (median {100 * v['median_error']:.1f} %)")
    ax_e.set_yscale("log")
    ax_e.set_ylabel("relative FRF error [%]")
    ax_e.set_title(f"Estimators in closed loop, orthogonal multisine at {e['peak_a']:g} A peak "
                   "(sensor noise fed back)")
    ax_e.legend(fontsize=8, ncol=2)
    ax_e.grid(True, which="both", alpha=0.3)
    ax_b.plot(f, e["h1_fraction_towards_minus_inv_c"], "o-", ms=3, label="H1, measured")
    ax_b.plot(f, e["h1_fraction_predicted"], "k--", label="H1, closed form n^2 / (1 + n^2)")
    ax_b.plot(f, e["indirect_fraction_towards_minus_inv_c"], "s-", ms=3, label="indirect, measured")
    ax_b.axhline(0.0, color="gray", lw=0.6)
    ax_b.set_xlabel("frequency [Hz]")
    ax_b.set_ylabel("fraction of the way from G to -1/C [-]")
    ax_b.set_title("Bias towards -1/C (n: fed-back noise / excitation in u)")
    ax_b.legend(fontsize=8)
    ax_b.grid(True, alpha=0.3)
    fig.savefig(path, dpi=110)
    return path


def _odd_full(plt, o: dict, path: Path) -> Path:
    fig, (ax_d, ax_e) = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    ro = o["grids"]["random_odd"].get("distortion")
    if ro:
        def amp(p):
            return [math.sqrt(max(v, 0.0)) for v in p]
        ax_d.plot(ro["excited_freq_hz"], amp(ro["excited_power_m2"]), "o", label="excited lines")
        ax_d.plot(ro["odd_freq_hz"], amp(ro["odd_power_m2"]), "v", color="tab:red", label="odd detection lines")
        ax_d.plot(ro["even_freq_hz"], amp(ro["even_power_m2"]), "^", color="tab:green",
                  label="even detection lines")
        ax_d.plot(ro["even_freq_hz"], amp(ro["even_noise_power_m2"]), "_", color="k", ms=10,
                  label="noise floor (period scatter)")
        ax_d.plot(ro["odd_freq_hz"], amp(ro["odd_noise_power_m2"]), "_", color="k", ms=10)
        ax_d.set_yscale("log")
        ax_d.set_title(f"Random-odd multisine, nonlinear magnets, {o['peak_a']:g} A: odd "
                       f"{max(ro['odd_db']):.1f} dB, even {max(ro['even_db']):.1f} dB above noise", fontsize=9)
    ax_d.set_xlabel("frequency [Hz]")
    ax_d.set_ylabel("output level, RMS over outputs of |Y| [m]")
    ax_d.legend(fontsize=8)
    ax_d.grid(True, which="both", alpha=0.3)
    for g in o["grids"].values():
        ax_e.plot(g["freq_hz"], [100 * v for v in g["error_per_line"]], "o-", ms=3, lw=0.8,
                  label=f"{g['label']} (median {100 * g['median_error']:.2f} %, var total/noise "
                        f"{g['variance_ratio']:.1f})")
    ax_e.set_yscale("log")
    ax_e.set_xlabel("frequency [Hz]")
    ax_e.set_ylabel("relative FRF error against the linearised rig [%]")
    ax_e.set_title("FRF error, full versus random-odd grid", fontsize=9)
    ax_e.legend(fontsize=8)
    ax_e.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=110)
    return path
