"""Every fenced block of the README and docs/ runs, and the lines a doc shows are the lines printed.

One test per block, named ``path:line``; the conventions are in ``doc_blocks.py``. The one full
``ambid identify`` that the README, identify.md and python.md show runs once for the whole suite.
Blocks marked ``not run`` are listed (with their reasons) at the end of the run, never run quietly.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from doc_blocks import (REPO, SHARED_IDENTIFY, Block, checkout_paths, commands, doc_files, inline_commands,
                        mismatch, parse, transcript)
from domain_ids import next_domain_id

BLOCKS = [b for f in doc_files() for b in parse(f)]
TIMEOUT_S = 900


@dataclass
class Ran:
    rc: int
    out: str
    err: str


class Docs:
    """The scratch folder of each doc, the blocks already run there, and the shared identify run."""

    def __init__(self, root: Path):
        self.root = root
        self.ran: dict[str, Ran] = {}
        self.shared: Ran | None = None

    def workdir(self, doc: str) -> Path:
        d = self.root / doc.replace("/", "_")
        if not d.exists():
            d.mkdir(parents=True)
            for name in ("tests", "rigs", "ambid_core", "ambid_nodes"):
                (d / name).symlink_to(REPO / name)
            # docs/ of its own: a block that writes into docs/ (ambid compare) writes here, not into the checkout
            (d / "docs").mkdir()
            (d / "docs" / "examples").symlink_to(REPO / "docs" / "examples")
        return d

    def identify(self) -> Ran:
        """``ambid identify`` as the README shows it, once; every doc's ``identify/`` is its output."""
        if self.shared is None:
            d = self.root / "_shared"
            d.mkdir(exist_ok=True)
            self.shared = _bash(SHARED_IDENTIFY, d)
            assert self.shared.rc == 0, f"{SHARED_IDENTIFY} failed:\n{self.shared.err[-3000:]}"
        return self.shared

    def link_identify(self, wd: Path) -> None:
        self.identify()
        if not (wd / "identify").exists():
            (wd / "identify").symlink_to(self.root / "_shared" / "identify")

    def run(self, block: Block) -> Ran:
        """Run ``block`` in its doc's folder, after the doc's earlier blocks (once each)."""
        if block.id in self.ran:
            return self.ran[block.id]
        for earlier in BLOCKS:
            if earlier.path == block.path and earlier.line < block.line and earlier.kind in ("shell", "yaml", "python"):
                self.run(earlier)
        wd = self.workdir(block.path)
        if "identify/" in block.text or SHARED_IDENTIFY in commands(block):
            self.link_identify(wd)
        if block.kind == "yaml":
            yaml.safe_load(block.text)  # raises on a doc's broken YAML
            if "file" in block.markers:
                (wd / block.markers["file"]).write_text(block.text + "\n")
            ran = Ran(0, "", "")
        elif block.kind == "python":
            ran = _run([sys.executable, "-c", block.text], wd)
        else:
            cmds = commands(block)
            if cmds == [SHARED_IDENTIFY]:
                ran = self.identify()
            else:
                ran = _bash("\n".join(": shared run" if c == SHARED_IDENTIFY else c for c in cmds), wd)
        self.ran[block.id] = ran
        return ran


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONUNBUFFERED="1", ROS_DOMAIN_ID=str(next_domain_id()))


