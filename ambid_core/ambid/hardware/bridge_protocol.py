"""The UDP protocol between the hardware bridge and the real-time target.

Pure packing and unpacking of datagrams (no sockets, no rclpy) and the
bridge's reassembly of the measurement stream. The wire format is
documented in ``docs/bridge_protocol.md``; this module is its reference
implementation.

Every datagram: a header, a payload whose layout depends on the kind, and a
trailer. Little-endian, no padding, at most :data:`MAX_DATAGRAM_BYTES` bytes
(one Ethernet frame without fragmentation). Version 3 (the default)::

    header  <4sBBBBIHH8s  magic b"AMBP", version 3, kind, sender (1 bridge, 2 target), reserved (0),
                          sequence, payload length, reserved (0), session id (8 bytes; 0 in HELLO)
    payload               kind specific, see the ``*_LAYOUT`` structs
    trailer <16sI         tag = HMAC-SHA-256(key, header + payload)[:16], crc32(header + payload + tag)

Versions 1 and 2 (unauthenticated)::

    header  <4sBBHIHH     magic b"AMBP", version, kind, flags (0), sequence, payload length, reserved (0)
    payload
    trailer <I            crc32(header + payload)

Sequence numbers are uint32, counted per sender and per kind, wrapping.

Versions. Version 3 authenticates every datagram with the rig's key
(:mod:`ambid.hardware.link_key`) and binds it to one session agreed by a
HELLO / WELCOME handshake (:mod:`ambid.hardware.link_session`); its HEARTBEAT
adds the sender's refusals by reason. Version 2 carries any number of axes
(1 to :data:`MAX_AXES`): a block's ``axes`` field (offset 12 of the payload)
says how many, its channels are y, u, ic, r of every axis (MEASUREMENT,
4 na) or r (EXCITATION, na) in the rig's channel order, and a HEARTBEAT's
byte 3 says the sender's axes; version 3 keeps all of that. Version 1 carries
the four radial axes only: channel sets 1 (16 channels) and 2 (4), heartbeat
byte 3 reserved. Each end speaks one version.
"""

from __future__ import annotations

import collections
import hmac
import math
import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ambid.channels import Layout

MAGIC = b"AMBP"
PROTOCOL_VERSION = 3         # authenticated; 2 and 1 only when both ends ask for them
AUTHENTICATED_VERSION = 3  # this version and later carry a tag and a session id
SUPPORTED_VERSIONS = (1, 2, 3)
MAX_AXES = 8  # version 2: axes a block may carry
V1_AXES = 4   # version 1: its channel sets carry exactly the four radial axes
# 1500-byte Ethernet MTU minus the IPv4 (20) and UDP (8) headers: no IP fragmentation
MAX_DATAGRAM_BYTES = 1472
SEQUENCE_MODULO = 2**32
NO_INDEX = 2**64 - 1  # "none" in uint64 sample-index fields

HEADER = struct.Struct("<4sBBHIHH")           # versions 1 and 2
TRAILER = struct.Struct("<I")                   # versions 1 and 2: the CRC-32
OVERHEAD_BYTES = HEADER.size + TRAILER.size
TAG_BYTES = 16                                  # HMAC-SHA-256 truncated to 128 bits (RFC 2104 allows >= 80)
SESSION_BYTES = 8
HEADER_V3 = struct.Struct("<4sBBBBIHH8s")       # ... sender, reserved, ..., session id
TRAILER_V3 = struct.Struct(f"<{TAG_BYTES}sI")   # tag, CRC-32
OVERHEAD_BYTES_V3 = HEADER_V3.size + TRAILER_V3.size
NO_SESSION = bytes(SESSION_BYTES)               # HELLO's session id: none agreed yet
NONCE_BYTES = 16
# block payloads (MEASUREMENT, EXCITATION): first_index, n_samples, n_channels, axes (version 2; version 1:
# channel set), value_bytes, reserved
BLOCK_LAYOUT = struct.Struct("<QHHHBB")
# state, safe_reason, clock_running, axes (version 2; version 1: reserved), sample_rate_hz, sample_index,
# sent_end, excitation_next, next_measurement_sequence, rx_datagrams, rx_rejected, late_excitation_samples,
# overruns, reserved
HEARTBEAT_LAYOUT = struct.Struct("<BBBBIQQQIIIIII")
# version 3 appends the sender's refusals: refused_auth, refused_session, refused_replay, duplicates
HEARTBEAT_V3_EXTRA = struct.Struct("<IIII")
# HELLO (bridge -> target): bridge_nonce; WELCOME (target -> bridge): bridge_nonce, target_nonce
HELLO_LAYOUT = struct.Struct(f"<{NONCE_BYTES}s")
WELCOME_LAYOUT = struct.Struct(f"<{NONCE_BYTES}s{NONCE_BYTES}s")
# command_id, code, reserved, reserved, arg0, arg1, arg2, reserved
COMMAND_LAYOUT = struct.Struct("<IBBHQQII")
# command_id, code, result, state, reserved, sample_index
ACK_LAYOUT = struct.Struct("<IBBBBQ")


