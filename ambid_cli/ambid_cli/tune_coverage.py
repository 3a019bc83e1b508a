"""One commissioning case of ``ambid validate --tune``: is the measured peak inside tune's prediction?

A case is what ``ambid commission`` does, on the session validate runs for a seed: identify with the running
controller (the seed's noise and phases; the update from a nominal rig drawn from the tolerances around the
simulated one, never the truth), ``ambid tune`` on that run with that nominal rig, and identify again with the
tuned controller (the same experiment, as commission repeats identify's options, with fresh sensor noise, as
a real rig would meet). The measured peak is the
verifying identification's headline input-sensitivity peak (:func:`ambid.commissioning.from_run.headline_peak`),
the quantity tune's ``predicted_peak`` claims. Each finished case leaves ``DIR/seeds/seed_NNN/tune_case.json``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path


def _identify(cfg_args: dict, rig, out: Path, controller_spec: str, nominal_path: Path,
              noise_seed: int | None = None) -> tuple[dict, Path]:
    """identify's session (the composed graph) and its offline identification on the nominal rig; returns
    identification.json's content and the session's path. ``noise_seed``: the sensor noise's own seed (None:
    the experiment's)."""
    from ambid.identification.pipeline import identify_session

    from ambid_nodes.running.plan import SessionConfig, plan_session
    from ambid_nodes.running.run import run_session

    cfg = SessionConfig(out_dir=out, controller=controller_spec, noise_seed=noise_seed, **cfg_args)
    run = run_session(cfg, plan_session(cfg, rig))
    identify_session(run["mcap_path"], out, estimator=cfg.estimator, report=False, rig=nominal_path)
    return json.loads((out / "identification.json").read_text()), Path(run["mcap_path"])


def run_tune_case(seed: int, rig_path: str, seed_dir: str, fingerprint: str, linear_magnets: bool = False,
                  controller_spec: str = "", spec_terms: dict | None = None,
                  tune_terms: dict | None = None) -> dict:
    """One case (module docstring); writes seed_dir/tune_case.json last (atomically) and returns it.

    ``spec_terms``: the experiment's DesignSpec fields besides the seed; ``tune_terms``: TuneSettings fields
    (n_check, n_prediction, max_evaluations)."""
    from ambid.commissioning.from_run import headline_peak, tune_run
    from ambid.commissioning.tuning import TuneSettings
    from ambid.excitation.spec import DesignSpec
    from ambid.plant.rig import rig_or_default
    from ambid.validation.coverage import seed_nominal_rig

    from ambid_cli.commands.commission import verify_noise_seed

    t0 = time.perf_counter()
    out = Path(seed_dir)
    rig = rig_or_default(rig_path)
    nominal_path, drawn = seed_nominal_rig(rig, seed, out)   # the user's nominal model, validate's for this seed
    cfg_args = dict(experiment=DesignSpec(seed=seed, **(spec_terms or {})), rig_file=rig_path, progress=False,
                    nonlinear_magnets=not linear_magnets)
    before, session = _identify(cfg_args, rig, out / "before", controller_spec, nominal_path)
    t1 = time.perf_counter()
    try:
        # tune reads the session as the CLI's does: the controller that ran (a start, the prediction of the
        # running loop) and the experiment (the new loop's operating point)
        doc = tune_run(out / "before", out / "tuned", rig=nominal_path,
                       settings=TuneSettings(**(tune_terms or {})), report=False)
    except ValueError as exc:   # tune refuses (as commission would, the running controller stays): no prediction
        session.unlink(missing_ok=True)
        return _write(out, dict(seed=seed, fingerprint=fingerprint, kind=None, predicted=None, measured=None,
                                inside=None, refused=str(exc), before=headline_peak(before.get("sensitivity") or {}),
                                nominal=drawn, wall_s=dict(total=time.perf_counter() - t0)))
    t2 = time.perf_counter()
    session.unlink(missing_ok=True)   # ~19 MB a session; identification.json and frf.npz stay
    # tune keeps the running controller when nothing beats it; its prediction is then for that one
    new = out / "tuned" / "controller.npz"
    verify_with = str(new) if doc["kind"] != "running" and new.is_file() else controller_spec
    # the same experiment (lines, phases) as the run, and fresh sensor noise: a real verifying run meets other
    # noise than the run the plant was identified from, which its prediction must hold too
    verify_noise = verify_noise_seed(seed)
    after, session = _identify(cfg_args, rig, out / "after", verify_with, nominal_path, verify_noise)
    session.unlink(missing_ok=True)
    measured = headline_peak(after.get("sensitivity") or {})
    lo, hi = doc["predicted_peak"]["ci95"]
    case = dict(seed=seed, fingerprint=fingerprint, kind=doc["kind"], predicted=doc["predicted_peak"],
                measured=measured, inside=measured is not None and lo <= measured <= hi,
                verify_noise_seed=verify_noise, loop_peak=doc["loop_peak"], running=doc["before"],
                before=headline_peak(before.get("sensitivity") or {}),
                true_peak_after=(after.get("sensitivity") or {}).get("true_peak"), nominal=drawn,
                wall_s=dict(identify=t1 - t0, tune=t2 - t1, verify=time.perf_counter() - t2,
                            total=time.perf_counter() - t0))
    return _write(out, case)


def _write(out: Path, case: dict) -> dict:
    """seed_dir/tune_case.json, atomically (a stopped run reuses only finished cases)."""
    from ambid.jsonable import to_jsonable

    case = to_jsonable(case)
    tmp = out / "tune_case.json.tmp"
    tmp.write_text(json.dumps(case, indent=1))
    tmp.replace(out / "tune_case.json")
    return case
