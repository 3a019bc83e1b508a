"""Issue 5's acceptance figures on the simulated rig, through the same loop code as the nodes.

An orthogonal random-odd multisine on the four radial inputs, closed loop,
realistic sensor noise (0.2 um RMS): the indirect FRF against the true rig's
linearised FRF, distortion at the detection lines with and without the
magnets' nonlinearity, and the input-sensitivity peak against the true loop.
The ROS graph runs this same loop (tests/nodes/test_frf_consumer.py).
"""

import numpy as np
import pytest
from ambid.control.closed_loop import input_sensitivity, loop_robustness
from ambid.control.pid import PidParameters, pid_controller
from ambid.excitation import design_multisine
from ambid.frf.offline import frf_from_arrays
from ambid.frf.sensitivity import iso14839_zone
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.control.simulated_loop import levitate, run_loop
from ambid.frf.accuracy import frf_relative_error as frf_error
from ambid.plant.true_rig import true_frf

INPUTS = ("u_a_x", "u_b_x", "u_a_y", "u_b_y")
AXES = ("a_x", "b_x", "a_y", "b_y")


def _experiment(nonlinear: bool, peak_a: float, periods: int, realisations: int):
    rig = make_rig()
    design = design_multisine((10.0, 1000.0), 10.0, 1.0 / rig.dt, INPUTS, peak_a, n_periods=periods,
                              n_realisations=realisations, n_transient_periods=3, grid="random_odd",
                              phases="crest_optimised", mimo="orthogonal", seed=3)
    start = levitate(rig, seed=5, nonlinear_magnets=nonlinear)
    rec = run_loop(start, design.samples(0, design.total_samples))
    assert rec.n_clipped == 0 and rec.n_contact == 0
    data = {**{f"y_{a}": rec.y[:, j] for j, a in enumerate(AXES)},
            **{f"u_{a}": rec.u[:, j] for j, a in enumerate(AXES)},
            **{f"r_{a}": rec.r[:, j] for j, a in enumerate(AXES)}}
    return rig, design, frf_from_arrays(data, design)


@pytest.fixture(scope="module")
def nonlinear_run():
    return _experiment(nonlinear=True, peak_a=0.5, periods=4, realisations=2)


def test_orthogonal_multisine_frf_within_issue_figures(nonlinear_run):
    rig, design, res = nonlinear_run
    err = frf_error(res.frf, true_frf(rig, res.freq_hz))
    # 2 realisations x 4 periods per experiment, 0.2 um sensor noise, 0.5 A peak per input
    assert np.median(err) <= 0.02, f"median {np.median(err):.4f}"
    assert err.max() <= 0.10, f"worst line {err.max():.4f} at {res.freq_hz[err.argmax()]:.0f} Hz"


def test_sensitivity_peak_matches_true_loop(nonlinear_run):
    rig, _, res = nonlinear_run
    k = pid_controller(PidParameters(), rig.dt)
    # the true loop's input sensitivity at the same excited lines
    s_true = np.abs(np.diagonal(input_sensitivity(true_linear_model(rig), k, res.freq_hz), axis1=1, axis2=2))
    peak_true = s_true.max(axis=0)
    peak = np.asarray(res.sensitivity_peak)
    assert np.all(np.abs(peak / peak_true - 1) < 0.05), (peak, peak_true)
    assert res.iso_zone == iso14839_zone(peak_true.max())
    # and the zone of the loop's continuous peak (between the lines) is the same here
    assert res.iso_zone == loop_robustness(true_linear_model(rig), k).zone


def test_detection_lines_show_the_magnets_nonlinearity_only_when_present(nonlinear_run):
    # a larger excitation makes the magnets' (mostly even-order) distortion stand out
    _, _, nl = _experiment(nonlinear=True, peak_a=0.8, periods=4, realisations=1)
    _, _, lin = _experiment(nonlinear=False, peak_a=0.8, periods=4, realisations=1)
    nl_db = max(np.nanmax(nl.distortion.even_db), np.nanmax(nl.distortion.odd_db))
    lin_db = max(np.nanmax(lin.distortion.even_db), np.nanmax(lin.distortion.odd_db))
    assert nl_db > 10.0, nl_db
    assert lin_db < 6.0, lin_db