def _run(argv: list[str], cwd: Path) -> Ran:
    proc = subprocess.Popen(argv, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        try:  # what the block started in the background ends with it
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return Ran(proc.returncode, out, err)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _bash(script: str, cwd: Path) -> Ran:
    # a doc's /tmp/ is the doc's own scratch folder's tmp/ (two runs of the suite never share a key file)
    (cwd / "tmp").mkdir(exist_ok=True)
    script = re.sub(r"(?<![\w.])/tmp/", f"{cwd}/tmp/", script)
    # and its loopback UDP ports are free ones (two runs of the suite at once never cross their datagrams)
    for port in sorted(set(re.findall(r"127\.0\.0\.1:(\d{4,5})\b", script))):
        script = re.sub(rf"\b{port}\b", str(_free_udp_port()), script)
    return _run(["bash", "-e", "-o", "pipefail", "-c", "trap 'kill $(jobs -p) 2>/dev/null || true' EXIT\n"
                 + checkout_paths(script)], cwd)


@pytest.fixture(scope="module")
def docs(tmp_path_factory) -> Docs:
    return Docs(tmp_path_factory.mktemp("docs"))


def _fail(block: Block, what: str, ran: Ran | None = None) -> None:
    tail = "" if ran is None else f"\nexit {ran.rc}\n---- stdout\n{ran.out[-3000:]}\n---- stderr\n{ran.err[-3000:]}"
    pytest.fail(f"{block.id}: {what}{tail}", pytrace=False)


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.kind not in ("not run", "run by")], ids=lambda b: b.id)
def test_doc_block(block: Block, docs: Docs) -> None:
    kind = block.kind
    if kind == "unmarked":
        _fail(block, f"a ```{block.lang} block that is neither commands nor marked: mark it "
                     "'<!-- not run: REASON -->', '<!-- output of: COMMAND -->' or '<!-- run by: TEST -->'")
    if kind == "transcript":
        wd = docs.workdir(block.path)
        steps = transcript(block.text)
        for i, (cmd, shown) in enumerate(steps):
            ran = _bash(cmd, wd)
            # the last command's exit code is the marker's (a bad input's 2), every other one's 0
            expected_rc = int(block.markers.get("exit", "0")) if i == len(steps) - 1 else 0
            if shown and mismatch(shown, ran.out) and mismatch(shown, ran.err):
                _fail(block, f"'{cmd}': {mismatch(shown, ran.err if ran.err.strip() else ran.out)}")
            if ran.rc != expected_rc:
                _fail(block, f"'{cmd}' exits {ran.rc}, the doc says {expected_rc}", ran)
        return
    if kind == "output":
        cmd = block.markers["output of"]
        source = [b for b in BLOCKS if b.path == block.path and b.line < block.line and cmd in commands(b)]
        if cmd == SHARED_IDENTIFY:
            ran = docs.identify()
        elif source:
            ran = docs.run(source[-1])
        else:
            _fail(block, f"'output of: {cmd}' names no command of a block above it")
        shown = block.text.splitlines()
        if mismatch(shown, ran.out) and mismatch(shown, ran.err):
            _fail(block, mismatch(shown, ran.out if ran.out.strip() else ran.err))
        return
    ran = docs.run(block)
    if ran.rc != 0:
        _fail(block, f"exits {ran.rc}", ran)


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.kind in ("not run", "run by")], ids=lambda b: b.id)
def test_marked_block_says_why(block: Block) -> None:
    """A block left out says why; one run by another test names a test that exists and names this doc."""
    if block.kind == "not run":
        assert len(block.markers["not run"]) >= 8, f"{block.id}: 'not run' needs a reason a reader can check"
        return
    test = REPO / block.markers["run by"]
    assert test.is_file(), f"{block.id}: 'run by: {block.markers['run by']}' names no test file"
    assert block.path in test.read_text(), f"{block.id}: {test.name} does not name {block.path}, which it runs"


def test_every_example_script_is_run() -> None:
    """docs/examples/*.py: each is run by a doc block or named by a test that runs it."""
    shown = "\n".join(b.text for b in BLOCKS if b.kind in ("shell", "run by"))
    tests = "\n".join(p.read_text() for p in (REPO / "tests" / "docs").glob("test_*.py"))
    for script in sorted((REPO / "docs" / "examples").glob("*.py")):
        rel = str(script.relative_to(REPO))
        assert rel in shown and rel in tests, f"{rel} is neither shown in a doc nor run by tests/docs"


def not_run_listing() -> str:
    """What the suite prints at its end: how many blocks ran and each one that did not, with its reason."""
    run = [b for b in BLOCKS if b.kind not in ("not run", "run by")]
    elsewhere = [b for b in BLOCKS if b.kind == "run by"]
    left = [b for b in BLOCKS if b.kind == "not run"]
    lines = [f"docs: {len(BLOCKS)} blocks: {len(run)} run here, {len(elsewhere)} run by other tests, "
             f"{len(left)} not run"]
    lines += [f"  {b.id}: run by {b.markers['run by']}" for b in elsewhere]
    lines += [f"  {b.id}: not run: {b.markers['not run']}" for b in left]
    return "\n".join(textwrap.shorten(ln, 160) if len(ln) > 160 else ln for ln in lines)


