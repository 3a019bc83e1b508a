"""ambid live PORT: show the session running on this ROS domain live in Foxglove (docs/live.md)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ambid_cli.commands.inputs import BadInput, free_port, output_file, port_number, rig_file, session_id

HELP = "show the session running on this ROS domain live in Foxglove: a WebSocket server on PORT"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("port", type=port_number, nargs="?", help="TCP port of the Foxglove WebSocket server (0: any)")
    p.add_argument("--live-host", default="127.0.0.1", metavar="HOST",
                   help="address to bind (default 127.0.0.1: this machine only; 0.0.0.0: every interface)")
    p.add_argument("--namespace", default="/amb", help="ROS namespace of the session (default /amb)")
    p.add_argument("--session", type=session_id, default=0, metavar="ID",
                   help="show only this session (its id as identify and graph print it); other sources on the "
                        "same topics are counted, not shown (default: every source)")
    p.add_argument("--estimator", default="indirect",
                   choices=["indirect", "h1", "h2", "arithmetic_mean", "log_mean", "eiv"],
                   help="the session's FRF estimator, for the live FRF (default indirect)")
    p.add_argument("--layout", metavar="FILE",
                   help="write the Foxglove layout (Bode, orbit and status panels) for the channels of --rig to "
                        "FILE and exit")
    p.add_argument("--rig", default="", help="with --layout: the rig whose axes the layout shows (default: built-in)")


def run(args: argparse.Namespace) -> int:
    if args.layout:
        from ambid.channels import RADIAL
        from ambid.live.layout import foxglove_layout

        out = output_file(args.layout, "--layout")
        axes = getattr(rig_file(args.rig), "layout", RADIAL)   # a rig's own axes where it names them
        out.write_text(json.dumps(foxglove_layout(axes, args.namespace.rstrip("/") + "/live"), indent=1) + "\n")
        print(f"ambid live: layout for axes {' '.join(axes.axes)} written to {out}; in Foxglove: "
              "Layouts, Import from file")
        return 0
    if args.port is None:
        raise BadInput("give the PORT to serve on (e.g. 'ambid live 8765'), or --layout FILE")
    free_port(args.live_host, args.port, "PORT")
    from ambid_nodes.running.domain import session_domain_id
    from ambid_nodes.supervisor import ros_args

    print(f"ambid live: the session in namespace {args.namespace} on ROS_DOMAIN_ID {session_domain_id()}; in "
          f"Foxglove open a connection to ws://{args.live_host}:{args.port} and import the layout "
          f"{Path('docs') / 'foxglove_layout.json'} (Ctrl-C stops)", file=sys.stderr, flush=True)
    params = {"port": args.port, "host": args.live_host, "estimator": args.estimator, "session": args.session}
    os.environ["ROS_DOMAIN_ID"] = str(session_domain_id())
    # replace this process: Ctrl-C goes straight to the node, which prints its figures as it ends
    os.execv(sys.executable, [sys.executable, "-m", "ambid_nodes.live_view", *ros_args(args.namespace, params)])
    return 0  # not reached
