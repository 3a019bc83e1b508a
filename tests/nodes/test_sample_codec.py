"""The hand-packed lock-step Sample: same bytes as rclpy, and every bad value refused, never raised."""

import math

import pytest
from ambid_nodes.conversions import BadMessage, all_finite
from ambid_nodes.sample_codec import decode_sample, encode_sample
from rclpy.serialization import deserialize_message

from ambid_msgs.msg import Sample


def test_round_trip_and_rclpy_reads_it():
    data = encode_sample(7, [1.0, -2.5, 3e-6, 4.0])
    assert decode_sample(data, 4, "y") == (7, [1.0, -2.5, 3e-6, 4.0])
    msg = deserialize_message(data, Sample)
    assert msg.index == 7 and list(msg.values) == [1.0, -2.5, 3e-6, 4.0]


def test_huge_finite_values_accepted():
    assert decode_sample(encode_sample(9, [1e308, 1e308, -1e308, 0.0]), 4, "y")[1][0] == 1e308


@pytest.mark.parametrize("values", [[math.nan, 0, 0, 0], [math.inf, -math.inf, 0, 0], [0, 0, 0, -math.inf],
                                    [1e308, 1e308, math.inf, -math.inf]])
def test_non_finite_refused_with_index(values):
    with pytest.raises(BadMessage) as err:
        decode_sample(encode_sample(3, values), 4, "y")
    assert err.value.index == 3 and "non-finite" in str(err.value)
    assert not all_finite(values)


def test_wrong_count_and_truncation_refused():
    with pytest.raises(BadMessage, match="3 values, expected 4"):
        decode_sample(encode_sample(3, [0.0] * 3), 4, "y")
    with pytest.raises(BadMessage, match="bytes"):
        decode_sample(encode_sample(3, [0.0] * 4)[:40], 4, "y")


def test_clock_bytes_are_the_clock_message():
    from ambid_nodes.conversions import time_msg
    from ambid_nodes.sample_codec import encode_clock
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock

    for t in (0.0, 1e-4, 0.9999999996, 12.3456, 2.0**31 - 1.5):
        assert encode_clock(t) == serialize_message(Clock(clock=time_msg(t)))
