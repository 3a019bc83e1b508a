"""The live view beside a session yields the CPU to the loop it shows: its process runs LIVE_NICENESS nicer
than the session's (on two busy cores it took the loop's turns otherwise; ``ambid bench`` section live
measures the loop's rate with and without it)."""

from __future__ import annotations

import os

from ambid_nodes.live_view import LIVE_NICENESS, LiveProcess, autogroup


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
    own) raises its group's nice too, else it would take as much CPU as the loop's whole session. Where the
    kernel shows it no autogroup (no CONFIG_SCHED_AUTOGROUP, or an empty /proc/PID/autogroup: its session's
    group is the root one, as in a container on CI) its process's nice is all there is, and it claims no
    autogroup nice."""
    ours = autogroup()   # e.g. ('/autogroup-2323', 0)
    expected = min(os.getpriority(os.PRIO_PROCESS, 0) + LIVE_NICENESS, 19)
    live = LiveProcess(0, "127.0.0.1", "/amb_nice_group", "indirect", ros.domain_id)
    try:
        live.wait_ready()
        theirs = autogroup(live.proc.pid)
        assert os.getpriority(os.PRIO_PROCESS, live.proc.pid) == expected
        if theirs is not None:
            assert ours is None or theirs[0] != ours[0]   # a group of its own
            assert theirs[1] == expected, theirs
        assert autogroup() == ours                        # ours left as it was
    finally:
        figures = live.stop()
    # what it reports is what the kernel shows: an autogroup nice only where it has a group
    assert figures["priority"] == ({"nice": expected} if theirs is None else
                                   {"nice": expected, "autogroup_nice": expected}), (figures["priority"], theirs)
