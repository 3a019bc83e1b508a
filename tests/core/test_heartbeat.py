"""The phases of a command said as they happen (ambid_cli.heartbeat): a line per phase; on a terminal a
status line once nothing was written for a while, cleared by the next write; in a log nothing more."""

from __future__ import annotations

import io
import sys
import time

from ambid_cli.heartbeat import Phases, current


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _wait_for(pred, timeout_s: float = 30.0) -> bool:
    end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > end:
            return False
        time.sleep(0.05)
    return True


def test_on_a_terminal_a_pause_gets_a_status_line_the_next_write_clears(monkeypatch):
    err, out = _Tty(), _Tty()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(sys, "stdout", out)
    with Phases("identify", quiet_s=0.2, tty=True) as phases:
        assert current() is phases
        phases.say("writing the report")
        assert _wait_for(lambda: "  ... writing the report (" in err.getvalue())
        print("the headline")           # a write: the status line is cleared first
        assert out.getvalue() == "the headline\n"
        assert err.getvalue().endswith("\r\x1b[K")
        phases.quiet()                  # no phase: no status line however long the pause
        n = len(err.getvalue())
        time.sleep(0.6)
        assert len(err.getvalue()) == n
    text = err.getvalue()
    assert text.startswith("ambid identify: writing the report\n")
    assert sys.stderr is err and sys.stdout is out   # the streams given back


def test_in_a_log_the_phases_are_lines_and_nothing_else(monkeypatch):
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    with Phases("identify", quiet_s=0.1, tty=False) as phases:
        phases.say("starting the graph")
        phases.say("designing", line=False)
        time.sleep(0.4)
    assert err.getvalue() == "ambid identify: starting the graph\n"
    assert current().command == ""   # outside a command: a silent one
