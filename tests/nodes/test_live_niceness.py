"""The live view beside a session yields the CPU to the loop it shows: its process runs LIVE_NICENESS nicer
than the session's (on two busy cores it took the loop's turns otherwise; ``ambid bench`` section live
measures the loop's rate with and without it)."""

from __future__ import annotations

import os

from ambid_nodes.live_view import LIVE_NICENESS, LiveProcess


def test_the_live_view_process_is_nicer_than_the_session(ros):
    live = LiveProcess(0, "127.0.0.1", "/amb_nice", "indirect", ros.domain_id)
    try:
        assert live.wait_ready().startswith("ws://127.0.0.1:")
        ours = os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, live.proc.pid) == min(ours + LIVE_NICENESS, 19)
        # and every thread of it (the server's, the executor's) inherited it
        for tid in os.listdir(f"/proc/{live.proc.pid}/task"):
            assert os.getpriority(os.PRIO_PROCESS, int(tid)) == min(ours + LIVE_NICENESS, 19)
    finally:
        live.stop()