def _option_names(command: str) -> set[str]:
    """The option strings ``ambid COMMAND`` takes (its parser, as the command line builds it)."""
    import argparse
    import importlib

    from ambid_cli.cli import COMMANDS

    p = argparse.ArgumentParser(prog=f"ambid {command}")
    importlib.import_module(f"ambid_cli.commands.{COMMANDS[command]}").add_arguments(p)
    return {s for action in p._actions for s in action.option_strings}  # noqa: SLF001 - argparse has no API


@pytest.mark.parametrize("doc", doc_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_commands_in_the_prose_name_what_the_command_line_has(doc: Path) -> None:
    """Every `` `ambid COMMAND --option ...` `` in a doc's sentences names a command of ``ambid --help`` and
    options that command takes: a renamed command or option fails here, not in a user's hands. ``a/b`` names
    two commands; what follows ``--ros-args`` is ROS's."""
    from ambid_cli.cli import COMMANDS, SCRIPT_COMMANDS

    wrong, options = [], {}
    for ref in inline_commands(doc):
        where = f"{ref.path}:{ref.line}: `ambid {ref.text}`"
        if ref.command in ("--help", "-h", "help") or ref.command in SCRIPT_COMMANDS:
            continue   # the overview; setup and test (its arguments are pytest's)
        given = ref.options[:ref.options.index("--ros-args")] if "--ros-args" in ref.options else ref.options
        for command in ref.command.split("/"):   # `ambid identify/graph --hardware ...`: each of them
            if command not in COMMANDS:
                wrong.append(f"{where}: no command '{command}'")
                continue
            if command not in options:
                options[command] = _option_names(command)
            wrong += [f"{where}: 'ambid {command}' has no option {o}" for o in given if o not in options[command]]
    assert not wrong, "\n".join(wrong)


def test_the_prose_check_reads_commands_and_options_as_written(tmp_path) -> None:
    """The extraction itself: spans in sentences (one may wrap a line), not fenced blocks nor the Python API."""
    import doc_blocks

    doc = doc_blocks.REPO / "docs" / "_probe_inline.md"
    doc.write_text("Run `ambid fit SESSION --out DIR [--order N]` or\n`./launch_scripts/ambid design\n--no-plan`; "
                   "not `ambid.design_excitation(...)` nor `ambid COMMAND --help`.\n```\nambid fit --bogus\n```\n")
    try:
        refs = inline_commands(doc)
    finally:
        doc.unlink()
    assert [(r.line, r.command, r.options) for r in refs] == [(1, "fit", ["--out", "--order"]),
                                                              (2, "design", ["--no-plan"])]


def test_commands_md_lists_every_command() -> None:
    """docs/commands.md has a row for every command the command line has."""
    from ambid_cli.cli import COMMANDS

    table = (REPO / "docs" / "commands.md").read_text()
    missing = [c for c in COMMANDS if f"| `ambid {c}" not in table]
    assert not missing, f"docs/commands.md lacks a row for {missing}"


def test_performance_md_describes_every_bench_section() -> None:
    """docs/performance.md's table has a row for every section ``ambid bench`` runs."""
    from ambid_cli.commands.bench import SECTIONS

    table = (REPO / "docs" / "performance.md").read_text()
    missing = [s for s in SECTIONS if f"| `{s}` |" not in table]
    assert not missing, f"docs/performance.md lacks a row for the bench sections {missing}"


def test_the_repositorys_compare_md_is_what_compare_writes(docs: Docs) -> None:
    """docs/compare/compare.md is what identify.md's ``ambid compare`` writes today: the same headings,
    rows, methods and sentences; only the numbers (wall times, errors in their last digits) may differ."""
    (block,) = [b for b in BLOCKS if b.path == "docs/identify.md" and "ambid compare --preset quick" in b.text]
    ran = docs.run(block)
    assert ran.rc == 0, ran.err[-3000:]

    def words(path: Path) -> list[str]:
        return [re.sub(r"[-+]?\d[\d.,e+-]*", "#", ln).rstrip() for ln in path.read_text().splitlines()]

    written = words(docs.workdir(block.path) / "docs" / "compare" / "compare.md")
    assert words(REPO / "docs" / "compare" / "compare.md") == written, \
        "docs/compare/compare.md is stale: regenerate it with identify.md's 'ambid compare' command"
