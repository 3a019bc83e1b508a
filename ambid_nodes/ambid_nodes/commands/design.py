"""ambid design: preview an excitation design without running anything (never imports rclpy).

Prints the design's figures (``describe``), its headroom against the rig's
amplifier current limit, the measurement times of stepped sine, swept sine
and multisines for the same band and resolution side by side, and writes
``design.png`` (spectrum and time signal) and ``design.json`` (loadable by
the excitation generator's ``start_experiment`` service) to ``--out``.

``build_design`` maps the design in the user's terms (kind, band,
resolution, inputs, peak current, ...) onto the ``ambid.excitation``
designers; the ``excitation_generator`` node uses it for its parameters.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

HELP = "preview an excitation design: figures, headroom, measurement times, spectrum plot"

KINDS = ("multisine", "stepped_sine", "swept_sine", "noise", "prbs", "dibs")
DEFAULT_INPUTS = ("u_a_x", "u_b_x", "u_a_y", "u_b_y")
# choices per kind that take them; the first is the kind's default ("" selects it)
GRIDS = {"multisine": ("random_odd", "odd", "full"), "stepped_sine": ("full", "odd"),
         "dibs": ("odd", "random_odd", "full")}
SPACINGS = {"multisine": ("linear", "log"), "stepped_sine": ("linear", "log"),
            "dibs": ("linear", "log"), "swept_sine": ("linear", "log")}
PHASES = {"multisine": ("random", "schroeder", "crest_optimised")}
MIMOS = {"multisine": ("orthogonal", "one_at_a_time"), "swept_sine": ("one_at_a_time", "orthogonal"),
         "noise": ("simultaneous", "one_at_a_time"), "prbs": ("one_at_a_time", "orthogonal"),
         "dibs": ("one_at_a_time", "orthogonal")}
PRBS_MAX_ORDER = 23
# a PRBS holds each bit for d samples; its spectrum falls as sinc(f d / fs): at f = fs / (3 d)
# the loss is 1.65 dB, so the clock divider keeps the band below that
PRBS_BAND_FRACTION = 1.0 / 3.0


def _option(kind: str, name: str, value: str, table: dict[str, tuple[str, ...]]) -> str:
    """The kind's default for "", the value if the kind takes it, else ValueError."""
    if kind not in table:
        if value:
            takers = ", ".join(table)
            raise ValueError(f"{name} {value!r} does not apply to a {kind} design (only to {takers}); "
                             f"leave {name} empty")
        return ""
    allowed = table[kind]
    if not value:
        return allowed[0]
    if value not in allowed:
        raise ValueError(f"{name} of a {kind} design must be one of {allowed}, got {value!r}")
    return value


def prbs_clock(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float) -> tuple[int, int]:
    """(order, clock_divider) of a PRBS for a band and resolution.

    The clock divider d is the largest keeping band_hz[1] <= fs / (3 d)
    (hold loss <= 1.65 dB); the order is the smallest whose period
    d (2^order - 1) samples gives a resolution at least as fine as asked.
    """
    f_hi, res = float(band_hz[1]), float(resolution_hz)
    if not (math.isfinite(f_hi) and math.isfinite(res)) or f_hi <= 0 or res <= 0:
        raise ValueError(f"band upper edge and resolution must be finite and > 0 [Hz], got {f_hi!r}, {res!r}")
    if f_hi >= fs_hz / 2:
        raise ValueError(f"band upper edge {f_hi:g} Hz is not below the Nyquist frequency fs/2 = "
                         f"{fs_hz / 2:g} Hz; lower the band")
    divider = max(1, int(PRBS_BAND_FRACTION * fs_hz / f_hi))
    bits = fs_hz / (res * divider)
    order = max(2, math.ceil(math.log2(bits + 1) - 1e-12))
    if order > PRBS_MAX_ORDER:
        raise ValueError(f"a PRBS with resolution {res:g} Hz needs order {order} > {PRBS_MAX_ORDER}; "
                         "coarsen the resolution")
    return order, divider


