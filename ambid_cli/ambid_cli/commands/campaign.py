"""ambid campaign: one identification session per rotor speed, then a measured Campbell diagram.

For each speed the rig (``--rig``, default the built-in one) runs at that speed, with its unbalance and
runout, and ``identify`` runs on it with a multisine steered clear of the synchronous harmonics; each
speed gets its own folder ``DIR/rpm_NNNNN/`` (session.mcap, summary.json, report/). A campaign that
stops half way continues where it stopped: a speed whose summary.json is there and done is not run
again (the settings must be the same; ``DIR/campaign.json`` keeps them). The speeds' sessions run as tasks
on Dask distributed (:mod:`ambid_cli.sessions_on_dask`: a local cluster of this machine's cores, or
``--scheduler ADDRESS``), each on its own ROS domain. At the end ``DIR/campbell.json``
(:mod:`ambid.identification.campbell`) and ``DIR/report/`` (campbell.png, index.html).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HELP = "identify at several rotor speeds (one session each, resumable) and draw the measured Campbell diagram"

from ambid.plant.rig import make_rig

from ambid_cli.commands.inputs import (BadInput, add_session_options, checked_controller, controller,
                                         experiment_spec, output_dir, rig_file)
from ambid_cli.sessions_on_dask import add_scheduler_option, as_finished, domain_base, session_client

_FORMAT = "ambid.campaign/1"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speeds-rpm", type=float, nargs="+", required=True, metavar="RPM",
                   help="rotor speeds [rpm], e.g. 0 3000 6000 9000 12000")
    p.add_argument("--out", required=True, help="campaign folder (created; an existing campaign there continues)")
    p.add_argument("--rig", default="", help="rig parameter YAML file (default: the built-in rig); its speed is "
                                             "replaced by each of --speeds-rpm")
    p.add_argument("--controller", type=controller, default="",
                   help="position controller: a kind or a controller file (default: the rig file's, else pid)")
    add_session_options(p)
    add_scheduler_option(p)
    p.add_argument("--no-progress", action="store_true", help="(kept for scripts: the sessions run as tasks and "
                                                               "each speed is reported when it is done)")


def _speeds(values: list[float]) -> list[float]:
    speeds = sorted(set(float(v) for v in values))
    bad = [v for v in speeds if not (0.0 <= v <= 100_000.0)]
    if bad:
        raise BadInput(f"--speeds-rpm {bad[0]:g} is outside [0, 100000] rpm; give speeds in rpm, e.g. 0 3000 6000")
    return speeds


def _rig_at(base, rpm: float, controller_spec: str) -> tuple:
    """(the rig at ``rpm``, its controller): made and checked once per speed, before the first session starts."""
    try:
        at = make_rig({**base.to_dict(), "rotor_speed_rpm": rpm})
    except ValueError as exc:
        raise BadInput(f"the rig at {rpm:g} rpm: {exc}") from None
    return at, checked_controller(controller_spec, at)


def _settings(args: argparse.Namespace, rig) -> dict:
    """What must not change between a campaign's runs (the speeds may grow)."""
    return dict(rig=rig.to_dict(), controller=args.controller, band_hz=list(args.band_hz), resolution_hz=args.resolution_hz,
                realisations=args.n_realisations, seed=args.seed)


def _speed_dir(out: Path, rpm: float) -> Path:
    return out / (f"rpm_{rpm:05.0f}" if rpm == int(rpm) else f"rpm_{rpm:07.1f}")


