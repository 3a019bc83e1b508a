"""ambid validate: how often every interval ambid prints covers the truth, over many seeds.

Runs ``ambid identify``'s session (the same graph, design and offline
identification, the report left out) once per seed; the seed sets the sensor
noise and the multisine's random phases. Each finished seed leaves
``DIR/seeds/seed_NNN/record.json`` (what it claimed beside the true rig's
values, :func:`ambid.studies.coverage.seed_record`); a later run with the same
options reuses those, so a stopped run loses only the sessions under way.
Sessions run in parallel, one per core (at most 2 by default). Writes
``DIR/coverage.json`` (:func:`ambid.studies.coverage.coverage_table`) and
``DIR/coverage.png``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from ambid_cli.commands.inputs import checked_controller, controller, output_dir, positive_int, rig_file

HELP = "measure the coverage of every printed interval over many seeds of the identify session"
PRESET_SEEDS = {"quick": 6, "full": 20}
_DOMAIN = None  # the worker's ROS_DOMAIN_ID slot (set by _init_worker)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=positive_int, default=None,
                   help="number of seeds (default: 6 for --preset quick, 20 for full)")
    p.add_argument("--preset", choices=tuple(PRESET_SEEDS), default="quick",
                   help="quick (6 seeds) or full (20 seeds); the session is identify's default either way")
    p.add_argument("--first-seed", type=int, default=1, help="first seed (default 1); seeds are consecutive")
    p.add_argument("--rig", default="", help="rig parameter YAML file (default: the built-in rig)")
    p.add_argument("--controller", type=controller, default="",
                   help="position controller: a kind or a controller file (default: the rig file's, else pid)")
    p.add_argument("--jobs", type=positive_int, default=None,
                   help="sessions run at once (default: the cores, at most 2)")
    p.add_argument("--out", type=Path, default=Path("validate"), help="output folder (default ./validate)")
    p.add_argument("--linear-magnets", action="store_true",
                   help="linearised magnets instead of eq. 2.14 (separates the magnets' nonlinearity from the rest)")
    p.add_argument("--no-figure", action="store_true", help="skip coverage.png")


def run_fingerprint(rig_path: str, linear_magnets: bool, controller_spec: str = "") -> str:
    """What a reused seed must share with this run: the rig file's content, the magnet law, the controller
    (its name and, for a file, its content) and the git commit."""
    h = hashlib.sha256(b"linear" if linear_magnets else b"nonlinear")
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


def _init_worker(counter, base: int) -> None:
    global _DOMAIN
    with counter.get_lock():
        slot = counter.value
        counter.value += 1
    _DOMAIN = base + slot
    os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN)   # two sessions at once must not hear each other


def run_seed(seed: int, rig_path: str, seed_dir: str, fingerprint: str, linear_magnets: bool = False,
             controller_spec: str = "") -> dict:
    """One identify session and its record; writes seed_dir/record.json last (atomically)."""
    import numpy as np

    from ambid.frf.offline import frf_from_session
    from ambid.plant.rig import load_rig, make_rig
    from ambid.studies.coverage import frf_record, seed_record
    from ambid.studies.identification import identify_session, refit_parameters

    from ambid.excitation.spec import DesignSpec

    from ambid_nodes.session import SessionConfig, plan_session, run_session_composed

    t0 = time.perf_counter()
    out = Path(seed_dir)
    # identify's session (the experiment's defaults) at this seed; the rig parsed once in this worker
    rig = load_rig(rig_path) if rig_path else make_rig()
    cfg = SessionConfig(out_dir=out, experiment=DesignSpec(seed=seed), rig_file=rig_path, progress=False,
                        nonlinear_magnets=not linear_magnets, controller=controller_spec)
    run = run_session_composed(cfg, plan_session(cfg, rig))
    summary = identify_session(run["mcap_path"], out, estimator=cfg.estimator, report=False)
    frf = np.load(out / "frf.npz")
    truths = {"small-signal truth": frf["true_frf"]}
    if "true_frf_at_excitation" in frf:
        truths["truth at the excitation level"] = frf["true_frf_at_excitation"]
    # a noise-only band claims to hold the noise alone: it is checked against the noise-free twin (below)
    variances = {"total per entry (var_total, not the printed band)": frf["var_total"]}
    if "var_band" in frf:
        variances["printed band (total, pooled)"] = frf["var_band"]
    rec = seed_record(summary, frf["frf"], truths, variances)
    # the noise-free twin: the same seed (grid, phases, everything) without sensor noise. Its FRF differs
    # from this session's by the noise alone, the truth a noise-only band claims to hold; the parameters
    # fitted to it with this session's weights carry only what the excitation itself does to them (the
    # magnets' distortion, the best linear approximation's departure from the rig)
    twin_cfg = SessionConfig(out_dir=out / "noise_free", experiment=cfg.experiment, progress=False,
                             rig_file=noise_free_rig_file(rig_path, out / "noise_free_rig.yaml"),
                             nonlinear_magnets=not linear_magnets, controller=controller_spec)
    twin_run = run_session_composed(twin_cfg)
    twin = frf_from_session(twin_run["mcap_path"])
    np.savez(out / "noise_free" / "frf.npz", freq_hz=twin.freq_hz, frf=twin.frf)
    if twin.frf.shape == frf["frf"].shape and np.allclose(twin.freq_hz, frf["freq_hz"]):
        rec["frf"]["noise only vs noise-free twin"] = frf_record(frf["frf"], twin.frf,
                                                               {"noise only": frf["var_noise"]})["noise only"]
        for name, value in refit_parameters(summary, rig, twin.freq_hz, twin.frf,
                                                frf["var_fit"] if "var_fit" in frf else frf["var_band"]).items():
            if f"parameter:{name}" in rec["intervals"]:
                rec["intervals"][f"parameter:{name}"]["noise_free"] = value
    Path(twin_run["mcap_path"]).unlink(missing_ok=True)
    rec.update(seed=seed, fingerprint=fingerprint, wall_s=time.perf_counter() - t0)
    tmp = out / "record.json.tmp"
    tmp.write_text(json.dumps(rec, indent=1))
    tmp.replace(out / "record.json")
    Path(run["mcap_path"]).unlink(missing_ok=True)   # 19 MB a seed; the record and frf.npz stay
    return rec


def noise_free_rig_file(rig_path: str, dest: Path) -> str:
    """The rig of ``rig_path`` (the built-in one if empty) without sensor noise, written to ``dest``."""
    import yaml

    from ambid.plant.rig import read_rig_file

    data = read_rig_file(Path(rig_path).resolve()) if rig_path else {}
    data["sensor_noise_m"] = 0.0
    dest.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(dest)


def reusable_record(path: Path, fingerprint: str) -> dict | None:
    """A finished seed's record.json if it holds this run's fingerprint, else None (missing, cut short, other run)."""
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("fingerprint") == fingerprint else None


def run(args: argparse.Namespace) -> int:
    import multiprocessing as mp

    from ambid.studies.coverage import coverage_figure, coverage_table

    # a bad rig or controller file, or a controller that cannot hold the rig, stops here before any session
    checked_controller(args.controller, rig_file(args.rig))
    out = output_dir(args.out)
    n = args.seeds or PRESET_SEEDS[args.preset]
    seeds = list(range(args.first_seed, args.first_seed + n))
    fp = run_fingerprint(args.rig, args.linear_magnets, args.controller)
    (out / "seeds").mkdir(parents=True, exist_ok=True)
    records, todo = {}, []
    for s in seeds:
        rec = reusable_record(out / "seeds" / f"seed_{s:03d}" / "record.json", fp)
        if rec is not None:
            records[s] = rec
        else:
            todo.append(s)
    jobs = args.jobs or max(1, min(2, os.cpu_count() or 1))
    print(f"ambid validate: {n} seeds ({len(records)} reused), {jobs} at a time, out {out}", flush=True)
    t0 = time.perf_counter()
    if todo:
        ctx = mp.get_context("spawn")
        # domain ids 215-230: outside the 100-199 that identify and graph derive from their pid, so that a
        # session on this machine does not hear (and reject) ours; one id per worker
        base = 215 + (os.getpid() % 8) * 2
        failed = []
        with ProcessPoolExecutor(max_workers=min(jobs, len(todo), 2), mp_context=ctx, initializer=_init_worker,
                                 initargs=(ctx.Value("i", 0), base)) as pool:
            futures = {pool.submit(run_seed, s, args.rig, str(out / "seeds" / f"seed_{s:03d}"), fp,
                                   args.linear_magnets, args.controller): s
                       for s in todo}
            for fut in as_completed(futures):
                s = futures[fut]
                try:
                    records[s] = fut.result()
                    print(f"  seed {s}: done in {records[s]['wall_s']:.0f} s "
                          f"({len(records)}/{n}, {time.perf_counter() - t0:.0f} s)", flush=True)
                except Exception as exc:  # one failed session must not lose the others
                    failed.append(s)
                    print(f"  seed {s}: failed: {exc}", file=sys.stderr, flush=True)
        if failed:
            print(f"ambid validate: seeds {failed} failed; the table uses the {len(records)} others",
                  file=sys.stderr)
    if not records:
        print("ambid validate: no session finished; nothing to tabulate", file=sys.stderr)
        return 1
    recs = [records[s] for s in sorted(records)]
    table = coverage_table(recs)
    result = dict(seeds=sorted(records), n_seeds=len(recs), rig=args.rig or "built-in",
                  session="ambid identify's default session, seed = noise and random phases",
                  kinds=table)
    (out / "coverage.json").write_text(json.dumps(result, indent=1))
    if not args.no_figure:
        coverage_figure(table, out / "coverage.png")
    print(format_table(table))
    print(f"written: {out / 'coverage.json'}" + ("" if args.no_figure else f", {out / 'coverage.png'}"))
    return 0


def format_table(table: dict) -> str:
    lines = [f"{'interval':62s} {'nominal':>7s} {'coverage':>8s} {'95 % binomial':>15s} {'n':>6s} "
             f"{'emp/claimed std':>15s} {'rms |e|/sigma':>13s}"]
    for k, r in table.items():
        if r.get("coverage") is None:
            continue
        z = f"{r['z_rms']:13.2f}" if r.get("z_rms") is not None else f"{'':13s}"
        lines.append(f"{k:62s} {r['nominal']:7.3f} {r['coverage']:8.3f} "
                     f"{r['ci95'][0]:7.3f}..{r['ci95'][1]:5.3f} {r['n']:6d} {r['std_ratio']:15.2f} {z}"
                     + ("  (noise only)" if r.get("noise_only") else ""))
    return "\n".join(lines)