class Kind(IntEnum):
    """Datagram kinds (header byte 5)."""

    MEASUREMENT = 1  # target -> bridge: y, u, ic, r of consecutive samples, with sample flags
    EXCITATION = 2   # bridge -> target: r of consecutive samples
    HEARTBEAT = 3    # both ways
    COMMAND = 4      # bridge -> target
    ACK = 5          # target -> bridge: answer to a COMMAND
    HELLO = 6        # version 3, bridge -> target: a session proposed, with the bridge's nonce
    WELCOME = 7      # version 3, target -> bridge: the session, with both nonces


class Sender(IntEnum):
    """Who sent a version-3 datagram (header byte 6, authenticated): a datagram reflected back to its sender
    is refused (``direction``)."""

    BRIDGE = 1
    TARGET = 2


class TargetState(IntEnum):
    IDLE = 0     # powered, waiting for START, clock stopped at 0
    RUNNING = 1  # control loop running, rotor levitated
    SAFE = 2     # safe state: zero current reference, the rotor lands; the clock stops after landing
    DONE = 3     # session over (sample budget reached or STOP), clock stopped


class SafeReason(IntEnum):
    NONE = 0
    COMMANDED = 1      # SAFE_STATE command
    BRIDGE_SILENT = 2  # no datagram from the bridge within the target's timeout


class CommandCode(IntEnum):
    START = 1       # IDLE -> RUNNING
    STOP = 2        # any -> DONE (clock stops)
    SAFE_STATE = 3  # RUNNING or IDLE -> SAFE
    EXPERIMENT = 4  # announce samples [arg0, arg0 + arg1) as excited (arg1 = 0 cancels); arg2 = slot


class AckResult(IntEnum):
    OK = 0
    REFUSED = 1       # not possible in the target's state
    BAD_ARGUMENT = 2


# sample flags of MEASUREMENT datagrams (bits 0, 1, 3 equal SampleBlock's FLAG_CLIPPED, _LANDED, _CONTROLLER_LOST)
FLAG_CLIPPED = 1          # |ic + r| hit the amplifier current limit
FLAG_LANDED = 2           # the rotor touched the backup bearings
FLAG_SAFE_STATE = 8       # the target was in its safe state: zero current reference
FLAG_EXCITATION_LATE = 16  # an announced sample had no excitation: r = 0 applied

# version 1's channel sets: the four radial axes (V1_AXES) in the default rig's order
CHANNEL_SET_MEASUREMENT = 1  # y(4) [m], u(4), ic(4), r(4) [A]
CHANNEL_SET_EXCITATION = 2   # r(4) [A]
_BLOCK_KINDS = {Kind.MEASUREMENT: CHANNEL_SET_MEASUREMENT, Kind.EXCITATION: CHANNEL_SET_EXCITATION}
_SIGNALS_PER_AXIS = {Kind.MEASUREMENT: 4, Kind.EXCITATION: 1}  # y, u, ic, r; r
_VALUE_DTYPES = {8: np.dtype("<f8"), 4: np.dtype("<f4")}


def block_channels(kind: Kind, layout: Layout) -> tuple[str, ...]:
    """The channel names of a block of ``kind`` for the rig's ``layout``, in wire order: a MEASUREMENT's y, u,
    ic, r of every axis (``Layout.measurement_names``), an EXCITATION's r of every axis."""
    return layout.measurement_names if Kind(kind) == Kind.MEASUREMENT else layout.excitations


class ProtocolError(ValueError):
    """A datagram is malformed or not of this protocol version.

    Attributes:
        reason: one of ``length`` (truncated, or payload length disagrees),
            ``oversized``, ``magic``, ``version``, ``crc``, ``kind``, ``auth``
            (version 3: the tag is not the key's), ``content`` (NaN, wrong channel
            set, zero samples); and from the link's state
            (:mod:`ambid.hardware.link_session`): ``direction``, ``session``,
            ``replay``, ``duplicate``.
    """

    def __init__(self, reason: str, text: str) -> None:
        super().__init__(text)
        self.reason = reason


@dataclass(frozen=True)
class Measurement:
    """MEASUREMENT: samples [first_index, first_index + n) measured by the target.

    Attributes:
        sequence: uint32, per kind.
        first_index: sample index of the first row.
        data: (n, 4 na) float64, rows (y [m], u [A], ic [A], r [A]) of the na axes
            (:func:`block_channels` order).
        sample_flags: (n,) uint8, FLAG_* bits.
    """

    sequence: int
    first_index: int
    data: np.ndarray
    sample_flags: np.ndarray

    @property
    def end_index(self) -> int:
        return self.first_index + len(self.data)

    @property
    def n_axes(self) -> int:
        return np.shape(self.data)[1] // 4


@dataclass(frozen=True)
class Excitation:
    """EXCITATION: r [A] (n, na) for samples [first_index, first_index + n)."""

    sequence: int
    first_index: int
    data: np.ndarray

    @property
    def end_index(self) -> int:
        return self.first_index + len(self.data)

    @property
    def n_axes(self) -> int:
        return np.shape(self.data)[1]


