"""The ``ambid`` command line (called by launch_scripts/ambid after set-up).

Each subcommand is a module of ``ambid_nodes.commands`` with ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; it is imported only when
it runs, so ``ambid design`` never loads rclpy.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# subcommand -> module in ambid_nodes.commands, or a note for what is still to come
COMMANDS = {
    "graph": "graph",
    "identify": "identify",
    "node": "node",
    "design": "design",
    "inspect": "inspect",
    "fit": "fit",
    "compare": "compare",
    "bench": "bench",
}
PLANNED = {
    "identify": "the end-to-end identification session",
    "design": "previewing an excitation design",
    "inspect": "inspecting a recorded MCAP session",
    "fit": "fitting a recorded session",
    "compare": "comparing excitations and estimators",
    "bench": "the benchmark",
    "node": "starting a single node",
}


def not_yet(name: str, what: str) -> int:
    print(f"ambid {name}: {what} is not available yet in this version; 'ambid graph' and 'ambid test' are.",
          file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog="ambid", description="system identification of AMB rotor systems on ROS 2")
    sub = parser.add_subparsers(dest="command", required=True)
    name = argv[0] if argv else None
    for cmd, module in COMMANDS.items():
        if cmd == name:
            mod = importlib.import_module(f"ambid_nodes.commands.{module}")
            p = sub.add_parser(cmd, help=mod.HELP)
            mod.add_arguments(p)
            p.set_defaults(func=mod.run)
        else:
            sub.add_parser(cmd)
    for cmd, what in PLANNED.items():
        if cmd not in COMMANDS:
            s = sub.add_parser(cmd, help=f"{what} (not available yet)")
            s.add_argument("rest", nargs=argparse.REMAINDER)
            s.set_defaults(func=lambda a, what=what, cmd=cmd: not_yet(cmd, what))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
