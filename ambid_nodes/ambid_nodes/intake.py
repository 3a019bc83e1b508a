"""What a node receives, per topic: every message received is accepted, rejected with its reason, or foreign.

Every subscription of an ambid node is raw (CDR bytes) and decoded here, so a
message that does not deserialize is counted and reported instead of being
dropped silently by rclpy, and a handler that raises cannot stop the node's
executor. Handlers signal a bad message by raising
:class:`~ambid_nodes.conversions.BadMessage`; any other exception is a bug,
counted apart (``errors``) and reported as an ERROR event, and the message
counts as rejected.

Reports are rate-limited, so a flood of bad messages costs the node little
(rclpy's logger inspects the call stack on every call, a few ms, even when
throttled): each rejection is reported as an event while a budget of
``EVENT_BURST`` events, refilled at ``EVENT_RATE`` per second, lasts; beyond it
rejections are folded into the next event, which says how many; the log gets
at most one line per ``LOG_PERIOD_S``.

A node with a session (``ambid_nodes.identity``) acts only on its own session's messages: one of
another session (or of none) is *foreign*, counted, its publishers named from the graph, reported as a
``foreign_message`` event within the same budget, and never handed to the handler. The loop topics' foreign
messages are counted in C by the loop pump (:meth:`Tally.count_foreign_also`).

The counters are reported in every node's ``status`` (``keys``/``values``
``received:<topic>``, ``accepted:<topic>``, ``rejected:<topic>``, ``foreign:<topic>`` and
``foreign_from:<topic>`` (the foreign publishers named) where there were any, and
``handler_errors`` when there were any); ``received == accepted + rejected + foreign``
holds per topic at any moment between callbacks.
"""

from __future__ import annotations

import collections
import time
from typing import Callable

import numpy as np
from ambid.session_id import format_session
from rclpy.node import Node

from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, decode_message

EVENT_BURST = 50       # rejection events reported back to back
MAX_NAMES = 8          # foreign publishers named per topic in status
EVENT_RATE = 10.0      # rejection events per second beyond the burst
LOG_PERIOD_S = 1.0     # log lines about rejections at most this often


class Tally:
    """Messages of one topic accepted and rejected so far; received = accepted + rejected.

    The loop handlers add to ``accepted`` directly (an attribute, no call). The messages a
    compiled path accepts it counts itself, in an int64 word :meth:`count_also` names.
    """

    __slots__ = ("_accepted", "rejected", "_also", "_foreign", "_foreign_also", "names")

    def __init__(self) -> None:
        self._accepted = 0
        self.rejected = 0
        self._also: np.ndarray | None = None
        self._foreign = 0
        self._foreign_also = None  # an object whose ``foreign`` counts more (a loop partner)
        self.names: set[str] = set()  # the foreign publishers named so far (at most MAX_NAMES)

    @property
    def foreign(self) -> int:
        return self._foreign + (self._foreign_also.foreign if self._foreign_also is not None else 0)

    def count_foreign_also(self, source) -> None:
        """Count ``source.foreign`` (messages a compiled path dropped as foreign) as foreign too."""
        self._foreign_also = source

    @property
    def accepted(self) -> int:
        return self._accepted + (int(self._also[0]) if self._also is not None else 0)

    @accepted.setter
    def accepted(self, value: int) -> None:
        self._accepted = value - (int(self._also[0]) if self._also is not None else 0)

    def count_also(self, word: np.ndarray) -> None:
        """Count the messages a compiled path accepts and adds to ``word[0]`` (an int64 view) as accepted."""
        accepted = self.accepted
        self._also = word
        self.accepted = accepted


