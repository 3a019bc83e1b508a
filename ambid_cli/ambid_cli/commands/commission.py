"""ambid commission: identify with the running controller, tune, identify again with the new one, and a
before/after report (docs/commissioning.md).

Each identification is ``ambid identify``'s own run (its options, its checks, its output folder:
``DIR/before`` and ``DIR/after``); the tuning is ``ambid tune``'s job on ``DIR/before``, written to
``DIR/tuned``. The new controller is deployed only when its own checks show it stable on the measured plant:
the updated physical model (the plant the run measured), every plant drawn from its posterior and the rig
file's nominal model (tune's checks), and the controller check identify makes before any run. A failed step leaves the running controller in
place and says why, in one line. ``DIR/commission.json`` holds the before/after comparison.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

HELP = "identify, tune and verify in one command: the running controller, a tuned one, and the ISO zone before/after"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ambid_cli.commands import identify, tune

    identify.add_arguments(p)
    p.set_defaults(out=Path("commission"))
    p.add_argument("--tune-kind", choices=tune.KIND_CHOICES, default="best",
                   help="the controller tuned: structured, hinf, or best (both, the better kept; default)")
    tune.add_effort_options(p, "tune-")
    p.add_argument("--tune-seed", type=int, default=0, help="seed of the tuning's drawn plants")


def verify_noise_seed(seed: int) -> int:
    """The simulated sensor noise's seed of a verifying run whose experiment has ``seed``: other noise than the
    run the plant was identified from (a real verifying run meets fresh noise; its prediction must hold it)."""
    import numpy as np

    return int(np.random.default_rng([seed, 37]).integers(2**31 - 1))


def _identify(args: argparse.Namespace, out: Path, controller: str, verify: bool = False) -> int:
    from ambid_cli.commands import identify
    from ambid_cli.heartbeat import current

    step = copy.copy(args)
    step.out, step.controller, step.live = out, controller, None
    if verify and not args.hardware:
        step.noise_seed = verify_noise_seed(args.seed if args.noise_seed is None else args.noise_seed)
    # its headline's wall times are its own, not the commission's so far
    return identify.run(step, wall_from_s=current().elapsed())


def _side(run: Path) -> dict:
    """One identification's figures for the comparison."""
    from ambid.commissioning.from_run import current_rms, headline_peak
    from ambid.frf.sensitivity import iso14839_zone

    s = json.loads((run / "summary.json").read_text())
    peak = headline_peak(s.get("sensitivity") or {})
    modes = [dict(freq_hz=m["freq_hz"], damping=m["damping"]) for m in (s.get("fit") or {}).get("modes", [])]
    ctrl = s.get("controller") or {}
    return dict(folder=str(run), measured_peak=peak, zone=None if peak is None else iso14839_zone(peak),
                peak_hz=((s.get("sensitivity") or {}).get("loop") or {}).get("peak_hz"), modes=modes,
                current_rms_a=current_rms(run), controller=dict(kind=ctrl.get("kind"), n_states=ctrl.get("n_states")),
                true_peak=((s.get("sensitivity") or {}).get("true_peak")))


def _peak(side: dict) -> str:
    v = side.get("measured_peak")
    return "not measured" if v is None else f"{v:.2f} (ISO 14839-3 zone {side['zone']})"


def format_commission(doc: dict) -> str:
    b, a, p = doc["before"], doc.get("after"), doc.get("predicted_peak")
    lines = [f"ambid commission: {doc['outcome']}",
             f"  before: input sensitivity peak {_peak(b)}, "
             f"current RMS {max(b['current_rms_a'] or [0]):.3f} A, modes "
             + ", ".join(f"{m['freq_hz']:.1f} Hz" for m in b["modes"][:5])]
    if p:
        lines.append(f"  predicted for {doc['kind']} ({doc['order']} states): {p['value']:.2f} "
                     f"(95 % {p['ci95'][0]:.2f}..{p['ci95'][1]:.2f}), designed in {doc['design_time_s']:.0f} s")
    if a:
        lines.append(f"  after:  input sensitivity peak {_peak(a)}, "
                     f"{'inside' if doc['inside'] else 'OUTSIDE'} the prediction, current RMS "
                     f"{max(a['current_rms_a'] or [0]):.3f} A, modes "
                     + ", ".join(f"{m['freq_hz']:.1f} Hz" for m in a["modes"][:5]))
    lines.append(f"  controller: {doc['controller']}")
    lines.append(f"  commission.json: {doc['out']}/commission.json")
    return "\n".join(lines)


