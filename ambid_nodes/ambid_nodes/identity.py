"""A node's session: the id it stamps on all it publishes, the session's roster, foreign sources named.

Every ambid message but the loop's ``Sample`` ends with ``session_id``; a node with a session acts only on
messages of its own (``ambid_nodes.intake`` counts the others as foreign, per topic, and names them). The
loop's ``Sample`` and ``/clock`` carry no id: each node announces its publishers' GIDs in one latched
``ambid_msgs/SessionMember`` on ``session`` (the roster), and the loop pump (``_loop_pump.c``) accepts a
loop message only from the GID of its session's partner, which rmw gives with every message taken
(:class:`LoopPartner`).

A node whose ``session`` parameter is 0 is *open*: it acts on every well-formed message, as a node
started by hand always did, and stamps 0. ``ambid identify`` and ``ambid graph`` give every node the id
of the session they start (docs/sessions.md).
"""

from __future__ import annotations

import time
from typing import Callable

from ambid.session_id import GID_BYTES, format_gid, format_session
from rclpy.node import Node

from ambid_msgs.msg import SessionMember
from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, decode_message, time_msg

try:
    from ambid_nodes._loop_pump import publisher_gid as _publisher_gid
except ImportError as exc:  # pragma: no cover - a set-up problem, not a code path
    raise ImportError("ambid_nodes._loop_pump, the loop nodes' C extension, is not built: run "
                      "'./launch_scripts/ambid setup'") from exc

SESSION_TOPIC = "session"
SESSION_PARAMETER = ("session", 0, "the session this node belongs to: it acts only on that session's messages "
                     "and stamps its id on all it publishes (ambid identify and graph give it); 0: open, acts on "
                     "every source", 0, 2**63 - 1)
NAMES_REFRESH_S = 1.0  # a topic's foreign publishers are looked up in the graph at most this often
# the graph knows a publisher before it knows its node (rmw's node info travels apart): named by GID meanwhile
UNNAMED = "its node not yet known to the graph"
GONE = "gone from the graph"   # a GID the graph no longer shows
_UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
HOLD_S = 5.0           # a loop message of a publisher the roster does not know yet waits this long for it
HOLD_MAX = 256         # and at most this many wait


def publisher_gid(publisher) -> bytes:
    """The GID rmw gives every message of ``publisher`` (an rclpy Publisher), 16 bytes."""
    with publisher.handle:
        return _publisher_gid(publisher.handle.pointer)


def endpoint_node(info) -> str | None:
    """The node of a publisher or subscription the graph shows (rclpy's TopicEndpointInfo), ``/ns/name``; None
    while the graph knows the endpoint but not yet its node."""
    if info.node_name == _UNKNOWN_NODE:
        return None
    return f"{info.node_namespace.rstrip('/')}/{info.node_name}"


def not_subscribed(node: Node, topic: str, names) -> list[str]:
    """Those of ``names`` (nodes in ``node``'s namespace) that ``node``'s graph does not show subscribed to
    ``topic`` yet.

    By name, not by count: any other listener (a ``ros2 topic echo``, a monitor, a test's) would otherwise stand
    in for a node that has not subscribed yet, and a loop started then would lose that node the first blocks of
    a volatile topic."""
    if not names:   # nothing to look for: no graph query (a wait's predicate asks many times)
        return []
    ns = node.get_namespace().rstrip("/")
    have = {i.node_name for i in node.get_subscriptions_info_by_topic(topic) if i.node_namespace.rstrip("/") == ns}
    return [n for n in names if n not in have]


def unnamed_endpoint(info) -> str:
    """An endpoint whose node the graph does not know yet, named by its GID."""
    return f"publisher {format_gid(bytes(info.endpoint_gid[:GID_BYTES]))} ({UNNAMED})"


def _endpoint_name(info, gid: bytes) -> str:
    """A foreign publisher the graph shows, named by its node (by its GID while the graph has no node for it)."""
    node = endpoint_node(info)
    if node is None:
        return f"publisher {format_gid(gid)} ({UNNAMED})"
    return f"{node} (not of this session)"


