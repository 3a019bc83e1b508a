"""A node's session: the id it stamps on all it publishes, the session's roster, foreign sources named.

Every ambid message but the loop's ``Sample`` carries ``session_id``; a node with a session acts only on
messages of its own (``ambid_nodes.intake`` counts the others as foreign, per topic, and names them). The
loop's ``Sample`` and ``/clock`` carry no id: each node announces its publishers' GIDs in one latched
``ambid_msgs/SessionMember`` on ``session`` (the roster), and the loop pump (``_loop_pump.c``) accepts a
loop message only from the GID of its session's partner, which rmw gives with every message taken.

A node whose ``session`` parameter is empty is *open*: it acts on every well-formed message, as a node
started by hand always did, and stamps ``""``. ``ambid identify`` and ``ambid graph`` give every node the id
of the session they start (docs/sessions.md).
"""

from __future__ import annotations

import time
from typing import Callable

from ambid.session.identity import GID_BYTES, format_gid
from rclpy.node import Node

from ambid_msgs.msg import SessionMember
from ambid_nodes import qos
from ambid_nodes.conversions import time_msg

try:
    from ambid_nodes._loop_pump import publisher_gid as _publisher_gid
except ImportError as exc:  # pragma: no cover - a set-up problem, not a code path
    raise ImportError("ambid_nodes._loop_pump, the loop nodes' C extension, is not built: run "
                      "'./launch_scripts/ambid setup'") from exc

SESSION_TOPIC = "session"
NAMES_REFRESH_S = 1.0  # a topic's foreign publishers are looked up in the graph at most this often


def publisher_gid(publisher) -> bytes:
    """The GID rmw gives every message of ``publisher`` (an rclpy Publisher), 16 bytes."""
    with publisher.handle:
        return _publisher_gid(publisher.handle.pointer)


class SessionIdentity:
    """The session of ``node``: its id, its roster (``session`` topic), and who is foreign.

    Args:
        node: the node.
        session_id: the session's id; ``""``: open (accepts every source).
        on_member: called with each SessionMember of the node's session that arrives (a loop node learns
            its partner's GID from it).
    """

    def __init__(self, node: Node, session_id: str, on_member: Callable[[SessionMember], None] | None = None) -> None:
        self.node = node
        self.id = session_id
        self.fqn = node.get_fully_qualified_name()
        self.on_member = on_member
        self.members: dict[bytes, tuple[str, str, str]] = {}  # gid -> (session id, node, topic)
        self._names: dict[str, tuple[float, list[str]]] = {}  # topic -> (when looked up, foreign publishers)
        self.pub = node.create_publisher(SessionMember, SESSION_TOPIC, qos.MEMBERS)
        self.topic = self.pub.topic_name
        # raw: a malformed roster entry from a foreign source must not reach rosidl's stderr
        self.sub = node.create_subscription(SessionMember, SESSION_TOPIC, self._on_raw,
                                            qos.subscription(qos.MEMBERS), raw=True)

    @property
    def open(self) -> bool:
        return not self.id

    def ours(self, session_id: str) -> bool:
        """A message stamped ``session_id`` is this node's to act on."""
        return not self.id or session_id == self.id

    def announce(self, publishers) -> None:
        """Publish this node's roster entry: its ``publishers``' topics and GIDs (once, latched)."""
        topics, gids = [], bytearray()
        for p in publishers:
            topics.append(p.topic_name)
            gids += publisher_gid(p)
        self.pub.publish(SessionMember(stamp=time_msg(0.0), session_id=self.id, node=self.fqn, topics=topics,
                                       gids=bytes(gids)))
        self._learn(self.id, self.fqn, topics, bytes(gids))

    def _on_raw(self, data: bytes) -> None:
        from ambid_nodes.conversions import BadMessage, decode_message
        try:
            msg = decode_message(data, SessionMember, SESSION_TOPIC)
        except BadMessage:
            return  # not a roster entry anyone can use; the graph still names its publisher
        if len(msg.gids) != GID_BYTES * len(msg.topics):
            return
        self._learn(msg.session_id, msg.node, list(msg.topics), bytes(msg.gids))
        if self.on_member is not None and msg.session_id == self.id:
            self.on_member(msg)

    def _learn(self, session_id: str, node: str, topics: list[str], gids: bytes) -> None:
        for i, topic in enumerate(topics):
            self.members[gids[GID_BYTES * i:GID_BYTES * (i + 1)]] = (session_id, node, topic)
        self._names.clear()

    def member_gid(self, topic: str, node: str | None = None) -> bytes | None:
        """The GID of a publisher of this session on ``topic`` (resolved), other than this node's; None if
        the roster has none yet."""
        for gid, (sid, who, t) in self.members.items():
            if sid == self.id and t == topic and who != self.fqn and (node is None or who == node):
                return gid
        return None

    def name_gid(self, gid: bytes, topic: str) -> str:
        """A publisher named for a person: its node (from the roster or the graph) and, where it belongs to
        another session, that session's id; its GID where nothing else knows it."""
        known = self.members.get(bytes(gid))
        if known is not None:
            sid, who, _ = known
            return f"{who} (session {sid!r})" if sid else f"{who} (no session)"
        try:
            for info in self.node.get_publishers_info_by_topic(topic):
                if bytes(info.endpoint_gid[:GID_BYTES]) == bytes(gid):
                    return f"{info.node_namespace.rstrip('/')}/{info.node_name} (not of this session)"
        except Exception:  # noqa: BLE001 - the graph may be gone while the context shuts down
            pass
        return f"publisher {format_gid(gid)} (not in the graph any more)"

    def foreign_publishers(self, topic: str) -> list[str]:
        """The publishers of ``topic`` the graph shows that are not of this session, named; looked up at most
        every NAMES_REFRESH_S (a flood of foreign messages costs no graph query each)."""
        now = time.monotonic()
        cached = self._names.get(topic)
        if cached is not None and now - cached[0] < NAMES_REFRESH_S:
            return cached[1]
        names = []
        try:
            infos = self.node.get_publishers_info_by_topic(topic)
        except Exception:  # noqa: BLE001 - the graph may be gone while the context shuts down
            infos = []
        for info in infos:
            gid = bytes(info.endpoint_gid[:GID_BYTES])
            known = self.members.get(gid)
            if known is not None and known[0] == self.id:
                continue
            names.append(self.name_gid(gid, topic))
        names = sorted(set(names))
        self._names[topic] = (now, names)
        return names