def build_design(kind: str, band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                 input_names: Sequence[str] = DEFAULT_INPUTS, peak_current_a: float = 0.5,
                 n_periods: int = 4, n_realisations: int = 1, n_transient_periods: int = 1,
                 grid: str = "", spacing: str = "", phases: str = "", mimo: str = "", seed: int = 0,
                 settle_s: float = 0.5, n_cycles: int = 10):
    """An ExcitationDesign from the user's terms, for any kind.

    Args:
        kind: one of KINDS.
        band_hz: (f_lo, f_hi) band of interest [Hz], f_hi < fs/2.
        resolution_hz: line spacing [Hz] (prbs: the resolution is at least this fine).
        fs_hz: sample rate of the plant [Hz].
        input_names: (Nu,) inputs, e.g. DEFAULT_INPUTS.
        peak_current_a: excitation peak per input [A].
        n_periods, n_realisations, n_transient_periods: P, M, Pt (unused by stepped_sine).
        grid, spacing, phases, mimo: "" = the kind's default (first entry of GRIDS, SPACINGS,
            PHASES, MIMOS); a choice a kind does not take raises ValueError. For swept_sine
            ``spacing`` is the sweep law.
        seed: seed of the random choices.
        settle_s, n_cycles: stepped sine settling wait [s] and measured cycles per line.

    Returns:
        ExcitationDesign.

    Raises:
        ValueError naming the bad argument (band above Nyquist, resolution not dividing fs, ...).
    """
    from ambid.excitation import (design_dibs, design_multisine, design_noise, design_prbs,
                                  design_stepped_sine, design_swept_sine)

    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    band = (float(band_hz[0]), float(band_hz[1]))
    grid = _option(kind, "grid", grid, GRIDS)
    spacing = _option(kind, "spacing", spacing, SPACINGS)
    phases = _option(kind, "phases", phases, PHASES)
    mimo = _option(kind, "mimo", mimo, MIMOS)
    common = dict(input_names=tuple(input_names), peak_current_a=peak_current_a)
    periodic = dict(n_periods=n_periods, n_realisations=n_realisations, n_transient_periods=n_transient_periods)
    if kind == "multisine":
        return design_multisine(band, resolution_hz, fs_hz, **common, **periodic, grid=grid, spacing=spacing,
                                phases=phases, mimo=mimo, seed=seed)
    if kind == "stepped_sine":
        return design_stepped_sine(band, resolution_hz, fs_hz, **common, settle_s=settle_s, n_cycles=n_cycles,
                                   grid=grid, spacing=spacing)
    if kind == "swept_sine":
        return design_swept_sine(band, resolution_hz, fs_hz, **common, **periodic, law=spacing, mimo=mimo)
    if kind == "noise":
        return design_noise(band, resolution_hz, fs_hz, **common, **periodic, mimo=mimo, seed=seed)
    if kind == "prbs":
        order, divider = prbs_clock(band, resolution_hz, fs_hz)
        return design_prbs(fs_hz, order, **common, clock_divider=divider, **periodic, mimo=mimo, seed=seed)
    return design_dibs(band, resolution_hz, fs_hz, **common, **periodic, grid=grid, spacing=spacing, mimo=mimo,
                       seed=seed)


