"""A measurement without settling periods: identify's experiment with --transient-periods 0 keeps the default's FRF
error (within 1.15x, same seed) once each segment's transient is removed by the local polynomial method, on a
shorter session (10 Hz lines, two realisations) of the loop identify runs (ambid.control.simulated_loop.run_loop, the
plant and controller code of the nodes), against the true rig's sampled small-signal FRF."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ambid.channels import Layout
from ambid.excitation.spec import DesignSpec
from ambid.frf.streaming import FrfStream
from ambid.plant.rig import make_rig
from ambid.control.simulated_loop import levitate, run_loop
from ambid.frf.accuracy import frf_relative_error as frf_error
from ambid.plant.true_rig import true_frf


def _error(design, x, g0) -> float:
    layout = Layout.from_names(design.input_names)       # the channels of the session, from its design
    stream = FrfStream(design, layout.outputs, layout.inputs, layout.excitations)
    stream.add(0, x)
    return float(np.median(frf_error(stream.estimate().frf, g0)))


@pytest.mark.parametrize("seed", [1])
def test_transient_periods_zero_keeps_the_default_error(seed):
    rig = make_rig()
    spec = DesignSpec(resolution_hz=10.0, n_realisations=2, seed=seed)      # identify's, shorter
    start = levitate(rig, seed, False, 0.3)
    default, quick = spec.build(rig.sample_rate_hz), replace(spec, n_transient_periods=0).build(rig.sample_rate_hz)
    assert quick.measurement_time_s == pytest.approx(default.measurement_time_s * 4 / 7)
    g0 = true_frf(rig, default.freq_hz)
    x_default = run_loop(start, default.samples(0, default.total_samples)).columns()
    x_quick = run_loop(start, quick.samples(0, quick.total_samples)).columns()
    e_default, e_quick = _error(default, x_default, g0), _error(quick, x_quick, g0)
    assert e_quick <= 1.15 * e_default, (e_quick, e_default)
    # the same record taken as if it had settled (one period dropped, no removal): the transient in every line
    n, m, ne, ch = quick.n_per_period, quick.n_realisations, quick.n_experiments, x_quick.shape[1]
    pad = np.concatenate([np.zeros((m, ne, n, ch)), x_quick.reshape(m, ne, quick.n_periods * n, ch)],
                         axis=2).reshape(-1, ch)
    e_raw = _error(replace(spec, n_transient_periods=1).build(rig.sample_rate_hz), pad, g0)
    assert e_raw > 4 * e_quick, (e_raw, e_quick)
