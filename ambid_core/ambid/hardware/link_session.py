"""One end of the bridge-target link: its sequence numbers and, in protocol version 3, the session it agreed
and the datagrams it accepts in it (docs/bridge_protocol.md, "Version 3: the authenticated link").

Version 3's handshake binds every datagram to one session that both ends made fresh::

    bridge                                           target
    HELLO   session 0, bridge_nonce Nb       --->    proposes S = HMAC(key, label | Nb | Nt)[:8], Nt fresh
            (again every heartbeat period
             until the target is heard)      <---    WELCOME  session S, Nb, Nt
    checks Nb is its own and S, then sends
    HEARTBEAT etc. in session S              --->    a proposal's first sealed datagram commits it: S
    the target's first datagram in S         <---    HEARTBEAT etc. in session S
    commits it

The bridge accepts only datagrams of session S, which depends on its own fresh Nb; the target only those of
S, which depends on its own fresh Nt. No datagram recorded in another session carries S, so neither end can
be made to accept one, whatever the other end or an attacker sends. Within the session, each kind's sequence
numbers pass a replay window (:class:`ReplayWindow`): a datagram seen before is a ``duplicate``, one older
than the window a ``replay``; both are refused.

:class:`LinkEnd` packs what its end sends (sequences per kind, seal) and checks what it receives, raising
:class:`ambid.hardware.bridge_protocol.ProtocolError` with the reason (the caller counts them). It reads no
clock and no socket.
"""

from __future__ import annotations

import collections
import dataclasses
import secrets
from collections.abc import Callable

from ambid.hardware import bridge_protocol as bp

__all__ = ["WINDOW", "PROPOSALS", "REFUSAL_EVENTS", "ReplayWindow", "LinkEnd", "link_words", "refusal_event"]

WINDOW = 64      # sequence numbers per kind a receiver remembers below the highest it accepted
PROPOSALS = 4    # sessions a target proposed and not yet seen confirmed (the newest kept)
# the event a refusal raises at the bridge, by reason (the framing reasons raise malformed_datagram)
REFUSAL_EVENTS = {"auth": "forged_datagram", "session": "foreign_session_datagram", "replay": "replayed_datagram",
                  "duplicate": "duplicate_datagram"}
_PEER = {bp.Sender.BRIDGE: bp.Sender.TARGET, bp.Sender.TARGET: bp.Sender.BRIDGE}
_SENDS = {bp.Sender.BRIDGE: {bp.Kind.EXCITATION, bp.Kind.HEARTBEAT, bp.Kind.COMMAND, bp.Kind.HELLO},
          bp.Sender.TARGET: {bp.Kind.MEASUREMENT, bp.Kind.HEARTBEAT, bp.Kind.ACK, bp.Kind.WELCOME}}


class ReplayWindow:
    """The sequence numbers of one kind accepted in a session: the highest and a bitmap of the WINDOW below it.

    Examples:
        >>> w = ReplayWindow()
        >>> [w.check(s) or w.accept(s) or "ok" for s in (5, 7, 6, 7, 100, 30)]
        ['ok', 'ok', 'ok', 'duplicate', 'ok', 'replay']
    """

    __slots__ = ("top", "bits")

    def __init__(self) -> None:
        self.top: int | None = None
        self.bits = 0  # bit i: top - i was accepted

    def check(self, seq: int) -> str:
        """"" if ``seq`` may be accepted, "duplicate" if it was, "replay" if it is older than the window."""
        if self.top is None:
            return ""
        d = bp.seq_diff(seq, self.top)
        if d > 0:
            return ""
        if -d >= WINDOW:
            return "replay"
        return "duplicate" if (self.bits >> -d) & 1 else ""

    def accept(self, seq: int) -> None:
        if self.top is None:
            self.top, self.bits = seq, 1
            return
        d = bp.seq_diff(seq, self.top)
        if d > 0:
            self.bits = ((self.bits << d) | 1) & ((1 << WINDOW) - 1) if d < WINDOW else 1
            self.top = seq
        else:
            self.bits |= 1 << -d


@dataclasses.dataclass(frozen=True)
class _Proposal:
    bridge_nonce: bytes
    target_nonce: bytes
    session: bytes


