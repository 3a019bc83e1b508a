"""Input sensitivity and ISO 14839-3 zones (ambid.frf.sensitivity)."""

import numpy as np
import pytest
from ambid.frf import (input_sensitivity, input_sensitivity_from_models, iso14839_zone, sensitivity_diagonal,
                       sensitivity_peak)


@pytest.mark.parametrize("peak,zone", [(0.0, "A"), (2.999, "A"), (3.0, "B"), (3.99, "B"),
                                       (4.0, "C"), (4.99, "C"), (5.0, "D"), (40.0, "D")])
def test_zone_boundaries(peak, zone):
    assert iso14839_zone(peak) == zone


@pytest.mark.parametrize("bad", [-1.0, np.nan, np.inf])
def test_zone_rejects_bad_peak(bad):
    with pytest.raises(ValueError, match="peak"):
        iso14839_zone(bad)


def test_sensitivity_from_models_siso_and_sign():
    # SISO: S = 1 / (1 + C P) for u = r - C y; a mass on a spring with PD control
    w = 2 * np.pi * np.linspace(1, 500, 200)
    p = 1.0 / (-(w**2) * 2.0 + 1e4)
    c = 3e4 + 40.0 * 1j * w
    s = input_sensitivity_from_models(p[:, None, None], c[:, None, None])
    np.testing.assert_allclose(s[:, 0, 0], 1 / (1 + c * p))
    # MIMO: the definition u = (I + C P)^-1 r, checked by substitution
    rng = np.random.default_rng(1)
    pm = rng.standard_normal((4, 3, 2)) + 1j * rng.standard_normal((4, 3, 2))
    cm = rng.standard_normal((4, 2, 3)) + 1j * rng.standard_normal((4, 2, 3))
    sm = input_sensitivity_from_models(pm, cm)
    r = rng.standard_normal((4, 2, 1))
    u = sm @ r
    np.testing.assert_allclose(u, r - cm @ (pm @ u), atol=1e-12)
    with pytest.raises(ValueError, match="c_jw"):
        input_sensitivity_from_models(pm, cm[:, :, :2])


def test_measured_sensitivity_and_peak():
    rng = np.random.default_rng(2)
    n_lines = 6
    s_true = (rng.standard_normal((n_lines, 2, 2)) + 1j * rng.standard_normal((n_lines, 2, 2)))
    s_true[3, 1, 1] = 4.2                       # axis 2 peaks at line 3
    s_true[1, 0, 0] = -3.5j                     # axis 1 peaks at line 1
    r = rng.standard_normal((2, 2, 3, n_lines, 2)) + 1j * rng.standard_normal((2, 2, 3, n_lines, 2))
    u = np.einsum("lab,meplb->mepla", s_true, r)
    s = input_sensitivity(u, r)
    np.testing.assert_allclose(s, s_true, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(sensitivity_diagonal(s), np.diagonal(s, axis1=1, axis2=2))
    peak, idx = sensitivity_peak(s)
    assert idx.tolist() == [1, 3]
    np.testing.assert_allclose(peak, [3.5, 4.2])
    assert iso14839_zone(peak.max()) == "C"
    np.testing.assert_allclose(sensitivity_peak(sensitivity_diagonal(s))[0], peak)
    with pytest.raises(ValueError, match="NaN"):
        sensitivity_peak(np.full((3, 2), np.nan))
