"""ambid validate: how often every interval ambid prints covers the truth, over many seeds.

Runs ``ambid identify``'s session (the same graph, design and offline
identification, the report left out) once per seed; the seed sets the sensor
noise and the multisine's random phases. Each seed's update starts from a
nominal rig drawn from the tolerances around the simulated one, as a data
sheet misses a real rig (:func:`ambid.validation.coverage.draw_nominal_rig`;
``seed_NNN/nominal_rig.yaml``, and per seed in coverage.json); the update
never sees the truth. Each seed also simulates its noise-free twin (the same
rig, controller and design without sensor noise,
:func:`ambid.validation.bla_truth.noise_free_twin`). Each finished seed leaves
``DIR/seeds/seed_NNN/record.json`` (what it claimed beside the true rig's
values, :func:`ambid.validation.coverage.seed_record`); a later run with the same
options reuses those, so a stopped run loses only the sessions under way.
The updated parameters' intervals claim the parameters of the rig's best
linear approximation at the excitation level: validate computes them from all
seeds' twins (:func:`ambid.validation.bla_truth.bla_parameters`), moves the
magnets' slopes to each seed's own excitation
(:func:`ambid.validation.bla_truth.at_own_excitation`) and measures the coverage
against them, the rig's values at rest beside them.
Sessions run as tasks on Dask distributed (:mod:`ambid_cli.sessions_on_dask`):
a local cluster of this machine's cores, or ``--scheduler ADDRESS``. Writes
``DIR/coverage.json`` (:func:`ambid.validation.coverage.coverage_table`) and
``DIR/coverage.png``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

from ambid_cli.commands.inputs import (checked_controller, controller, output_dir, output_file, positive_float,
                                       positive_int, rig_file)
from ambid_cli.commands.tune import add_effort_options
from ambid_cli.results_page import measured_on, write_section
from ambid_cli.sessions_on_dask import add_scheduler_option, as_finished, domain_base, session_client

HELP = "measure the coverage of every printed interval over many seeds of the identify session"
PRESET_SEEDS = {"quick": 6, "full": 20}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=positive_int, default=None,
                   help="number of seeds (default: 6 for --preset quick, 20 for full)")
    p.add_argument("--preset", choices=tuple(PRESET_SEEDS), default="quick",
                   help="quick (6 seeds) or full (20 seeds); the session is identify's default either way")
    p.add_argument("--first-seed", type=int, default=1, help="first seed (default 1); seeds are consecutive")
    p.add_argument("--rig", default="", help="rig parameter YAML file (default: the built-in rig)")
    p.add_argument("--controller", type=controller, default="",
                   help="position controller: a kind or a controller file (default: the rig file's, else pid)")
    add_scheduler_option(p)
    p.add_argument("--out", type=Path, default=Path("validate"), help="output folder (default ./validate)")
    p.add_argument("--linear-magnets", action="store_true",
                   help="linearised magnets instead of eq. 2.14 (separates the magnets' nonlinearity from the rest)")
    p.add_argument("--no-figure", action="store_true", help="skip coverage.png")
    p.add_argument("--tune", action="store_true",
                   help="measure ambid tune's predicted peak instead: each seed commissions (identify, tune, "
                        "identify again with the tuned controller) and its measured peak is checked against the "
                        "prediction's 95 %% interval")
    p.add_argument("--resolution", type=positive_float, default=None,
                   help="the sessions' frequency resolution [Hz] (default identify's)")
    p.add_argument("--periods", type=positive_int, default=None, help="the sessions' steady-state periods P "
                                                                        "(default identify's)")
    p.add_argument("--realisations", type=positive_int, default=None,
                   help="the sessions' random-phase realisations M (default identify's)")
    add_effort_options(p, "tune-", "with --tune: ")
    p.add_argument("--results", metavar="FILE",
                   help="write the coverage table as the validate section of a results page, e.g. docs/results.md")


def run_fingerprint(rig_path: str, linear_magnets: bool, controller_spec: str = "", terms: str = "") -> str:
    """What a reused seed must share with this run: the rig file's content, the magnet law, the controller
    (its name and, for a file, its content), the experiment's and tuning's terms and the git commit."""
    h = hashlib.sha256(b"linear" if linear_magnets else b"nonlinear")
    h.update(terms.encode())
    h.update(_code_version().encode())
    if rig_path:
        h.update(Path(rig_path).read_bytes())
    if controller_spec:
        h.update(controller_spec.encode())
        if Path(controller_spec).is_file():
            h.update(Path(controller_spec).read_bytes())
    return h.hexdigest()[:16]


def _code_version() -> str:
    """The git commit of this checkout (a seed from other code is not reused), or '' outside git."""
    import subprocess

    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                              text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def run_seed(seed: int, rig_path: str, seed_dir: str, fingerprint: str, linear_magnets: bool = False,
             controller_spec: str = "", spec_terms: dict | None = None) -> dict:
    """One identify session and its record; writes seed_dir/record.json last (atomically)."""
    import numpy as np

    from ambid.excitation.spec import DesignSpec
    from ambid.fit.model_update import total_lag
    from ambid.identification.pipeline import identify_session
    from ambid.identification.update import refit_parameters
    from ambid.plant.rig import load_rig, rig_or_default
    from ambid.validation.bla_truth import noise_free_twin
    from ambid.validation.coverage import frf_record, seed_nominal_rig, seed_record

    from ambid_nodes.running.plan import SessionConfig, plan_session
    from ambid_nodes.running.run import run_session

    t0 = time.perf_counter()
    out = Path(seed_dir)
    # identify's session (the experiment's defaults) at this seed; the rig parsed once in this worker
    rig = rig_or_default(rig_path)
    nominal_path, drawn = seed_nominal_rig(rig, seed, out)
    cfg = SessionConfig(out_dir=out, experiment=DesignSpec(seed=seed, **(spec_terms or {})), rig_file=rig_path,
                        progress=False,
                        nonlinear_magnets=not linear_magnets, controller=controller_spec)
    plan = plan_session(cfg, rig)
    run = run_session(cfg, plan)
    summary = identify_session(run["mcap_path"], out, estimator=cfg.estimator, report=False, rig=nominal_path)
    frf = np.load(out / "frf.npz")
    truths = {"small-signal truth": frf["true_frf"]}
    if "true_frf_at_excitation" in frf:
        truths["truth at the excitation level"] = frf["true_frf_at_excitation"]
    # a noise-only band claims to hold the noise alone: it is checked against the noise-free twin (below)
    variances = {"total per entry (var_total, not the printed band)": frf["var_total"]}
    if "var_band" in frf:
        variances["printed band (total, pooled)"] = frf["var_band"]
    rec = seed_record(summary, frf["frf"], truths, variances)
    rec["nominal"] = drawn
    # the noise-free twin: the same seed (grid, phases, everything) without sensor noise, simulated here (what
    # the session's graph measures without noise, bit for bit). Its FRF differs from this session's by the
    # noise alone, the truth a noise-only band claims to hold; the parameters fitted to it with this session's
    # weights carry only what the excitation itself does to them (the magnets' distortion, the best linear
    # approximation's departure from the rig); the twins of all seeds give the parameters' estimand (run)
    twin = noise_free_twin(rig, plan.controller.model, plan.controller.current_limit_a, plan.design,
                           nonlinear_magnets=not linear_magnets, estimator=cfg.estimator)
    weights = frf["var_fit"] if "var_fit" in frf else frf["var_band"]
    (out / "noise_free").mkdir(exist_ok=True)
    np.savez(out / "noise_free" / "frf.npz", freq_hz=twin.freq_hz, frf=twin.frf, var_fit=weights)
    if twin.frf.shape == frf["frf"].shape and np.allclose(twin.freq_hz, frf["freq_hz"]):
        rec["frf"]["noise only vs noise-free twin"] = frf_record(frf["frf"], twin.frf,
                                                               {"noise only": frf["var_noise"]})["noise only"]
        refit = refit_parameters(summary, load_rig(nominal_path), twin.freq_hz, twin.frf, weights)
        for name, value in refit.items():
            if f"parameter:{name}" in rec["intervals"]:
                rec["intervals"][f"parameter:{name}"]["noise_free"] = value
        if "derived:total_lag_s" in rec["intervals"]:
            values = {k: v.value for k, v in summary.update.parameters.items()}
            rec["intervals"]["derived:total_lag_s"]["noise_free"] = total_lag({**values, **refit})
    rec.update(seed=seed, fingerprint=fingerprint, wall_s=time.perf_counter() - t0)
    tmp = out / "record.json.tmp"
    tmp.write_text(json.dumps(rec, indent=1))
    tmp.replace(out / "record.json")
    Path(run["mcap_path"]).unlink(missing_ok=True)   # 19 MB a seed; the record and frf.npz stay
    return rec


def reusable_record(path: Path, fingerprint: str) -> dict | None:
    """A finished seed's record.json if it holds this run's fingerprint, else None (missing, cut short, other run)."""
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("fingerprint") == fingerprint else None


def bla_estimands(seeds_dir: Path, records: dict[int, dict], rig_path: str) -> tuple[dict[int, dict], list[dict]]:
    """The BLA parameters each seed's intervals claim (:func:`ambid.validation.bla_truth.bla_parameters`): the seeds
    of one model structure (the update's parameters and free ones) share one pooled estimand, their noise-free
    twins pooled (each seed's own twin among them, one in N), and each seed's magnets' slopes moved from it by
    its own excitation (:func:`ambid.validation.bla_truth.at_own_excitation`).

    Returns:
        (seed -> estimand, [{seeds, names, free, parameters: the pooled estimand, slopes_mean: the seeds'
        mean slopes at their own excitation, per_seed: seed -> its slopes' estimand}, ...] for coverage.json).
    """
    import numpy as np

    from ambid.plant.rig import rig_or_default
    from ambid.validation.bla_truth import SLOPES, Twin, at_own_excitation, bla_parameters

    rig = rig_or_default(rig_path)
    groups: dict[tuple, list[int]] = {}
    for s, rec in sorted(records.items()):
        twin = seeds_dir / f"seed_{s:03d}" / "noise_free" / "frf.npz"
        if rec.get("model") and rec["model"]["free"] and twin.is_file():
            groups.setdefault((tuple(rec["model"]["names"]), tuple(rec["model"]["free"])), []).append(s)
    per_seed, listed = {}, []
    for (names, free), seeds in groups.items():
        twins = []
        for s in seeds:
            with np.load(seeds_dir / f"seed_{s:03d}" / "noise_free" / "frf.npz") as z:
                twins.append(Twin(z["freq_hz"], z["frf"], z["var_fit"]))
        est = bla_parameters(rig, twins, names, free)
        # each seed's grid and amplitudes set its own excitation level: the magnets' slopes at it (the
        # summary's truth for them) move its estimand from the pooled one
        own = {s: {k: float(row["true"]) for k in SLOPES
                   if (row := records[s]["intervals"].get(f"parameter:{k}")) and row.get("true") is not None}
               for s in seeds}
        pooled = {k: float(np.mean([o[k] for o in own.values()])) for k in SLOPES
                  if all(k in o for o in own.values())}
        per_seed.update({s: at_own_excitation(est, own[s], pooled) for s in seeds})
        listed.append(dict(seeds=seeds, names=list(names), free=list(free), parameters=est,
                           slopes_mean=pooled, per_seed={str(s): {k: per_seed[s][k] for k in pooled} for s in seeds}))
    return per_seed, listed


def run(args: argparse.Namespace) -> int:
    from ambid.validation.coverage import coverage_figure, coverage_table, with_bla_truth

    # a bad rig or controller file, or a controller that cannot hold the rig, stops here before any session
    checked_controller(args.controller, rig_file(args.rig))
    out = output_dir(args.out)
    if args.results:
        output_file(args.results, "--results")
    n = args.seeds or PRESET_SEEDS[args.preset]
    seeds = list(range(args.first_seed, args.first_seed + n))
    if args.tune:
        return run_tune(args, out, seeds)
    fp = run_fingerprint(args.rig, args.linear_magnets, args.controller, json.dumps(spec_terms(args)))
    (out / "seeds").mkdir(parents=True, exist_ok=True)
    records, todo = {}, []
    for s in seeds:
        rec = reusable_record(out / "seeds" / f"seed_{s:03d}" / "record.json", fp)
        if rec is not None:
            records[s] = rec
        else:
            todo.append(s)
    where = args.scheduler or f"a local Dask cluster ({args.jobs or os.cpu_count() or 1} at a time)"
    print(f"ambid validate: {n} seeds ({len(records)} reused), on {where}, out {out}", flush=True)
    t0 = time.perf_counter()
    if todo:
        base = domain_base(args)     # one ROS domain per worker
        failed = []
        items = [(s, (s, args.rig, str((out / "seeds" / f"seed_{s:03d}").resolve()), fp, args.linear_magnets,
                      args.controller, spec_terms(args))) for s in todo]
        with session_client(args.scheduler, args.jobs, len(todo)) as client:
            for s, rec, exc in as_finished(client, base, run_seed, items):
                if exc is None:
                    records[s] = rec
                    print(f"  seed {s}: done in {rec['wall_s']:.0f} s "
                          f"({len(records)}/{n}, {time.perf_counter() - t0:.0f} s)", flush=True)
                else:
                    failed.append(s)
                    print(f"  seed {s}: failed: {exc}", file=sys.stderr, flush=True)
        if failed:
            print(f"ambid validate: seeds {failed} failed; the table uses the {len(records)} others",
                  file=sys.stderr)
    if not records:
        print("ambid validate: no session finished; nothing to tabulate", file=sys.stderr)
        return 1
    # what the parameters' intervals claim: the rig's best linear approximation at this excitation level
    t_bla = time.perf_counter()
    estimands, bla_listed = bla_estimands(out / "seeds", records, args.rig)
    print(f"ambid validate: the BLA parameters from {len(estimands)} noise-free twins "
          f"({time.perf_counter() - t_bla:.0f} s)", flush=True)
    recs = [with_bla_truth(records[s], estimands[s]) if s in estimands else records[s] for s in sorted(records)]
    table = coverage_table(recs)
    result = dict(seeds=sorted(records), n_seeds=len(recs), rig=args.rig or "built-in",
                  session="ambid identify's default session, seed = noise and random phases; each seed's update "
                          "from a nominal rig drawn from the tolerances (nominal_models)",
                  wall_s=time.perf_counter() - t0, kinds=table, bla_parameters=bla_listed,
                  nominal_models={str(s): records[s].get("nominal") for s in sorted(records)})
    (out / "coverage.json").write_text(json.dumps(result, indent=1))
    if not args.no_figure:
        coverage_figure(table, out / "coverage.png")
    print(format_table(table))
    print(f"written: {out / 'coverage.json'}" + ("" if args.no_figure else f", {out / 'coverage.png'}"))
    if args.results:
        write_section(args.results, "validate", "Coverage of the printed intervals (`ambid validate`)",
                      f"{measured_on()} {len(recs)} seeds ({', '.join(map(str, sorted(records)))}) of identify's "
                      f"session on the {args.rig or 'built-in'} rig.\n\n" + coverage_markdown(table))
        print(f"results written to {args.results}")
    return 0


def spec_terms(args: argparse.Namespace) -> dict:
    """The experiment's terms the options set (DesignSpec fields; the rest identify's defaults)."""
    given = dict(resolution_hz=args.resolution, n_periods=args.periods, n_realisations=args.realisations)
    return {k: v for k, v in given.items() if v is not None}


def run_tune(args: argparse.Namespace, out: Path, seeds: list[int]) -> int:
    """``--tune``: one commissioning case per seed (:mod:`ambid_cli.tune_coverage`) on Dask, and the coverage of
    tune's predicted peak in coverage.json (:func:`ambid.validation.coverage.predicted_peak_row`)."""
    from ambid.validation.coverage import PREDICTED_PEAK, predicted_peak_row

    from ambid_cli.tune_coverage import run_tune_case

    terms = dict(n_check=args.tune_checks, n_prediction=max(args.tune_samples, 3),
                 max_evaluations=args.tune_evaluations)
    fp = run_fingerprint(args.rig, args.linear_magnets, args.controller,
                         json.dumps(dict(tune=terms, spec=spec_terms(args))))
    (out / "seeds").mkdir(parents=True, exist_ok=True)
    cases, todo = {}, []
    for s in seeds:
        rec = reusable_record(out / "seeds" / f"seed_{s:03d}" / "tune_case.json", fp)
        (todo.append(s) if rec is None else cases.__setitem__(s, rec))
    where = args.scheduler or f"a local Dask cluster ({args.jobs or os.cpu_count() or 1} at a time)"
    print(f"ambid validate --tune: {len(seeds)} commissioning cases ({len(cases)} reused), on {where}, out {out}",
          flush=True)
    t0 = time.perf_counter()
    if todo:
        items = [(s, (s, args.rig, str((out / "seeds" / f"seed_{s:03d}").resolve()), fp, args.linear_magnets,
                      args.controller, spec_terms(args), terms)) for s in todo]
        with session_client(args.scheduler, args.jobs, len(todo)) as client:
            for s, rec, exc in as_finished(client, domain_base(args), run_tune_case, items):
                if exc is None and rec.get("refused"):
                    cases[s] = rec
                    print(f"  seed {s}: tune refused ({rec['refused']}); no prediction", flush=True)
                elif exc is None:
                    cases[s] = rec
                    p = rec["predicted"]
                    print(f"  seed {s}: predicted {p['value']:.3f} ({p['ci95'][0]:.3f}..{p['ci95'][1]:.3f}), "
                          f"measured {rec['measured'] if rec['measured'] is None else round(rec['measured'], 3)}: "
                          f"{'inside' if rec['inside'] else 'OUTSIDE'} "
                          f"({rec['wall_s']['total']:.0f} s; {len(cases)}/{len(seeds)}, "
                          f"{time.perf_counter() - t0:.0f} s)", flush=True)
                else:
                    print(f"  seed {s}: failed: {exc}", file=sys.stderr, flush=True)
    row = predicted_peak_row([cases[s] for s in sorted(cases)])
    if row is None:
        print("ambid validate: no commissioning case finished; nothing to tabulate", file=sys.stderr)
        return 1
    refused = sorted(s for s in cases if cases[s].get("refused"))
    row["refused"] = refused   # cases where tune made no prediction (commission keeps the running controller)
    table = {PREDICTED_PEAK: row}
    result = dict(seeds=sorted(cases), n_seeds=len(cases), refused=refused, rig=args.rig or "built-in",
                  session="ambid commission's steps per seed: identify (seed = noise and random phases; the update "
                          "from a nominal rig drawn from the tolerances), tune on it, identify with the tuned "
                          "controller", experiment=spec_terms(args), tune=terms, wall_s=time.perf_counter() - t0,
                  kinds=table, cases={str(s): cases[s] for s in sorted(cases)})
    (out / "coverage.json").write_text(json.dumps(result, indent=1))
    print(format_table(table))
    if refused:
        print(f"tune refused {len(refused)} of {len(cases)} cases (seeds {refused}): no prediction, not counted")
    print(f"written: {out / 'coverage.json'}")
    if args.results:
        write_section(args.results, "validate_tune", "Coverage of tune's predicted peak (`ambid validate --tune`)",
                      f"{measured_on()} {len(cases)} commissioning cases (seeds "
                      f"{', '.join(map(str, sorted(cases)))}) on the {args.rig or 'built-in'} rig.\n\n"
                      + coverage_markdown(table))
        print(f"results written to {args.results}")
    return 0


def _at_rest(r: dict) -> tuple[str, str]:
    """('coverage, std ratio' against the rig at rest, the BLA's shift from it in claimed std), or blanks."""
    a = r.get("at_rest")
    if not a:
        return "", ""
    shift = a.get("shift_over_std")
    return f"{a['coverage']:.3f}, {a['std_ratio']:.2f}", "" if shift is None else f"{shift:+.2f}"


def coverage_markdown(table: dict) -> str:
    """The coverage table in markdown: per interval its nominal level, coverage and binomial interval, the
    empirical / claimed std, and for the updated parameters the same against the rig at rest beside the
    shift of what they claim (the best linear approximation's parameter) from it."""
    rows = ["| interval | nominal | coverage | 95 % binomial | n | empirical / claimed std | at rest: coverage, "
            "std ratio | BLA - at rest [claimed std] |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for k, r in table.items():
        if r.get("coverage") is not None:
            rest, shift = _at_rest(r)
            rows.append(f"| {k}{' (noise only)' if r.get('noise_only') else ''} | {r['nominal']:.3f} | "
                        f"{r['coverage']:.3f} | {r['ci95'][0]:.3f}..{r['ci95'][1]:.3f} | {r['n']} | "
                        f"{r['std_ratio']:.2f} | {rest} | {shift} |")
    return "\n".join(rows)


def format_table(table: dict) -> str:
    lines = [f"{'interval':62s} {'nominal':>7s} {'coverage':>8s} {'95 % binomial':>15s} {'n':>6s} "
             f"{'emp/claimed std':>15s} {'rms |e|/sigma':>13s} {'at rest: cov, ratio':>19s} {'shift':>6s}"]
    for k, r in table.items():
        if r.get("coverage") is None:
            continue
        z = f"{r['z_rms']:13.2f}" if r.get("z_rms") is not None else f"{'':13s}"
        rest, shift = _at_rest(r)
        lines.append(f"{k:62s} {r['nominal']:7.3f} {r['coverage']:8.3f} "
                     f"{r['ci95'][0]:7.3f}..{r['ci95'][1]:5.3f} {r['n']:6d} {r['std_ratio']:15.2f} {z} "
                     f"{rest:>19s} {shift:>6s}" + ("  (noise only)" if r.get("noise_only") else ""))
    return "\n".join(lines)
