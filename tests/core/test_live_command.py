"""The live view's command-line inputs: ``ambid live`` and ``--live PORT``, refused in one line with exit code 2
before anything starts, and ``ambid live --layout`` writing the Foxglove layout of a rig's channels."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
from ambid.channels import RADIAL
from ambid.live.layout import foxglove_layout
from test_cli_bad_input import _run   # in-process through ambid_cli.cli.main, no traceback allowed

DOCS = Path(__file__).resolve().parents[2] / "docs"


@pytest.mark.parametrize("argv, option", [(["identify", "--live", "70000"], "--live"),
                                          (["graph", "--live", "x"], "--live"),
                                          (["live", "-1"], "port")])
def test_a_port_out_of_range_is_refused(argv, option, capsys):
    code, out = _run(argv, capsys)
    assert code == 2 and option in out.err


def test_live_without_a_port_says_what_to_give(capsys):
    code, out = _run(["live"], capsys)
    assert code == 2 and out.err.count("\n") == 1 and "give the PORT" in out.err


@pytest.mark.parametrize("command", [["identify", "--out"], ["graph", "--sim-seconds", "0.1", "--rig"]])
def test_a_port_in_use_is_refused_before_the_graph_starts(command, tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        argv = [*command, str(tmp_path / "out")] if command[0] == "identify" else command[:-1]
        code, out = _run([*argv, "--live", str(port)], capsys)
    assert code == 2 and out.err.count("\n") == 1 and f"cannot listen on 127.0.0.1:{port}" in out.err
    assert "choose another port" in out.err and not (tmp_path / "out").exists()


def test_the_layout_command_writes_the_rigs_layout(tmp_path, capsys):
    code, out = _run(["live", "--layout", str(tmp_path / "layout.json")], capsys)
    assert code == 0 and "a_x b_x a_y b_y" in out.out
    written = json.loads((tmp_path / "layout.json").read_text())
    assert written == foxglove_layout(RADIAL) == json.loads((DOCS / "foxglove_layout.json").read_text())
    code, out = _run(["live", "--layout", str(tmp_path)], capsys)   # a folder: one line, exit code 2
    assert code == 2 and "is a folder" in out.err
