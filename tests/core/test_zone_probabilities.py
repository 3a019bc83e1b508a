"""The headline zone's confidence: draws of the loop's worst sensitivity peak from the FRF's uncertainty
(ambid.frf.sensitivity.sensitivity_peak_draws) and the probability of each ISO 14839-3 zone."""

import numpy as np

from ambid.frf.sensitivity import ZONES, sensitivity_lines, sensitivity_peak_draws, zone_probabilities


def _siso(peak: float, phase: float = 0.4):
    """One line of a SISO loop whose |S| is ``peak``: G = 1, C = 1/S - 1."""
    s = peak * np.exp(1j * phase)
    g = np.ones((1, 1, 1), complex)
    c = np.full((1, 1, 1), 1.0 / s - 1.0)
    return np.full((1, 1, 1), s), g, c


def test_probabilities_sum_to_one_and_far_inside_a_zone_is_certain():
    s, g, c = _siso(2.0)
    p = zone_probabilities(sensitivity_peak_draws(s, g, np.full((1, 1, 1), 1e-6), c, 1000,
                                                  np.random.default_rng(1)))
    assert abs(sum(p.values()) - 1.0) < 1e-12
    assert p["A"] > 0.999
    s, g, c = _siso(4.5)
    p = zone_probabilities(sensitivity_peak_draws(s, g, np.full((1, 1, 1), 1e-6), c, 1000,
                                                  np.random.default_rng(2)))
    assert p["C"] > 0.999 and abs(sum(p.values()) - 1.0) < 1e-12


def test_a_peak_on_a_boundary_with_a_large_variance_splits():
    s, g, c = _siso(3.0)
    p = zone_probabilities(sensitivity_peak_draws(s, g, np.full((1, 1, 1), 0.01), c, 1000,
                                                  np.random.default_rng(3)))
    assert p["A"] > 0.25 and p["B"] > 0.25
    assert abs(sum(p.values()) - 1.0) < 1e-12
    # no variance: the point value's zone, with certainty
    d = sensitivity_peak_draws(s * 0.999, g, np.zeros((1, 1, 1)), c, 50)
    assert zone_probabilities(d)["A"] == 1.0


VAR = 0.002


def test_against_an_independent_monte_carlo():
    """2x2 loop over 3 lines: the test draws the plant in polar form (Rayleigh modulus, uniform phase: the
    same circular Gaussian) and inverts I + C G by the 2x2 adjugate; the zone shares agree within sampling."""
    rng = np.random.default_rng(7)
    n_lines = 3
    g = rng.normal(size=(n_lines, 2, 2)) + 1j * rng.normal(size=(n_lines, 2, 2))
    # the controller that gives these sensitivities: the worst |S_ii| near the B/C boundary at line 1
    s0 = np.array([np.diag([2.0, 1.2]), [[4.0 * np.exp(0.3j), 0.5], [0.3j, 2.5]], np.diag([1.5, 3.6])], complex)
    c = (np.linalg.inv(s0) - np.eye(2)) @ np.linalg.inv(g)
    var = np.full(g.shape, VAR)
    p = zone_probabilities(sensitivity_peak_draws(s0, g, var, c, 4000, np.random.default_rng(11)))

    n = 40000
    mc = np.random.default_rng(12)
    mod = np.sqrt(var * -np.log(mc.uniform(size=(n, *g.shape))))
    gd = g + mod * np.exp(2j * np.pi * mc.uniform(size=(n, *g.shape)))
    m = np.eye(2) + np.einsum("lij,nljk->nlik", c, gd)
    det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
    s11, s22 = m[..., 1, 1] / det, m[..., 0, 0] / det
    peaks = np.maximum(np.abs(s11), np.abs(s22)).max(axis=1)
    ref = {z: float(np.mean(np.searchsorted([3.0, 4.0, 5.0], peaks, side="right") == k)) for k, z in enumerate(ZONES)}
    spread = {z: ref[z] for z in ZONES if 0.02 < ref[z] < 0.98}
    assert spread, f"the case should split between zones: {ref}"
    for z in ZONES:
        assert abs(p[z] - ref[z]) < 4 * np.sqrt(ref[z] * (1 - ref[z]) / 4000) + 0.005, (p, ref)


def test_the_headline_prints_the_probabilities():
    sens = {"loop": {"peak": 4.9, "peak_hz": 58.3, "channel": "u_b_y", "source": "the measured lines",
                     "iso_zone": "C", "zone_probabilities": {"A": 0.0, "B": 0.0, "C": 0.97, "D": 0.03}}}
    lines = sensitivity_lines(sens)
    assert lines[-1] == ("  zone probabilities A 0.00, B 0.00, C 0.97, D 0.03 (from the measured and fitted "
                         "sensitivity's uncertainty)")
    del sens["loop"]["zone_probabilities"]
    assert not any("zone probabilities" in ln for ln in sensitivity_lines(sens))
