"""The ``ambid`` command line (called by launch_scripts/ambid after set-up).

Each subcommand is a module of ``ambid_cli.commands`` with ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; it is imported only when
it runs, so ``ambid design`` never loads rclpy.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys

# subcommand -> module in ambid_cli.commands
COMMANDS = {
    "graph": "graph",
    "identify": "identify",
    "node": "node",
    "design": "design",
    "inspect": "inspect",
    "fit": "fit",
    "compare": "compare",
    "bench": "bench",
    "target-model": "target_model",
    "keygen": "keygen",
    "import": "import_record",
    "export": "export_record",
    "campaign": "campaign",
    "validate": "validate",
    "live": "live",
    "tune": "tune",
}


def main(argv: list[str] | None = None) -> int:
    # ^C (SIGINT) stops a run even when a script started it in the background, where the shell makes its
    # children ignore SIGINT and Python would inherit that: every command's runs end cleanly on it
    signal.signal(signal.SIGINT, signal.default_int_handler)
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog="ambid", description="system identification of AMB rotor systems on ROS 2")
    sub = parser.add_subparsers(dest="command", required=True)
    name = argv[0] if argv else None
    for cmd, module in COMMANDS.items():
        if cmd == name:
            mod = importlib.import_module(f"ambid_cli.commands.{module}")
            p = sub.add_parser(cmd, help=mod.HELP)
            mod.add_arguments(p)
            p.set_defaults(func=mod.run)
        else:
            sub.add_parser(cmd)
    args = parser.parse_args(argv)  # a bad option value: argparse's usage and one line, exit code 2
    from ambid_cli.commands.inputs import BadInput

    try:
        return args.func(args)
    except BadInput as exc:
        print(f"ambid {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ambid {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
