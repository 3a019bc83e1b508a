"""The bridge's side of the protocol (docs/bridge_protocol.md) beyond packing datagrams: what it holds,
re-sends and reports.

- :func:`content_error`: a well-formed datagram whose content is impossible;
- :class:`CommandQueue`: commands to the target, re-sent until acknowledged or given up;
- :class:`ExcitationChunks`: excitation held in datagram-sized chunks until the target has applied it,
  re-sent where its heartbeat says it lacks some;
- :class:`FlagRuns`: runs of samples a flag marks, reported once each when they end;
- :func:`target_refusals`: what the target refused since its last heartbeat, by reason (version 3).

The hardware_bridge node is these over ROS and a UDP socket; nothing here reads a clock or a socket
(times are passed in).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from ambid.hardware import bridge_protocol as bp
from ambid.recording.blocks import MAX_SAMPLE_INDEX


def content_error(msg) -> str:
    """Why a well-formed datagram's content is impossible (an enum out of range, an index beyond
    MAX_SAMPLE_INDEX, no sample rate), or "" if it is usable."""
    if isinstance(msg, bp.Heartbeat):
        if msg.state not in bp.TargetState._value2member_map_:
            return f"HEARTBEAT with state {msg.state}, not a TargetState"
        if msg.safe_reason not in bp.SafeReason._value2member_map_:
            return f"HEARTBEAT with safe_reason {msg.safe_reason}, not a SafeReason"
        if msg.sample_rate_hz == 0:
            return "HEARTBEAT with sample_rate_hz 0"
        for name in ("sample_index", "sent_end"):
            if getattr(msg, name) > MAX_SAMPLE_INDEX:
                return f"HEARTBEAT with {name} {getattr(msg, name)} beyond {MAX_SAMPLE_INDEX}"
        if msg.excitation_next != bp.NO_INDEX and msg.excitation_next > MAX_SAMPLE_INDEX:
            return f"HEARTBEAT with excitation_next {msg.excitation_next} beyond {MAX_SAMPLE_INDEX}"
    elif isinstance(msg, bp.Ack):
        if msg.result not in bp.AckResult._value2member_map_ or msg.state not in bp.TargetState._value2member_map_:
            return f"ACK with result {msg.result} / state {msg.state} out of range"
    elif isinstance(msg, bp.Measurement) and msg.first_index + len(msg.data) > MAX_SAMPLE_INDEX:
        return f"MEASUREMENT at sample {msg.first_index} beyond {MAX_SAMPLE_INDEX}"
    return ""


@dataclass
class PendingCommand:
    code: int
    args: tuple[int, int, int]
    sent: float | None = None  # when last sent
    tries: int = 0


@dataclass
class CommandQueue:
    """Commands to the target, each re-sent every ``retry_s`` until acknowledged or sent ``retries`` times.

    START waits until every EXPERIMENT announcement is acknowledged: the target must know them first.
    """

    retry_s: float
    retries: int
    pending: dict[int, PendingCommand] = field(default_factory=dict)  # command id -> command
    next_id: int = 1

    def queue(self, code: int, arg0: int = 0, arg1: int = 0, arg2: int = 0) -> int:
        """Queue a command; returns its id."""
        cid = self.next_id
        self.pending[cid] = PendingCommand(code, (arg0, arg1, arg2))
        self.next_id += 1
        return cid

    def due(self, now: float) -> tuple[list[tuple[int, PendingCommand]], list[PendingCommand]]:
        """(the commands to send now, as (id, command), counted as sent; the commands given up)."""
        announcing = any(c.code == bp.CommandCode.EXPERIMENT for c in self.pending.values())
        send, failed = [], []
        for cid, cmd in list(self.pending.items()):
            if cmd.code == bp.CommandCode.START and announcing:
                continue
            if cmd.sent is not None and now - cmd.sent < self.retry_s:
                continue
            if cmd.tries >= self.retries:
                del self.pending[cid]
                failed.append(cmd)
                continue
            cmd.sent, cmd.tries = now, cmd.tries + 1
            send.append((cid, cmd))
        return send, failed

    def acknowledged(self, command_id: int) -> PendingCommand | None:
        """The command an ACK answers, no longer pending (None: not one of ours, or answered before)."""
        return self.pending.pop(command_id, None)


class ExcitationChunks:
    """Excitation held in chunks of at most ``chunk`` samples, by first index, until the target applied them.

    Each chunk remembers when it was last sent (None: not yet).
    """

    def __init__(self, chunk: int) -> None:
        self.chunk = chunk
        self.held: dict[int, list] = {}  # first index -> [rows (n, channels), last sent or None]
        self.firsts: list[int] = []  # sorted keys of held

    def length(self, first: int) -> int:
        return len(self.held[first][0])

    def add(self, first_index: int, data: np.ndarray) -> list[int]:
        """Hold a block cut into chunks; returns their first indices."""
        firsts = []
        for off in range(0, len(data), self.chunk):
            first = first_index + off
            self.held[first] = [data[off:off + self.chunk], None]
            bisect.insort(self.firsts, first)
            firsts.append(first)
        return firsts

    def sent(self, first: int, now: float) -> tuple[np.ndarray, bool]:
        """(the chunk's rows, whether it was sent before), marked sent at ``now``."""
        ch = self.held[first]
        again = ch[1] is not None
        ch[1] = now
        return ch[0], again

    def applied(self, sample_index: int) -> None:
        """The target is at ``sample_index``: chunks wholly before it are no longer needed for a re-send."""
        for first in [f for f, ch in self.held.items() if f + len(ch[0]) <= sample_index]:
            del self.held[first]
            self.firsts.remove(first)

    def to_resend(self, index: int, now: float, min_age_s: float, max_chunks: int = 8) -> list[int]:
        """The chunks to send again when the target lacks excitation at ``index``: those held from there on,
        contiguous, not sent within ``min_age_s``, at most ``max_chunks``."""
        out = []
        for first in sorted(self.held):
            if max_chunks == 0:
                break
            data, sent = self.held[first]
            if first + len(data) <= index:
                continue
            if first > index:
                break  # not held here (the generator has not published it yet)
            if sent is None or now - sent > min_age_s:
                out.append(first)
            index = first + len(data)
            max_chunks -= 1
        return out


class FlagRuns:
    """Runs of consecutive samples that carry a flag bit, each reported once, when it ends."""

    def __init__(self) -> None:
        self.open: dict[int, int] = {}  # bit -> first index of its run being followed

    def feed(self, first: int, mask: np.ndarray, bit: int) -> list[tuple[int, int]]:
        """Samples [first, first + len(mask)) with ``mask`` True where flagged; returns the runs this ended
        as (start, end)."""
        ended = []
        was_open = bit in self.open
        # a change of the flag between consecutive samples (the first compared with the open run, if any)
        for e in np.flatnonzero(np.diff(np.concatenate([[was_open], mask]).astype(np.int8))):
            if bit not in self.open:
                self.open[bit] = first + int(e)
            else:
                ended.append((self.open.pop(bit), first + int(e)))
        return ended

    def close(self, bit: int, end: int) -> tuple[int, int] | None:
        """End the bit's open run at ``end`` (a gap or the session end); (start, end) or None."""
        start = self.open.pop(bit, None)
        return None if start is None else (start, end)


TARGET_REFUSALS = {"auth": "refused_auth", "session": "refused_session", "replay": "refused_replay",
                   "duplicate": "duplicates"}  # reason -> HEARTBEAT field (version 3)


def target_refusals(hb: bp.Heartbeat) -> dict[str, int]:
    """The target's refusals by reason as its heartbeat counts them (all 0 before version 3)."""
    return {reason: int(getattr(hb, name)) for reason, name in TARGET_REFUSALS.items()}


def refusals_text(grown: dict[str, int]) -> str:
    """"auth 3, replay 1" of the reasons that grew."""
    return ", ".join(f"{reason} {n}" for reason, n in grown.items() if n)