@dataclass(frozen=True)
class Heartbeat:
    """HEARTBEAT, both ways. The bridge fills only state and the counters it has; the rest 0.

    Attributes:
        sequence: uint32, per kind.
        state: TargetState of the target (the bridge sends its own view, RUNNING once connected).
        safe_reason: SafeReason.
        clock_running: the target's sample clock advances.
        sample_rate_hz: the target's control rate [Hz].
        sample_index: target: samples done (the next sample index); bridge: next contiguous index received.
        sent_end: target: end of the measurement samples sent so far.
        excitation_next: target: first announced sample >= sample_index without excitation, NO_INDEX if none.
        next_measurement_sequence: target: the sequence number of its next MEASUREMENT datagram.
        rx_datagrams, rx_rejected: datagrams the sender received / refused (malformed, foreign).
        late_excitation_samples: target: announced samples applied with r = 0.
        overruns: target: times the real-time schedule fell behind.
        axes: version 2: the sender's axes (target: those it runs; bridge: its rig's); 0: not said
            (version 1).
        refused_auth, refused_session, refused_replay, duplicates: version 3: datagrams the sender refused
            with a wrong tag, of another session, older than its replay window, and seen before (0 before
            version 3).
    """

    sequence: int
    state: int
    safe_reason: int = 0
    clock_running: bool = False
    sample_rate_hz: int = 0
    sample_index: int = 0
    sent_end: int = 0
    excitation_next: int = NO_INDEX
    next_measurement_sequence: int = 0
    rx_datagrams: int = 0
    rx_rejected: int = 0
    late_excitation_samples: int = 0
    overruns: int = 0
    axes: int = 0
    refused_auth: int = 0
    refused_session: int = 0
    refused_replay: int = 0
    duplicates: int = 0


@dataclass(frozen=True)
class Command:
    """COMMAND: ``code`` (CommandCode) with its arguments; answered by an ACK of the same command_id."""

    sequence: int
    command_id: int
    code: int
    arg0: int = 0
    arg1: int = 0
    arg2: int = 0


@dataclass(frozen=True)
class Ack:
    """ACK: the target's answer (AckResult) to command ``command_id``, its state and sample index after it."""

    sequence: int
    command_id: int
    code: int
    result: int
    state: int
    sample_index: int


@dataclass(frozen=True)
class Hello:
    """HELLO (version 3, bridge -> target): the bridge proposes a session; ``bridge_nonce`` is fresh per bridge
    run (NONCE_BYTES random bytes)."""

    sequence: int
    bridge_nonce: bytes


@dataclass(frozen=True)
class Welcome:
    """WELCOME (version 3, target -> bridge): the target's answer to a HELLO, with its own fresh nonce; the
    header carries the session id both derive from the two nonces (:func:`session_id`)."""

    sequence: int
    bridge_nonce: bytes
    target_nonce: bytes


Message = Measurement | Excitation | Heartbeat | Command | Ack | Hello | Welcome
_KIND_OF = {Measurement: Kind.MEASUREMENT, Excitation: Kind.EXCITATION, Heartbeat: Kind.HEARTBEAT,
            Command: Kind.COMMAND, Ack: Kind.ACK, Hello: Kind.HELLO, Welcome: Kind.WELCOME}


def kind_of(msg: Message) -> Kind:
    """The datagram kind of a message."""
    return _KIND_OF[type(msg)]


@dataclass(frozen=True)
class Envelope:
    """A received datagram: its message, and what a version-3 header says besides (``sender``: a
    :class:`Sender`, ``session``: the SESSION_BYTES session id); 0 and b"" before version 3."""

    message: Message
    sender: int = 0
    session: bytes = b""


def overhead_bytes(version: int = PROTOCOL_VERSION) -> int:
    """Header and trailer bytes of a datagram of ``version``."""
    return OVERHEAD_BYTES_V3 if version >= AUTHENTICATED_VERSION else OVERHEAD_BYTES


def session_id(key, bridge_nonce: bytes, target_nonce: bytes) -> bytes:
    """The id (SESSION_BYTES) of the session agreed by a HELLO and its WELCOME: HMAC-SHA-256 under the rig's
    key of a label and both nonces, truncated. Each end's own fresh nonce makes it differ from every earlier
    session's, whatever the other end sent."""
    return key.mac(b"AMBP3 session\0", bytes(bridge_nonce), bytes(target_nonce))[:SESSION_BYTES]


def max_block_samples(kind: Kind, value_bytes: int = 8, n_axes: int = V1_AXES, version: int = PROTOCOL_VERSION) -> int:
    """Most samples one MEASUREMENT or EXCITATION datagram of ``n_axes`` axes can carry within
    MAX_DATAGRAM_BYTES at protocol ``version``."""
    n_ch = _SIGNALS_PER_AXIS[Kind(kind)] * int(n_axes)
    per_sample = n_ch * value_bytes + (1 if kind == Kind.MEASUREMENT else 0)
    return (MAX_DATAGRAM_BYTES - overhead_bytes(version) - BLOCK_LAYOUT.size) // per_sample


