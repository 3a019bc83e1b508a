"""ambid tune: a controller for the plant a run measured (never imports rclpy).

Reads a run's folder (``ambid identify``, ``ambid fit`` or ``ambid commission`` output), designs the
structured and the H-infinity controller on the plants its update's posterior allows, keeps the best one
that holds them all (the running controller when none beats it), predicts the peak the verifying
identification will measure, and writes ``DIR/controller.npz``, ``DIR/tune.json`` and
``DIR/report/index.html`` (:func:`ambid.commissioning.from_run.tune_run`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "design a controller for the plant a run measured, with its predicted sensitivity peak and ISO zone"

KIND_CHOICES = ("best", "structured", "hinf")


def add_effort_options(p: argparse.ArgumentParser, prefix: str = "", when: str = "") -> None:
    """How hard tune works: ``--checks``, ``--samples`` and ``--evaluations``, named ``--PREFIXchecks`` ... where
    another command passes them on (commission, validate), their help led by ``when``."""
    from ambid_cli.commands.inputs import positive_int

    p.add_argument(f"--{prefix}checks", type=positive_int, default=100,
                   help=f"{when}drawn plants every candidate must hold (default 100)")
    p.add_argument(f"--{prefix}samples", type=positive_int, default=100,
                   help=f"{when}simulated verifying measurements behind the prediction (default 100)")
    p.add_argument(f"--{prefix}evaluations", type=positive_int, default=600,
                   help=f"{when}objective evaluations per stage of the structured tuning (default 600)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", help="a run's folder: the --out of ambid identify, fit or commission")
    p.add_argument("--out", type=Path, required=True, help="output folder (controller.npz, tune.json, report/)")
    p.add_argument("--rig", default="", help="the nominal rig the run's model update was made on "
                                             "(default: the rig the run's session recorded)")
    p.add_argument("--kind", choices=KIND_CHOICES, default="best",
                   help="structured (per-axis PID with lead/lag and notches), hinf (H-infinity mixed sensitivity, "
                        "reduced), or best: both, the better kept (default)")
    add_effort_options(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the drawn plants and simulated measurements")
    p.add_argument("--no-report", action="store_true", help="skip the report page")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def format_tune(doc: dict) -> str:
    """tune.json's headline, a few lines."""
    p, z = doc["predicted_peak"], doc["zones"]
    zones = ", ".join(f"{k} {100 * v:.1f} %" for k, v in z.items())
    lines = [f"ambid tune: {doc['kind']} controller ({doc['order']} states) for {doc['run']}, designed in "
             f"{doc['design_time_s']:.0f} s",
             f"  predicted input sensitivity peak {p['value']:.2f} (95 % {p['ci95'][0]:.2f}..{p['ci95'][1]:.2f}) at "
             f"{doc['frequency_hz']:.4g} Hz ({doc['axis']}): ISO 14839-3 zone {doc['zone']} ({zones})"]
    b = doc.get("before") or {}
    if b.get("measured_peak") is not None:
        line = f"  before: measured {b['measured_peak']:.2f} (zone {b['measured_zone']})"
        if b.get("predicted"):
            bp = b["predicted"]
            line += (f"; predicted for the running controller {bp['value']:.2f} ({bp['ci95'][0]:.2f}.."
                     f"{bp['ci95'][1]:.2f}), the run's measurement {'inside' if b['measured_inside'] else 'outside'}")
        lines.append(line)
    cur, m = doc.get("current") or {}, doc["margins"]
    lines.append(f"  stable on {doc['stable_on']['plants']} drawn plants and the nominal model; noise "
                 f"{max(cur.get('noise_rms_a') or [0]):.3f} A RMS (current margin {cur.get('current_margin_a', 0):.2f} A); "
                 f"gain margins {max(m['gain_margin_low']):.2f}..{min(m['gain_margin_high']):.2f}, phase margin "
                 f"{min(m['phase_margin_deg']):.0f} deg")
    lines += [f"  {note}" for note in doc.get("notes", [])]
    out = Path(doc["controller"]).parent
    lines += [f"  controller: {doc['controller']}",
              f"  verify:     ambid identify --controller {doc['controller']} (with the run's experiment options)",
              f"  tune.json:  {out / 'tune.json'}"]
    if doc.get("report"):
        lines.append(f"  report:     {doc['report']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ambid.commissioning.from_run import read_run, tune_run
    from ambid.commissioning.tuning import KINDS, TuneSettings

    from ambid_cli.commands.inputs import BadInput, output_dir, rig_file

    output_dir(args.out)
    if args.rig:
        rig_file(args.rig)   # a bad rig file: one line before anything runs
    try:
        read_run(args.run, args.rig or None)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    kinds = tuple(KINDS) if args.kind == "best" else (args.kind,)
    settings = TuneSettings(kinds=kinds, n_check=args.checks, n_prediction=max(args.samples, 3),
                            max_evaluations=args.evaluations, seed=args.seed)

    def progress(line: str) -> None:
        if not args.quiet:
            print(f"  {line}", file=sys.stderr, flush=True)

    try:
        doc = tune_run(args.run, args.out, rig=args.rig or None, settings=settings, report=not args.no_report,
                       progress=progress)
    except ValueError as exc:   # no controller holds the plants: a refusal, nothing written
        print(f"ambid tune: {exc}", file=sys.stderr)
        return 2
    print(format_tune(doc))
    return 0
