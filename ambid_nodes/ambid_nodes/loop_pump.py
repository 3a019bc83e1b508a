"""The loop nodes' message pump: their loop subscriptions' messages taken, stepped and answered in compiled code.

:mod:`ambid_nodes._loop_pump` (a C extension) runs a node's compiled kernel on
each message of its loop subscription, publishes the answer with rcl and takes
the next message of any loop node of the same context itself, so the plant
and controller composed in one process answer each other without a Python
frame or an executor dispatch per message; what a kernel leaves undone goes to
the node's Python handler. One pump per rclpy context: the nodes sharing it
are spun by one executor, as every ambid graph is.
"""

from __future__ import annotations

import functools
import weakref
from typing import Callable

from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from ambid_nodes.loop_call import BoundKernel
from ambid_nodes.raw_publish import raw_publisher

try:
    from ambid_nodes._loop_pump import NOT_RUN, Entry, Pump
except ImportError as exc:  # pragma: no cover - a set-up problem, not a code path
    raise ImportError("ambid_nodes._loop_pump, the loop nodes' C extension, is not built: run "
                      "'./launch_scripts/ambid setup' (it needs gcc, the Python headers and rcl's headers)") from exc

# messages one pump call takes before the executor serves timers, services and other topics again
# (~1-3 ms); a subscriber of a loop topic in the same process then has up to BUDGET / 2 queued
BUDGET = 64
_PUMPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # rclpy Context -> Pump
# the kick: a message to the node's own hidden topic, whose event the executor queues behind
# every event queued before it (a timer's can come sooner: rclpy's timers manager may have
# queued its next check before them)
KICK_TOPIC = "~/_loop_pump_kick"
KICK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

__all__ = ["BUDGET", "NOT_RUN", "Entry", "GatingState", "LoopEntry", "Pump", "pump_of"]


def pump_of(context) -> Pump:
    """The loop pump of an rclpy context (made on first use, with :data:`BUDGET`)."""
    pump = _PUMPS.get(context)
    if pump is None:
        pump = _PUMPS[context] = Pump(BUDGET)
    return pump


class GatingState:
    """A node's state attribute whose every assignment also calls ``node.regate()``, which sets the
    gate word of its loop kernel (the pump runs the kernel only while the state allows it)."""

    def __set_name__(self, owner, name: str) -> None:
        self.attr = "_" + name

    def __get__(self, obj, objtype=None):
        return self if obj is None else getattr(obj, self.attr)

    def __set__(self, obj, value) -> None:
        setattr(obj, self.attr, value)
        obj.regate()


class LoopEntry:
    """A raw subscription of ``node`` to ``topic`` whose messages go through ``kernel`` in the
    pump of the node's context, the answers out on ``publisher``.

    Its callback is the pump's :class:`Entry`. Per message: with the gate word
    of the kernel's context open and k below its limit (``loop_kernels.LOOP_*``),
    the kernel runs; where it returns ``LOOP_DONE`` the pump publishes the
    answer it packed and adds 1 to k and to the count word. Anything else goes
    to ``handler(data: bytes, code: int)`` on the executor's thread: ``code``
    is what the kernel returned, or :data:`NOT_RUN` where it did not run. After
    :data:`BUDGET` messages the pump holds what waits and publishes a kick on
    the node's hidden topic :data:`KICK_TOPIC`: the executor serves what
    queued meanwhile, then the kick resumes the pump. :meth:`close` before the node destroys its
    entities: the entry holds the subscription's and publisher's rcl handles
    until then.
    """

    def __init__(self, node: Node, msg_type, topic: str, qos_profile: QoSProfile, publisher: Publisher,
                 kernel: BoundKernel, handler: Callable[[bytes, int], None]) -> None:
        self.handler = handler
        self.subscription = node.create_subscription(msg_type, topic, self.not_run, qos_profile, raw=True)
        kick_pub = node.create_publisher(msg_type, KICK_TOPIC, KICK_QOS)
        self._kick_sub = node.create_subscription(msg_type, KICK_TOPIC, self._resume, KICK_QOS, raw=True)
        kick = functools.partial(raw_publisher(kick_pub), serialize_message(msg_type()))
        # entering an rclpy handle defers its destruction until the matching exit: the pump's
        # addresses stay valid even if the node goes without closing the entry
        self._handles = [self.subscription.handle, publisher.handle]
        for h in self._handles:
            h.__enter__()
        try:
            self.entry = pump_of(node.context).add(self.subscription.handle.pointer, publisher.handle.pointer,
                                                   kernel.address, kernel.context, handler, kick)
        except BaseException:
            self._release()
            raise
        self.subscription.callback = self.entry

    def not_run(self, data: bytes) -> None:
        self.handler(data, NOT_RUN)

    def _resume(self, _kick: bytes) -> None:
        self.entry.resume()

    def close(self) -> None:
        """Out of the pump (every further message to the handler), the handles released (idempotent)."""
        if not self._handles:
            return
        self.entry.close()
        self.subscription.callback = self.not_run
        self._release()

    def _release(self) -> None:
        while self._handles:
            self._handles.pop().__exit__(None, None, None)
