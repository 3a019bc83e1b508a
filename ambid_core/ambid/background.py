"""Files written after a command has answered: a function run in a detached process, its state in a status file.

A command prints its figures and returns; what only draws them (``design.png``, identify's report) is written by
:func:`start` in a process of its own session (no terminal, not the command's process group: Ctrl-C at the
prompt does not reach it, the shell does not wait for it). The status file says where it is::

    {"state": "writing" | "done" | "failed", "pid": 1234, "started": <unix s>, "seconds": 0.8, "error": "..."}

written ``writing`` by :func:`start` before the process exists (a reader never sees the old state), then
``done`` or ``failed`` by the process. :func:`wait` blocks until it is no longer ``writing``. The process's
output goes to the status file's name with ``.log``.

The function and its arguments travel as a pickle beside the status file (removed once read): they must be
picklable, and the function importable by its module and name.
"""

from __future__ import annotations

import importlib
import json
import os
import pickle
import subprocess
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Callable

__all__ = ["start", "wait", "read_status", "BackgroundFailed"]


class BackgroundFailed(RuntimeError):
    """The detached process said it failed, or vanished without saying."""


def _write_status(path: Path, status: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(status))
    os.replace(tmp, path)   # whole or not at all: a reader never sees half a status


def read_status(path: str | os.PathLike) -> dict | None:
    """The status file's contents, or None where there is none."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return None


def start(status: str | os.PathLike, func: Callable[..., Any], *args: Any, nice: int = 0) -> Path:
    """Run ``func(*args)`` in a detached process; return ``status``, the file that says how it went.

    Parameters
    ----------
    status
        the status file (its folder is created).
    func
        a module-level function (found again by its module and name in the new process).
    *args
        its arguments (pickled).
    nice
        added to the process's niceness (it draws while the user goes on working).
    """
    status = Path(status)
    status.parent.mkdir(parents=True, exist_ok=True)
    job = status.with_name(status.name + ".job")
    job.write_bytes(pickle.dumps((func.__module__, func.__qualname__, args, nice), protocol=pickle.HIGHEST_PROTOCOL))
    _write_status(status, {"state": "writing", "pid": None, "started": time.time()})
    with open(status.with_name(status.name + ".log"), "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "ambid.background", str(status)], stdin=subprocess.DEVNULL,
                                stdout=log, stderr=subprocess.STDOUT, start_new_session=True, close_fds=True)
    # not waited for: the process outlives this one (the shell's prompt returns). Kept, so that should this
    # process live on (a test, a notebook) its end is reaped, not left a zombie, and nothing warns of it
    _STARTED.append(proc)
    _STARTED[:] = [p for p in _STARTED if p.poll() is None]
    return status


_STARTED: list[subprocess.Popen] = []


def wait(status: str | os.PathLike, timeout_s: float = 120.0) -> dict:
    """Block until the job of ``status`` is done; its final status. Raises :class:`BackgroundFailed`
    if it failed, vanished or did not end within ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while True:
        s = read_status(status)
        if s is None:
            raise BackgroundFailed(f"{status}: no such status file (nothing was started)")
        if s["state"] == "done":
            return s
        if s["state"] == "failed":
            raise BackgroundFailed(f"{status}: {s.get('error', 'failed')}")
        if s.get("pid") and not _alive(s["pid"]):
            s2 = read_status(status)   # it may have ended between the two reads
            if s2 is not None and s2["state"] != "writing":
                continue
            raise BackgroundFailed(f"{status}: the process {s['pid']} ended without a word (see its .log)")
        if time.monotonic() > end:
            raise BackgroundFailed(f"{status}: still writing after {timeout_s:g} s")
        time.sleep(0.02)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # a zombie (ours, not yet reaped) counts as ended
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True


def _run(status: Path) -> int:
    """The detached process: read the job, run it, say how it went."""
    job = status.with_name(status.name + ".job")
    t0 = time.perf_counter()
    started = (read_status(status) or {}).get("started", time.time())
    try:
        module, name, args, nice = pickle.loads(job.read_bytes())
        job.unlink()
        _write_status(status, {"state": "writing", "pid": os.getpid(), "started": started})
        if nice > 0:
            os.nice(nice)
        func = importlib.import_module(module)
        for part in name.split("."):
            func = getattr(func, part)
        func(*args)
    except BaseException as exc:  # noqa: BLE001 - said in the status file, which is what its reader sees
        traceback.print_exc()
        _write_status(status, {"state": "failed", "pid": os.getpid(), "started": started,
                               "seconds": time.perf_counter() - t0, "error": f"{type(exc).__name__}: {exc}"})
        return 1
    log = status.with_name(status.name + ".log")
    # before "done": a reader that saw "done" finds the folder as it stays
    if log.exists() and log.stat().st_size == 0:   # nothing said: no file to look at
        log.unlink()
    _write_status(status, {"state": "done", "pid": os.getpid(), "started": started,
                           "seconds": time.perf_counter() - t0})
    return 0


if __name__ == "__main__":
    sys.exit(_run(Path(sys.argv[1])))
