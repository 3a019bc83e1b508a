"""ambid graph: run the plant and controller graph on the simulated rig."""

from __future__ import annotations

import argparse
import sys

from ambid.control.kinds import describe_kinds
from ambid_cli.commands.inputs import (add_link_options, add_live_options, add_run_options, address,
                                       checked_controller, controller, count, free_port, hardware_link,
                                       no_controller_on_hardware, positive_float, rig_file)
from ambid_cli.commands.session_report import (death_line, levitation_lines, live_line, print_foreign, session_of,
                                                session_words)

from ambid_nodes.running.domain import DEFAULT_NAMESPACE, session_domain_id

HELP = "run the plant and controller graph on the simulated rig"


def add_arguments(g: argparse.ArgumentParser) -> None:
    g.add_argument("--sim-seconds", type=positive_float, default=2.0, help="simulated time [s] (default 2)")
    g.add_argument("--processes", action="store_true", help="run each node as its own process")
    g.add_argument("--seed", type=int, default=0, help="seed of the simulated noise")
    g.add_argument("--rig", help="rig parameter YAML file (default: the built-in rig)")
    g.add_argument("--nonlinear", action="store_true", help="nonlinear magnet force (eq. 2.14)")
    add_run_options(g, DEFAULT_NAMESPACE)
    g.add_argument("--controller", type=controller, default="",
                   help=f"position controller: {describe_kinds()}, or a controller file (.npz, .mat, .yaml) "
                        "(default: the rig file's controller, else pid)")
    g.add_argument("--hardware", metavar="HOST:PORT", type=address,
                   help="run against a real-time target over the UDP bridge instead of plant_sim "
                        "(the target runs the fast loop; see docs/bridge_protocol.md)")
    g.add_argument("--local-port", type=count, default=0, help="with --hardware: local UDP port (default: any)")
    add_link_options(g)
    add_live_options(g)


def run(args: argparse.Namespace) -> int:
    rig = rig_file(args.rig)  # a bad rig file stops here, before any node starts
    no_controller_on_hardware(args)
    hardware_link(args)  # a missing or bad key file stops here
    if args.live is None:
        return run_graph(args, rig)
    free_port(args.live_host, args.live)
    from ambid_nodes.live_view import LiveProcess

    args.session = session_of(args)   # the live view shows this session only; run_graph runs it
    live = LiveProcess(args.live, args.live_host, args.namespace, "indirect", session_domain_id(), args.session)
    try:
        try:
            url = live.wait_ready()
        except RuntimeError as exc:
            print(f"ambid graph: {exc}", file=sys.stderr)
            return 1
        print(f"ambid graph: live view on {url} (docs/live.md)", flush=True)
        return run_graph(args, rig)
    finally:
        f = live.stop()
        if f:
            print(live_line(f))


def loop_config(args: argparse.Namespace, session: int):
    """The loop alone for ``--sim-seconds`` (:class:`ambid_nodes.running.plan.SessionConfig`): the run
    identify makes, without its experiment; ``--seed`` seeds the sensor noise."""
    from ambid.excitation.spec import DesignSpec

    from ambid_nodes.running.plan import SessionConfig

    return SessionConfig(experiment=DesignSpec(seed=args.seed), rig_file=args.rig or "",
                         controller=args.controller or "", nonlinear_magnets=bool(getattr(args, "nonlinear", False)),
                         namespace=args.namespace, progress=False, session=session,
                         processes=bool(getattr(args, "processes", False)) and not args.hardware, loop_seconds=args.sim_seconds,
                         hardware=args.hardware or "", local_port=args.local_port, **hardware_link(args))


def run_loop(args: argparse.Namespace, rig, ctrl=None) -> dict:
    """Run the loop alone through its layout (:func:`ambid_nodes.running.run.run_session`); its summary.
    Composed, the nodes take this rig and controller (parsed and designed once, here); as processes each
    node reads its own parameters."""
    from ambid_nodes.running.plan import plan_session
    from ambid_nodes.running.run import run_session

    cfg = loop_config(args, args.session)
    return run_session(cfg, plan_session(cfg, rig, ctrl), lambda found: print_foreign("graph", found))


def run_graph(args: argparse.Namespace, rig) -> int:
    if args.hardware:
        return run_on_hardware(args, rig)
    ctrl = checked_controller(args.controller, rig)  # and an unknown or unstable controller
    session = args.session = session_of(args)
    layout = "separate processes" if args.processes else "one process (EventsExecutor)"
    layout += f", {ctrl.kind.upper()} controller"
    print(f"ambid graph: {session_words(session)}, plant_sim + position_controller in {layout}, axes "
          f"{' '.join(rig.layout.axes)}, namespace "
          f"{args.namespace}, ROS_DOMAIN_ID {session_domain_id()}, {args.sim_seconds:g} s simulated", flush=True)
    try:  # the foreign publishers named before anything starts
        summary = run_loop(args, rig, ctrl)
    except KeyboardInterrupt:
        print("ambid graph: interrupted; every node stopped", file=sys.stderr)
        return 130
    except (RuntimeError, ValueError) as exc:
        print(f"ambid graph: {exc}", file=sys.stderr)
        return 1
    death = summary.get("death")
    if death:  # one line naming the node and the sample; the figures below are true up to there
        print(death_line("graph", death), file=sys.stderr, flush=True)
    print(f"simulated samples per wall second: {summary['samples_per_wall_s']:.0f} "
          f"({summary['samples']} samples in {summary['wall_s']:.2f} s wall, "
          f"{summary['samples_per_wall_s'] * summary['simulated_s'] / max(summary['samples'], 1):.2f}x real time)")
    print(levitation_lines(summary))
    print(f"rejected messages: {summary['messages_rejected']}")
    if summary.get("resends"):
        print(f"lost loop messages recovered: the plant asked again {summary['resends']} times")
    if death:
        levitated = summary["levitated"]
        print(f"rotor levitated until the session ended at sample {death['sample_index']}" if levitated
              else "rotor NOT levitated")
        return 2
    ok = summary["state"] == "done" and summary["levitated"]
    print("rotor levitated" if ok else "rotor NOT levitated: the session failed")
    return 0 if ok else 1


def run_on_hardware(args: argparse.Namespace, rig) -> int:
    session = args.session = session_of(args)
    print(f"ambid graph: {session_words(session)}, hardware_bridge to the real-time target at {args.hardware}, "
          f"namespace {args.namespace}, ROS_DOMAIN_ID {session_domain_id()}, {args.sim_seconds:g} s of samples",
          flush=True)
    try:
        f = run_loop(args, rig)
    except KeyboardInterrupt:
        print("ambid graph: interrupted", file=sys.stderr)
        return 130
    except (RuntimeError, ValueError) as exc:
        print(f"ambid graph: {exc}", file=sys.stderr)
        return 1
    print(f"samples published per wall second: {f['samples_per_wall_s']:.0f} ({f['samples_published']} samples)")
    print(f"target state {f['target_state']}; lost {f['missing_samples']} samples in {f['gaps']} gaps, "
          f"{f['datagrams_malformed']} malformed and {f['datagrams_foreign']} foreign datagrams")
    print(levitation_lines(f) + f", {f['contact_samples']} samples landed")
    ok = f["samples_published"] > 0 and not f["silent"] and f["target_state"] != "safe"
    print("target running normally" if ok else "target NOT running normally")
    print("rotor levitated" if f["levitated"] else "rotor NOT levitated")
    return 0 if ok and f["levitated"] else 1
