"""Suite-wide collection order: under pytest-xdist (``./launch_scripts/ambid test`` with no arguments runs
the suite on workers, each test file whole on one worker), the files that take longest start first, so the
workers finish together instead of one running a long file alone at the end (longest first is the classic
rule for scheduling jobs on a few machines). The order of the tests within a file is kept."""

from __future__ import annotations

import os

# the slowest files of the suite, slowest first (pytest --durations on the 2-core machine beside a busy
# process); a file missing from the list keeps its place after these
SLOW_FIRST = (
    "tests/nodes/test_nominal_models.py",
    "tests/nodes/test_validate_command.py",
    "tests/nodes/test_bench.py",
    "tests/nodes/test_campaign.py",
    "tests/nodes/test_target_c_bridge.py",
    "tests/nodes/test_live_identify.py",
    "tests/nodes/test_five_axis.py",
)


def pytest_collection_modifyitems(session, config, items) -> None:
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    rank = {path: i for i, path in enumerate(SLOW_FIRST)}
    root = str(config.rootpath)

    def key(item) -> int:
        path = os.path.relpath(str(item.path), root)
        return rank.get(path, len(rank))

    items.sort(key=key)  # stable: each file's tests keep their order, the other files theirs
