"""The design behind an excitation record is found again: every kind of multisine ambid designs (orthogonal,
one input at a time, a single input; random-odd, odd, full and log grids), fed in chunks of any size, gives
its layout, lines, amplitudes and phasors back; float32 logging is tolerated."""

from __future__ import annotations

import numpy as np
import pytest
from ambid.excitation import design_multisine
from ambid.excitation.reconstruct import DesignFinder, DesignNotFound

FS = 5000.0
CASES = {
    "orthogonal": dict(input_names=["u_a_x", "u_b_x", "u_a_y"], mimo="orthogonal", grid="random_odd"),
    "one_at_a_time": dict(input_names=["u_a_x", "u_b_y"], mimo="one_at_a_time", grid="odd"),
    "single": dict(input_names=["u_b_x"], grid="full", n_realisations=4),
    "log": dict(input_names=["u_a_x", "u_b_x"], spacing="log", n_lines=20, phases="schroeder"),
}


def _find(design, chunk, pre=333, post=100, dtype=float):
    r = np.vstack([np.zeros((pre, design.n_inputs)), design.samples(0, design.total_samples),
                   np.zeros((post, design.n_inputs))]).astype(dtype)
    f = DesignFinder(design.input_names, FS, design.n_transient_periods, design.band_hz)
    for a in range(0, len(r), chunk):
        f.add(r[a:a + chunk], np.zeros((len(r[a:a + chunk]), 1)))
    return f.finish()


@pytest.mark.parametrize("chunk", [97, 5000])
@pytest.mark.parametrize("case", list(CASES))
def test_every_multisine_is_found_again(case, chunk):
    kw = {"n_realisations": 2, "n_periods": 2, "n_transient_periods": 1, **CASES[case]}
    names = kw.pop("input_names")
    d = design_multisine((30.0, 800.0), 25.0, FS, names, 0.3, seed=4, **kw)
    found = _find(d, chunk)
    g = found.design
    assert (found.start_row, found.end_row) == (333, 333 + d.total_samples)
    for key in ("n_per_period", "n_periods", "n_transient_periods", "n_realisations", "n_experiments",
                "input_names", "band_hz"):
        assert getattr(g, key) == getattr(d, key), key
    for key in ("excited_lines", "detection_lines_odd", "detection_lines_even"):
        np.testing.assert_array_equal(getattr(g, key), getattr(d, key))
    np.testing.assert_allclose(g.amplitudes_a, d.amplitudes_a, rtol=1e-12)
    np.testing.assert_allclose(g.phasors, d.phasors, atol=1e-12)
    if len(names) > 1:
        assert g.options["mimo"] == kw.get("mimo", "orthogonal")
    np.testing.assert_allclose(g.samples(0, g.total_samples), d.samples(0, d.total_samples), atol=1e-12)


def test_a_float32_logger_is_tolerated():
    d = design_multisine((30.0, 800.0), 25.0, FS, ["u_a_x", "u_b_x"], 0.3, n_periods=2, n_realisations=2,
                         n_transient_periods=1, seed=2)
    g = _find(d, 4096, dtype=np.float32).design
    assert (g.n_per_period, g.n_realisations, g.n_experiments) == (d.n_per_period, 2, 2)
    np.testing.assert_array_equal(g.excited_lines, d.excited_lines)
    np.testing.assert_allclose(g.phasors, d.phasors, atol=1e-5)


def test_two_experiments_in_one_record_are_refused():
    d = design_multisine((30.0, 800.0), 25.0, FS, ["u_a_x"], 0.3, n_periods=2, n_transient_periods=1, seed=2)
    x = d.samples(0, d.total_samples)
    r = np.vstack([x, np.zeros((1000, 1)), x])
    f = DesignFinder(d.input_names, FS, 1)
    with pytest.raises(DesignNotFound, match=f"starts again at row {len(x) + 1001}"):
        f.add(r, np.zeros((len(r), 1)))
        f.finish()
