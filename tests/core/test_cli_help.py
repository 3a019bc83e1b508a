"""``ambid --help``: every command with its one line, read without importing any command module."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from ambid_cli import cli

ROOT = Path(__file__).resolve().parents[2]


def _help_in_a_fresh_interpreter(*argv: str) -> tuple[subprocess.CompletedProcess, dict]:
    code = ("import json, sys\nfrom ambid_cli.cli import main\nrc = main(%r)\n"
            "print(json.dumps({'rc': rc, 'loaded': sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numpy', 'rclpy', 'ambid', 'ambid_nodes') or m.startswith('ambid_cli.commands'))}))" % list(argv))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, PYTHONPATH=str(ROOT / "ambid_cli")))
    return run, json.loads(run.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [["--help"], ["-h"], ["help"], []])
def test_help_lists_every_command_with_its_modules_help_and_imports_none(argv):
    run, status = _help_in_a_fresh_interpreter(*argv)
    assert status == {"rc": 0, "loaded": []}, run.stderr
    rows = {ln.split()[0]: ln.split(None, 1)[1] for ln in run.stdout.splitlines()
            if ln.startswith("  ") and len(ln.split()) > 1}
    # each command of COMMANDS once, with the HELP its module has when imported
    for name, module in cli.COMMANDS.items():
        assert rows[name] == importlib.import_module(f"ambid_cli.commands.{module}").HELP
    assert set(cli.SCRIPT_COMMANDS) <= set(rows)
    assert len(rows) == len(cli.COMMANDS) + len(cli.SCRIPT_COMMANDS)


def test_the_launch_script_prints_the_same_list():
    run = subprocess.run([str(ROOT / "launch_scripts" / "ambid"), "--help"], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == cli.overview(), run.stderr
    assert "set -euo" not in run.stdout


def test_the_command_reference_names_every_command():
    text = (ROOT / "docs" / "commands.md").read_text()
    missing = [name for name in [*cli.COMMANDS, *cli.SCRIPT_COMMANDS] if f"| `ambid {name}" not in text]
    assert not missing, f"docs/commands.md has no row for {missing}"