class LinkEnd:
    """One end of the link (the bridge's or the target's).

    Args:
        role: ``bp.Sender.BRIDGE`` or ``bp.Sender.TARGET``.
        version: the protocol version this end speaks; 3 authenticates.
        key: the rig's :class:`ambid.hardware.link_key.LinkKey` (version 3: required).
        n_axes: the axes this end runs; blocks of another number are refused (None: any).
        value_bytes: 8 or 4, for the blocks this end sends.
        nonce: source of fresh nonces (``n -> n random bytes``).

    Attributes:
        seq: the next sequence number per kind.
        session: version 3: the session id once agreed (None before); versions 1 and 2: b"".
    """

    def __init__(self, role: bp.Sender, version: int = bp.PROTOCOL_VERSION, key=None, n_axes: int | None = None,
                 value_bytes: int = 8, nonce: Callable[[int], bytes] = secrets.token_bytes) -> None:
        self.role = bp.Sender(role)
        self.peer = _PEER[self.role]
        self.version = int(version)
        self.authenticated = self.version >= bp.AUTHENTICATED_VERSION
        if self.authenticated and key is None:
            raise ValueError(f"protocol version {self.version} authenticates every datagram and needs the rig's "
                             "key (a key file, 'ambid keygen --out FILE'); version 2 on both ends is unauthenticated")
        self.key = key if self.authenticated else None
        self.n_axes = n_axes
        self.value_bytes = value_bytes
        self._nonce = nonce
        self.seq = dict.fromkeys(bp.Kind, 0)
        self.windows: dict[bp.Kind, ReplayWindow] = {}
        self.session: bytes | None = None if self.authenticated else b""
        self.bridge_nonce = nonce(bp.NONCE_BYTES) if self.authenticated and self.role == bp.Sender.BRIDGE else b""
        self.pending: _Proposal | None = None  # the bridge's: the WELCOME it answers, until the target is heard
        self.proposals: collections.deque[_Proposal] = collections.deque(maxlen=PROPOSALS)  # the target's
        self.agreed_nonces = (b"", b"")

    @property
    def established(self) -> bool:
        """Datagrams other than the handshake may flow (always, before version 3)."""
        return self.session is not None

    @property
    def sending_session(self) -> bytes | None:
        """The session id this end seals its datagrams with (the bridge's pending one before the target is
        heard); None: nothing but HELLO may be sent yet."""
        if self.session is not None:
            return self.session
        return self.pending.session if self.pending is not None else None

    def fingerprint(self) -> str:
        return self.key.fingerprint if self.key is not None else ""

    # --- sending -----------------------------------------------------------
    def next_sequence(self, kind: bp.Kind) -> int:
        s = self.seq[kind]
        self.seq[kind] = (s + 1) % bp.SEQUENCE_MODULO
        return s

    def pack(self, msg: bp.Message, value_bytes: int | None = None) -> bytes:
        """The datagram of ``msg``, its sequence number this end's next of its kind (``msg.sequence`` is
        ignored), sealed in version 3.

        Raises:
            ValueError: version 3 before a session (only HELLO may go then), or a message :func:`pack_datagram`
                refuses.
        """
        kind = bp.kind_of(msg)
        seal = None
        if self.authenticated:
            session = bp.NO_SESSION if kind == bp.Kind.HELLO else self.sending_session
            if session is None:
                raise ValueError(f"no session agreed yet: a {kind.name} cannot be sent before the handshake")
            seal = bp.Seal(self.key, self.role, session)
        msg = dataclasses.replace(msg, sequence=self.next_sequence(kind))
        return bp.pack_datagram(msg, self.version, self.value_bytes if value_bytes is None else value_bytes, seal)

    def hello(self) -> bytes:
        """The bridge's HELLO (version 3), sent until the target is heard in the session."""
        return self.pack(bp.Hello(0, self.bridge_nonce))

    def welcome(self, hello: bp.Hello) -> bytes | None:
        """The target's WELCOME to a HELLO it accepted: the same answer to the same bridge nonce; None once the
        session is agreed (a late repeat of its HELLO needs no answer)."""
        if self.session is not None:
            return None
        p = next((p for p in self.proposals if p.bridge_nonce == hello.bridge_nonce), None)
        if p is None:
            nt = self._nonce(bp.NONCE_BYTES)
            p = _Proposal(hello.bridge_nonce, nt, bp.session_id(self.key, hello.bridge_nonce, nt))
            self.proposals.append(p)
        seal = bp.Seal(self.key, self.role, p.session)
        msg = bp.Welcome(self.next_sequence(bp.Kind.WELCOME), p.bridge_nonce, p.target_nonce)
        return bp.pack_datagram(msg, self.version, seal=seal)

    # --- receiving ---------------------------------------------------------
    def receive(self, datagram: bytes) -> bp.Message:
        """The message of a datagram this end accepts.

        Version 3: after :func:`bp.open_datagram`'s checks (a wrong tag is ``auth``), the sender must be the
        peer and send this kind (``direction``), the datagram must belong to this end's session (``session``;
        a target commits a proposal on its first datagram), and its sequence must pass its kind's window
        (``duplicate``, ``replay``; HELLOs are not windowed). A HELLO (target) or WELCOME (bridge) is returned
        for the caller to answer or note; a repeated one of the agreed session changes nothing.

        Raises:
            ProtocolError: refused; ``reason`` says why.
        """
        env = bp.open_datagram(datagram, self.version, self.n_axes, self.key)
        if not self.authenticated:
            return env.message
        msg, kind = env.message, bp.kind_of(env.message)
        if env.sender != self.peer or kind not in _SENDS[self.peer]:
            raise bp.ProtocolError("direction", f"a {kind.name} datagram sealed by sender {env.sender}: this end "
                                            f"hears only the {self.peer.name.lower()}'s kinds (reflected?)")
        if kind == bp.Kind.HELLO:  # not windowed: a bridge started again before its session counts from 0
            return self._on_hello(msg, env.session)
        if kind == bp.Kind.WELCOME:
            session = self._on_welcome(msg, env.session)
        else:
            session = self._session_of(env.session)
        window = self.windows.setdefault(kind, ReplayWindow())
        verdict = window.check(msg.sequence)
        if verdict == "replay":
            raise bp.ProtocolError("replay", f"{kind.name} of sequence {msg.sequence}, older than the replay window "
                                         f"({WINDOW} below {window.top}): replayed")
        if verdict == "duplicate":
            raise bp.ProtocolError("duplicate", f"{kind.name} of sequence {msg.sequence} accepted before "
                                            "(duplicated on the way, or replayed)")
        window.accept(msg.sequence)
        if self.session is None and kind != bp.Kind.WELCOME:
            self._commit(session)
        return msg

    def _session_of(self, session: bytes) -> _Proposal | bytes:
        if self.session is not None:
            if session == self.session:
                return session
        elif self.role == bp.Sender.TARGET:
            p = next((p for p in self.proposals if p.session == session), None)
            if p is not None:
                return p
        elif self.pending is not None and session == self.pending.session:
            return self.pending
        raise bp.ProtocolError("session", f"a datagram of session {bytes(session).hex()}, not this end's "
                                      f"({self.session_text()}): of another session (replayed?)")

    def _commit(self, p: _Proposal) -> None:
        self.session = p.session
        self.agreed_nonces = (p.bridge_nonce, p.target_nonce)
        self.proposals.clear()
        self.pending = None

    def _on_hello(self, hello: bp.Hello, session: bytes) -> bp.Hello:
        if session != bp.NO_SESSION:
            raise bp.ProtocolError("session", f"a HELLO of session {session.hex()}: a HELLO proposes one, it has none")
        if self.session is not None and hello.bridge_nonce != self.agreed_nonces[0]:
            raise bp.ProtocolError("session", "a HELLO after the session was agreed: one session per target run "
                                          "(replayed, or another bridge)")
        return hello

    def _on_welcome(self, w: bp.Welcome, session: bytes) -> _Proposal | bytes:
        if w.bridge_nonce != self.bridge_nonce:
            raise bp.ProtocolError("session", "a WELCOME to another bridge's HELLO (not this run's nonce): replayed "
                                          "or another bridge's")
        if session != bp.session_id(self.key, w.bridge_nonce, w.target_nonce):
            raise bp.ProtocolError("content", "a WELCOME whose session id is not the one its nonces give")
        if self.session is None:
            self.pending = _Proposal(w.bridge_nonce, w.target_nonce, session)
            return self.pending
        if session != self.session:
            raise bp.ProtocolError("session", "a WELCOME of another session after the session was agreed")
        return session

    def session_text(self) -> str:
        """The session id in hex (not secret), or what there is instead."""
        if not self.authenticated:
            return f"unauthenticated (protocol version {self.version})"
        if self.session is None:
            return "none agreed yet"
        return self.session.hex()


def link_words(link: LinkEnd, who: str) -> str:
    """What a start says of its link: authenticated with the key's fingerprint, or unauthenticated."""
    if link.authenticated:
        return f"{who}: protocol version {link.version}, authenticated with the key of fingerprint {link.fingerprint()}"
    return (f"{who}: the link is unauthenticated (protocol version {link.version}): any host on the rig network can "
            "command the magnets; use protocol version 3 with a key file")


def refusal_event(reason: str) -> str:
    """The event code of a refusal's reason: REFUSAL_EVENTS', else ``malformed_datagram``."""
    return REFUSAL_EVENTS.get(reason, "malformed_datagram")
