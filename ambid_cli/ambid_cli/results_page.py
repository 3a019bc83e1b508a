"""docs/results.md: the figures ambid measures, written by the commands that measure them.

``ambid bench --results FILE`` and ``ambid validate --results FILE`` each replace their own section of
the page (between ``<!-- ambid <command>: begin -->`` and ``<!-- ambid <command>: end -->``) and leave
the rest as it is, so the page always holds each command's last run, with the command line, the date
and the machine that measured it. Nothing on it is typed by hand.
"""

from __future__ import annotations

import datetime
import os
import platform
import re
import sys
from pathlib import Path

HEADER = """# Results

The figures ambid measures, each section written by the command named in it (`ambid bench
--results FILE`, `ambid validate --results FILE`); run the command again to renew its section. What the
figures mean and how they are measured: [performance.md](performance.md) (bench) and
[uncertainty.md](uncertainty.md) (validate).
"""


def measured_on() -> str:
    """One line: when, where and by which command line the figures were measured."""
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    argv = " ".join(["ambid", *sys.argv[1:]]) if sys.argv and "cli" in Path(sys.argv[0]).name else "ambid"
    return (f"Measured {when} by `{argv}` on {os.cpu_count()} CPUs ({platform.machine()}, Python "
            f"{platform.python_version()}), load average {load} at the end.")


def write_section(path: str | os.PathLike, command: str, title: str, body: str) -> Path:
    """Replace (or add) ``command``'s section of the results page at ``path`` with ``title`` and ``body``."""
    p = Path(path)
    text = p.read_text() if p.exists() else HEADER
    begin, end = f"<!-- ambid {command}: begin -->", f"<!-- ambid {command}: end -->"
    section = f"{begin}\n## {title}\n\n{body.rstrip()}\n{end}\n"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end) + r"\n?", re.S)
    text = pattern.sub(lambda _: section, text) if pattern.search(text) else text.rstrip() + "\n\n" + section
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text)
    return p
