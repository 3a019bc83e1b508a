"""The fenced blocks of the README and docs/, what each one is, and how a printed line is compared.

The conventions a doc follows (docs/architecture.md, "Docs are tested"):

- A block of shell commands (no language, ``bash``, ``sh``) runs as one bash script (``set -e``) in a
  scratch folder of its doc, in which ``tests``, ``rigs``, ``ambid_core``, ``ambid_nodes`` and
  ``docs/examples`` point into the checkout (``docs/`` itself is the folder's own); ``./launch_scripts/`` and ``ros_ws/install/`` name the checkout's. Every
  block of a doc runs in the same folder, in the doc's order, so a block may use what an earlier one
  wrote; ``/tmp/`` in a command is that folder's ``tmp/`` and a loopback port ``127.0.0.1:N`` a free one. It must exit 0; what it started in the
  background is stopped when it ends.
- A block whose lines start with ``$ `` is a transcript: each command runs and the lines under it are
  what it prints.
- A block marked ``<!-- output of: COMMAND -->`` is what COMMAND (a command of a block above, in the same
  doc, or ``./launch_scripts/ambid identify``, which every doc shares) prints.
- Printed lines are compared exactly (trailing blanks aside), as a contiguous run of the command's
  standard output or standard error, with two marks for what varies: ``<name>`` stands for one figure
  or phrase (any text within the line) and a line ``...`` for any number of lines.
- ``python`` blocks run with the suite's interpreter; ``yaml`` blocks must parse, and one marked
  ``<!-- file: NAME -->`` is written to NAME for the blocks after it.
- A command in backticks in the prose (`` `ambid fit SESSION --out DIR` ``) names a command and options that
  exist (:func:`inline_commands`; what stands in for a value, ``SESSION``, ``DIR``, ``[...]``, is not read).
- Any other block is marked ``<!-- not run: REASON -->`` (hardware, a cluster, a diagram, a server that
  runs until stopped, a synopsis) or ``<!-- run by: tests/...py -->`` (a test that runs it in full); the
  suite lists every such block with its reason.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

#: the keys a marker comment may have
MARKER_KEYS = ("not run", "run by", "output of", "file", "exit")
SHELL_LANGS = ("", "bash", "sh", "shell")
#: the one command every doc shares (a full identify, run once per suite)
SHARED_IDENTIFY = "./launch_scripts/ambid identify"

_FENCE = re.compile(r"^(\s*)```\s*([\w+-]*)\s*$")
_MARKER = re.compile(r"^\s*<!--\s*([a-z ]+?)\s*:\s*(.*?)\s*-->\s*$")
_COMMAND = re.compile(r"^(\./)?(launch_scripts/|ros_ws/)|^(python|pip|source|rm|export|for|cd|ros2|dask|echo|mkdir)\b")


@dataclass
class Block:
    """One fenced block: where it is, its language and text, and the marker comments right above it."""

    path: str  # relative to the checkout
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    markers: dict[str, str] = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.path}:{self.line}"

    @property
    def kind(self) -> str:
        """``not run``, ``run by``, ``output``, ``transcript``, ``shell``, ``python``, ``yaml`` or
        ``unmarked`` (a block the conventions do not cover: the suite fails on it)."""
        if "not run" in self.markers:
            return "not run"
        if "run by" in self.markers:
            return "run by"
        if "output of" in self.markers:
            return "output"
        if self.lang in ("python", "yaml"):
            return self.lang
        if self.lang in SHELL_LANGS:
            lines = [ln.strip() for ln in self.text.splitlines() if ln.strip()]
            if lines and lines[0].startswith("$ "):
                return "transcript"
            if lines and all(_COMMAND.match(ln) or ln.startswith("#") or ln in ("done",) or ln.startswith("--")
                             or ln.endswith("\\") or prev.endswith("\\")
                             for ln, prev in zip(lines, [""] + lines[:-1])):
                return "shell"
        return "unmarked"


def doc_files() -> list[Path]:
    """README.md and every Markdown file under docs/, in a stable order."""
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def parse(path: Path) -> list[Block]:
    """The fenced blocks of a Markdown file with their markers.

    Raises:
        ValueError: on an unclosed fence or a marker key that is not one of :data:`MARKER_KEYS`.
    """
    rel = str(path.relative_to(REPO))
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        start, indent = i, len(m.group(1))
        body = []
        i += 1
        while i < len(lines) and not re.match(r"^\s*```\s*$", lines[i]):
            body.append(lines[i][indent:] if lines[i][:indent].isspace() else lines[i])
            i += 1
        if i == len(lines):
            raise ValueError(f"{rel}:{start + 1}: the fence is never closed")
        markers = {}
        j = start - 1
        while j >= 0 and (not lines[j].strip() or _MARKER.match(lines[j])):
            mm = _MARKER.match(lines[j])
            if mm:
                if mm.group(1) not in MARKER_KEYS:
                    raise ValueError(f"{rel}:{j + 1}: marker {mm.group(1)!r} is not one of {MARKER_KEYS}")
                markers.setdefault(mm.group(1), mm.group(2))
            j -= 1
        blocks.append(Block(rel, start + 1, m.group(2), "\n".join(body), markers))
        i += 1
    return blocks


def transcript(text: str) -> list[tuple[str, list[str]]]:
    """``$ command`` lines and the lines printed under each."""
    out: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        if line.startswith("$ "):
            out.append((line[2:].strip(), []))
        elif out:
            out[-1][1].append(line)
    return out


def _line_pattern(line: str) -> str:
    parts = re.split(r"(<[^<>\n]+>)", line.rstrip())
    return "".join(r"[^\n]+?" if p.startswith("<") and p.endswith(">") else re.escape(p) for p in parts)


def mismatch(expected: list[str], printed: str) -> str | None:
    """None if the expected lines are a contiguous run of ``printed``'s lines (``<name>`` any text in a
    line, a line ``...`` any lines), else what was printed, for the failure message."""
    expected = [ln for ln in expected]
    while expected and not expected[-1].strip():
        expected.pop()
    pattern = ""
    for ln in expected:
        pattern += r"(?:[^\n]*\n)*?" if ln.strip() == "..." else _line_pattern(ln) + r"[ \t]*\n"
    text = "\n".join(ln.rstrip() for ln in printed.splitlines()) + "\n"
    if re.search(r"(?m)^" + pattern, text):
        return None
    return "the doc shows\n" + "\n".join(expected) + "\n---- but the command printed\n" + text[-4000:]


def commands(block: Block) -> list[str]:
    """The logical command lines of a shell block (continuations joined, comments dropped)."""
    out, cur = [], ""
    for raw in block.text.splitlines():
        line = re.sub(r"\s+#.*$", "", raw).strip() if not raw.strip().startswith("#") else ""
        if line.endswith("\\"):
            cur += line[:-1] + " "
            continue
        cur += line
        if cur.strip():
            out.append(cur.strip())
        cur = ""
    return out


def checkout_paths(script: str) -> str:
    """The one rewrite a command gets: ``./launch_scripts/`` and ``ros_ws/install/`` name the checkout's."""
    script = re.sub(r"(?<![\w/.])(\./)?launch_scripts/", f"{REPO}/launch_scripts/", script)
    return re.sub(r"(?<![\w/.])(\./)?ros_ws/install/", f"{REPO}/ros_ws/install/", script)


