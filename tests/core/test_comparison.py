"""ambid.comparison.thesis on a tiny preset: structure, the orthogonal-versus-stepped claim, estimator bias,
nonlinear distortions, the lock-step loop's order and the error measure."""

import copy
import json
import math

import numpy as np
import pytest
from ambid.control.pid import PidParameters, pid_controller
from ambid.excitation import design_stepped_sine
from ambid.plant.rig import make_rig
from ambid.comparison.thesis import METHODS, PARTS, ComparePreset, comparison_markdown, run_comparison, settling_time
from ambid.control.simulated_loop import levitate, run_loop
from ambid.frf.accuracy import frf_relative_error as frf_error

# every part, shrunk: the stepped sine on every 5th line (time extrapolated), two multisine realisations,
# one estimator realisation, the nonlinear runs at 40 Hz resolution
TINY = ComparePreset(
    name="tiny", band_hz=(20.0, 600.0), resolution_hz=20.0, peak_current_a=0.5, target_error=0.02,
    multisine_periods=2, max_realisations=2, noise_blocks=8, stepped_cycles=(1, 2), stepped_tuned_settle_s=(0.02,),
    stepped_line_stride=5, estimator_peak_a=0.02, estimator_realisations=1, estimator_periods=4,
    nonlinear_peak_a=0.6, nonlinear_realisations=2, nonlinear_periods=2, nonlinear_band_hz=(40.0, 600.0),
    nonlinear_resolution_hz=40.0, liftoff_s=0.3)
TINY_METHODS = ("stepped_sine", "multisine_orthogonal")


@pytest.fixture(scope="module")
def rig():
    return make_rig()


@pytest.fixture(scope="module")
def result(rig):
    return run_comparison(TINY, rig, PARTS, TINY_METHODS)


def test_structure_and_report(result):
    assert set(PARTS) <= set(result) and result["preset"]["name"] == "tiny"
    m = result["methods"]
    assert tuple(m["methods"]) == TINY_METHODS
    assert len(m["freq_hz"]) == 30 and m["freq_hz"][0] == 20.0 and m["freq_hz"][-1] == 600.0
    st, ms = m["methods"]["stepped_sine"], m["methods"]["multisine_orthogonal"]
    assert len(st["ladder"]) == 2 * 2 and len(ms["ladder"]) == TINY.max_realisations
    assert st["lines_measured"] == 6 and st["time_extrapolated"] and not ms["time_extrapolated"]
    for e in (st, ms):
        assert e["clipped_samples"] == 0 and e["contact_samples"] == 0
        assert e["wall_s"] > 0 and all(len(s["error_per_line"]) == e["lines_measured"] for s in e["ladder"])
    assert set(result["estimators"]["estimators"]) == {"indirect", "h1", "h2", "arithmetic_mean", "log_mean", "eiv"}
    assert set(result["odd_full"]["grids"]) == {"full", "random_odd"}
    assert "distortion" in result["odd_full"]["grids"]["random_odd"]
    assert "distortion" not in result["odd_full"]["grids"]["full"]
    assert json.loads(json.dumps(result))["methods"]["target_error"] == TINY.target_error
    text = comparison_markdown(result)
    for heading in ("## Excitation methods", "## Estimators in closed loop", "## Odd versus full"):
        assert heading in text
    assert "| orthogonal multisine |" in text and "| H1 |" in text and "| random-odd multisine |" in text


def test_orthogonal_multisine_needs_ten_times_less_time_than_stepped_sine(result):
    m = result["methods"]
    target = m["target_error"]
    st, ms = m["methods"]["stepped_sine"], m["methods"]["multisine_orthogonal"]
    rule = [s for s in st["ladder"] if s["settle_s"] == st["settle_s"]]

    def first(steps, scale=1.0):
        hit = [s["measurement_time_s"] * scale for s in steps if s["median_error"] <= target]
        return min(hit) if hit else math.inf

    t_stepped = first(rule, 30 / 6)
    t_ortho = first(ms["ladder"])
    assert math.isfinite(t_ortho) and math.isfinite(t_stepped)
    assert ms["error_at_target"] <= target and st["error_at_target"] <= target
    assert t_stepped >= 10 * t_ortho
    c = m["orthogonal_vs_stepped"]
    assert c["claim_holds"] and c["target_ratio"] == pytest.approx(t_stepped / t_ortho)