class Intake:
    """Per-topic counters of one node and its raw, decoding subscriptions.

    Args:
        node: the node that subscribes.
        on_reject: ``on_reject(topic, why)`` reports a rejected message as an event (the node's
            conventions); called within the event budget, ``why`` then says how many were folded.
        on_error: ``on_error(topic, why)`` reports a handler bug (an ERROR event), same budget.
        session: the node's session (``ambid_nodes.identity.SessionIdentity``); None or open: every
            well-formed message is the node's.
        on_foreign: ``on_foreign(topic, why)`` reports foreign messages (a ``foreign_message`` WARN event),
            same budget; needed with a session.
    """

    def __init__(self, node: Node, on_reject: Callable[[str, str], None],
                 on_error: Callable[[str, str], None], session=None,
                 on_foreign: Callable[[str, str], None] | None = None) -> None:
        self.node = node
        self.on_reject = on_reject
        self.on_error = on_error
        self.session = session if session is not None and not session.open else None
        self.on_foreign = on_foreign
        self.tallies: dict[str, Tally] = {}
        self.errors = 0
        self._tokens = float(EVENT_BURST)
        self._refilled = time.monotonic()
        self._folded = 0
        self._last_log = -1e9
        self._log_folded = 0

    def subscribe(self, msg_type, topic: str, handler: Callable, qos_profile):
        """A raw subscription whose messages are decoded and handed to ``handler(msg)``.

        ``handler`` raises BadMessage to reject a message; returning normally accepts it.
        """
        tally = self.tally(topic)
        session = self.session
        name = self.node.resolve_topic_name(topic)

        def on_raw(data: bytes) -> None:
            try:
                msg = decode_message(data, msg_type, topic)
                if session is not None and msg.session_id != session.id:
                    self.foreign(topic, msg.session_id, getattr(msg, "node", "") or getattr(msg, "name", ""),
                                 resolved=name)
                    return
                handler(msg)
            except BadMessage as exc:
                self.reject(topic, str(exc))
                return
            except Exception as exc:  # noqa: BLE001 - a bug must not stop the node; it is reported
                self.errors += 1
                self.reject(topic, f"{topic}: the node failed to handle the message ({type(exc).__name__}: {exc})",
                            error=True)
                return
            tally.accepted += 1

        return self.node.create_subscription(msg_type, topic, on_raw, qos.subscription(qos_profile), raw=True)

    # for hand-written raw handlers (the lock-step loop): accept or reject each message exactly once
    def tally(self, topic: str) -> Tally:
        """The counters of ``topic`` (created at zero)."""
        t = self.tallies.get(topic)
        if t is None:
            t = self.tallies[topic] = Tally()
        return t

    def accept(self, topic: str) -> None:
        self.tally(topic).accepted += 1

    def foreign(self, topic: str, session_id: int | None = None, who: str = "", gid: bytes | None = None,
                count: bool = True, resolved: str | None = None) -> None:
        """A foreign message on ``topic``: counted (unless a compiled path counted it), its publishers named
        (``gid``: the one that sent it; else those of the topic the graph shows that are not of this
        session, or ``who``, the node the message names), reported."""
        t = self.tally(topic)
        if count:
            t._foreign += 1
        name = resolved or self.node.resolve_topic_name(topic)
        if self.session is None:
            names = []
        elif gid is not None:
            names = [self.session.name_gid(gid, name)]
        else:
            names = self.session.foreign_publishers(name)
        if not names:
            names = [f"{who or 'a publisher gone from the graph'} (session {format_session(session_id or 0)})"]
        if gid is None:  # the topic's foreign publishers as the graph shows them now
            t.names = set(names[:MAX_NAMES])
        else:  # one more publisher of a loop topic
            for n in names:
                if len(t.names) < MAX_NAMES:
                    t.names.add(n)
        sid = f" of session {format_session(session_id)}" if session_id is not None else ""
        ours = format_session(self.session.id) if self.session is not None else "none"
        why = f"{name}: a message{sid} from {', '.join(names)}, not of this session ({ours}): counted, not acted on"
        self._report(topic, why, False, self.on_foreign or self.on_reject, "foreign")

    def reject(self, topic: str, why: str, error: bool = False) -> None:
        self.tally(topic).rejected += 1
        self._report(topic, why, error, self.on_error if error else self.on_reject, "rejected")

    def _report(self, topic: str, why: str, error: bool, report: Callable[[str, str], None], what: str) -> None:
        """One log line a second at most, and an event within the budget (both shared by every kind)."""
        now = time.monotonic()
        if now - self._last_log >= LOG_PERIOD_S or error:
            more = f" ({self._log_folded} more since the last line)" if self._log_folded else ""
            log = self.node.get_logger()
            so_far = self.total_rejected if what == "rejected" else self.total_foreign
            (log.error if error else log.warn)(f"{what} message ({so_far} so far): {why}{more}")
            self._last_log, self._log_folded = now, 0
        else:
            self._log_folded += 1
        self._tokens = min(EVENT_BURST, self._tokens + (now - self._refilled) * EVENT_RATE)
        self._refilled = now
        if self._tokens < 1.0 and not error:
            self._folded += 1
            return
        self._tokens -= 1.0
        if self._folded:
            why += f" ({self._folded} more rejected or foreign messages since the last event, not reported one by one)"
            self._folded = 0
        report(topic, why)

    @property
    def received(self) -> collections.Counter[str]:
        """Messages received per topic (a snapshot)."""
        return collections.Counter({t: c.accepted + c.rejected + c.foreign for t, c in self.tallies.items()})

    @property
    def accepted(self) -> collections.Counter[str]:
        """Messages accepted per topic (a snapshot)."""
        return collections.Counter({t: c.accepted for t, c in self.tallies.items()})

    @property
    def rejected(self) -> collections.Counter[str]:
        """Messages rejected per topic (a snapshot)."""
        return collections.Counter({t: c.rejected for t, c in self.tallies.items()})

    @property
    def foreign_counts(self) -> collections.Counter[str]:
        """Foreign messages per topic (a snapshot)."""
        return collections.Counter({t: c.foreign for t, c in self.tallies.items()})

    @property
    def total_received(self) -> int:
        return sum(c.accepted + c.rejected + c.foreign for c in self.tallies.values())

    @property
    def total_rejected(self) -> int:
        return sum(c.rejected for c in self.tallies.values())

    @property
    def total_foreign(self) -> int:
        return sum(c.foreign for c in self.tallies.values())

    def figures(self) -> dict:
        """``{"received:<topic>": n, "accepted:<topic>": n, "rejected:<topic>": n, ...}`` for status."""
        out: dict = {}
        for topic in sorted(self.tallies):
            c = self.tallies[topic]
            foreign = c.foreign
            out[f"received:{topic}"] = c.accepted + c.rejected + foreign
            out[f"accepted:{topic}"] = c.accepted
            out[f"rejected:{topic}"] = c.rejected
            if foreign:
                out[f"foreign:{topic}"] = foreign
                out[f"foreign_from:{topic}"] = sorted(c.names)
        if self.errors:
            out["handler_errors"] = self.errors
        return out
