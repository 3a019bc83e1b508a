"""ROS domain ids for the tests that start ROS, one module so that every test file and fixture draws from one counter
(``from conftest import ...`` would pick whichever conftest was imported last)."""

from __future__ import annotations

import itertools
import os

# domain ids 1..200: under pytest-xdist each worker its own residue class (worker w of n takes the ids
# = offset + w mod n), so two workers' tests never share a domain; the offset, from the run (xdist's run id,
# else this process), spreads concurrent test runs so they don't meet
_counter = itertools.count()
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:] or 0)
_WORKERS = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
_SLOTS = max(1, 200 // _WORKERS)  # ids each worker takes in turn
_OFFSET = int(os.environ.get("PYTEST_XDIST_TESTRUNUID", "") or "%x" % (os.getpid() * 37), 16) % 200


def next_domain_id() -> int:
    """A ROS domain id no other test of this run holds now: 1 .. 200."""
    return 1 + (_OFFSET + _WORKER + _WORKERS * (next(_counter) % _SLOTS)) % (_WORKERS * _SLOTS)