def seq_diff(a: int, b: int) -> int:
    """a - b for wrapping uint32 sequence numbers, in [-2**31, 2**31)."""
    return (a - b + 2**31) % SEQUENCE_MODULO - 2**31


def _check_uint(name: str, value: int, bits: int) -> int:
    if not (isinstance(value, (int, np.integer)) and 0 <= int(value) < 2**bits):
        raise ValueError(f"{name} = {value!r} must be an integer in [0, 2**{bits})")
    return int(value)


@dataclass(frozen=True)
class Seal:
    """What a version-3 datagram is sealed with: the rig's key (a :class:`ambid.hardware.link_key.LinkKey`),
    the sender and the session id (NO_SESSION in a HELLO)."""

    key: object
    sender: int
    session: bytes = NO_SESSION

    def __repr__(self) -> str:
        return f"Seal(key={self.key!r}, sender={self.sender}, session={bytes(self.session).hex()})"


def _frame(kind: Kind, sequence: int, payload: bytes, version: int, n_axes: int = V1_AXES,
           seal: Seal | None = None) -> bytes:
    _check_uint("sequence", sequence, 32)
    _check_uint("version", version, 8)
    size = overhead_bytes(version) + len(payload)
    if size > MAX_DATAGRAM_BYTES:
        raise ValueError(f"{kind.name} datagram of {size} bytes exceeds {MAX_DATAGRAM_BYTES} bytes; "
                         f"send fewer samples per datagram (at most {max_block_samples(kind, 8, n_axes, version)} "
                         "at float64)")
    if version < AUTHENTICATED_VERSION:
        body = HEADER.pack(MAGIC, version, kind, 0, sequence, len(payload), 0) + payload
        return body + TRAILER.pack(zlib.crc32(body))
    if seal is None or seal.key is None:
        raise ValueError(f"protocol version {version} authenticates every datagram: give the rig's key")
    if seal.sender not in (Sender.BRIDGE, Sender.TARGET) or len(seal.session) != SESSION_BYTES:
        raise ValueError(f"a version-{version} datagram needs a sender (1 bridge, 2 target) and an "
                         f"{SESSION_BYTES}-byte session id, got {seal.sender!r} and {len(seal.session)} bytes")
    body = HEADER_V3.pack(MAGIC, version, kind, seal.sender, 0, sequence, len(payload), 0, bytes(seal.session)) \
        + payload
    body += seal.key.tag(body, TAG_BYTES)
    return body + TRAILER.pack(zlib.crc32(body))


def _pack_block(kind: Kind, sequence: int, first_index: int, data, sample_flags, version: int,
                value_bytes: int, seal: Seal | None) -> bytes:
    if value_bytes not in _VALUE_DTYPES:
        raise ValueError(f"value_bytes = {value_bytes!r}: use 8 (float64) or 4 (float32)")
    data = np.asarray(data, dtype=float)
    per_axis = _SIGNALS_PER_AXIS[kind]
    n_axes = data.shape[1] // per_axis if data.ndim == 2 else 0
    most = V1_AXES if version == 1 else MAX_AXES
    if data.ndim != 2 or data.shape[1] != per_axis * n_axes or not (1 <= n_axes <= most) or data.shape[0] < 1 \
            or (version == 1 and n_axes != V1_AXES):
        want = f"{per_axis * V1_AXES}" if version == 1 else f"{per_axis} x axes, 1 to {MAX_AXES} axes"
        raise ValueError(f"{kind.name} data of protocol version {version} must have shape (n >= 1, {want}), "
                         f"got {data.shape}")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{kind.name} data contains NaN or Inf")
    _check_uint("first_index", first_index, 64)
    axes_field = _BLOCK_KINDS[kind] if version == 1 else n_axes
    head = BLOCK_LAYOUT.pack(first_index, data.shape[0], data.shape[1], axes_field, value_bytes, 0)
    payload = head + data.astype(_VALUE_DTYPES[value_bytes]).tobytes()
    if kind == Kind.MEASUREMENT:
        flags = np.asarray(sample_flags)
        if flags.shape != (data.shape[0],) or np.any((flags < 0) | (flags > 255)):
            raise ValueError(f"sample_flags must be (n,) = ({data.shape[0]},) values in [0, 255], got {flags.shape}")
        payload += flags.astype(np.uint8).tobytes()
    return _frame(kind, sequence, payload, version, n_axes, seal)


def _nonce(name: str, value: bytes) -> bytes:
    if not isinstance(value, (bytes, bytearray)) or len(value) != NONCE_BYTES:
        raise ValueError(f"{name} must be {NONCE_BYTES} bytes")
    return bytes(value)


