"""The commands as a user meets them: ``ambid design``, ``ambid fit FRF_FILE`` and ``ambid identify``, each
run as its own process on a pseudo-terminal (as typed at a prompt), every chunk of its output timed.

Figures per command: wall seconds to its answer (the first line of its figures) and to its end, and the
longest silence on the terminal (a status line counts: that is what the user sees). For identify,
what it spent beyond its session (the headline's own split: set-up and design, closing and analysis),
to the headline and to its exit, and the report's own time (written by a process of its own after the headline).
"""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

from ambid.background import wait

ROOT = Path(__file__).resolve().parents[3]
FRF_FILE = ROOT / "tests" / "data" / "real" / "ladisk_beam_uff" / "measurement.uff"
HEADLINE = re.compile(r"ambid identify: done in ([0-9.]+) s wall: ([0-9.]+) s set-up and design, ([0-9.]+) s "
                      r"the session \(([0-9.]+) s simulated")


def run_on_terminal(argv: list[str], cwd: str | os.PathLike, timeout_s: float = 900.0) -> dict:
    """Run ``python -m ambid_cli.cli ARGV`` with stdout and stderr on a pseudo-terminal.

    Returns:
        dict: ``returncode``, ``wall_s`` (start to exit), ``chunks`` [(seconds since start, text)],
        ``longest_silence_s`` (the largest gap between the start, the chunks and the exit) and ``text``.
    """
    master, slave = pty.openpty()
    env = dict(os.environ, AMBID_T0="")   # the start counted from here
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "ambid_cli.cli", *argv], stdout=slave, stderr=slave,
                            stdin=subprocess.DEVNULL, cwd=cwd, env=env, close_fds=True)
    os.close(slave)
    chunks: list[tuple[float, str]] = []
    try:
        while True:
            ready, _, _ = select.select([master], [], [], 0.05)
            data = b""
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:   # EIO: every writer of the terminal is gone
                    data = b""
                if data:
                    chunks.append((time.monotonic() - t0, data.decode(errors="replace")))
                    continue
            if proc.poll() is not None:   # ended, and nothing more to read
                break
            if ready and not data:   # the terminal closed before the process ended: wait for its end
                proc.wait(timeout_s)
                break
            if time.monotonic() - t0 > timeout_s:
                proc.kill()
                raise RuntimeError(f"ambid {argv[0]} did not end within {timeout_s:g} s")
        proc.wait()
    finally:
        os.close(master)
    wall = time.monotonic() - t0
    marks = [0.0] + [t for t, _ in chunks] + [wall]
    return {"returncode": proc.returncode, "wall_s": wall, "chunks": chunks,
            "longest_silence_s": max(b - a for a, b in zip(marks, marks[1:])),
            "text": "".join(c for _, c in chunks)}


def _first(chunks: list[tuple[float, str]], pattern: str) -> float | None:
    """Seconds to the first chunk holding ``pattern`` (in the text so far)."""
    text = ""
    for t, c in chunks:
        text += c
        if pattern in text:
            return t
    return None


def command_figures(work: Path, identify_options: list[str]) -> dict:
    """Time ``design``, ``fit FRF_FILE`` and ``identify`` (with ``identify_options``) on a terminal."""
    work.mkdir(parents=True, exist_ok=True)
    design = run_on_terminal(["design", "--out", str(work / "design")], work)
    # design.png is drawn by a detached process after the command has answered: when it is there, counted from
    # the command's start (the shell had its prompt back at wall_s)
    t0 = time.monotonic() - design["wall_s"]
    figure = wait(work / "design" / "design.status.json") if design["returncode"] == 0 else {}
    design["figure_s"] = time.monotonic() - t0
    design["figure_own_s"] = figure.get("seconds")
    fit = run_on_terminal(["fit", str(FRF_FILE), "--out", str(work / "fit")], work)
    ident = run_on_terminal(["identify", "--out", str(work / "identify"), *identify_options], work)
    report = wait(work / "identify" / "report" / "status.json", 300.0) if ident["returncode"] == 0 else {}
    for name, r in (("design", design), ("fit", fit), ("identify", ident)):
        if r["returncode"] != 0:
            raise RuntimeError(f"ambid {name} exited {r['returncode']}: {r['text'][-800:]}")
    m = HEADLINE.search(ident["text"])
    if m is None:
        raise RuntimeError(f"ambid identify printed no headline: {ident['text'][-800:]}")
    headline_total, setup, session, simulated = (float(x) for x in m.groups())
    to_headline = _first(ident["chunks"], "ambid identify: done in")
    return {
        "design": {"wall_s": design["wall_s"], "longest_silence_s": design["longest_silence_s"],
                   "figure_s": design["figure_s"], "figure_own_s": design["figure_own_s"]},
        "fit": {"file": str(FRF_FILE.relative_to(ROOT)), "to_figures_s": _first(fit["chunks"], "model order"),
                "wall_s": fit["wall_s"], "longest_silence_s": fit["longest_silence_s"]},
        "identify": {"options": identify_options, "simulated_s": simulated, "session_s": session,
                     "setup_s": setup, "headline_s": headline_total, "to_headline_s": to_headline,
                     "beyond_session_to_headline_s": to_headline - session,
                     "wall_s": ident["wall_s"], "beyond_session_s": ident["wall_s"] - session,
                     "longest_silence_s": ident["longest_silence_s"], "report_own_s": report.get("seconds")},
    }
