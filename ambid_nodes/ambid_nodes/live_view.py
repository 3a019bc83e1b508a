"""live_view: a Foxglove WebSocket server showing the session running on this ROS domain.

Subscribes, in its namespace, ``measurement`` (SampleBlock; KEEP_LAST, so a
slow live view can never make the plant wait: a block it misses is counted
and its periods left out of the live FRF), the latched
``excitation/design``, every node's ``status`` and the ``events``. Each
message is handed as it is to :class:`ambid.live.server.LiveServer`, which
queues it (bounded) for its own thread: the Foxglove frames, the live FRF
and the WebSocket server are the core's (:mod:`ambid.live`). Run it as
``ambid live PORT`` (attached to a running graph) or let ``ambid identify
--live PORT`` / ``ambid graph --live PORT`` start it.

Parameters: ``port`` (0: any free one), ``host`` (127.0.0.1: this machine
only), ``estimator`` (the session's FRF estimator), ``signal_rate_hz``
(the most envelope pairs of the time plot per second of session time),
``display_rate_hz`` (the most times per wall second the time plot's envelope
and the orbits are sent: what a viewer draws, not what a session many times
faster than real time could send), ``session`` (the session to show: another
source's messages on the same topics are counted per topic, never shown; 0
shows every source). On exit it prints one line ``AMBID_SUMMARY {json}`` of
its figures (frames sent, frames dropped, blocks lost, foreign messages, ...).
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading
import time


def autogroup(pid: int | str = "self") -> tuple[str, int] | None:
    """The autogroup scheduling ``pid`` and its nice, e.g. ``("/autogroup-2323", 0)``; None where none does.

    The kernel prints ``/proc/PID/autogroup`` only for a task whose session has an autogroup of its own
    (kernel/sched/autogroup.c, proc_sched_autogroup_show_task); it prints nothing when the session's group is
    the root one (seen in a container on CI) and the file is absent without CONFIG_SCHED_AUTOGROUP: in both,
    no autogroup weighs the task, its nice is all there is.
    """
    try:
        with open(f"/proc/{pid}/autogroup") as f:
            words = f.read().split()
    except OSError:
        return None
    if len(words) != 3 or words[1] != "nice":
        return None
    return words[0], int(words[2])


def lower_priority(niceness: int) -> dict:
    """Make this process yield the CPU: ``niceness`` more nice, and so its autogroup where it leads one.

    With the kernel's autogroups (``/proc/sys/kernel/sched_autogroup_enabled``, on by default in most
    distributions) every session is scheduled as one group against the others, a task's nice weighing only
    inside its group: the live view, a session of its own (LiveProcess), niced alone still took as much CPU
    as the loop's whole session. Its autogroup's nice is raised too; each step only where permitted (a
    process may always lower its own priority) and only where the kernel shows an autogroup (:func:`autogroup`).
    Call it before any thread starts: threads inherit it. What was applied, as the kernel reports it
    afterwards, e.g. ``{"nice": 10, "autogroup_nice": 10}`` (no ``autogroup_nice`` where none was raised).
    """
    done = {"nice": os.nice(niceness)}
    # the autogroup is this session's own (nothing else is made nicer) and one the kernel shows
    if os.getsid(0) == os.getpid() and autogroup() is not None:
        for _ in range(20):   # without CAP_SYS_ADMIN the kernel takes one such write a 0.1 s, machine-wide
            try:
                with open("/proc/self/autogroup", "w") as f:
                    f.write(str(done["nice"]))
                break
            except BlockingIOError:   # EAGAIN: another process's write came within 0.1 s
                time.sleep(0.05)
            except OSError:
                break
        group = autogroup()
        if group is not None and group[1] == done["nice"]:   # what the kernel says it has, not what was asked
            done["autogroup_nice"] = group[1]
    return done


if __name__ == "__main__" and os.environ.get("AMBID_LIVE_NICENESS", "").isdigit():
    # started by LiveProcess: lower the priority before any import starts a thread, so that all inherit it
    PRIORITY = lower_priority(int(os.environ.pop("AMBID_LIVE_NICENESS")))
else:
    PRIORITY = {}   # what lower_priority applied to this process (reported in the live view's figures)

from ambid.excitation import ExcitationDesign
from ambid.frf.streaming import ESTIMATORS
from ambid.live.follower import SessionFollower
from ambid.live.server import LiveServer, LiveUnavailable
from ambid.recording.blocks import decode_sample_block, sample_block_session
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ambid_msgs.msg import ExcitationDesign as DesignMsg
from ambid_msgs.msg import SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid_nodes.identity import SESSION_PARAMETER
from ambid_nodes.parameters import ParameterError, declare, refuse_unknown

# reliable, so that a fragment lost on the way is sent again, but KEEP_LAST: the plant's writer (KEEP_LAST 200)
# never waits for this reader; a live view 200 blocks (20 s of a 10 kHz session) behind loses the oldest
LIVE_BLOCKS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)


LIVE_NICENESS = 10   # the live view's niceness beside a session: the loop first
DESIGN_LINE = "live view: experiment "   # printed on each design shown
FINISHED_LINE = "live view: finished "   # printed once it has shown an experiment's last period


def _t_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class LiveView(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("live_view", **kwargs)
        port = declare(self, "port", 8765, "TCP port of the Foxglove WebSocket server (0: any free one)", 0, 65535)
        host = declare(self, "host", "127.0.0.1", "address the server binds (0.0.0.0: every interface)")
        estimator = declare(self, "estimator", "indirect", "the session's FRF estimator: " + " | ".join(ESTIMATORS))
        rate = declare(self, "signal_rate_hz", 200.0, "most envelope pairs (each channel's min and max) of the time "
                       "plot per second of session time", 1.0, 10_000.0, "Hz")
        display = declare(self, "display_rate_hz", 30.0, "most times per wall second the time plot's envelope and "
                          "the orbits are sent (a viewer draws ~30 a second; a simulated session runs faster than "
                          "real time); 0: after every block", 0.0, 1000.0, "Hz")
        self.session = declare(self, *SESSION_PARAMETER)
        self.foreign: dict[str, int] = {}   # topic -> messages of another session, not shown
        refuse_unknown(self)
        if estimator not in ESTIMATORS:
            raise ParameterError(f"live_view: estimator '{estimator}' is not one of {list(ESTIMATORS)}")
        prefix = self.get_namespace().rstrip("/") + "/live"
        try:
            # at most one live estimate a wall second: a viewer reads them, a simulated session completes
            # records several times faster (each costs the estimate, 16 entries' frames and the client's decoding)
            follower = SessionFollower(estimator, rate, estimate_every_s=1.0)
            self.server = LiveServer(int(port), host, follower, prefix=prefix,
                                     queue_size=256, display_hz=float(display)).start()
        except LiveUnavailable as exc:
            raise ParameterError(f"live_view: {exc}") from None
        self.create_subscription(SampleBlock, "measurement", self.on_block, LIVE_BLOCKS, raw=True)
        self.create_subscription(DesignMsg, "excitation/design", self.on_design, qos.subscription(qos.LATCHED))
        self.create_subscription(SessionStatus, "status", self.on_status, qos.subscription(qos.STATUS))
        self.create_subscription(SessionEvent, "events", self.on_event, qos.subscription(qos.EVENTS))
        self.finished: set[str] = set()   # experiments whose end the live view has shown
        self.create_timer(0.2, self.say_finished)
        self.cpu_at_start = time.process_time()
        self.get_logger().info(f"live view on {self.server.url} (topics {prefix}/...)")

    def say_finished(self) -> None:
        """Print once per experiment when the live view has shown its end, for a supervising command
        (LiveProcess.wait_finished): a live view behind the loop catches up once the loop is over."""
        f = self.server.follower
        if f.experiment_id and f.experiment_id not in self.finished and f.stream is not None and f.stream.finished:
            self.finished.add(f.experiment_id)
            print(f"{FINISHED_LINE}{f.experiment_id}", flush=True)

    def foreign_message(self, topic: str, msg, session_id: int | None = None) -> bool:
        """True (and counted) if ``msg`` (or a message of ``session_id``) is of another session than the one
        shown."""
        if not self.session or (msg.session_id if session_id is None else session_id) == self.session:
            return False
        self.foreign[topic] = self.foreign.get(topic, 0) + 1
        return True

    def on_block(self, cdr: bytes) -> None:
        """A measurement block as its CDR bytes, its samples read in place: the blocks are most of what the live
        view takes (some 100 kB each), and made into a message first each was copied twice more."""
        try:
            if self.foreign_message("measurement", None, sample_block_session(cdr)):
                return
            block = decode_sample_block(cdr)
        except ValueError:
            return   # malformed: the session's own nodes say so; the live view shows what it can
        if block.n_samples <= 0 or not block.channel_names:
            return
        self.server.submit("block", block.first_index, block.sample_period_s, list(block.channel_names),
                           block.data)

    def on_design(self, msg: DesignMsg) -> None:
        if self.foreign_message("excitation/design", msg):
            return
        try:
            design = ExcitationDesign.from_dict(json.loads(msg.design_json))
        except (ValueError, KeyError, TypeError) as exc:
            self.get_logger().warning(f"excitation/design {msg.experiment_id!r} not shown: {exc}")
            return
        self.server.submit("design_message", msg.experiment_id, design, int(msg.start_index), int(msg.total_samples))
        print(f"{DESIGN_LINE}{msg.experiment_id}", flush=True)   # for a supervising command (LiveProcess)

    def on_status(self, msg: SessionStatus) -> None:
        if self.foreign_message("status", msg):
            return
        self.server.submit("status_message", msg.node, int(msg.state), int(msg.sample_index), float(msg.progress),
                           int(msg.messages_received), int(msg.messages_rejected), msg.text,
                           dict(zip(msg.keys, msg.values)), _t_ns(msg.stamp))

    def on_event(self, msg: SessionEvent) -> None:
        if self.foreign_message("events", msg):
            return
        self.server.submit("event_message", msg.node, int(msg.severity), msg.code, msg.text, int(msg.sample_index),
                           _t_ns(msg.stamp))

    def close(self) -> dict:
        """Stop the server (what is queued is shown first); its figures, with the foreign messages not shown,
        the CPU seconds the process used since it listened (``cpu_s``: every thread, the SDK's included) and the
        priority it runs at (``priority``: :func:`lower_priority`'s answer, {} if it was started without one)."""
        return {**self.server.close(), "foreign_messages": dict(self.foreign),
                "cpu_s": time.process_time() - self.cpu_at_start, "priority": dict(PRIORITY)}


class LiveProcess:
    """``live_view`` as a process of its own beside a graph, on the same ROS domain and namespace: its work
    and its clients never share the loop's interpreter (nor its GIL).

    Args:
        port, host: where the server listens (port 0: any free one, :attr:`url` says which).
        namespace: the session's namespace.
        estimator: the session's FRF estimator.
        domain_id: ROS_DOMAIN_ID of the session.
        session: the session's id (0: show every source).
    """

    def __init__(self, port: int, host: str, namespace: str, estimator: str, domain_id: int,
                 session: int = 0) -> None:
        from ambid_nodes.supervisor import ros_args

        # a viewer yields the CPU to the loop it shows: beside a busy process on two cores the live view and its
        # client's frames took the loop's turns (0.83 of the loop without them); the process lowers its priority
        # (and its autogroup's: it leads a session of its own) before any thread starts, so that all inherit it
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), AMBID_LIVE_NICENESS=str(LIVE_NICENESS))
        self._lines: queue.Queue = queue.Queue()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "ambid_nodes.live_view",
             *ros_args(namespace, {"port": int(port), "host": host, "estimator": estimator, "session": session})],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.url = ""
        self.errors: list[str] = []
        threading.Thread(target=self._read, args=(self.proc.stdout, True), daemon=True).start()
        threading.Thread(target=self._read, args=(self.proc.stderr, False), daemon=True).start()

    def _read(self, stream, is_stdout: bool) -> None:
        for line in stream:
            if is_stdout:
                self._lines.put(line.rstrip("\n"))
            elif line.startswith("error:") or "Error" in line:
                self.errors.append(line.strip())
        if is_stdout:
            self._lines.put(None)

    def _stdout(self, timeout_s: float):
        """The process's output lines, until it closes its output or ``timeout_s`` passes."""
        end = time.monotonic() + timeout_s
        while (left := end - time.monotonic()) > 0:
            try:
                line = self._lines.get(timeout=min(left, 0.1))
            except queue.Empty:
                continue
            if line is None:
                return
            yield line

    def wait_ready(self, timeout_s: float = 120.0) -> str:
        """Wait until the server listens; its URL. RuntimeError with the process's own words if it could not."""
        if self.url:
            return self.url
        for line in self._stdout(timeout_s):
            if line.startswith("live view: "):
                self.url = line[len("live view: "):]
                return self.url
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise RuntimeError(f"the live view did not listen within {timeout_s:g} s") from None
        why = "; ".join(e.removeprefix("error: ") for e in self.errors) or f"exit code {self.proc.returncode}"
        raise RuntimeError(f"the live view did not start: {why}")

    def wait_design(self, experiment_id: str, timeout_s: float = 60.0) -> None:
        """Wait until the live view has the experiment's design (so it shows the experiment from its first
        sample); RuntimeError if it has not within ``timeout_s``."""
        for line in self._stdout(timeout_s):
            if line == DESIGN_LINE + experiment_id:
                return
        raise RuntimeError(f"the live view did not get the design of {experiment_id} within {timeout_s:g} s")

    def wait_finished(self, experiment_id: str, timeout_s: float = 30.0) -> bool:
        """Wait until the live view has shown the end of the experiment (it runs nicer than the loop, so on a
        busy machine it may still be catching up when the session ends); False if it has not within
        ``timeout_s``."""
        return any(line == FINISHED_LINE + experiment_id for line in self._stdout(timeout_s))

    def stop(self) -> dict:
        """SIGTERM, then its figures (from its summary line); {} if it printed none."""
        from ambid_nodes.supervisor import stop_processes
        from ambid_nodes.node_main import SUMMARY_PREFIX

        stop_processes([self.proc], grace_s=10.0)
        figures: dict = {}
        for line in self._stdout(5.0):
            if line.startswith(SUMMARY_PREFIX):
                figures = json.loads(line[len(SUMMARY_PREFIX):])
        return figures


def main(args=None) -> int:
    """Run the live view until SIGINT/SIGTERM; print its figures as ``AMBID_SUMMARY {json}``.
    Exit codes: 0, 2 bad parameters or the port cannot be bound."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    from ambid_nodes.node_main import SUMMARY_PREFIX, apply_network_defaults, spin_until_done
    from rclpy.task import Future
    apply_network_defaults()
    rclpy.init(args=args)
    executor = EventsExecutor()
    node = None
    code = 0
    try:
        node = LiveView()
        print(f"live view: {node.server.url}", flush=True)
        executor.add_node(node)
        spin_until_done(executor, Future())
    except ParameterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = 2
    except KeyboardInterrupt:
        pass
    finally:
        executor.shutdown()
        if node is not None:
            print(SUMMARY_PREFIX + json.dumps(node.close()), flush=True)
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