def pack_datagram(msg: Message, version: int = PROTOCOL_VERSION, value_bytes: int = 8,
                  seal: Seal | None = None) -> bytes:
    """The datagram (bytes, at most MAX_DATAGRAM_BYTES) of one message.

    Args:
        msg: a Measurement, Excitation, Heartbeat, Command, Ack, Hello or Welcome (the last two: version 3).
        version: protocol version written into the header.
        value_bytes: 8 (float64) or 4 (float32) for the sample values of block kinds.
        seal: version 3: the key, sender and session id the datagram is sealed with (required).

    Raises:
        ValueError: a field out of range, data of the wrong shape or non-finite, too many samples, a kind the
            version does not have, or version 3 without a seal.
    """
    if isinstance(msg, Measurement):
        return _pack_block(Kind.MEASUREMENT, msg.sequence, msg.first_index, msg.data, msg.sample_flags, version,
                           value_bytes, seal)
    if isinstance(msg, Excitation):
        return _pack_block(Kind.EXCITATION, msg.sequence, msg.first_index, msg.data, None, version, value_bytes,
                           seal)
    if isinstance(msg, Heartbeat):
        payload = HEARTBEAT_LAYOUT.pack(
            _check_uint("state", msg.state, 8), _check_uint("safe_reason", msg.safe_reason, 8),
            1 if msg.clock_running else 0, 0 if version == 1 else _check_uint("axes", msg.axes, 8),
            _check_uint("sample_rate_hz", msg.sample_rate_hz, 32),
            _check_uint("sample_index", msg.sample_index, 64), _check_uint("sent_end", msg.sent_end, 64),
            _check_uint("excitation_next", msg.excitation_next, 64),
            _check_uint("next_measurement_sequence", msg.next_measurement_sequence, 32),
            _check_uint("rx_datagrams", msg.rx_datagrams % SEQUENCE_MODULO, 32),
            _check_uint("rx_rejected", msg.rx_rejected % SEQUENCE_MODULO, 32),
            _check_uint("late_excitation_samples", msg.late_excitation_samples % SEQUENCE_MODULO, 32),
            _check_uint("overruns", msg.overruns % SEQUENCE_MODULO, 32), 0)
        if version >= AUTHENTICATED_VERSION:
            payload += HEARTBEAT_V3_EXTRA.pack(*(int(getattr(msg, f)) % SEQUENCE_MODULO for f in
                                                 ("refused_auth", "refused_session", "refused_replay", "duplicates")))
        return _frame(Kind.HEARTBEAT, msg.sequence, payload, version, seal=seal)
    if isinstance(msg, Command):
        payload = COMMAND_LAYOUT.pack(_check_uint("command_id", msg.command_id, 32), _check_uint("code", msg.code, 8),
                                      0, 0, _check_uint("arg0", msg.arg0, 64), _check_uint("arg1", msg.arg1, 64),
                                      _check_uint("arg2", msg.arg2, 32), 0)
        return _frame(Kind.COMMAND, msg.sequence, payload, version, seal=seal)
    if isinstance(msg, Ack):
        payload = ACK_LAYOUT.pack(_check_uint("command_id", msg.command_id, 32), _check_uint("code", msg.code, 8),
                                  _check_uint("result", msg.result, 8), _check_uint("state", msg.state, 8), 0,
                                  _check_uint("sample_index", msg.sample_index, 64))
        return _frame(Kind.ACK, msg.sequence, payload, version, seal=seal)
    if isinstance(msg, (Hello, Welcome)):
        if version < AUTHENTICATED_VERSION:
            raise ValueError(f"{type(msg).__name__.upper()} exists from protocol version {AUTHENTICATED_VERSION} on")
        if isinstance(msg, Hello):
            return _frame(Kind.HELLO, msg.sequence, HELLO_LAYOUT.pack(_nonce("bridge_nonce", msg.bridge_nonce)),
                          version, seal=seal)
        return _frame(Kind.WELCOME, msg.sequence, WELCOME_LAYOUT.pack(_nonce("bridge_nonce", msg.bridge_nonce),
                                                                      _nonce("target_nonce", msg.target_nonce)),
                      version, seal=seal)
    raise ValueError(f"cannot pack a {type(msg).__name__}; expected Measurement, Excitation, Heartbeat, Command, "
                     "Ack, Hello or Welcome")