_INLINE = re.compile(r"`(?:\./)?(?:launch_scripts/)?ambid[ \t\n]+([^`]+)`")


@dataclass(frozen=True)
class InlineCommand:
    """An ``ambid ...`` command in backticks in a doc's prose (outside its fenced blocks)."""

    path: str   # relative to the checkout
    line: int   # 1-based
    text: str   # what follows ``ambid``

    @property
    def command(self) -> str:
        return self.text.split()[0]

    @property
    def options(self) -> list[str]:
        """The option names it gives (``--out`` of ``--out DIR`` or ``--out=DIR``), in order."""
        words = re.sub(r"[\[\]|(),]", " ", self.text).split()[1:]
        return [w.split("=", 1)[0] for w in words if re.fullmatch(r"--?[a-zA-Z][\w-]*(=\S*)?", w)]


def inline_commands(path: Path) -> list[InlineCommand]:
    """Every `` `ambid COMMAND ...` `` of a Markdown file's prose (a span may wrap a line), fenced blocks left out
    (they are run, or marked); a placeholder command (``ambid COMMAND``) is not one."""
    rel = str(path.relative_to(REPO))
    lines, prose, fenced = path.read_text(encoding="utf-8").splitlines(), [], False
    for ln in lines:
        if re.match(r"^\s*```", ln):
            fenced = not fenced
            prose.append("")
            continue
        prose.append("" if fenced else ln)
    text = "\n".join(prose)
    out = []
    for m in _INLINE.finditer(text):
        body = " ".join(m.group(1).split())
        if re.match(r"[a-z/-]+\b", body) or body.startswith("-"):
            out.append(InlineCommand(rel, text.count("\n", 0, m.start()) + 1, body))
    return out
