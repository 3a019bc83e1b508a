"""docs/results.md is written by the commands that measure its figures: each replaces its own section."""

from __future__ import annotations

from ambid_cli.commands.bench import results_markdown
from ambid_cli.commands.validate import coverage_markdown
from ambid_cli.results_page import HEADER, write_section


def test_each_command_replaces_its_own_section_and_keeps_the_others(tmp_path):
    page = tmp_path / "results.md"
    write_section(page, "bench", "Performance", "old bench")
    write_section(page, "validate", "Coverage", "the coverage table")
    write_section(page, "bench", "Performance", "new bench")
    text = page.read_text()
    assert text.startswith(HEADER) and "old bench" not in text
    assert text.count("<!-- ambid bench: begin -->") == 1 and "new bench" in text and "the coverage table" in text
    assert text.index("new bench") < text.index("the coverage table")  # in place, not appended again


def test_the_tables_are_markdown_of_the_measured_figures():
    figures = [{"name": "loop composed: simulated samples/s", "value": 48123.4, "unit": "1/s",
                "target": ">= 20000", "pass": True},
               {"name": "4x4 fit: CPU time", "value": 1.234, "unit": "s", "target": None, "pass": None}]
    table = results_markdown(figures).splitlines()
    assert table[2] == "| loop composed: simulated samples/s | 48,123 /s | >= 20000 | pass |"
    assert table[3] == "| 4x4 fit: CPU time | 1.23 s |  |  |"
    cov = coverage_markdown({"modes": {"nominal": 0.95, "coverage": 0.9, "ci95": [0.7, 0.98], "n": 20,
                                       "std_ratio": 1.1}, "skipped": {"coverage": None}})
    assert cov.splitlines()[2] == "| modes | 0.950 | 0.900 | 0.700..0.980 | 20 | 1.10 |  |  |" and "skipped" not in cov
    # an updated parameter: beside its claim (the best linear approximation's value) the rig at rest
    cov = coverage_markdown({"parameter:delay_s": {"nominal": 0.95, "coverage": 0.95, "ci95": [0.83, 0.99], "n": 40,
                                                   "std_ratio": 1.0, "at_rest": {"coverage": 0.6, "std_ratio": 1.9,
                                                                                 "shift_over_std": -1.6}}})
    assert cov.splitlines()[2] == "| parameter:delay_s | 0.950 | 0.950 | 0.830..0.990 | 40 | 1.00 | 0.600, 1.90 | -1.60 |"
