"""A loop node's subscription callback run in compiled code: kernel and answer, no Python frame."""

from __future__ import annotations

from typing import Callable

from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile

from ambid_nodes.loop_call import BoundKernel

try:
    from ambid_nodes._loop_callback import NOT_RUN, LoopCallback
except ImportError as exc:  # pragma: no cover - a set-up problem, not a code path
    raise ImportError("ambid_nodes._loop_callback, the loop nodes' C extension, is not built: run "
                      "'./launch_scripts/ambid setup' (it needs gcc, the Python headers and rcl's headers)") from exc

__all__ = ["NOT_RUN", "KernelCallback", "LoopCallback"]


class KernelCallback:
    """A raw subscription of ``node`` to ``topic`` whose messages go through ``kernel``, their
    answers out on ``publisher``.

    Its callback is a :class:`LoopCallback` (:mod:`ambid_nodes._loop_callback`). Per message: with the gate word of the kernel's context open and k below
    its limit (``loop_kernels.LOOP_*``), the kernel runs; where it returns
    ``LOOP_DONE`` the answer it packed is published and k and the count word
    go up by 1. Anything else goes to ``handler(data: bytes, code: int)``:
    ``code`` is what the kernel returned, or :data:`NOT_RUN` where it did not
    run. The publisher's rcl handle is held until :meth:`close`, which the node
    calls before it destroys its entities.
    """

    def __init__(self, node: Node, msg_type, topic: str, qos_profile: QoSProfile, publisher: Publisher,
                 kernel: BoundKernel, handler: Callable[[bytes, int], None]) -> None:
        self.handler = handler
        self.subscription = node.create_subscription(msg_type, topic, self.not_run, qos_profile, raw=True)
        # entering an rclpy handle defers its destruction until the matching exit: the compiled
        # callback's publisher address stays valid while it may be called
        self._handle = publisher.handle
        self._handle.__enter__()
        try:
            self.callback = LoopCallback(self._handle.pointer, kernel.address, kernel.context, handler)
        except BaseException:
            self.close()
            raise
        self.subscription.callback = self.callback

    def close(self) -> None:
        """Hand every further message to the handler and release the publisher (idempotent)."""
        if self._handle is None:
            return
        self.subscription.callback = self.not_run
        self._handle.__exit__(None, None, None)
        self._handle = None

    def not_run(self, data: bytes) -> None:
        self.handler(data, NOT_RUN)
