"""Hand-rolled CDR for ambid_msgs/Sample, the one message of the per-sample hot loop.

rclpy builds a Python message object per sample and converts it field by
field; packing the Sample of the rig's channels directly is about 4x cheaper. The bytes
are the standard XCDR1 little-endian encoding, so typed subscribers (recorder,
ros2 topic echo) read them as usual.

Layout: encapsulation header 00 01 00 00, uint64 index, uint32 count,
4 bytes padding (float64 alignment), count x float64.
"""

from __future__ import annotations

import struct

from ambid_nodes.conversions import BadMessage, all_finite, sec_nanosec

_HEADER = b"\x00\x01\x00\x00"
_HEAD = struct.Struct("<4sQI")
_PACKERS: dict[int, struct.Struct] = {}


def _packer(n: int) -> struct.Struct:
    p = _PACKERS.get(n)
    if p is None:
        p = _PACKERS[n] = struct.Struct(f"<4sQI{'4x' if n else ''}{n}d")
    return p


def encode_sample(index: int, values) -> bytes:
    """CDR bytes of Sample(index, values)."""
    return _packer(len(values)).pack(_HEADER, index, len(values), *values)


def decode_sample(data: bytes, n_expected: int, what: str) -> tuple[int, list[float]]:
    """(index, values) of a serialized Sample, or BadMessage naming what is wrong.

    Checks the encapsulation, the channel count and that every value is finite.
    """
    fast = _packer(n_expected)
    if len(data) == fast.size:
        # the per-sample path: one unpack; the sum is finite iff all values are, unless a huge
        # finite sum overflows, which the general path below then decides exactly
        header, index, count, *values = fast.unpack(data)
        t = sum(values)
        if header == _HEADER and count == n_expected and t - t == 0.0:
            return index, values
    if len(data) < _HEAD.size:
        raise BadMessage(f"{what}: {len(data)} bytes, too short for a Sample")
    header, index, count = _HEAD.unpack_from(data)
    if header != _HEADER:
        raise BadMessage(f"{what}: unexpected CDR encapsulation {header.hex()}")
    if count != n_expected:
        raise BadMessage(f"{what}: {count} values, expected {n_expected}", index)
    p = _packer(count)
    if len(data) < p.size:
        raise BadMessage(f"{what}: {len(data)} bytes for {count} values, expected {p.size}", index)
    values = list(p.unpack_from(data)[3:])
    if not all_finite(values):
        raise BadMessage(f"{what}: non-finite value in {values}", index)
    return index, values


_CLOCK = struct.Struct("<4siI")


def encode_clock(seconds: float) -> bytes:
    """CDR bytes of rosgraph_msgs/Clock(clock=time_msg(seconds)) (builtin_interfaces/Time: int32 sec,
    uint32 nanosec), for the plant's /clock without building a message object (~30 us with one)."""
    return _CLOCK.pack(_HEADER, *sec_nanosec(seconds))