def _unpack_block(kind: Kind, sequence: int, payload: memoryview, version: int, n_axes: int | None):
    if len(payload) < BLOCK_LAYOUT.size:
        raise ProtocolError("length", f"{kind.name} payload of {len(payload)} bytes is shorter than its "
                                      f"{BLOCK_LAYOUT.size}-byte block header")
    first, n, n_ch, axes_field, value_bytes, _ = BLOCK_LAYOUT.unpack_from(payload)
    per_axis = _SIGNALS_PER_AXIS[kind]
    if version == 1:
        want_set = _BLOCK_KINDS[kind]
        if axes_field != want_set or n_ch != per_axis * V1_AXES:
            raise ProtocolError("content", f"{kind.name} with channel set {axes_field} of {n_ch} channels; "
                                           f"expected set {want_set} of {per_axis * V1_AXES} channels")
        axes = V1_AXES
    else:
        axes = axes_field
        if not 1 <= axes <= MAX_AXES or n_ch != per_axis * axes:
            raise ProtocolError("content", f"{kind.name} of {axes} axes with {n_ch} channels; expected 1 to "
                                           f"{MAX_AXES} axes of {per_axis} channel(s) each")
    if n_axes is not None and axes != n_axes:
        raise ProtocolError("content", f"{kind.name} of {axes} axes, this end runs {n_axes}: give bridge and "
                                       "target the same rig (its axes)")
    if value_bytes not in _VALUE_DTYPES:
        raise ProtocolError("content", f"{kind.name} with {value_bytes}-byte values; expected 8 or 4")
    if n < 1:
        raise ProtocolError("content", f"{kind.name} with no samples")
    n_flags = n if kind == Kind.MEASUREMENT else 0
    want = BLOCK_LAYOUT.size + n * n_ch * value_bytes + n_flags
    if len(payload) != want:
        raise ProtocolError("length", f"{kind.name} payload of {len(payload)} bytes; {n} samples x {n_ch} channels "
                                      f"x {value_bytes} bytes need {want}")
    data = np.frombuffer(payload, _VALUE_DTYPES[value_bytes], n * n_ch, BLOCK_LAYOUT.size).reshape(n, n_ch)
    data = data.astype(float)  # a writable float64 copy, independent of the receive buffer
    if not np.isfinite(data).all():
        raise ProtocolError("content", f"{kind.name} data at samples {first}.. contains NaN or Inf")
    if kind == Kind.EXCITATION:
        return Excitation(sequence, first, data)
    flags = np.frombuffer(payload, np.uint8, n, want - n).copy()
    return Measurement(sequence, first, data, flags)


_FIXED_LAYOUTS = {Kind.HEARTBEAT: HEARTBEAT_LAYOUT, Kind.COMMAND: COMMAND_LAYOUT, Kind.ACK: ACK_LAYOUT,
                  Kind.HELLO: HELLO_LAYOUT, Kind.WELCOME: WELCOME_LAYOUT}


def open_datagram(datagram: bytes, version: int = PROTOCOL_VERSION, n_axes: int | None = None,
                  key=None) -> Envelope:
    """The message in one received datagram, with its version-3 sender and session id.

    The checks of docs/bridge_protocol.md in their order: size, magic, version, CRC, payload length, kind,
    (version 3) the tag under ``key``, the kind's payload size, its content. What depends on the link's state
    (the sender, the session, the replay window) is :mod:`ambid.hardware.link_session`'s.

    Args:
        datagram: the bytes received.
        version: the only protocol version accepted.
        n_axes: the axes this end runs (its rig's); a block of another number is refused (``content``).
            None accepts any.
        key: version 3: the rig's :class:`ambid.hardware.link_key.LinkKey` (required).

    Raises:
        ProtocolError: the datagram is truncated, oversized, not of this protocol or version, corrupted
            (CRC), of an unknown kind, not sealed with this key (``auth``), or its content is invalid;
            ``reason`` says which.
        ValueError: version 3 without a key.
    """
    view = memoryview(datagram)
    size = len(view)
    sealed = version >= AUTHENTICATED_VERSION
    if sealed and key is None:
        raise ValueError(f"protocol version {version} authenticates every datagram: give the rig's key")
    head, overhead = (HEADER_V3, OVERHEAD_BYTES_V3) if sealed else (HEADER, OVERHEAD_BYTES)
    if size > MAX_DATAGRAM_BYTES:
        raise ProtocolError("oversized", f"datagram of {size} bytes exceeds the protocol's {MAX_DATAGRAM_BYTES}")
    if size < OVERHEAD_BYTES:  # the shortest datagram of any version; version 3's own minimum once it is known
        raise ProtocolError("length", f"datagram of {size} bytes is shorter than header + trailer ({overhead})")
    if bytes(view[:4]) != MAGIC:
        raise ProtocolError("magic", f"magic {bytes(view[:4])!r}, expected {MAGIC!r}: not an ambid bridge datagram")
    ver = view[4]
    if ver != version:
        raise ProtocolError("version", f"protocol version {ver}, this end speaks version {version}: run matching "
                                       "bridge and target versions (parameter protocol_version)")
    if size < overhead:
        raise ProtocolError("length", f"datagram of {size} bytes is shorter than header + trailer ({overhead})")
    (crc,) = TRAILER.unpack_from(view, size - TRAILER.size)
    if zlib.crc32(view[:size - TRAILER.size]) != crc:
        raise ProtocolError("crc", f"CRC mismatch in a datagram of {size} bytes: corrupted in transit")
    if sealed:
        _, _, kind, sender, _, sequence, payload_len, _, session = head.unpack_from(view)
    else:
        _, _, kind, _, sequence, payload_len, _ = head.unpack_from(view)
        sender, session = 0, b""
    if payload_len != size - overhead:
        raise ProtocolError("length", f"header says {payload_len} payload bytes, the datagram has "
                                      f"{size - overhead}")
    try:
        kind = Kind(kind)
    except ValueError:
        raise ProtocolError("kind", f"unknown datagram kind {kind}") from None
    if kind in (Kind.HELLO, Kind.WELCOME) and not sealed:
        raise ProtocolError("kind", f"{kind.name} exists from protocol version {AUTHENTICATED_VERSION} on")
    if sealed:
        end = size - TRAILER_V3.size
        if not hmac.compare_digest(key.tag(view[:end], TAG_BYTES), view[end:end + TAG_BYTES]):
            raise ProtocolError("auth", f"{kind.name} datagram whose tag is not the rig key's (fingerprint "
                                        f"{key.fingerprint}): forged, or sealed with another key")
    payload = view[head.size:head.size + payload_len]
    if kind in _BLOCK_KINDS:
        return Envelope(_unpack_block(kind, sequence, payload, ver, n_axes), sender, session)
    layout = _FIXED_LAYOUTS[kind]
    extra = HEARTBEAT_V3_EXTRA.size if kind == Kind.HEARTBEAT and sealed else 0
    if len(payload) != layout.size + extra:
        raise ProtocolError("length", f"{kind.name} payload of {len(payload)} bytes, expected {layout.size + extra}")
    f = layout.unpack_from(payload)
    if kind == Kind.HEARTBEAT:
        refused = HEARTBEAT_V3_EXTRA.unpack_from(payload, layout.size) if extra else (0, 0, 0, 0)
        msg = Heartbeat(sequence, f[0], f[1], bool(f[2]), f[4], f[5], f[6], f[7], f[8], f[9], f[10], f[11], f[12],
                        0 if ver == 1 else f[3], *refused)
    elif kind == Kind.COMMAND:
        msg = Command(sequence, f[0], f[1], f[4], f[5], f[6])
    elif kind == Kind.ACK:
        msg = Ack(sequence, f[0], f[1], f[2], f[3], f[5])
    elif kind == Kind.HELLO:
        msg = Hello(sequence, f[0])
    else:
        msg = Welcome(sequence, f[0], f[1])
    return Envelope(msg, sender, bytes(session))


