"""The live view beside a session yields the CPU to the loop it shows: its process runs LIVE_NICENESS nicer
than the session's (on two busy cores it took the loop's turns otherwise; ``ambid bench`` section live
measures the loop's rate with and without it)."""

from __future__ import annotations

import os

import pytest

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



def test_the_live_view_leads_a_nicer_autogroup_where_the_kernel_has_them(ros):
    """With autogroups, a task's nice weighs only inside its session's group: the live view (a session of its
    own) raises its group's nice too, else it would take as much CPU as the loop's whole session."""
    if not os.path.exists("/proc/self/autogroup"):
        pytest.skip("this kernel has no autogroups (CONFIG_SCHED_AUTOGROUP): the process's nice is all there is")
    ours = open("/proc/self/autogroup").read().split()   # e.g. ['/autogroup-2323', 'nice', '0']
    live = LiveProcess(0, "127.0.0.1", "/amb_nice_group", "indirect", ros.domain_id)
    try:
        live.wait_ready()
        theirs = open(f"/proc/{live.proc.pid}/autogroup").read().split()
        assert theirs[0] != ours[0]                                    # a group of its own
        assert int(theirs[-1]) == min(os.getpriority(os.PRIO_PROCESS, 0) + LIVE_NICENESS, 19), theirs
        assert open("/proc/self/autogroup").read().split() == ours     # ours left as it was
    finally:
        live.stop()
