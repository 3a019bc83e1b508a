"""The live view shows its own session only (issue 30): given ``session``, another source's blocks, statuses and
events on the same topics are counted per topic and never reach the view; given none (0, ``ambid live`` without
``--session``), it shows every source."""

from __future__ import annotations

import numpy as np
import pytest
from ambid.channels import RADIAL
from ambid_nodes.conversions import block_msg, status_msg, time_msg
from rclpy.node import Node
from rclpy.parameter import Parameter

from ambid_msgs.msg import SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos

OWN, OTHER = 0x5, 0x7
NAMES = RADIAL.measurement_names
UNITS = ("m",) * 4 + ("A",) * 12


class Sources(Node):
    """Two sessions' publishers on the live view's topics."""

    def __init__(self, context, ns: str) -> None:
        super().__init__("two_sources", namespace=ns, context=context)
        self.pub_block = self.create_publisher(SampleBlock, "measurement", qos.BLOCKS)
        self.pub_status = self.create_publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.create_publisher(SessionEvent, "events", qos.EVENTS)

    def send(self, session: int, k: int) -> None:
        block = block_msg(k, 1e-4, NAMES, UNITS, np.full((1000, 16), float(session)))
        block.session_id = session
        status = status_msg(time_msg(k * 1e-4), "/amb/plant_sim", SessionStatus.STATE_RUNNING, k, 0.0, 0, 0,
                            "running", {})
        status.session_id = session
        event = SessionEvent(stamp=time_msg(k * 1e-4), sample_index=k, node="/amb/plant_sim",
                             severity=SessionEvent.INFO, code="note", text=f"of session {session}", session_id=session)
        self.pub_block.publish(block)
        self.pub_status.publish(status)
        self.pub_event.publish(event)


@pytest.mark.parametrize("shown", [OWN, 0], ids=["own-session", "open"])
def test_the_live_view_shows_its_own_session_and_counts_the_others(ros, shown):
    from ambid_nodes.live_view import LiveView

    ns = "/amb"
    view = ros.add(LiveView(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter("port", value=0), Parameter("session", value=shown)]))
    sources = ros.add(Sources(ros.context, ns))
    ros.matched(sources.pub_block, sources.pub_status, sources.pub_event)
    n = 5
    for i in range(n):
        sources.send(OWN, i * 1000)
        sources.send(OTHER, i * 1000 + 500)
    shown_blocks = n if shown else 2 * n
    try:
        assert ros.spin_until(lambda: view.server.follower.counts["blocks"] >= shown_blocks
                              and sum(view.foreign.values()) >= (0 if not shown else 3 * n), 30), \
            (view.server.follower.counts, view.foreign)
        assert view.server.drain(10)
        figures = view.close()
    finally:
        view.server.close()
    assert figures["blocks"] == shown_blocks
    if shown:
        assert figures["foreign_messages"] == {"measurement": n, "status": n, "events": n}
        # the view's samples are its own session's only: every block it took held the value OWN
        assert view.server._latest["signals"].message["y_a_x"] == float(OWN)
    else:
        assert figures["foreign_messages"] == {}