def test_ladder_times_are_the_cut_designs_times(result, rig):
    m = result["methods"]
    st, ms = m["methods"]["stepped_sine"], m["methods"]["multisine_orthogonal"]
    lines = np.array(m["lines"])[::TINY.stepped_line_stride]
    for s in st["ladder"]:
        d = design_stepped_sine(TINY.band_hz, TINY.resolution_hz, 1 / rig.dt, rig.layout.inputs, TINY.peak_current_a,
                                settle_s=s["settle_s"], n_cycles=s["cycles"], lines=lines)
        assert s["measurement_time_s"] == pytest.approx(d.measurement_time_s, rel=1e-12)
    pt = math.ceil(st["settle_s"] * TINY.resolution_hz)   # whole 50 ms periods covering the settling wait
    for s in ms["ladder"]:
        want = s["realisations"] * 4 * (pt + TINY.multisine_periods) / TINY.resolution_hz
        assert s["measurement_time_s"] == pytest.approx(want, rel=1e-12)


def test_h1_is_pulled_towards_minus_inverse_controller_and_indirect_is_not(result):
    e = result["estimators"]
    h1, ind = np.array(e["h1_fraction_towards_minus_inv_c"]), np.array(e["indirect_fraction_towards_minus_inv_c"])
    predicted = np.array(e["h1_fraction_predicted"])
    assert np.median(predicted) > 0.05                       # the noise fed back matters at this excitation
    assert np.median(h1) == pytest.approx(np.median(predicted), rel=0.5)
    assert abs(np.median(ind)) < 0.3 * np.median(h1)


def test_random_odd_grid_shows_the_magnets_distortions(result):
    grids = result["odd_full"]["grids"]
    dist = grids["random_odd"]["distortion"]
    assert dist["even_db_max"] > 6.0                        # even distortions well above the noise floor
    assert len(dist["even_freq_hz"]) > 0 and len(dist["odd_freq_hz"]) > 0
    assert grids["full"]["variance_ratio"] > 1.5             # realisation scatter exceeds the noise alone
    assert grids["full"]["clipped_samples"] == 0 and grids["random_odd"]["clipped_samples"] == 0


def test_run_loop_follows_the_plant_sim_order(rig):
    start = levitate(rig, seed=3, liftoff_s=0.3)
    x0 = start.sim.x.copy()
    r = 0.05 * np.random.default_rng(0).standard_normal((400, 4))
    rec = run_loop(start, r)
    again = run_loop(start, r)
    np.testing.assert_array_equal(rec.y, again.y)             # deterministic, start untouched
    np.testing.assert_array_equal(start.sim.x, x0)
    ctl = copy.deepcopy(start.ctl)
    ic = np.array([ctl.step(y) for y in rec.y])                # ic[k] answers y[k]
    np.testing.assert_allclose(rec.u - rec.r, ic, rtol=0, atol=1e-15)
    assert rec.n_clipped == 0 and rec.n_contact == 0
    with pytest.raises(ValueError, match="shape"):
        run_loop(start, np.zeros((10, 3)))


def test_frf_error_and_settling_time(rig):
    g = np.random.default_rng(1).standard_normal((5, 4, 4)) + 1j
    np.testing.assert_allclose(frf_error(1.1 * g, g), 0.1)
    bad = g.copy()
    bad[2, 0, 0] = np.nan
    assert np.isnan(frf_error(bad, g)[2]) and np.isfinite(frf_error(bad, g)[[0, 1, 3, 4]]).all()
    k = pid_controller(PidParameters(), rig.dt)
    low, high = settling_time(rig, k, 600.0, 3.0), settling_time(rig, k, 2000.0, 1.0)
    assert low["settle_s"] == pytest.approx(3 * low["time_constant_s"])
    assert low["pole_hz"] <= 600.0 and high["time_constant_s"] >= low["time_constant_s"]


def test_bad_presets_and_parts_are_refused(rig):
    with pytest.raises(ValueError, match="noise_blocks"):
        ComparePreset(**{**TINY.__dict__, "noise_blocks": 4})
    with pytest.raises(ValueError, match="stepped_cycles"):
        ComparePreset(**{**TINY.__dict__, "stepped_cycles": (2, 1)})
    with pytest.raises(ValueError, match="parts"):
        run_comparison(TINY, rig, ("bogus",))
    with pytest.raises(ValueError, match="preset"):
        run_comparison("nope", rig)
    with pytest.raises(ValueError, match="methods"):
        run_comparison(TINY, rig, ("methods",), ("stepped_sine", "chirp"))
    assert set(METHODS) >= set(TINY_METHODS)
