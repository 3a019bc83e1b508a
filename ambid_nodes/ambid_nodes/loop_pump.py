"""The loop nodes' message pump: their loop subscriptions' messages taken, stepped and answered in compiled code.

:mod:`ambid_nodes._loop_pump` (a C extension) runs a node's compiled kernel on
each message of its loop subscription, publishes the answer with rcl and takes
the next message of any loop node of the same context itself, so the plant
and controller composed in one process answer each other without a Python
frame or an executor dispatch per message; what a kernel leaves undone goes to
the node's Python handler. One pump per rclpy context: the nodes sharing it
are spun by one executor, as every ambid graph is.

Each entry accepts the messages of its session's partner only (``entry.accept(gid)``, the GID rmw gives
with every message; ``ambid_nodes.identity.LoopPartner``): a foreign publisher's messages are counted and
dropped in C. A *tap* (no kernel, no publisher) hands every accepted message to its handler: the recorder
takes ``/clock`` and the loop topics so, from its session's publishers only; taps have a pump of their own,
so the loop's pump takes from its two entries only.
"""

from __future__ import annotations

import weakref
from typing import Callable

import numpy as np
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.type_support import check_for_type_support

from ambid_nodes import qos
from ambid_nodes.loop_call import BoundKernel

try:
    from ambid_nodes._loop_pump import GID_SIZE, NOT_RUN, Entry, Pump
except ImportError as exc:  # pragma: no cover - a set-up problem, not a code path
    raise ImportError("ambid_nodes._loop_pump, the loop nodes' C extension, is not built: run "
                      "'./launch_scripts/ambid setup' (it needs gcc, the Python headers and rcl's headers)") from exc

# messages one pump call takes before the executor serves timers, services and other topics again
# (~1-3 ms); a subscriber of a loop topic in the same process then has up to BUDGET / 2 queued
BUDGET = 64
_PUMPS: dict[str, weakref.WeakKeyDictionary] = {"loop": weakref.WeakKeyDictionary(),  # rclpy Context -> Pump
                                                "taps": weakref.WeakKeyDictionary()}
# the kick: a message to the node's own hidden topic, whose event the executor queues behind
# every event queued before it (a timer's can come sooner: rclpy's timers manager may have
# queued its next check before them)
KICK_TOPIC = "~/_loop_pump_kick"
KICK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

TAP_CONTEXT_WORDS = 6  # _loop_pump.c's N_LOOP: a tap's context, never read

__all__ = ["BUDGET", "GID_SIZE", "NOT_RUN", "Entry", "GatingState", "LoopEntry", "Pump", "pump_of"]


def pump_of(context, kind: str = "loop") -> Pump:
    """The loop pump of an rclpy context (``kind`` "taps": the pump of its taps), made on first use."""
    pumps = _PUMPS[kind]
    pump = pumps.get(context)
    if pump is None:
        pump = pumps[context] = Pump(BUDGET)
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

    The subscription is the pump's, not the executor's (rmw's new-message
    callback wakes the pump; the node's other entities stay the executor's).
    Per message: with the gate word of the kernel's context open and k below
    its limit (``loop_kernels.LOOP_*``), the kernel runs; where it returns
    ``LOOP_DONE`` the pump publishes the answer it packed and adds 1 to k and
    to the count word. Anything else goes to ``handler(data: bytes, code: int)``
    on the executor's thread: ``code`` is what the kernel returned, or
    :data:`NOT_RUN` where it did not run. A message that comes while the pump
    is idle, and every :data:`BUDGET` messages, the pump kicks itself through
    the node's hidden topic :data:`KICK_TOPIC`, so it runs on the executor's
    thread, after what queued there before. :meth:`close` before the node
    destroys its entities.

    ``kernel`` and ``publisher`` None: a tap, whose every message goes to
    ``handler(data, NOT_RUN)`` (in the pump of the context's taps).
    """

    def __init__(self, node: Node, msg_type, topic: str, qos_profile: QoSProfile, publisher: Publisher | None,
                 kernel: BoundKernel | None, handler: Callable[[bytes, int], None]) -> None:
        check_for_type_support(msg_type)
        tap = kernel is None
        if tap != (publisher is None):
            raise ValueError("LoopEntry: a tap has neither kernel nor publisher; a loop entry has both")
        with node.handle:  # as Node.create_subscription does, without handing it to the executor
            self.subscription = _rclpy.Subscription(node.handle, msg_type, topic,
                                                     qos.subscription(qos_profile).get_c_qos_profile())
        kick_topic = KICK_TOPIC + ("_tap" + self.subscription.get_topic_name().replace("/", "_") if tap else "")
        self._kick_pub = node.create_publisher(msg_type, kick_topic, KICK_QOS)
        self._kick_sub = node.create_subscription(msg_type, kick_topic, self._resume, KICK_QOS, raw=True)
        # entering an rclpy handle defers its destruction until the matching exit: the pump's
        # addresses stay valid until close()
        self._handles = [self.subscription, self._kick_pub.handle] + ([] if tap else [publisher.handle])
        for h in self._handles:
            h.__enter__()
        try:
            context = kernel.context if not tap else np.zeros(TAP_CONTEXT_WORDS, dtype=np.int64)
            self.entry = pump_of(node.context, "taps" if tap else "loop").add(
                self.subscription.pointer, 0 if tap else publisher.handle.pointer, 0 if tap else kernel.address,
                context, handler, self._kick_pub.handle.pointer, serialize_message(msg_type()), tuple(self._handles))
        except BaseException:
            self._release()
            raise

    def _resume(self, _kick: bytes) -> None:
        self.entry.resume()

    def close(self) -> None:
        """Out of the pump, the subscription destroyed, the handles released (idempotent)."""
        if not self._handles:
            return
        self.entry.close()
        self._release()
        self.subscription.destroy_when_not_in_use()

    def _release(self) -> None:
        while self._handles:
            self._handles.pop().__exit__(None, None, None)
