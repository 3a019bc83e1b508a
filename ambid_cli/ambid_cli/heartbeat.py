"""A command's phases said as they happen, and on a terminal never more than ~2 s without a word.

:class:`Phases` prints each phase once (``ambid identify: designing the experiment``) and, on a
terminal only, a thread that sees nothing written for ``quiet_s`` rewrites one status line with the
phase and its seconds so far (``  ... writing the report (4 s)``); in a log the phases are plain
lines and nothing else is added. Whatever the command writes to ``sys.stdout`` or ``sys.stderr`` counts
as a word (the nodes' own log lines, written by the ROS logger to the file descriptor, do not).
"""

from __future__ import annotations

import sys
import threading
import time

_started = time.monotonic()
_current: Phases | None = None


def mark_start(epoch_text: str = "") -> None:
    """The command's start: ``epoch_text`` (``$EPOCHREALTIME`` as launch_scripts/ambid took it before its
    set-up check) where it is a time of the last minutes, else now."""
    global _started
    now_epoch, now = time.time(), time.monotonic()
    try:
        age = now_epoch - float(epoch_text)
    except ValueError:
        age = -1.0
    _started = now - age if 0 <= age < 300 else now


def current() -> Phases:
    """The running command's :class:`Phases` (a silent one where none runs, e.g. a command called in-process)."""
    return _current if _current is not None else Phases("", tty=False)



class _Watched:
    """A text stream that notes the time of every write (the heartbeat stays quiet after one)."""

    def __init__(self, stream, owner: "Phases") -> None:
        self._stream, self._owner = stream, owner

    def write(self, text: str) -> int:
        with self._owner.lock:
            self._owner.clear_status()
            self._owner.last = time.monotonic()
            return self._stream.write(text)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


class Phases:
    """``with Phases("identify") as phases: phases.say("designing the experiment") ...``

    Args:
        command: the command's name, the prefix of each line.
        quiet_s: seconds without output after which the status line is written (terminal only).
        tty: whether stderr is a terminal (default: asked).
        started: ``time.monotonic()`` when the command started (default: now).
    """

    def __init__(self, command: str, quiet_s: float = 2.0, tty: bool | None = None,
                 started: float | None = None) -> None:
        self.command = command
        self.quiet_s = quiet_s
        self.tty = sys.stderr.isatty() if tty is None else tty
        self.lock = threading.RLock()
        self.t0 = _started if started is None else started
        self.last = self.t0   # the user has waited since the command started
        self.phase, self.since = "", self.t0
        self._status = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved = (sys.stdout, sys.stderr)

    def __enter__(self) -> Phases:
        global _current
        _current = self
        if self.tty:
            self._raw = sys.stderr
            sys.stdout, sys.stderr = _Watched(sys.stdout, self), _Watched(sys.stderr, self)
            self._thread = threading.Thread(target=self._beat, name="ambid-heartbeat", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        global _current
        _current = None
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            with self.lock:
                self.clear_status()
        sys.stdout, sys.stderr = self._saved

    def say(self, phase: str, line: bool = True) -> None:
        """Start ``phase``: one line now (``ambid <command>: <phase>``); ``line`` False: the status line
        only (on a terminal, once ``quiet_s`` passed without output)."""
        with self.lock:
            self.phase, self.since = phase, time.monotonic()
        if line:
            print(f"ambid {self.command}: {phase}", file=sys.stderr, flush=True)

    def quiet(self) -> None:
        """No phase: the status line is cleared and stays away until the next :meth:`say`."""
        with self.lock:
            self.phase = ""
            self.clear_status()

    def elapsed(self) -> float:
        """Seconds since the command started."""
        return time.monotonic() - self.t0

    def clear_status(self) -> None:
        if self._status:
            self._raw.write("\r\x1b[K")
            self._raw.flush()
            self._status = False

    def _beat(self) -> None:
        while not self._stop.wait(0.25):
            with self.lock:
                now = time.monotonic()
                if self.phase and now - self.last >= self.quiet_s and (self._status or now - self.last < 3600):
                    self._raw.write(f"\r  ... {self.phase} ({now - self.since:.0f} s)\x1b[K")
                    self._raw.flush()
                    self._status = True
