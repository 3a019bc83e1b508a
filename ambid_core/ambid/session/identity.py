"""A session's identity: the id every message of one session carries, so a session keeps to itself.

Several sessions can share a DDS domain and even a namespace (a rig next door, a replayed recording, a
script left running). Every ambid message but the lock-step ``Sample`` carries a ``session_id``; the nodes
of a session act only on messages with their own id, and the recorder records only those. The loop's
``Sample`` and ``/clock`` carry none: their publishers are known by GID from the session's roster
(``ambid_msgs/SessionMember`` on ``session``). See docs/sessions.md.

Pure Python; nothing here imports rclpy.
"""

from __future__ import annotations

import re
import secrets

__all__ = ["GID_BYTES", "check_session_id", "format_gid", "new_session_id"]

GID_BYTES = 16  # rmw's RMW_GID_STORAGE_SIZE in ROS 2 Jazzy
_VALID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def new_session_id() -> str:
    """A fresh session id: 8 random hex digits (two sessions on one domain collide once in 4e9)."""
    return secrets.token_hex(4)


def check_session_id(text: str) -> str:
    """``text`` if it is a valid session id (1-64 of letters, digits, ``_ . -``, not starting with a
    punctuation mark); ValueError with the fix otherwise."""
    if not isinstance(text, str) or not _VALID.fullmatch(text):
        raise ValueError(f"session id {text!r} is not valid: use 1-64 letters, digits, '_', '.' or '-', "
                         "starting with a letter or digit (or leave it out for a fresh one)")
    return text


def format_gid(gid: bytes | bytearray | list[int] | tuple[int, ...]) -> str:
    """A publisher GID as rclpy prints it (``01.0f.2a....``), for naming a publisher the graph does not."""
    return ".".join(f"{int(b):02x}" for b in bytes(gid)[:GID_BYTES])