def unpack_datagram(datagram: bytes, version: int = PROTOCOL_VERSION, n_axes: int | None = None,
                    key=None) -> Message:
    """The message in one received datagram (:func:`open_datagram` without the envelope).

    Raises:
        ProtocolError: see :func:`open_datagram`; ``reason`` says why.
    """
    return open_datagram(datagram, version, n_axes, key).message


# --- the bridge's side: reassembling the measurement stream -------------------

@dataclass(frozen=True)
class Block:
    """Contiguous measured samples [first_index, first_index + n): data (n, 4 na), sample_flags (n,) uint8.

    ``final``: the last block of the stream (see :meth:`MeasurementAssembler.finish`).
    """

    first_index: int
    data: np.ndarray
    sample_flags: np.ndarray
    final: bool = False

    @property
    def end_index(self) -> int:
        return self.first_index + len(self.data)


@dataclass(frozen=True)
class Gap:
    """Samples [start, end) declared lost; ``datagrams``: MEASUREMENT datagrams lost (-1 if unknown)."""

    start: int
    end: int
    datagrams: int


@dataclass
class AssemblerCounts:
    """What the assembler has seen (datagrams unless named samples)."""

    accepted: int = 0
    duplicates: int = 0      # a sequence number received before
    reordered: int = 0       # arrived after a datagram with a higher sequence number, still in time
    late: int = 0            # arrived after its samples were declared lost (or before the stream start)
    gaps: int = 0
    missing_samples: int = 0
    lost_datagrams: int = 0
    blocks: int = 0


