"""The shape every node of a session shares: identity, intake, events and ``main``, written once.

A node of a session (docs/sessions.md) declares its own typed parameters, then joins the session
(:meth:`SessionNode.join_session`: the ``session`` parameter, unknown parameters refused, its
:class:`~ambid_nodes.identity.SessionIdentity`); it takes messages through one
:class:`~ambid_nodes.intake.Intake` (:meth:`SessionNode.make_intake`) whose rejected, foreign and failed
messages become ``rejected_message``, ``foreign_message`` and ``handler_error`` events; every event carries
the sample index the node stands at (:meth:`SessionNode.event_index`) and its time. A node file keeps only
what makes it itself: its parameters, topics, the handling of its messages, and where it stands.
"""

from __future__ import annotations

import signal

from rclpy.node import Node

from ambid_msgs.msg import SessionEvent
from ambid_nodes.conversions import time_msg
from ambid_nodes.identity import SESSION_PARAMETER, SessionIdentity
from ambid_nodes.intake import Intake
from ambid_nodes.node_main import run_single
from ambid_nodes.parameters import declare, refuse_unknown


class SessionNode(Node):
    """A ROS node of a session; a subclass creates ``pub_event`` (the identity's publisher of ``events``) and
    ``dt`` [s], the sample period its events are dated in."""

    identity: SessionIdentity
    dt: float
    # SIGINT and SIGTERM end the node's run without raising anywhere (:func:`stop_on_signal`): a node that
    # writes a file (the recorder) must not be interrupted in the middle of a write
    stop_on_signal = False

    def join_session(self) -> SessionIdentity:
        """Declare the ``session`` parameter, refuse unknown ones (call after the node's own), and join."""
        session = declare(self, *SESSION_PARAMETER)
        refuse_unknown(self)
        self.identity = SessionIdentity(self, session)
        return self.identity

    def make_intake(self) -> Intake:
        """The node's intake: its rejected, foreign and failed messages reported as events."""
        self.intake = Intake(self, self.on_reject, self.on_handler_error, self.identity, self.on_foreign)
        return self.intake

    def event_index(self) -> int:
        """The sample index the node stands at, which its events carry unless given one."""
        return 0

    def event_stamp(self, index: int):
        """The time an event at sample ``index`` carries: the sample's (a node without a sample clock, the
        recorder, says the time of now)."""
        return time_msg(index * self.dt)

    def log_event(self, severity: int, code: str, text: str) -> None:
        """Write an event to the node's log too (none by default: events are published)."""

    def event(self, severity: int, code: str, text: str, index: int | None = None) -> None:
        """Publish a :class:`SessionEvent` at ``index`` (default :meth:`event_index`); once the context is shut
        down (SIGINT, SIGTERM) there is nobody left to tell, and nothing is raised."""
        k = self.event_index() if index is None else index
        self.log_event(severity, code, text)
        msg = SessionEvent(stamp=self.event_stamp(k), sample_index=k, severity=severity,
                           node=self.get_fully_qualified_name(), code=code, text=text)
        try:
            self.pub_event.publish(msg)
        except Exception:  # noqa: BLE001 - rcl refuses a publish after shutdown; before it, the error is real
            if self.context.ok():
                raise

    def on_reject(self, topic: str, why: str) -> None:
        self.event(SessionEvent.WARN, "rejected_message", why)

    def on_foreign(self, topic: str, why: str) -> None:
        self.event(SessionEvent.WARN, "foreign_message", why)

    def on_handler_error(self, topic: str, why: str) -> None:
        self.event(SessionEvent.ERROR, "handler_error", why)

    @classmethod
    def main(cls, args=None) -> int:
        """Run this node alone until it finishes (:func:`ambid_nodes.node_main.run_single`): its console script."""
        if cls.stop_on_signal:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, stop_on_signal)
        return run_single(cls, args)


def stop_on_signal(signum, frame) -> None:
    """SIGINT/SIGTERM: shut the ROS context down so run_single leaves its spin and the node closes what it
    writes (:attr:`SessionNode.stop_on_signal`).

    rclpy's own handlers (installed by rclpy.init, chaining to this one) usually did it already.
    This handler never raises: a KeyboardInterrupt in the middle of a chunk write would corrupt the file.
    """
    from rclpy.utilities import get_default_context

    get_default_context().try_shutdown()
