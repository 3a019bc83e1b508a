"""The public API (ambid.api, reachable as ambid.*): its docstrings' examples run, in order, on a session
that docs/examples/offline_identification.py makes (the example runs too), and fit_model gives the very
modes identify_session records."""

from __future__ import annotations

import doctest
import inspect
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ambid
from ambid import api
from ambid.plant.true_rig import true_linear_model
from ambid.identification import identify_session, true_modes

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "docs" / "examples" / "offline_identification.py"


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """The docs example, run as a user runs it: a record of the simulated rig, imported and identified."""
    out = tmp_path_factory.mktemp("example")
    run = subprocess.run([sys.executable, str(EXAMPLE), str(out)], capture_output=True, text=True, timeout=600,
                         cwd=ROOT)
    assert run.returncode == 0, run.stderr[-3000:]
    return out, run.stdout


def test_the_example_identifies_the_rig_it_recorded(example):
    _, printed = example
    fitted = [float(f) for f in re.findall(r"mode +([\d.]+) Hz", printed)]
    rig = ambid.load_rig()
    truth = [f for f, _ in true_modes(true_linear_model(rig).poles(), (10.0, 1000.0))]
    # every fitted mode is a true mode of the simulated rig (the 177 Hz housing pair counts once) within 0.1 %
    for f in fitted:
        assert min(abs(f / t - 1) for t in truth) < 1e-3, (f, truth)
    assert {round(f) for f in fitted} >= {177, 310, 927}
    assert "updated ki_n_per_a" in printed and "updated ks_n_per_m" in printed


def test_the_docstrings_examples_run_in_order(example, tmp_path):
    out, _ = example
    names = {"ambid": ambid, "session_path": str(out / "rig.mcap"), "record_path": str(out / "rig.npz"),
             "map_path": str(out / "rig.MAP.yaml"), "new_session_path": str(tmp_path / "again.mcap")}
    parser, runner = doctest.DocTestParser(), doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    # the package's own example, then the API's in the order of the module: one session of a user's
    texts = [("ambid", ambid.__doc__)] + [(name, inspect.getdoc(getattr(api, name))) for name in ambid.API]
    assert all("Examples\n" in doc for name, doc in texts[1:]), "every API function has an Examples section"
    globs = dict(names)
    for name, doc in texts:
        test = parser.get_doctest(doc, globs, name, None, 0)
        assert test.examples, f"{name} has no runnable example"
        runner.run(test, clear_globs=False)
        globs = test.globs
    assert runner.failures == 0, f"{runner.failures} example(s) failed (see the output above)"


def test_fit_model_gives_the_modes_identify_records(example, tmp_path):
    out, _ = example
    summary = identify_session(out / "rig.mcap", tmp_path, report=False, update=False)
    model = ambid.fit_model(ambid.estimate_frf(ambid.read_session(out / "rig.mcap")))
    rows = summary["fit"]["modes"]
    assert model.order == summary["fit"]["order"] and len(model.modes) == len(rows)
    for mode, row in zip(model.modes, rows):
        assert (mode.freq_hz, mode.damping, mode.stable) == (row["freq_hz"], row["damping"], row["stable"])
        assert np.allclose(mode.freq_hz_ci95, row["freq_hz_ci95"], rtol=0, atol=0)


def test_bad_input_is_named():
    with pytest.raises(FileNotFoundError):
        ambid.read_session("no/such/session.mcap")
    with pytest.raises(ValueError, match="Nyquist"):
        ambid.design_excitation(band_hz=(10, 6000))
    with pytest.raises(AttributeError):
        ambid.no_such_function  # noqa: B018
