"""A session's identity: the id every message of one session carries, so a session keeps to itself.

Several sessions can share a DDS domain and even a namespace (a rig next door, a replayed recording, a
script left running). Every ambid message but the lock-step ``Sample`` ends with ``uint64 session_id``; the
nodes of a session act only on messages with their own id, and the recorder records only those. The loop's
``Sample`` and ``/clock`` carry none: their publishers are known by GID from the session's roster
(``ambid_msgs/SessionMember`` on ``session``). See docs/sessions.md.

The id is the last field of every ambid message and 8-aligned, so a message as rmw serializes it is a
multiple of 4 bytes long: the copies a subscriber in the same process and one in another process receive
are the same bytes (RTPS pads a payload to 4 bytes).

Pure Python; nothing here imports rclpy.
"""

from __future__ import annotations

import re
import secrets

__all__ = ["GID_BYTES", "NO_SESSION", "check_session_id", "format_gid", "format_session", "new_session_id"]

GID_BYTES = 16  # rmw's RMW_GID_STORAGE_SIZE in ROS 2 Jazzy
NO_SESSION = 0  # the id of a message published outside any session (a node started without one, a script)
_HEX = re.compile(r"[0-9a-fA-F]{1,16}")


def new_session_id() -> int:
    """A fresh session id: 32 random bits, never 0 (two sessions on one domain collide once in 4e9)."""
    return secrets.randbits(32) or 1


def format_session(session_id: int) -> str:
    """A session id as it is printed and given back to ``--session``: hex, at least 8 digits (``3fa9c01b``).

    Examples
    --------
    >>> format_session(0x3fa9c01b)
    '3fa9c01b'
    >>> format_session(0x2a)
    '0000002a'
    >>> format_session(0)
    'none'
    """
    return f"{int(session_id):08x}" if session_id else "none"


def check_session_id(text: str | int) -> int:
    """The session id ``text`` names (1-16 hex digits as printed, or an int), in (0, 2**63) (a ROS integer
    parameter is int64); ValueError with the fix.

    Examples
    --------
    >>> check_session_id("3fa9c01b") == 0x3fa9c01b
    True
    >>> check_session_id(42)
    42
    >>> check_session_id("0")
    Traceback (most recent call last):
        ...
    ValueError: session id '0' is not valid: give 1-16 hex digits ...
    """
    if isinstance(text, int) and not isinstance(text, bool) and 0 < text < 2**63:
        return text
    if isinstance(text, str) and _HEX.fullmatch(text) and 0 < int(text, 16) < 2**63:
        return int(text, 16)
    raise ValueError(f"session id {text!r} is not valid: give 1-16 hex digits (below 8000000000000000), not all "
                     "zero, as ambid prints them (e.g. 3fa9c01b), or leave it out for a fresh one")


def format_gid(gid: bytes | bytearray | list[int] | tuple[int, ...]) -> str:
    """A publisher GID as rclpy prints it (``01.0f.2a....``), for naming a publisher the graph does not.

    Examples
    --------
    >>> format_gid(bytes(range(4)))
    '00.01.02.03'
    """
    return ".".join(f"{int(b):02x}" for b in bytes(gid)[:GID_BYTES])
