"""The docs' tests end the run with the list of blocks that were not run here and why."""

from __future__ import annotations

_collected = {"docs": False}


def pytest_collection_modifyitems(session, config, items):  # noqa: ARG001 (pytest's hook signature)
    _collected["docs"] = any(item.nodeid.startswith("tests/docs/test_doc_blocks.py") for item in items)


def pytest_terminal_summary(terminalreporter, exitstatus, config):  # noqa: ARG001 (pytest's hook signature)
    if not _collected["docs"]:
        return
    from test_doc_blocks import not_run_listing

    terminalreporter.write_sep("-", "doc blocks")
    terminalreporter.write_line(not_run_listing())