def _write(out: Path, doc: dict) -> None:
    from ambid.jsonable import to_jsonable

    doc["out"] = str(out)
    (out / "commission.json").write_text(json.dumps(to_jsonable(doc), indent=1))


def run(args: argparse.Namespace) -> int:
    from ambid.commissioning.from_run import tune_run
    from ambid.commissioning.tuning import KINDS, TuneSettings

    from ambid_cli.commands.inputs import BadInput, checked_controller, output_dir, rig_file

    out = output_dir(args.out)
    rig = rig_file(args.rig)
    if not args.hardware:
        checked_controller(args.controller, rig)   # a bad running controller: one line before anything runs
    elif args.controller:
        raise BadInput("--controller with --hardware: the target runs its own controller; leave --controller out")
    before = out / "before"
    code = _identify(args, before, args.controller)
    if code != 0 or not (before / "identification.json").is_file():
        print("ambid commission: the identification with the running controller failed (above); nothing was "
              "tuned and the running controller stays", file=sys.stderr)
        return code or 1
    kinds = tuple(KINDS) if args.tune_kind == "best" else (args.tune_kind,)
    settings = TuneSettings(kinds=kinds, n_check=args.tune_checks, n_prediction=max(args.tune_samples, 3),
                            max_evaluations=args.tune_evaluations, seed=args.tune_seed)
    tuned = out / "tuned"
    say = None if args.no_progress else (lambda line: print(f"  {line}", file=sys.stderr, flush=True))
    doc = dict(before=_side(before), rig=args.rig or "the built-in rig", controller=args.controller or "the rig's")
    try:
        t = tune_run(before, tuned, rig=args.rig or None, settings=settings, progress=say)
    except ValueError as exc:   # no controller holds the plants: the running one stays
        doc.update(outcome=f"not tuned: {exc}; the running controller stays")
        _write(out, doc)
        print(f"ambid commission: {exc}; the running controller stays", file=sys.stderr)
        return 2
    doc.update(kind=t["kind"], order=t["order"], predicted_peak=t["predicted_peak"], zones=t["zones"],
               design_time_s=t["design_time_s"], tune=str(tuned / "tune.json"))
    new = tuned / "controller.npz"
    if t["kind"] == "running":
        doc.update(outcome="the running controller is kept: no tuned controller beats it on the drawn plants",
                   controller=doc["controller"])
        _write(out, doc)
        print(format_commission(doc))
        return 0
    why = "" if t["stable_on"]["share"] == 1.0 else "it does not hold every drawn plant"
    if not why and not args.hardware:
        try:
            checked_controller(str(new), rig)
        except BadInput as exc:
            why = str(exc)
    if why:
        doc.update(outcome=f"not deployed: {why}; the running controller stays")
        _write(out, doc)
        print(f"ambid commission: the tuned controller is not deployed: {why}; the running controller stays",
              file=sys.stderr)
        return 1
    if args.hardware:
        doc.update(outcome=f"tuned; load {new} into the target (the C target: ambid target-model --controller "
                           f"{new}) and verify with ambid identify --hardware", controller=str(new))
        _write(out, doc)
        print(format_commission(doc))
        return 0
    code = _identify(args, out / "after", str(new), verify=True)
    if code != 0 or not (out / "after" / "summary.json").is_file():
        doc.update(outcome="the verifying identification failed (above); the running controller stays")
        _write(out, doc)
        print(f"ambid commission: {doc['outcome']}", file=sys.stderr)
        return code or 1
    after = _side(out / "after")
    lo, hi = t["predicted_peak"]["ci95"]
    inside = after["measured_peak"] is not None and lo <= after["measured_peak"] <= hi
    doc.update(after=after, inside=inside, controller=str(new),
               outcome=f"zone {doc['before']['zone']} -> zone {after['zone']}")
    _write(out, doc)
    print(format_commission(doc))
    return 0
