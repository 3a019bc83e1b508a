"""Every node's SessionStatus: its figures as JSON texts."""

import json
import math

import numpy as np
from ambid_nodes.conversions import json_text, status_msg
from builtin_interfaces.msg import Time


def test_status_values_are_json():
    """A status carries its figures as JSON texts; the shortcut for plain numbers writes what json does."""
    values = [0, -7, 2**70, True, False, None, 0.1, -2.5e-308, 1e300, 5e-324, math.nan, math.inf, -math.inf,
              np.float64(0.3), [1.0, -2.0], [math.nan], {"a": 1}, "text", 1.0 / 3.0]
    for v in values:
        expected = json.dumps(v)
        assert json_text(v) == expected, v
        if json_text(v) not in ("NaN", "[NaN]"):  # NaN is not equal to itself
            assert json.loads(json_text(v)) == v
    msg = status_msg(Time(sec=1, nanosec=2), "/ambid/x", 1, 12, 0.5, 3, 1, "ok", {"a": 0.25, "b": None})
    assert (list(msg.keys), list(msg.values)) == (["a", "b"], ["0.25", "null"])
    assert (msg.node, msg.sample_index, msg.progress, msg.messages_received, msg.messages_rejected) == (
        "/ambid/x", 12, 0.5, 3, 1)
