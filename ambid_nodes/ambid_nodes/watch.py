"""session_watch: what the orchestrator of a session hears of it, from the graph.

A listener in the orchestrator's process (``ambid graph --processes``, ``ambid identify --processes``): the
plant's progress and the levitation up to there (from the ``measurement`` blocks, so the figures are true
up to the last block whichever node died), each node's last ``status``, the ``events`` that end a run, and
the foreign publishers on the session's topics, counted and named. It acts on nothing: the nodes do.

Before a session starts, :meth:`SessionWatch.foreign_publishers` lists the publishers already on the
session's topics (a rig next door, a replayed recording, a script left running): the session runs
unaffected (every node acts only on its own session's messages) and the orchestrator names them.
"""

from __future__ import annotations

import collections
import json

import numpy as np
from ambid.plant.levitation import LevitationMonitor
from ambid.recording.blocks import decode_sample_block, sample_block_session
from rclpy.node import Node

from ambid_msgs.msg import SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, decode_message
from ambid_nodes.identity import SessionIdentity, not_subscribed

# the topics of a session (relative to its namespace) a foreign publisher can reach
SESSION_TOPICS = ("displacement", "control_current", "measurement", "excitation", "excitation/design",
                  "plant/description", "controller/description", "frf", "status", "events", "session")
_EXCLUDED = SampleBlock.FLAG_CONTROLLER_LOST  # a safe state's landing: after the run under control ended


class SessionWatch(Node):
    """Listens to one session (``session_id``) in ``namespace``.

    Args:
        session_id: the session's id.
        clearance_m: the rig's backup clearance [m] (levitation judged as plant_sim judges it).
        settle_samples, after_lift_off: the levitation window (ambid.plant.levitation.LevitationMonitor).
    """

    def __init__(self, session_id: str, clearance_m: float, settle_samples: int, after_lift_off: int,
                 **kwargs) -> None:
        super().__init__("session_watch", **kwargs)
        self.identity = SessionIdentity(self, session_id)
        self.monitor = LevitationMonitor(clearance_m, settle_samples, after_lift_off)
        self.progress = 0          # end index of the session's newest measurement block
        self.blocks = 0
        self.sample_period = 0.0
        self.statuses: dict[str, SessionStatus] = {}
        self.events: list[SessionEvent] = []
        self.foreign = collections.Counter()  # topic -> foreign messages heard
        self.foreign_names: dict[str, set[str]] = collections.defaultdict(set)
        self.measurement = self.resolve_topic_name("measurement")
        sub = qos.subscription
        self.sub_measurement = self.create_subscription(SampleBlock, "measurement", self.on_measurement,
                                                        sub(qos.BLOCKS), raw=True)
        self.create_subscription(SessionStatus, "status", self.on_status, sub(qos.STATUS), raw=True)
        self.create_subscription(SessionEvent, "events", self.on_event, sub(qos.EVENTS), raw=True)

    # --- what it hears ----------------------------------------------------------------------------------
    def _foreign(self, topic: str, session_id: str, who: str = "") -> None:
        self.foreign[topic] += 1
        names = self.identity.foreign_publishers(topic) or [f"{who or 'a publisher'} (session {session_id!r})"]
        self.foreign_names[topic].update(names)

    def on_measurement(self, data: bytes) -> None:
        try:
            if not self.identity.ours(sample_block_session(data)):
                self._foreign(self.measurement, sample_block_session(data))
                return
            block = decode_sample_block(data)
        except ValueError:
            return  # the nodes report malformed blocks; the watch only listens
        n = block.n_samples
        if n == 0 or block.data.shape[1] < 1:
            return
        self.blocks += 1
        self.sample_period = block.sample_period_s
        self.progress = max(self.progress, block.first_index + n)
        flags = block.sample_flags if len(block.sample_flags) == n else np.zeros(n, np.uint8)
        keep = (flags & _EXCLUDED) == 0
        ys = [i for i, c in enumerate(block.channel_names) if c.startswith("y_")]
        if ys and keep.any():
            last = int(np.flatnonzero(keep)[-1]) + 1  # the landing comes last: the run under control before it
            self.monitor.add_block(block.first_index, block.data[:last, ys],
                                   (flags[:last] & SampleBlock.FLAG_LANDED) != 0)

    def _session_message(self, data: bytes, kind, topic: str):
        """The message of ``data`` if it is of this session; another session's counted and named, None."""
        try:
            msg = decode_message(data, kind, topic)
        except BadMessage:
            return None
        if not self.identity.ours(msg.session_id):
            self._foreign(self.resolve_topic_name(topic), msg.session_id, msg.node)
            return None
        return msg

    def on_status(self, data: bytes) -> None:
        msg = self._session_message(data, SessionStatus, "status")
        if msg is not None:
            self.statuses[msg.node] = msg

    def on_event(self, data: bytes) -> None:
        msg = self._session_message(data, SessionEvent, "events")
        if msg is not None:
            self.events.append(msg)

    def subscribed(self, topic: str, nodes) -> list[str]:
        """Those of ``nodes`` (names in the watch's namespace) the graph does not show subscribed to ``topic`` yet
        (:func:`ambid_nodes.identity.not_subscribed`)."""
        return not_subscribed(self, topic, nodes)

    def hears_the_plant(self) -> bool:
        """Its measurement subscription is matched to a publisher (the plant's): it hears every block from the
        first, so the figures it keeps are true from sample 0 (start the loop after this)."""
        return self.sub_measurement.get_publisher_count() >= 1

    # --- what it tells -----------------------------------------------------------------------------------
    def figures(self, node: str) -> dict:
        """The named figures of ``node``'s last status (``plant_sim`` or a full name), JSON-decoded."""
        msg = self.status_of(node)
        if msg is None:
            return {}
        out = {}
        for k, v in zip(msg.keys, msg.values):
            try:
                out[k] = json.loads(v)
            except json.JSONDecodeError:
                out[k] = v
        return out

    def status_of(self, node: str) -> SessionStatus | None:
        for name, msg in self.statuses.items():
            if name == node or name.rsplit("/", 1)[-1] == node:
                return msg
        return None

    def event(self, code: str | None = None, severity: int | None = None) -> SessionEvent | None:
        """The first event of the session with ``code`` (or at least ``severity``), None if none came."""
        for e in self.events:
            if (code is None or e.code == code) and (severity is None or e.severity >= severity):
                return e
        return None

    def foreign_publishers(self, topics=SESSION_TOPICS) -> dict[str, list[str]]:
        """{topic: [named publishers not of this session]} for the session's topics that have any, now."""
        out = {}
        for t in topics:
            names = self.identity.foreign_publishers(self.resolve_topic_name(t))
            if names:
                out[self.resolve_topic_name(t)] = names
        return out

    def foreign_heard(self) -> dict[str, tuple[int, list[str]]]:
        """{topic: (foreign messages heard, their publishers named)} so far."""
        return {t: (n, sorted(self.foreign_names[t])) for t, n in self.foreign.items()}