# ---- the command ------------------------------------------------------------
def add_arguments(g: argparse.ArgumentParser) -> None:
    g.add_argument("--kind", choices=KINDS, default="multisine", help="excitation kind (default multisine)")
    g.add_argument("--band", type=float, nargs=2, default=(10.0, 1000.0), metavar=("LOW", "HIGH"),
                   help="band of interest [Hz] (default 10 1000)")
    g.add_argument("--resolution", type=float, default=5.0, help="frequency resolution fs/N [Hz] (default 5)")
    g.add_argument("--inputs", default=",".join(DEFAULT_INPUTS),
                   help=f"comma-separated excited inputs (default {','.join(DEFAULT_INPUTS)})")
    g.add_argument("--peak-current", type=float, default=0.5, help="excitation peak per input [A] (default 0.5)")
    g.add_argument("--periods", type=int, default=4, help="steady-state periods P (default 4)")
    g.add_argument("--realisations", type=int, default=1, help="realisations M (default 1)")
    g.add_argument("--transient-periods", type=int, default=1, help="transient periods Pt (default 1)")
    g.add_argument("--grid", default="", help="line grid: random_odd | odd | full (default: the kind's)")
    g.add_argument("--spacing", default="", help="linear | log (swept sine: the sweep law; default: the kind's)")
    g.add_argument("--phases", default="", help="multisine phases: random | schroeder | crest_optimised")
    g.add_argument("--mimo", default="", help="orthogonal | one_at_a_time | simultaneous (default: the kind's)")
    g.add_argument("--seed", type=int, default=0, help="seed of the random choices (default 0)")
    g.add_argument("--settle", type=float, default=0.5, help="stepped sine settling wait per line [s]")
    g.add_argument("--cycles", type=int, default=10, help="stepped sine measured cycles per line")
    g.add_argument("--rig", help="rig parameter YAML file (default: the built-in rig): sample rate, current limit")
    g.add_argument("--working-current", type=float, default=1.0,
                   help="controller's peak working current [A] for the headroom check (default 1.0)")
    g.add_argument("--no-plan", action="store_true", help="skip the stepped/swept/multisine time table")
    g.add_argument("--no-figure", action="store_true", help="skip design.png (quicker)")
    g.add_argument("--out", default="design", help="directory for design.png and design.json (default design/)")
    g.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def _plan(args, fs_hz: float, inputs: tuple[str, ...]) -> list:
    from ambid.excitation import plan_measurements

    grid = args.grid if args.kind == "multisine" and args.grid else "random_odd"
    return plan_measurements((args.band[0], args.band[1]), args.resolution, fs_hz, inputs, args.peak_current,
                             n_periods=args.periods, n_transient_periods=args.transient_periods,
                             n_realisations=args.realisations, grid=grid, settle_s=args.settle,
                             n_cycles=args.cycles, seed=args.seed)


def run(args: argparse.Namespace) -> int:
    from ambid.excitation import check_headroom, describe, format_plan, plot_design
    from ambid.rig import load_rig, make_rig

    try:
        rig = load_rig(args.rig) if args.rig else make_rig()
        fs_hz = float(rig.sample_rate_hz)
        inputs = tuple(s.strip() for s in args.inputs.split(",") if s.strip())
        design = build_design(args.kind, tuple(args.band), args.resolution, fs_hz, inputs, args.peak_current,
                              args.periods, args.realisations, args.transient_periods, args.grid, args.spacing,
                              args.phases, args.mimo, args.seed, args.settle, args.cycles)
        plan = None if args.no_plan else _plan(args, fs_hz, inputs)
    except (ValueError, OSError) as exc:
        print(f"ambid design: {exc}", file=sys.stderr)
        return 2
    limit = float(rig.current_limit_a)
    try:
        margin = check_headroom(design, limit, args.working_current)
        headroom = {"ok": True, "text": f"headroom: fits the {limit:g} A amplifier limit with a working current "
                                        f"of {args.working_current:g} A; smallest margin {margin.min():.3g} A",
                    "margin_a": margin.tolist()}
    except ValueError as exc:
        headroom = {"ok": False, "text": f"headroom: REFUSED, {exc}", "margin_a": None}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = None if args.no_figure else plot_design(design, out / "design.png")
    (out / "design.json").write_text(json.dumps(design.to_dict()))
    if args.json:
        print(json.dumps({
            "kind": design.kind, "sample_rate_hz": design.fs_hz, "n_per_period": design.n_per_period,
            "resolution_hz": design.fs_hz / design.n_per_period, "n_lines": int(design.excited_lines.size),
            "input_names": list(design.input_names), "peak_a": design.peak_a.tolist(),
            "rms_a": design.rms_a.tolist(), "crest_factor": design.crest_factor.tolist(),
            "total_samples": design.total_samples, "measurement_time_s": design.measurement_time_s,
            "current_limit_a": limit, "working_current_a": args.working_current, "headroom": headroom,
            "plan": None if plan is None else [
                {"method": r.name, "n_lines": r.n_lines, "n_experiments": r.n_experiments,
                 "total_samples": r.total_samples, "measurement_time_s": r.measurement_time_s} for r in plan],
            "figure": png and str(png), "design_json": str(out / "design.json")}))
    else:
        print(describe(design))
        print(headroom["text"])
        if plan is not None:
            print(f"\nmeasurement time of the full {len(inputs)} x {len(inputs)} FRF matrix on the same lines:")
            print(format_plan(plan))
        if png is not None:
            print(f"\nfigure: {png}")
        print(f"design: {out / 'design.json'} (start it with the excitation generator's "
              "start_experiment service, design_json = this file's text)")
    return 0 if headroom["ok"] else 1
