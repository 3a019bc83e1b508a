"""Excitation that steers clear of a spinning rotor's synchronous harmonics, and the FRF at speed.

The closed-loop runs use the spinning rig (G2.5 unbalance, 6 um runout) at 12,000 rpm (1X = 200 Hz)
with a resolution of 8 Hz, on which 1X and 3X fall on odd lines that the plain random-odd design
excites: the case steering exists for.
"""

import sys
from pathlib import Path

import numpy as np
import pytest
from ambid.control.pid import PidParameters, pid_controller
from ambid.excitation.design import ExcitationDesign
from ambid.excitation.spec import build_design
from ambid.excitation.synchronous import commensurate_period, harmonic_bins
from ambid.frf.streaming import FrfStream
from ambid.plant.rig import load_rig, make_rig
from ambid.plant.sensors import runout_table
from ambid.plant.true_rig import true_linear_model
from ambid.frf.accuracy import frf_relative_error as frf_error
from ambid.plant.true_rig import true_frf

sys.path.insert(0, str(Path(__file__).resolve().parent))
from session_testbench import simulate_closed_loop  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
FS = 10_000.0
RPM = 12_000.0
KW = dict(peak_current_a=0.4, n_periods=4, n_realisations=2, n_transient_periods=2, phases="random", seed=3)
PRE = 5000


def _clear(lines, rpm, res, guard, n_harm=6):
    """Smallest distance [bins] of any line from a harmonic k * rpm / 60, k = 1..n_harm."""
    h = np.arange(1, n_harm + 1) * rpm / 60 / res
    return np.min(np.abs(np.asarray(lines, float)[:, None] - h[None]))


@pytest.mark.parametrize("rpm, res, guard", [(12_000, 8.0, 1), (12_000, 5.0, 2), (7_777, 5.0, 1)])
def test_design_keeps_excited_and_detection_lines_off_the_harmonics(rpm, res, guard):
    plain = build_design("multisine", (10, 1000), res, FS, **KW)
    d = build_design("multisine", (10, 1000), res, FS, speed_rpm=rpm, guard_bins=guard, **KW)
    r = d.fs_hz / d.n_per_period
    assert _clear(plain.excited_lines, rpm, r, guard) <= guard  # the plain design has lines in a guard
    assert _clear(d.excited_lines, rpm, r, guard) > guard
    det = np.concatenate([d.detection_lines_odd, d.detection_lines_even])
    assert _clear(det, rpm, r, guard) > guard
    sync = d.options["synchronous"]
    assert sync["moved"] and all(frm in plain.excited_lines for frm, _, _ in sync["moved"])
    # the line count and the grid's parity survive the moves
    assert d.excited_lines.size == plain.excited_lines.size
    assert np.all(d.excited_lines % 2 == 1)
    # the disturbance lines are the harmonics' bins, and the design survives its JSON round trip
    assert sync["disturbance_lines"] == [int(round(b)) for b in harmonic_bins(rpm, FS, d.n_per_period, 6)]
    assert ExcitationDesign.from_dict(d.to_dict()).options["synchronous"] == sync


def test_period_is_chosen_so_the_harmonics_fall_on_lines():
    # 11,500 rpm: f_rot / fs = 23 / 1200, so a period must be a multiple of 1200 samples
    n = commensurate_period(11_500, FS, 2000)
    assert n == 2400
    d = build_design("multisine", (10, 1000), 5.0, FS, speed_rpm=11_500, **KW)
    assert d.n_per_period == 2400
    h = harmonic_bins(11_500, FS, d.n_per_period, 6)
    np.testing.assert_allclose(h, np.round(h), atol=1e-9)
    # none in reach: keep the period, widen the guard by the half bin a harmonic leaks into
    assert commensurate_period(7_777, FS, 2000) is None
    d = build_design("multisine", (10, 1000), 5.0, FS, speed_rpm=7_777, **KW)
    assert d.n_per_period == 2000 and not d.options["synchronous"]["on_lines"]


def _frf_run(rig, design):
    names, x = simulate_closed_loop(rig, design, PRE, seed=1, nonlinear_magnets=True)
    stream = FrfStream(design, names[:4], names[4:8], names[12:16], start_index=PRE)
    stream.add(0, x[:, list(range(8)) + list(range(12, 16))])
    res = stream.estimate("indirect")
    return res, frf_error(res.frf, true_frf(rig, res.freq_hz))


def test_frf_at_speed_matches_standstill_accuracy_only_when_steered():
    spin = load_rig(REPO / "rigs" / "spinning.yaml")
    assert spin.rotor_speed_rpm == RPM and spin.unbalance_planes()
    still = make_rig()
    plain = build_design("multisine", (10, 1000), 8.0, FS, **KW)
    steered = build_design("multisine", (10, 1000), 8.0, FS, speed_rpm=RPM, **KW)
    _, e_still = _frf_run(still, plain)
    r_plain, e_plain = _frf_run(spin, plain)
    r_steer, e_steer = _frf_run(spin, steered)
    assert np.median(e_steer) <= 1.5 * np.median(e_still)
    assert e_steer.max() <= 1.5 * e_still.max()
    assert _clear(steered.excited_lines, RPM, 8.0, 1) > 1
    # the plain design at speed: the lines near k * Omega carry the synchronous response as if it were FRF
    near = _clear_each(r_plain.freq_hz) <= 2 * 8.0
    assert e_plain[near].max() > 4 * e_still.max()
    assert e_plain[near].max() > 4 * e_steer[_clear_each(r_steer.freq_hz) <= 3 * 8.0].max()
    # the steered result carries the synchronous response and keeps it out of the FRF lines
    sync = r_steer.synchronous
    assert sync is not None and not np.intersect1d(sync.lines, r_steer.lines).size
    assert r_plain.synchronous is None


def _clear_each(freq_hz):
    return np.min(np.abs(np.asarray(freq_hz)[:, None] - 200.0 * np.arange(1, 7)[None]), axis=1)


def test_synchronous_response_to_runout_is_the_closed_loop_output_sensitivity():
    """Runout d alone (unbalance off): the loop answers y = (I - P K)^-1 d at each harmonic, with P the true
    rig's sampled model and K the PID, and d's phasor from the rig file's runout at the experiment start."""
    values = load_rig(REPO / "rigs" / "spinning.yaml").to_dict()
    values.update(stack_eccentricity_m=0.0, sleeve_a_eccentricity_m=0.0, sleeve_b_eccentricity_m=0.0)
    rig = make_rig(values)
    design = build_design("multisine", (10, 1000), 8.0, FS, speed_rpm=RPM, **KW)
    res, _ = _frf_run(rig, design)
    sync = res.synchronous
    table = runout_table(rig.values)
    p_model, k_model = true_linear_model(rig, discrete=True), pid_controller(PidParameters(), rig.dt)
    for h in (1, 2, 3):
        i = list(sync.harmonic).index(h)
        d = (table[h - 1, :, 0] - 1j * table[h - 1, :, 1]) * np.exp(1j * h * rig.speed_rad_s * PRE * rig.dt)
        p, k = p_model.freqresp([h * 200.0])[0], k_model.freqresp([h * 200.0])[0]
        want = np.linalg.solve(np.eye(4) - p @ k, d)
        got = sync.amplitude[i, :4] * np.exp(1j * sync.phase_rad[i, :4])
        sigma = sync.amplitude_std[i, :4]
        assert np.all(sigma > 0) and np.all(sigma < 0.01 * np.abs(want))
        assert np.all(np.abs(got - want) < 5 * sigma + 0.005 * np.abs(want)), (h, got, want, sigma)
