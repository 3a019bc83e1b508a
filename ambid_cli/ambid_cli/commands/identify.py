"""ambid identify: the main job. Runs the graph on the simulated rig with a broadband experiment,
records it, then fits, updates the model and writes summary.json and the report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ambid.control.kinds import describe_kinds

from ambid_cli.commands.inputs import (BadInput, add_experiment_options, add_link_options, add_live_options,
                                        add_run_options, add_session_options, address, check_amplifier,
                                        checked_controller, controller, count, experiment_spec, free_port, hardware_link, no_controller_on_hardware,
                                        output_dir, rig_file)
from ambid_cli.commands.session_report import (death_line, kept_out_line, levitation_lines, live_line,
                                                print_foreign, session_of, session_words)
from ambid_nodes.running.domain import DEFAULT_NAMESPACE

if TYPE_CHECKING:
    from ambid_nodes.running.identify import IdentifyResult

HELP = "identify the simulated rig end to end (graph, experiment, recording, FRF, fit, report)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("identify"), help="output folder (default ./identify)")
    add_session_options(p)
    add_experiment_options(p)  # the experiment's terms; with none given, what 'ambid design' previews
    p.add_argument("--rig", default="", help="rig parameter YAML file (default: the built-in rig)")
    p.add_argument("--controller", type=controller, default="",
                   help=f"position controller: {describe_kinds()}, or a controller file (.npz, .mat, .yaml) "
                        "(default: the rig file's controller, else pid)")
    p.add_argument("--linear-magnets", action="store_true", help="linearised magnets instead of eq. 2.14")
    p.add_argument("--noise-seed", type=count, default=None,
                   help="seed of the simulated sensor noise alone (default: --seed's); a verifying run repeats the "
                        "experiment with fresh noise, as a real rig meets")
    p.add_argument("--estimator", default="indirect",
                   choices=["indirect", "h1", "h2", "arithmetic_mean", "log_mean", "eiv"])
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-report", action="store_true",
                   help="no HTML report: the results, summary.json and the model files only")
    p.add_argument("--hardware", metavar="HOST:PORT", type=address,
                   help="identify a real-time target over the UDP bridge instead of the simulated rig (the target "
                        "runs plant and controller, e.g. the C reference target; see docs/bridge_protocol.md)")
    p.add_argument("--local-port", type=count, default=0, help="with --hardware: local UDP port (default: any)")
    add_link_options(p)
    p.add_argument("--processes", action="store_true",
                   help="run each node as its own process, supervised: a node's death ends the run with one line "
                        "naming it and the sample (docs/sessions.md)")
    add_run_options(p, DEFAULT_NAMESPACE)
    p.add_argument("--true-model", default="", metavar="FILE",
                   help="with --hardware: the model file the C reference target runs ('ambid target-model'); "
                        "the FRF error and modes are compared with it")
    add_live_options(p)


def run(args: argparse.Namespace, wall_from_s: float = 0.0) -> int:
    """``ambid identify``; ``wall_from_s``: where a step of a longer command (commission) starts on the command's
    clock (heartbeat's elapsed seconds), so the step's wall times are its own, not the command's so far."""
    from ambid_cli.heartbeat import current

    phases = current()
    from ambid_nodes.running.domain import session_domain_id
    from ambid_nodes.running.identify import run_identify
    from ambid_nodes.running.plan import NodeDied, SessionConfig, plan_session

    spec = experiment_spec(args)
    output_dir(args.out)
    no_controller_on_hardware(args)
    # the run's decisions, each made once, here, and handed to the nodes: a bad rig file, an unknown or
    # unstable controller or an experiment that cannot be designed stops here, before any node starts
    rig = rig_file(args.rig)
    ctrl = None if args.hardware else checked_controller(args.controller, rig)
    if args.hardware and args.noise_seed is not None:
        raise BadInput("--noise-seed with --hardware: a real rig's sensor noise has no seed; leave --noise-seed out")
    if args.true_model:
        if not args.hardware:
            raise BadInput("--true-model needs --hardware: a simulated session is compared with its own true rig")
        from ambid.hardware.target_model import read_target_model

        try:
            read_target_model(args.true_model)
        except (OSError, ValueError, IndexError) as exc:
            raise BadInput(f"--true-model {exc}; give the file 'ambid target-model' wrote") from None
    link = hardware_link(args)  # a missing or bad key file stops here
    if args.live is not None:
        free_port(args.live_host, args.live)
    session = session_of(args)
    cfg = SessionConfig(out_dir=args.out, experiment=spec, rig_file=args.rig, controller=args.controller,
                        nonlinear_magnets=not args.linear_magnets, estimator=args.estimator,
                        noise_seed=args.noise_seed,
                        hardware=args.hardware or "", local_port=args.local_port, true_model=args.true_model, **link,
                        progress=not args.no_progress and sys.stderr.isatty(), namespace=args.namespace,
                        session=session, processes=args.processes, live_port=args.live, live_host=args.live_host,
                        report=not args.no_report and "background")   # the headline is the answer; the figures follow
    phases.say("planning the run: rig, controller, experiment design", line=False)  # a line once it holds
    try:
        plan = plan_session(cfg, rig, ctrl)  # the design, made once
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    from ambid.excitation.experiment import WORKING_CURRENT_A

    # the generator's refusal, now; and an excitation the amplifier's voltage cannot follow
    check_amplifier(plan.design, float(plan.rig.current_limit_a), WORKING_CURRENT_A, None if args.hardware else plan.rig)
    layout = "separate processes" if args.processes else "one process"
    print(f"ambid identify: {session_words(session)}, {layout}, namespace {args.namespace}, ROS_DOMAIN_ID "
          f"{session_domain_id()}", file=sys.stderr, flush=True)
    phases.say("starting the graph and waiting for every reader; the rotor lifts off, then the experiment runs")
    started = phases.elapsed() - wall_from_s

    def headline(summary: IdentifyResult) -> None:   # printed as soon as the results are there; the report follows
        kept_out = kept_out_line("identify", summary.session.foreign_messages)
        if kept_out:
            print(kept_out, file=sys.stderr, flush=True)
        print(format_headlines(summary, args.out, (started, phases.elapsed() - wall_from_s), not args.no_report),
              flush=True)

    try:  # the foreign publishers named before anything starts
        summary = run_identify(cfg, plan, lambda found: print_foreign("identify", found), on_headline=headline,
                               on_phase=phases.say)
    except KeyboardInterrupt:
        print("ambid identify: interrupted; the recording so far is in", args.out / "session.mcap", file=sys.stderr)
        return 130
    except NodeDied as died:  # one line naming the node and the sample; what is kept, true up to there
        print(death_line("identify", died.death), file=sys.stderr)
        recover = "" if died.complete else f"; read it with 'ambid inspect --recover {died.mcap_path}'"
        print(f"ambid identify: the recording so far is in {died.mcap_path} ({died.messages} messages"
              f"{', incomplete' if not died.complete else ''}){recover}", file=sys.stderr)
        print(levitation_lines(died.figures), file=sys.stderr)
        return 2
    except (ValueError, RuntimeError) as exc:
        print(f"ambid identify: {exc}", file=sys.stderr)
        return 1
    if summary.live:
        print("  " + live_line(summary.live))
    report = args.out / "report"
    print(f"ambid identify: {phases.elapsed() - wall_from_s:.1f} s wall in all"
          + ("; no report (--no-report)" if args.no_report else
          f"; the report is being written by a process of its own, {report / 'index.html'} in a few seconds "
          f"({report / 'status.json'} says when)"), file=sys.stderr)
    return 0 if summary.state == "done" else 1


def format_headlines(s: IdentifyResult, out: Path, wall: tuple[float, float], report: bool = True) -> str:
    """The headline lines; ``wall`` (seconds from the command's start to the session's start and to now)
    splits the whole wall time into set-up, the session and the analysis; ``report``: one follows."""
    ident = s.identification
    before, total = wall
    lines = [f"ambid identify: done in {total:.1f} s wall: {before:.1f} s set-up and design, {s.wall_time_s:.1f} s "
             f"the session ({s.simulated_time_s:.2f} s simulated, {s.simulated_samples_per_wall_s:.0f} samples/s, "
             f"{s.layout}), {max(total - before - s.wall_time_s, 0.0):.1f} s closing and analysis"]
    ctrl = ident.controller
    if ctrl:
        what = (ctrl.get("parameters") or {}).get("file", "") if ctrl["kind"] == "file" else ""
        lines.append(f"  controller: {ctrl['kind']}{' ' + what if what else ''} ({ctrl['n_states']} states)")
    err = ident.frf_error
    if err:
        lines.append(f"  FRF error vs the true rig: median {100 * err.median:.2f} %, worst excited line "
                     f"{100 * err.worst:.2f} % (at {err.worst_at_hz:.0f} Hz)")
    fit = ident.fit
    modes = ", ".join(f"{m.freq_hz:.1f} Hz (zeta {m.damping:.4f}"
                      + (f", {m.whirl}" if m.whirl and m.whirl != "standing" else "") + ")"
                      for m in fit.modes[:5])
    lines.append(f"  fitted model: order {fit.order}, modes {modes}")
    upd = (ident.update.parameters if ident.update is not None else None) or {}
    for name in ("ki_n_per_a", "ks_n_per_m"):
        if name in upd:
            p = upd[name]
            lines.append(f"  updated {name}: {p.value:.5g} {p.unit} (95 % CI {p.ci95[0]:.5g}..{p.ci95[1]:.5g})"
                         + (f", true {p.true:.5g}" if p.true is not None else "")
                         + (f" at this excitation ({p.true_small_signal:.5g} at rest)"
                            if p.true_small_signal is not None else ""))
    sync = ident.synchronous
    if sync and sync.harmonics:
        h1 = sync.harmonics[0]
        moved = len((ident.excitation.synchronous or {}).get("moved") or [])
        lines.append(f"  at speed: {moved} excited line(s) moved off k x {h1.freq_hz:.1f} Hz; synchronous 1X "
                     f"response {max(h1.amplitude[:len(ident.outputs)]) * 1e6:.2f} um (largest output), kept out "
                     "of the FRF")
    from ambid.frf.sensitivity import sensitivity_lines

    lines += [f"  {ln}" for ln in sensitivity_lines(ident.sensitivity)]
    lines += [f"  data quality: {q['text']}" for q in ident.quality.findings]
    if "headline_after_last_period_s" in s.analysis_timing:
        lines.append(f"  results {s.analysis_timing['headline_after_last_period_s']:.1f} s after the last period"
                     + ("; the report follows" if report else ""))
    lines += [f"  summary: {out / 'summary.json'}"] + ([f"  report:  {out / 'report' / 'index.html'}"] if report else [])
    lines += [f"  session: {s.recording.path} ({s.recording.messages} messages)"]
    return "\n".join(lines)
