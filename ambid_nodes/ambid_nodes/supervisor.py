"""A session's nodes as processes: started so that none outlives the run, watched, every death named.

The processes layout (:mod:`ambid_nodes.running.processes`) runs a session with it.

The orchestrator (``ambid graph --processes``, ``ambid identify --processes``) is every node's parent, so
it sees a death at once, whatever the node was doing:

- a node that exits before the run is over (``kill -9``, a crash, an exception): its exit status, polled
  every :data:`POLL_S`;
- a node that is stopped (``kill -STOP``, ^Z, a debugger): its state in ``/proc/<pid>/stat``, polled alike.

Each node process also dies with the orchestrator (``AMBID_DIE_WITH_PARENT``: the node asks the kernel
for SIGTERM when its parent goes, ``node_main``), so even a ``kill -9`` of the orchestrator leaves no node
behind. :meth:`Supervisor.stop_all` wakes stopped nodes (SIGCONT) and ends every node with SIGTERM (the
recorder then closes its file completely), SIGKILL after :data:`STOP_GRACE_S`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

from ambid_nodes.node_main import DIE_WITH_PARENT_ENV, SUMMARY_PREFIX

POLL_S = 0.1         # how often the children are looked at
STOP_GRACE_S = 5.0   # SIGTERM to SIGKILL


@dataclass
class Death:
    """A node that died before its run was over.

    Attributes:
        node: the node's name (``position_controller``).
        how: what happened, for the one line (``was killed (SIGKILL)``, ``exited with code 1``,
            ``was stopped (SIGSTOP)``).
        pid: its process id.
        seen_wall: ``time.monotonic()`` when the orchestrator saw it.
    """

    node: str
    how: str
    pid: int
    seen_wall: float


@dataclass
class NodeProcess:
    """One node's process and what it printed: its ``AMBID_SUMMARY`` (a node that finishes prints one)."""

    name: str
    proc: subprocess.Popen
    summary: dict | None = None
    expected_exit: bool = False  # the node finishes by itself (the plant at the end of its run)
    lines: list[str] = field(default_factory=list)

    def read_stdout(self) -> None:
        for line in self.proc.stdout:
            if line.startswith(SUMMARY_PREFIX):
                try:
                    self.summary = json.loads(line[len(SUMMARY_PREFIX):])
                except json.JSONDecodeError:
                    self.lines.append(line)
            else:
                sys.stdout.write(line)
                sys.stdout.flush()


def exit_words(code: int) -> str:
    """What an exit status says, for a person: ``was killed (SIGKILL)`` or ``exited with code 1``."""
    if code < 0:
        try:
            return f"was killed ({signal.Signals(-code).name})"
        except ValueError:
            return f"was killed (signal {-code})"
    return f"exited with code {code}"


def stopped_words(pid: int) -> str | None:
    """``was stopped (SIGSTOP)`` while process ``pid`` is stopped (state T), ``is held by a debugger``
    (state t), else None."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return None
    return {"T": "was stopped (SIGSTOP)", "t": "is held by a debugger"}.get(state)


def ros_args(namespace: str, params: dict) -> list[str]:
    """``--ros-args`` putting a node in ``namespace`` with ``params`` (strings quoted as YAML)."""
    args = ["--ros-args", "-r", f"__ns:={namespace}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={json.dumps(v) if isinstance(v, str) else str(v).lower() if isinstance(v, bool) else v}"]
    return args


def stop_processes(procs: list[subprocess.Popen], grace_s: float = STOP_GRACE_S) -> None:
    """SIGCONT and SIGTERM every process, SIGKILL what is left after ``grace_s``.

    A running node shuts down cleanly on SIGTERM (rclpy handles it as SIGINT; the recorder closes its
    file); a stopped one must run again to handle it; a process still importing ends quietly, where SIGINT
    would print a KeyboardInterrupt traceback from the middle of an import.
    """
    for p in procs:
        if p.poll() is None:
            for sig in (signal.SIGCONT, signal.SIGTERM):
                try:
                    p.send_signal(sig)
                except ProcessLookupError:
                    pass
    end = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(end - time.monotonic(), 0.01))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


class Supervisor:
    """The node processes of one session.

    Args:
        namespace: the rig's namespace.
        env: the nodes' environment (ROS_DOMAIN_ID ...).
    """

    def __init__(self, namespace: str, env: dict) -> None:
        self.namespace = namespace
        self.env = {**env, DIE_WITH_PARENT_ENV: str(os.getpid())}
        self.nodes: dict[str, NodeProcess] = {}
        self.death: Death | None = None  # the first, kept

    def start(self, name: str, params: dict, *, module: str | None = None, finishes: bool = False) -> NodeProcess:
        """Start node ``name`` (module ``ambid_nodes.<module or name>``) with ``params``; ``finishes``: it
        ends its run by itself and exits (the plant), which is no death."""
        cmd = [sys.executable, "-m", f"ambid_nodes.{module or name}", *ros_args(self.namespace, params)]
        # its own session: a terminal's ^C reaches the orchestrator only, which stops the nodes in order
        proc = subprocess.Popen(cmd, env=self.env, stdout=subprocess.PIPE, text=True, start_new_session=True)
        node = NodeProcess(name, proc, expected_exit=finishes)
        threading.Thread(target=node.read_stdout, name=f"{name}_stdout", daemon=True).start()
        self.nodes[name] = node
        return node

    def check(self) -> Death | None:
        """The first node that died (exited while it was not expected to, or is stopped); remembered."""
        if self.death is not None:
            return self.death
        now = time.monotonic()
        for node in self.nodes.values():
            code = node.proc.poll()
            if code is not None:
                if node.expected_exit and code in (0, 1):
                    continue  # done, or its run failed: its summary says why
                self.death = Death(node.name, exit_words(code), node.proc.pid, now)
                return self.death
            how = stopped_words(node.proc.pid)
            if how is not None:
                self.death = Death(node.name, how, node.proc.pid, now)
                return self.death
        return None

    def exited(self, name: str) -> bool:
        return self.nodes[name].proc.poll() is not None

    def stop(self, names: list[str] | None = None, grace_s: float = STOP_GRACE_S) -> None:
        """End the named nodes (default: all, in reverse start order): :func:`stop_processes`."""
        stop_processes([self.nodes[n].proc for n in (names or list(self.nodes)[::-1])], grace_s)

    def stop_all(self, grace_s: float = STOP_GRACE_S) -> None:
        self.stop(None, grace_s)


def consequence(node: str, failure: dict | None, finished: bool = False) -> str:
    """What a node's death did to the session, for the one line (``finished``: the plant ended its run
    meanwhile, as it should)."""
    code = (failure or {}).get("code")
    if code == "controller_lost":
        return "the plant went to its safe state there, the rotor landed"
    if code == "excitation_lost":
        return "the plant waited there for excitation that never came"
    if finished:
        return f"the plant had finished its run; the session was ended without {node}"
    return {"plant_sim": "the loop stopped with it", "hardware_bridge": "the target's samples stopped reaching ROS",
            "position_controller": "the loop stopped there",
            "excitation_generator": "no more excitation: the session was ended there",
            "frf_consumer": "no live estimate: the session was ended there",
            "recorder": "nothing more was recorded: the session was ended there"}.get(node, "the session was ended there")
