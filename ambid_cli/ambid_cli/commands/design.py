"""ambid design: preview an excitation design without running anything (never imports rclpy).

Prints the design's figures (``describe``), its headroom against the rig's
amplifier current limit, the measurement times of stepped sine, swept sine
and multisines for the same band and resolution side by side, and writes
``design.png`` (spectrum and time signal, drawn in a detached process once the figures are out: its state in
``design.status.json``) and ``design.json`` (loadable by
the excitation generator's ``start_experiment`` service) to ``--out``.

The design in the user's terms is :class:`ambid.excitation.spec.DesignSpec`; with no options it is the
experiment ``ambid identify`` runs and records.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HELP = "preview an excitation design: figures, headroom, measurement times, spectrum plot"

from ambid.excitation.spec import GRIDS, KINDS, MIMOS, PHASES, SPACINGS, build_design, prbs_clock  # noqa: F401 - re-exported
from ambid.excitation.experiment import WORKING_CURRENT_A
from ambid_cli.commands.inputs import (D, BadInput, add_experiment_options, add_session_options, check_amplifier, count,
                                       experiment_spec, output_dir, positive_float, positive_int, spec_option)


# ---- the command ------------------------------------------------------------
def add_arguments(g: argparse.ArgumentParser) -> None:
    # the experiment's terms with identify's defaults: no options preview the experiment identify runs
    add_session_options(g)
    add_experiment_options(g)
    g.add_argument("--inputs", default=",".join(D.input_names),
                   help="comma-separated excited inputs, e.g. u_a_x,u_a_y (default: every current of the rig)")
    spec_option(g, "--settle", "settle_s", type=positive_float)
    spec_option(g, "--cycles", "n_cycles", type=positive_int)
    g.add_argument("--rig", help="rig parameter YAML file (default: the built-in rig): sample rate, current limit")
    g.add_argument("--speed-rpm", type=float, default=None,
                   help="rotor speed [rpm]: keep the lines clear of its synchronous harmonics and say which moved "
                        "(default: the rig file's rotor_speed_rpm; 0 = standstill)")
    spec_option(g, "--harmonics", "n_harmonics", type=positive_int, help="synchronous harmonics kept clear")
    spec_option(g, "--guard-bins", "guard_bins", type=count, help="bins kept free each side of a harmonic")
    g.add_argument("--working-current", dest="working_current_a", metavar="WORKING_CURRENT", type=positive_float,
                   default=WORKING_CURRENT_A,
                   help=f"controller's peak working current [A] for the headroom check (default {WORKING_CURRENT_A:g})")
    g.add_argument("--no-plan", action="store_true", help="skip the stepped/swept/multisine time table")
    g.add_argument("--no-figure", action="store_true", help="skip design.png (otherwise drawn in the background once the figures are out)")
    g.add_argument("--out", default="design", help="directory for design.png and design.json (default design/)")
    g.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def _plan(spec, fs_hz: float, inputs) -> list:
    from ambid.excitation import plan_measurements

    grid = spec.grid if spec.kind == "multisine" and spec.grid else "random_odd"
    return plan_measurements(spec.band_hz, spec.resolution_hz, fs_hz, spec.input_names or inputs, spec.peak_current_a,
                             n_periods=spec.n_periods, n_transient_periods=spec.n_transient_periods,
                             n_realisations=spec.n_realisations, grid=grid, settle_s=spec.settle_s,
                             n_cycles=spec.n_cycles, seed=spec.seed)


def draw_in_background(design, out: Path) -> Path:
    """Start drawing ``out/design.png`` in a detached process (matplotlib's import and drawing are most of
    design's time: the figures are printed and the prompt is back meanwhile); its status file
    (:mod:`ambid.background`)."""
    from ambid.background import start
    from ambid.excitation.preview import plot_design

    return start(out / "design.status.json", plot_design, design, out / "design.png")


def run(args: argparse.Namespace) -> int:
    from ambid.excitation import describe, format_plan
    from ambid.excitation.synchronous import describe_steering
    from ambid.plant.rig import rig_or_default

    from ambid_cli.heartbeat import current

    current().say("designing the experiment, its time table and its figure", line=False)   # terminal only
    spec = experiment_spec(args, input_names=tuple(s.strip() for s in args.inputs.split(",") if s.strip()))
    output_dir(args.out)
    try:
        rig = rig_or_default(args.rig)
        fs_hz = float(rig.sample_rate_hz)
        speed = float(rig.rotor_speed_rpm) if args.speed_rpm is None else args.speed_rpm
        if not (speed >= 0 and speed < 1e6):
            raise ValueError(f"--speed-rpm must be a speed in rpm >= 0, got {args.speed_rpm!r}")
        design = spec.build(fs_hz, speed, rig.layout.inputs)
        plan = None if args.no_plan else _plan(spec, fs_hz, rig.layout.inputs)
    except (ValueError, OSError) as exc:
        print(f"ambid design: {exc}", file=sys.stderr)
        return 2
    limit = float(rig.current_limit_a)
    try:  # refused: one line, exit code 2, nothing written (identify refuses the same design before it starts)
        check_amplifier(design, limit, args.working_current_a, rig)
    except BadInput as exc:
        print(f"ambid design: headroom: REFUSED, {exc}", file=sys.stderr)
        return 2
    margin = limit - args.working_current_a - design.peak_a
    headroom = {"ok": True, "text": f"headroom: fits the {limit:g} A amplifier limit with a working current "
                                    f"of {args.working_current_a:g} A; smallest margin {margin.min():.3g} A",
                "margin_a": margin.tolist()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "design.json").write_text(json.dumps(design.to_dict()))
    status = None if args.no_figure else draw_in_background(design, out)
    if args.json:
        print(json.dumps({
            "kind": design.kind, "sample_rate_hz": design.fs_hz, "n_per_period": design.n_per_period,
            "resolution_hz": design.fs_hz / design.n_per_period, "n_lines": int(design.excited_lines.size),
            "input_names": list(design.input_names), "peak_a": design.peak_a.tolist(),
            "rms_a": design.rms_a.tolist(), "crest_factor": design.crest_factor.tolist(),
            "total_samples": design.total_samples, "measurement_time_s": design.measurement_time_s,
            "current_limit_a": limit, "working_current_a": args.working_current_a, "headroom": headroom,
            "plan": None if plan is None else [
                {"method": r.name, "n_lines": r.n_lines, "n_experiments": r.n_experiments,
                 "total_samples": r.total_samples, "measurement_time_s": r.measurement_time_s} for r in plan],
            "figure": status and str(out / "design.png"), "figure_status": status and str(status),
            "design_json": str(out / "design.json"),
            "synchronous": design.options.get("synchronous")}))
    else:
        print(describe(design))
        for line in describe_steering(design.options, design.fs_hz):
            print(line)
        print(headroom["text"])
        if plan is not None:
            n = len(design.input_names)   # the spec's inputs, else every current of the rig
            print(f"\nmeasurement time of the full {n} x {n} FRF matrix on the same lines:")
            print(format_plan(plan))
        if status is not None:
            print(f"\nfigure: {out / 'design.png'} (drawn in the background, about a second; {status} says "
                  "when it is there)")
        print(f"design: {out / 'design.json'} (start it with the excitation generator's "
              "start_experiment service, design_json = this file's text)")
    return 0
