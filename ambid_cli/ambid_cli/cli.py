"""The ``ambid`` command line (called by launch_scripts/ambid after set-up).

Each subcommand is a module of ``ambid_cli.commands`` with ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; it is imported only when
it runs, so ``ambid design`` never loads rclpy, and ``ambid --help`` reads
each module's ``HELP`` from its source without importing it.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import importlib
import os
import signal
import sys
from pathlib import Path

from ambid_cli import heartbeat

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
    "commission": "commission",
}
# what launch_scripts/ambid answers itself, before Python runs
SCRIPT_COMMANDS = {
    "setup": "create the environment (venv, ROS 2 wheels, colcon build, compiled kernels); a no-op when it is ready",
    "test": "run the test suite (pytest; extra arguments go to pytest)",
}


def command_help(module: str) -> str:
    """The ``HELP`` string of ``ambid_cli.commands.<module>``, read from its source (nothing imported)."""
    path = Path(__file__).resolve().parent / "commands" / f"{module}.py"
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return ""
    for node in tree.body:
        if (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "HELP" for t in node.targets)
                and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)):
            return node.value.value
    return ""


def overview() -> str:
    """``ambid --help``: every command with one line each."""
    rows = [(cmd, command_help(module)) for cmd, module in COMMANDS.items()]
    rows += list(SCRIPT_COMMANDS.items())
    w = max(len(cmd) for cmd, _ in rows)
    lines = ["usage: ambid COMMAND [options]   (ambid COMMAND --help: that command's options)", "",
             "system identification of AMB rotor systems on ROS 2", "", "commands:"]
    lines += [f"  {cmd:<{w}}  {text}" for cmd, text in rows]
    return "\n".join(lines)


def did_you_mean(word: str, choices) -> str:
    """'; did you mean X?' for the closest of ``choices`` to ``word``, else ''."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"; did you mean '{close[0]}'?" if close else ""


def _unknown_options(parser: argparse.ArgumentParser, command: str, extras: list[str]) -> str:
    """One line naming the first argument ``parser`` did not take, with the closest option it has."""
    options = [s for action in parser._actions for s in action.option_strings]  # noqa: SLF001 - argparse has no API
    word = next((e for e in extras if e.startswith("-")), extras[0])
    name = word.split("=", 1)[0]
    if not name.startswith("-"):
        return f"ambid {command}: unexpected argument '{word}'; 'ambid {command} --help' lists what it takes"
    return (f"ambid {command}: unknown option '{name}'{did_you_mean(name, options)} "
            f"('ambid {command} --help' lists the options)")


def main(argv: list[str] | None = None) -> int:
    # ^C (SIGINT) stops a run even when a script started it in the background, where the shell makes its
    # children ignore SIGINT and Python would inherit that: every command's runs end cleanly on it
    signal.signal(signal.SIGINT, signal.default_int_handler)
    argv = sys.argv[1:] if argv is None else argv
    name = argv[0] if argv else None
    if name in (None, "-h", "--help", "help"):
        print(overview())
        return 0
    if name not in COMMANDS:
        what = "option" if name.startswith("-") else "command"
        print(f"ambid: unknown {what} '{name}'{did_you_mean(name, [*COMMANDS, *SCRIPT_COMMANDS])} "
              "('ambid --help' lists the commands)", file=sys.stderr)
        return 2
    # the command's start as the launcher took it (its set-up check included), not handed on to children
    heartbeat.mark_start(os.environ.pop("AMBID_T0", ""))
    with heartbeat.Phases(name) as phases:   # on a terminal: no silence over ~2 s, loading included
        phases.say(f"loading ambid {name}", line=False)
        return _run(argv, name)


def _run(argv: list[str], name: str) -> int:
    parser = argparse.ArgumentParser(prog="ambid", description="system identification of AMB rotor systems on ROS 2")
    sub = parser.add_subparsers(dest="command", required=True)
    mod = importlib.import_module(f"ambid_cli.commands.{COMMANDS[name]}")
    p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
    mod.add_arguments(p)
    p.set_defaults(func=mod.run)
    args, extras = parser.parse_known_args(argv)  # a bad option value: argparse's usage and one line, exit code 2
    if extras:
        print(_unknown_options(p, name, extras), file=sys.stderr)
        return 2
    heartbeat.current().quiet()   # loaded: from here the command says its own phases, if it has any
    from ambid_cli.commands.inputs import BadInput

    try:
        return args.func(args)
    except BadInput as exc:
        print(f"ambid {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ambid {args.command}: interrupted", file=sys.stderr)
        return 130


#: commands whose interpreter teardown is skipped once they have answered: a session's ROS graph leaves DDS
#: participants whose C++ destructors held the prompt back 0.3-2 s after the last line (measured under load);
#: everything such a command writes is closed before it returns, its processes stopped or detached
EXIT_AT_ONCE = ("identify",)


if __name__ == "__main__":
    code = main()
    if sys.argv[1:2] and sys.argv[1] in EXIT_AT_ONCE:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code if isinstance(code, int) else 1)
    sys.exit(code)