def stamped(publisher, session_id: int):
    """``publisher`` (rclpy) whose every message is stamped with ``session_id`` as it is published."""
    publish = publisher.publish

    def publish_stamped(msg) -> None:
        msg.session_id = session_id
        publish(msg)

    publisher.publish = publish_stamped
    return publisher


class SessionIdentity:
    """The session of ``node``: its id, its roster (``session`` topic), and who is foreign.

    Args:
        node: the node.
        session_id: the session's id; 0: open (accepts every source).
    """

    def __init__(self, node: Node, session_id: int) -> None:
        self.node = node
        self.id = int(session_id)
        self.fqn = node.get_fully_qualified_name()
        self.members: dict[bytes, tuple[int, str, str]] = {}  # gid -> (session id, node, topic)
        self.listeners: list[Callable[[], None]] = []  # called when the roster grew
        self._names: dict[str, tuple[float, list[str]]] = {}  # topic -> (when looked up, foreign publishers)
        self.pub = None  # the roster entry's publisher, made by announce (a listener announces nothing)
        # raw: a malformed roster entry from a foreign source must not reach rosidl's stderr
        self.sub = node.create_subscription(SessionMember, SESSION_TOPIC, self._on_raw,
                                            qos.subscription(qos.MEMBERS), raw=True)

    def __str__(self) -> str:
        return format_session(self.id)

    @property
    def open(self) -> bool:
        return not self.id

    def ours(self, session_id: int) -> bool:
        """A message stamped ``session_id`` is this node's to act on."""
        return not self.id or session_id == self.id

    def publisher(self, msg_type, topic: str, profile):
        """A publisher of ``node`` whose messages carry this session's id."""
        return stamped(self.node.create_publisher(msg_type, topic, profile), self.id)

    def announce(self, publishers) -> None:
        """Publish this node's roster entry: its ``publishers``' topics and GIDs (once, latched)."""
        if self.pub is None:
            self.pub = node_pub = self.node.create_publisher(SessionMember, SESSION_TOPIC, qos.MEMBERS)
            publishers = [*publishers, node_pub]
        topics, gids = [], bytearray()
        for p in publishers:
            topics.append(p.topic_name)
            gids += publisher_gid(p)
        self.pub.publish(SessionMember(stamp=time_msg(0.0), node=self.fqn, topics=topics, gids=bytes(gids),
                                       session_id=self.id))
        self._learn(self.id, self.fqn, topics, bytes(gids))

    def _on_raw(self, data: bytes) -> None:
        try:
            msg = decode_message(data, SessionMember, SESSION_TOPIC)
        except BadMessage:
            return  # not a roster entry anyone can use; the graph still names its publisher
        if len(msg.gids) != GID_BYTES * len(msg.topics):
            return
        self._learn(msg.session_id, msg.node, list(msg.topics), bytes(msg.gids))

    def _learn(self, session_id: int, node: str, topics: list[str], gids: bytes) -> None:
        new = False
        for i, topic in enumerate(topics):
            gid = gids[GID_BYTES * i:GID_BYTES * (i + 1)]
            if gid not in self.members:
                self.members[gid] = (session_id, node, topic)
                new = True
        if new:
            self._names.clear()
            for listener in list(self.listeners):
                listener()

    def member_gid(self, topic: str) -> bytes | None:
        """The GID of a publisher of this session on ``topic`` (resolved), other than this node's; None if the
        roster has none yet."""
        for gid, (sid, who, t) in self.members.items():
            if sid == self.id and t == topic and who != self.fqn:
                return gid
        return None

    def name_gid(self, gid: bytes, topic: str) -> str:
        """A publisher named for a person: its node (from the roster or the graph) and, where the roster knows
        it, its session; its GID where nothing else knows it."""
        known = self.members.get(bytes(gid))
        if known is not None:
            sid, who, _ = known
            return f"{who} (session {format_session(sid)})"
        try:
            for info in self.node.get_publishers_info_by_topic(topic):
                if bytes(info.endpoint_gid[:GID_BYTES]) == bytes(gid):
                    return _endpoint_name(info, gid)
        except Exception:  # noqa: BLE001 - the graph may be gone while the context shuts down
            pass
        return f"publisher {format_gid(gid)} ({GONE})"

    def foreign_publishers(self, topic: str) -> list[str]:
        """The publishers of ``topic`` the graph shows that are not of this session, named; looked up at most
        every NAMES_REFRESH_S (a flood of foreign messages costs no graph query each)."""
        now = time.monotonic()
        cached = self._names.get(topic)
        if cached is not None and now - cached[0] < NAMES_REFRESH_S:
            return cached[1]
        try:
            infos = self.node.get_publishers_info_by_topic(topic)
        except Exception:  # noqa: BLE001 - the graph may be gone while the context shuts down
            infos = []
        names = set()
        for info in infos:
            gid = bytes(info.endpoint_gid[:GID_BYTES])
            known = self.members.get(gid)
            if known is not None and known[0] == self.id:
                continue
            names.add(self.name_gid(gid, topic))
        out = sorted(names)
        if not any(UNNAMED in n for n in out):  # a node the graph does not name yet is looked up again
            self._names[topic] = (now, out)
        return out