def _done(folder: Path) -> dict | None:
    try:
        s = json.loads((folder / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return s if isinstance(s, dict) and s.get("state", "done") == "done" and "fit" in s else None


def _identify_speed(cfg, rig, controller) -> tuple:
    """One speed's identify session (a Dask task): its summary and wall time [s]."""
    from ambid_nodes.running.identify import run_identify
    from ambid_nodes.running.plan import plan_session

    t0 = time.perf_counter()
    summary = run_identify(cfg, plan_session(cfg, rig, controller))
    return summary, time.perf_counter() - t0


def run(args: argparse.Namespace) -> int:
    import yaml

    from ambid.identification.campbell import campbell_summary, campbell_table, write_campbell_report
    from ambid.jsonable import to_jsonable
    from ambid_nodes.running.plan import SessionConfig

    spec = experiment_spec(args)
    out = output_dir(args.out)
    speeds = _speeds(args.speeds_rpm)
    base = rig_file(args.rig)
    rigs = {rpm: _rig_at(base, rpm, args.controller) for rpm in speeds}
    settings = _settings(args, base)
    manifest = out / "campaign.json"
    if manifest.exists():
        try:
            old = json.loads(manifest.read_text())
        except (OSError, ValueError):
            raise BadInput(f"--out {out} holds a campaign.json that is not a campaign's; give another folder") from None
        if not isinstance(old, dict) or old.get("format") != _FORMAT:
            raise BadInput(f"--out {out} holds a campaign.json that is not a campaign's; give another folder")
        if old.get("settings") != to_jsonable(settings):
            raise BadInput(f"--out {out} holds a campaign with other settings (rig, controller, band, resolution, "
                           "realisations or seed); continue it with the same ones or give another folder")
        speeds = sorted(set(speeds) | set(old.get("speeds_rpm", [])))
        rigs.update((rpm, _rig_at(base, rpm, args.controller)) for rpm in speeds if rpm not in rigs)
    out.mkdir(parents=True, exist_ok=True)
    tmp = manifest.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"format": _FORMAT, "settings": to_jsonable(settings), "speeds_rpm": speeds}, indent=1))
    tmp.replace(manifest)

    t0 = time.perf_counter()
    runs, walls, pending = {}, {}, []
    n = len(speeds)
    for i, rpm in enumerate(speeds, start=1):
        folder = _speed_dir(out, rpm)
        done = _done(folder)
        if done is not None:
            print(f"ambid campaign: [{i}/{n}] {rpm:.0f} rpm: done before, kept ({folder})", file=sys.stderr)
            runs[rpm] = done
            continue
        folder.mkdir(parents=True, exist_ok=True)
        rig_path = folder / "rig.yaml"
        rig_path.write_text(yaml.safe_dump({**to_jsonable(base.to_dict()), "rotor_speed_rpm": rpm}, sort_keys=False))
        cfg = SessionConfig(out_dir=folder.resolve(), experiment=spec, rig_file=str(rig_path.resolve()),
                            controller=args.controller, progress=False)
        pending.append((rpm, (cfg, *rigs[rpm])))
    failed = []
    if pending:
        where = args.scheduler or "a local Dask cluster"
        print(f"ambid campaign: identifying at {len(pending)} speed(s) on {where} ...", file=sys.stderr)
        base_id = domain_base(args)     # one ROS domain per worker
        try:
            with session_client(args.scheduler, args.jobs, len(pending)) as client:
                for rpm, result, exc in as_finished(client, base_id, _identify_speed, pending):
                    if exc is not None:
                        failed.append(rpm)
                        print(f"ambid campaign: {rpm:.0f} rpm failed: {exc}", file=sys.stderr)
                        continue
                    summary, walls[rpm] = result
                    if summary.state != "done":
                        failed.append(rpm)
                        print(f"ambid campaign: {rpm:.0f} rpm did not finish ({summary.state}); see "
                              f"{_speed_dir(out, rpm)}", file=sys.stderr)
                        continue
                    fb = [m for m in summary.identification.fit.modes if m.whirl]
                    print(f"ambid campaign: {rpm:.0f} rpm done in {walls[rpm]:.1f} s; modes "
                          + ", ".join(f"{m.freq_hz:.1f} Hz {m.whirl[0]}" for m in fb[:8]), file=sys.stderr)
                    runs[rpm] = summary
        except KeyboardInterrupt:
            print("ambid campaign: interrupted; run the same command again to continue (finished speeds are kept)",
                  file=sys.stderr)
            return 130
    if failed:
        print(f"ambid campaign: {', '.join(f'{r:.0f}' for r in sorted(failed))} rpm failed; run the same command "
              "again to retry them (finished speeds are kept)", file=sys.stderr)
        return 1
    runs = [(rpm, runs[rpm]) for rpm in speeds]

    camp = campbell_summary(base, runs, tuple(args.band_hz))
    camp["wall_time_s"] = time.perf_counter() - t0
    camp["session_wall_time_s"] = {f"{k:.0f}": v for k, v in walls.items()}
    tmp = out / "campbell.json.tmp"
    tmp.write_text(json.dumps(to_jsonable(camp), indent=1))
    tmp.replace(out / "campbell.json")
    index = write_campbell_report(camp, out / "report")
    print(campbell_table(camp))
    err = camp["first_bending_max_error"]
    crit = ", ".join(f"{c['label']} {c['speed_rpm']:.0f} rpm" for c in camp["critical_speeds"]) or "none in range"
    cov = camp.get("first_bending_ci_covered")
    held = "" if not cov else f"; its 95 % intervals hold the true frequency {cov[0]} of {cov[1]} times"
    print(f"first bending mode: worst error vs true {'-' if err is None else f'{100 * err:.3f} %'}, whirl "
          f"{'right' if camp['first_bending_whirl_right'] else 'WRONG'} at every speed{held}" if err is not None
          else "first bending mode: no true rig to compare with")
    print(f"critical speeds (analytical model): {crit}")
    print(f"campaign: {n} speed{'s' if n != 1 else ''}, {camp['wall_time_s']:.1f} s wall ({len(walls)} run now)")
    print(f"campbell: {out / 'campbell.json'}\nreport:   {index}")
    return 0
