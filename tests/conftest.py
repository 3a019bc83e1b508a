"""Suite-wide collection order: under pytest-xdist (``./launch_scripts/ambid test`` with no arguments runs
the suite on workers, each test file whole on one worker), the files that take longest start first, so the
workers finish together instead of one running a long file alone at the end (longest first is the classic
rule for scheduling jobs on a few machines). The order of the tests within a file is kept."""

from __future__ import annotations

import os

# the slowest files of the suite, slowest first: their tests' summed durations (pytest --durations of a whole
# suite, three workers on the 2-core machine beside other work, less what the reports left out since saved),
# about 310 s down to 40 s; a file missing from the list keeps its place after these
SLOW_FIRST = (
    "tests/nodes/test_target_c_bridge.py",
    "tests/docs/test_doc_blocks.py",
    "tests/nodes/test_drills.py",
    "tests/nodes/test_nominal_models.py",
    "tests/nodes/test_live_identify.py",
    "tests/nodes/test_sessions.py",
    "tests/nodes/test_validate_tune.py",        # not yet measured in a whole suite: placed by what it runs
    "tests/core/test_import_any_channels.py",
    "tests/nodes/test_loop.py",
    "tests/nodes/test_validate_command.py",
    "tests/nodes/test_commission.py",           # likewise
    "tests/nodes/test_fuzz.py",
    "tests/nodes/test_identify_session.py",
    "tests/nodes/test_five_axis.py",
    "tests/core/test_early_analysis.py",
    "tests/core/test_live.py",
    "tests/nodes/test_bench.py",
    "tests/nodes/test_own_rotor.py",
    "tests/core/test_warm_caches.py",
    "tests/core/test_import_any_excitation.py",
    "tests/nodes/test_reliability_watchdog.py",
    "tests/core/test_design_cache.py",
    "tests/nodes/test_identify_controller.py",
    "tests/core/test_import_export.py",
    "tests/docs/test_dask_cluster.py",
    "tests/core/test_frf_file.py",
    "tests/core/test_architecture.py",
    "tests/nodes/test_campaign.py",
    "tests/nodes/test_identify_ideal_rig.py",
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


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:  # noqa: ARG001 (pytest's hook)
    """The doc blocks not run here and why, whenever a doc block's test ran (tests/docs/test_doc_blocks.py).

    Read from the run's reports, not its collection: under pytest-xdist this process collects nothing."""
    ran = any(getattr(r, "nodeid", "").startswith("tests/docs/test_doc_blocks.py")
              for reports in terminalreporter.stats.values() for r in reports)
    if not ran:
        return
    import sys

    sys.path.insert(0, os.path.join(str(config.rootpath), "tests", "docs"))
    from test_doc_blocks import not_run_listing

    terminalreporter.write_sep("-", "doc blocks")
    terminalreporter.write_line(not_run_listing())
