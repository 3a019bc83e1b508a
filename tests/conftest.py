"""Suite-wide collection order: under pytest-xdist (``./launch_scripts/ambid test`` with no arguments runs
the suite on workers, each test file whole on one worker), the files that take longest start first, so the
workers finish together instead of one running a long file alone at the end (longest first is the classic
rule for scheduling jobs on a few machines). The order of the tests within a file is kept."""

from __future__ import annotations

import os

# the slowest files of the suite, slowest first: their tests' summed durations (pytest --durations=120 of a
# fresh-clone CI run beside a busy process and other work, 2 workers; 21 min in all, so about twice the usual
# figures), about 186 s down to 12 s; a file missing from the list keeps its place after these. The launcher
# runs xdist with --no-loadscope-reorder: xdist's default queues the files by their count of tests, which put
# the one-test files (test_nominal_models, test_commission, test_validate_tune) last, a long tail on one worker
SLOW_FIRST = (
    "tests/nodes/test_nominal_models.py",       # 186 s (155 s of it the session and the twins)
    "tests/nodes/test_commission.py",           # 172 s
    "tests/docs/test_doc_blocks.py",            # 145 s
    "tests/nodes/test_target_c_bridge.py",      # 132 s
    "tests/nodes/test_validate_tune.py",        # 130 s
    "tests/nodes/test_bench.py",
    "tests/nodes/test_drills.py",
    "tests/docs/test_dask_cluster.py",
    "tests/nodes/test_identify_session.py",
    "tests/nodes/test_live_identify.py",
    "tests/nodes/test_validate_command.py",
    "tests/nodes/test_loop.py",
    "tests/core/test_architecture.py",
    "tests/core/test_warm_caches.py",
    "tests/core/test_live.py",
    "tests/nodes/test_sessions.py",
    "tests/core/test_early_analysis.py",
    "tests/nodes/test_fuzz.py",
    "tests/nodes/test_five_axis.py",
    "tests/nodes/test_own_rotor.py",
    "tests/nodes/test_identify_controller.py",
    "tests/docs/test_core_wheel.py",
    "tests/nodes/test_reliability_config.py",
    "tests/core/test_import_any_excitation.py",
    "tests/nodes/test_reliability_watchdog.py",
    "tests/core/test_import_any_channels.py",
    "tests/core/test_import_export.py",
    "tests/core/test_commissioning.py",
    "tests/core/test_optional_dependencies.py",
    "tests/core/test_api.py",
    "tests/core/test_coverage.py",
    "tests/core/test_tune_command.py",
    "tests/core/test_design_cache.py",
    "tests/nodes/test_netns.py",
    "tests/core/test_identification.py",
    "tests/nodes/test_identify_ideal_rig.py",
    "tests/nodes/test_loop_recovery.py",
    "tests/core/test_frf_file.py",           # 12 s
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
