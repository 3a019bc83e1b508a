"""The docs' tests end the run with the list of blocks that were not run here and why."""

from __future__ import annotations


def pytest_terminal_summary(terminalreporter, exitstatus, config):  # noqa: ARG001 (pytest's hook signature)
    # from the reports, not the collection: under pytest-xdist the process that writes the summary collects
    # nothing, its workers do
    ran = any(getattr(r, "nodeid", "").startswith("tests/docs/test_doc_blocks.py")
              for reports in terminalreporter.stats.values() for r in reports)
    if not ran:
        return
    from test_doc_blocks import not_run_listing

    terminalreporter.write_sep("-", "doc blocks")
    terminalreporter.write_line(not_run_listing())
