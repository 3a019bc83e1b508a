"""The core's docstrings teach by examples that run: every example in ambid_core/ambid is run here (those of
``ambid`` and ``ambid.api``, which read a recorded session, by tests/core/test_api.py), and there are at least
150 example lines, so the count cannot fall back."""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[2] / "ambid_core" / "ambid"
LEAST_EXAMPLE_LINES = 150
RUN_BY_TEST_API = {"ambid", "ambid.api"}  # their examples need a recorded session (test_api's fixture)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(CORE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _example_lines(text: str) -> int:
    """Lines of doctest input: a prompt ``>>>`` or its continuation ``...``."""
    return sum(1 for line in text.splitlines()
               if line.strip() == ">>>" or line.lstrip().startswith((">>> ", "... ")))


WITH_EXAMPLES = sorted(_module_name(p) for p in CORE.rglob("*.py") if ">>>" in p.read_text())


def test_the_core_holds_at_least_150_example_lines():
    n = sum(_example_lines(p.read_text()) for p in CORE.rglob("*.py"))
    assert n >= LEAST_EXAMPLE_LINES, f"{n} example lines in the core's docstrings, fewer than {LEAST_EXAMPLE_LINES}"


def test_the_count_counts_prompts_and_continuations_only():
    text = '    >>> x = 1\n    >>> def f():\n    ...     return x\n    >>>\n    1\n'
    assert _example_lines(text) == 4
    assert _example_lines("no examples here\n...\n") == 0


@pytest.mark.parametrize("name", [m for m in WITH_EXAMPLES if m not in RUN_BY_TEST_API])
def test_the_examples_of_a_module_run(name):
    module = importlib.import_module(name)
    tests = [t for t in doctest.DocTestFinder().find(module, name) if t.examples]
    assert tests, f"{name} has '>>>' in its text but no example doctest finds"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    assert runner.failures == 0, f"{runner.failures} example(s) of {name} failed (see the output above)"