class LoopPartner:
    """The one publisher of a loop topic a node takes messages from: its session's partner, by GID.

    Open (session 0): every publisher. Else the entry accepts none until the roster names the partner
    (its session's publisher on the topic); a message of a publisher the roster does not know yet waits
    (up to HOLD_S, HOLD_MAX messages: the partner's roster entry may arrive after its first message) and is
    then handed to ``deliver(data, NOT_RUN)`` if it was the partner's, counted foreign otherwise. From then on
    the pump drops every other publisher's messages in C. ``foreign``: the messages counted so; ``report(gid)``
    is called for the first message of each foreign publisher.
    """

    def __init__(self, identity: SessionIdentity, entry, topic: str, deliver: Callable[[bytes, int], None],
                 report: Callable[[bytes], None], not_run: int) -> None:
        self.identity = identity
        self.entry = entry
        self.topic = topic
        self.deliver = deliver
        self.not_run = not_run
        self.gid: bytes | None = None
        self.held: list[tuple[bytes, bytes, float]] = []  # (data, gid, when) of publishers not known yet
        self.foreign_py = 0
        self.reported: set[bytes] = set()
        self._report = report
        if identity.open:
            entry.accept(b"")
            return
        entry.on_foreign = self.report
        entry.on_unknown = self.unknown
        entry.accept(None)
        identity.listeners.append(self.resolve)
        self.resolve()

    @property
    def known(self) -> bool:
        """The partner is known (always, open)."""
        return self.identity.open or self.gid is not None

    @property
    def foreign(self) -> int:
        return self.entry.foreign + self.foreign_py

    def report(self, gid: bytes) -> None:
        if gid not in self.reported:
            self.reported.add(gid)
            self._report(gid)

    def unknown(self, data: bytes, gid: bytes) -> None:
        """A message while the partner is not known: the partner's (the roster knew it meanwhile), foreign
        (the roster knows it as another's), or held until the roster tells."""
        self.resolve()
        if self.gid is not None and gid == self.gid:
            self.deliver(data, self.not_run)
            return
        if gid in self.identity.members or self.gid is not None:
            self.foreign_py += 1
            self.report(gid)
            return
        now = time.monotonic()
        self.held.append((data, gid, now))
        while self.held and (len(self.held) > HOLD_MAX or now - self.held[0][2] > HOLD_S):
            self.foreign_py += 1
            self.report(self.held.pop(0)[1])

    def resolve(self) -> None:
        """Take the partner from the roster once it is there; hand over what waited."""
        if self.gid is not None:
            return
        gid = self.identity.member_gid(self.topic)
        if gid is None:
            return
        self.gid = gid
        self.entry.accept(gid)
        held, self.held = self.held, []
        for data, g, _ in held:
            if g == gid:
                self.deliver(data, self.not_run)
            else:
                self.foreign_py += 1
                self.report(g)
