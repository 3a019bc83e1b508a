"""CDR bytes of any ROS 2 message from a dict of its fields, without rclpy.

The definitions come from the install prefixes (:func:`ambid.recording.ros2_schema.load_message_schema`),
the encoding from mcap_ros2, so a message written here reads back as the
node's would. SampleBlocks, which carry the data, have their own fast encoder
(:func:`ambid.recording.blocks.encode_sample_block`).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, Callable, Mapping

from mcap_ros2._dynamic import serialize_dynamic

from .ros2_schema import load_message_schema, normalize_type_name

__all__ = ["encode_message"]


@lru_cache(maxsize=None)
def _encoder(type_name: str) -> Callable[[Any], bytes]:
    schema = load_message_schema(type_name)
    return serialize_dynamic(type_name, schema.definition)[type_name]


def encode_message(type_name: str, fields: Mapping[str, Any]) -> bytes:
    """CDR bytes of message ``type_name`` (``pkg/msg/Type``) with ``fields`` (nested dicts for nested messages).

    Raises
    ------
    FileNotFoundError
        the type's definition is not installed.
    """
    return bytes(_encoder(normalize_type_name(type_name))(dict(fields)))