class MeasurementAssembler:
    """Turns MEASUREMENT datagrams, in any order, into contiguous blocks and declared gaps.

    Datagrams are ordered by their first sample index. A missing datagram is
    waited for until ``reorder_window`` later datagrams have arrived or for
    ``reorder_timeout_s`` (whichever first); then its samples are declared
    lost: the block being filled ends at the gap and a :class:`Gap` names
    the range. Blocks never span a gap; otherwise they end where the sample
    index reaches a multiple of ``block_size`` (as the simulated plant's).

    A finished block is handed out once a later sample arrived, so the last
    one can still be marked final when the sender halts (:meth:`finish`);
    this delays a block by one datagram, not by one block.

    Args:
        block_size: samples per output block.
        reorder_window: later datagrams that make a missing one lost.
        reorder_timeout_s: longest wait for a missing datagram [s].
    """

    def __init__(self, block_size: int = 1000, reorder_window: int = 16, reorder_timeout_s: float = 0.2) -> None:
        if block_size < 1 or reorder_window < 1 or not (reorder_timeout_s >= 0 and math.isfinite(reorder_timeout_s)):
            raise ValueError(f"MeasurementAssembler needs block_size >= 1 ({block_size}), reorder_window >= 1 "
                             f"({reorder_window}) and a finite reorder_timeout_s >= 0 ({reorder_timeout_s})")
        self.block_size = int(block_size)
        self.reorder_window = int(reorder_window)
        self.reorder_timeout_s = float(reorder_timeout_s)
        self.counts = AssemblerCounts()
        self.next_index: int | None = None  # first sample not yet delivered or declared lost
        self._last_seq: int | None = None   # sequence of the last datagram delivered
        self._highest_seq: int | None = None
        self._pending: dict[int, Measurement] = {}
        self._seen: set[int] = set()
        self._seen_order: collections.deque[int] = collections.deque()
        self._buf: list[tuple[np.ndarray, np.ndarray]] = []
        self._buf_start = 0
        self._stall_since: float | None = None
        self._held: list = []  # blocks and gaps not yet followed by a delivered sample

    @property
    def started(self) -> bool:
        return self.next_index is not None

    @property
    def pending(self) -> int:
        """Datagrams held waiting for an earlier one."""
        return len(self._pending)

    def start(self, first_index: int, next_sequence: int) -> None:
        """Begin the stream at sample ``first_index``, whose datagram carries ``next_sequence``.

        Datagrams already pushed for earlier samples are dropped (counted late).
        """
        self.next_index = self._buf_start = int(first_index)
        self._last_seq = (int(next_sequence) - 1) % SEQUENCE_MODULO
        for first in [f for f in self._pending if f < first_index]:
            del self._pending[first]
            self.counts.late += 1

    def push(self, m: Measurement) -> str:
        """Take one datagram; returns ``accepted``, ``reordered``, ``duplicate`` or ``late``."""
        seq = m.sequence
        if seq in self._seen:
            self.counts.duplicates += 1
            return "duplicate"
        self._seen.add(seq)
        self._seen_order.append(seq)
        if len(self._seen_order) > 8 * self.reorder_window + 64:
            self._seen.discard(self._seen_order.popleft())
        if self.next_index is not None and m.first_index < self.next_index:
            self.counts.late += 1
            return "late"
        verdict = "accepted"
        if self._highest_seq is not None and seq_diff(seq, self._highest_seq) < 0:
            self.counts.reordered += 1
            verdict = "reordered"
        else:
            self._highest_seq = seq
        self.counts.accepted += 1
        self._pending[m.first_index] = m
        if self.next_index is None and len(self._pending) > 64 * self.reorder_window:
            self._pending.pop(min(self._pending))  # not started: keep memory bounded
            self.counts.late += 1
        return verdict

    def poll(self, now_s: float, sent_end: int | None = None, next_sequence: int | None = None) -> list:
        """Blocks that are complete and gaps now declared, in sample order.

        Args:
            now_s: current time [s] (any monotonic clock).
            sent_end: the sender says samples up to here were sent (from its heartbeat), or None.
            next_sequence: the sequence its next MEASUREMENT datagram will carry (same heartbeat), or None.

        Returns:
            list of :class:`Block` and :class:`Gap`.
        """
        out: list = []
        if self.next_index is None:
            return out
        while True:
            m = self._pending.pop(self.next_index, None)
            if m is not None:
                out += self._held  # a sample follows them: none of them is the last
                self._held = []
                self._deliver(m)
                self._stall_since = None
                continue
            if not self._pending and (sent_end is None or sent_end <= self.next_index):
                break
            if self._stall_since is None:
                self._stall_since = now_s
            if len(self._pending) < self.reorder_window and now_s - self._stall_since < self.reorder_timeout_s:
                break
            if self._pending:
                end = min(self._pending)
                seq_after = self._pending[end].sequence
            else:
                end, seq_after = int(sent_end), next_sequence
            lost = seq_diff(seq_after, self._last_seq) - 1 if seq_after is not None else -1
            self._emit()
            self._held.append(Gap(self.next_index, end, lost))
            self.counts.gaps += 1
            self.counts.missing_samples += end - self.next_index
            self.counts.lost_datagrams += max(lost, 0)
            self.next_index = self._buf_start = end
            if seq_after is not None:
                self._last_seq = (seq_after - 1) % SEQUENCE_MODULO
            self._stall_since = None
        return out

    def finish(self) -> list:
        """Everything still held, and the partial block, when the sender halted; the last block marked final."""
        self._emit()
        out, self._held = self._held, []
        last = max((i for i, x in enumerate(out) if isinstance(x, Block)), default=None)
        if last is not None:
            b = out[last]
            out[last] = Block(b.first_index, b.data, b.sample_flags, True)
        return out

    def _deliver(self, m: Measurement) -> None:
        self._last_seq = m.sequence
        n = len(m.data)
        pos = 0
        while pos < n:
            boundary = (self.next_index // self.block_size + 1) * self.block_size
            take = min(n - pos, boundary - self.next_index)
            self._buf.append((m.data[pos:pos + take], m.sample_flags[pos:pos + take]))
            self.next_index += take
            pos += take
            if self.next_index == boundary:
                self._emit()

    def _emit(self) -> None:
        if not self._buf:
            return
        data = np.concatenate([d for d, _ in self._buf]) if len(self._buf) > 1 else self._buf[0][0]
        flags = np.concatenate([f for _, f in self._buf]) if len(self._buf) > 1 else self._buf[0][1]
        self._held.append(Block(self._buf_start, data, flags))
        self.counts.blocks += 1
        self._buf = []
        self._buf_start = self.next_index
