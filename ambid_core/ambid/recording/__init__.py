"""Session recording in MCAP, laid out as rosbag2's MCAP storage writes it.

- :mod:`.ros2_schema`: message definitions and RIHS01 type hashes from the
  ament install prefixes, concatenated rosbag2-style.
- :mod:`.writer`: :class:`SessionWriter`, chunked, compressed, crash-safe.
- :mod:`.reader`: streaming message iteration, decoding, recovery of files a
  killed writer left.
- :mod:`.inspect`: topic/rate/gap summary of a session.

Pure Python (mcap, mcap_ros2, PyYAML); nothing here imports rclpy.
"""

from .inspect import format_inspection, inspect_session
from .reader import (IncompleteSessionError, NotASessionError, SessionMessage, SessionScan, check_session_file,
                     iter_decoded, iter_messages, read_metadata, scan_session)
from .ros2_schema import MessageSchema, load_message_schema
from .writer import QosProfile, SessionWriteError, SessionWriter, serialize_qos_profiles

__all__ = [
    "IncompleteSessionError",
    "MessageSchema",
    "NotASessionError",
    "QosProfile",
    "SessionMessage",
    "SessionScan",
    "SessionWriteError",
    "SessionWriter",
    "check_session_file",
    "format_inspection",
    "inspect_session",
    "iter_decoded",
    "iter_messages",
    "load_message_schema",
    "read_metadata",
    "scan_session",
    "serialize_qos_profiles",
]
