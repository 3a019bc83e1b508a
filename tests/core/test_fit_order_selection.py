"""Stabilisation diagram and CMIF (ambid.fit.order_selection)."""

import matplotlib.image
import numpy as np
import pytest
from ambid.fit import STATUS_LABELS, RationalModel, cmif, plot_cmif, plot_stabilisation, stabilisation_diagram

F_HZ = np.linspace(5.0, 400.0, 400)


def pair(freq_hz, zeta):
    wn = 2 * np.pi * freq_hz
    return complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))


@pytest.fixture(scope="module")
def data():
    """2x2 truth of order 6: modes at 80 and 200 Hz, an unstable (+150 rad/s) and a stable real pole."""
    p1, p2 = pair(80.0, 0.01), pair(200.0, 0.02)
    r1 = 400.0 * np.outer([1.0, 0.6], [1.0, -0.4 + 0.2j])
    r2 = 900.0 * np.outer([0.5, -1.0], [0.3j, 1.0])
    r3 = 5e3 * np.outer([1.0, 1.0], [1.0, 0.8])
    r4 = 2e4 * np.outer([1.0, -0.5], [0.7, 1.0])
    truth = RationalModel(np.array([p1, np.conj(p1), p2, np.conj(p2), 150.0, -900.0]),
                          np.stack([r1, r1.conj(), r2, r2.conj(), r3, r4]), np.zeros((2, 2)))
    g = truth.freqresp(F_HZ)
    rng = np.random.default_rng(8)
    var = np.broadcast_to((0.01 * np.abs(g).mean(axis=(1, 2))) ** 2, (2, 2, F_HZ.size)).T.copy()
    gn = g + np.sqrt(var / 2) * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape))
    diagram = stabilisation_diagram(F_HZ, gn, var, orders=range(4, 13))
    return truth, gn, var, diagram


def test_true_poles_are_stable_over_orders_and_spurious_ones_are_not(data):
    truth, _, _, d = data
    assert list(d.orders) == list(range(4, 13))
    true_poles = truth.poles[truth.poles.imag >= 0]
    for p in true_poles:
        tol = 0.005 if p.imag else 0.02  # real poles (no resonance) are less sharply fixed by the data
        stable_orders = [n for n in range(7, 13)
                         if np.any(d.status[(d.order == n) & (np.abs(d.pole_rad_s - p) < tol * abs(p))] == 3)]
        assert len(stable_orders) >= 4, f"pole {p:.1f} stable only at orders {stable_orders}"
    # and whatever is stable in frequency and damping is a true pole
    for q in d.pole_rad_s[d.status == 3]:
        assert np.min(np.abs(true_poles - q) / np.abs(true_poles)) < 0.02
    # the unstable real pole is fitted as unstable
    assert np.all(d.pole_rad_s[(d.order >= 6) & (np.abs(d.pole_rad_s - 150) < 5)].real > 0)
    # first order: nothing to compare with
    assert np.all(d.status[d.order == 4] == 0)
    # the fit statistic drops to ~1 at the true order, not before
    chi = dict(zip(d.orders, d.chi2_per_dof))
    assert chi[4] > 10 and chi[5] > 1.5 and abs(chi[6] - 1) < 0.1
    # row fields agree with the poles
    np.testing.assert_allclose(d.freq_hz, np.abs(d.pole_rad_s) / (2 * np.pi))
    assert d.poles_of(6).size == 4  # two pairs (Im > 0 rows) + two real poles


def test_cmif_is_the_singular_values():
    rng = np.random.default_rng(0)
    g = rng.standard_normal((5, 3, 2)) + 1j * rng.standard_normal((5, 3, 2))
    sv = cmif(g)
    assert sv.shape == (5, 2)
    for k in range(5):
        np.testing.assert_allclose(sv[k] ** 2, np.sort(np.linalg.eigvalsh(g[k].conj().T @ g[k]))[::-1])
    diag = np.zeros((4, 2, 2), dtype=complex)
    diag[:, 0, 0], diag[:, 1, 1] = 3.0, -5.0j
    np.testing.assert_allclose(cmif(diag), np.tile([5.0, 3.0], (4, 1)))
    with pytest.raises(ValueError, match="L, Ny, Nu"):
        cmif(np.ones((3, 3)))


def test_figures_are_written_with_units_and_legend(data, tmp_path):
    truth, gn, _, d = data
    fig = plot_stabilisation(d, tmp_path / "stab.png", G=gn, freq_hz=F_HZ)
    img = matplotlib.image.imread(tmp_path / "stab.png")
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 500
    ax = fig.axes[0]
    assert "[Hz]" in ax.get_xlabel() and "order" in ax.get_ylabel()
    assert "[m/A]" in fig.axes[1].get_ylabel()
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert set(STATUS_LABELS) <= set(labels)
    fig2 = plot_cmif(F_HZ, gn, tmp_path / "cmif.png", model=truth)
    assert matplotlib.image.imread(tmp_path / "cmif.png").ndim == 3
    assert len(fig2.axes[0].get_lines()) == 4  # two measured, two model singular values
    assert "[m/A]" in fig2.axes[0].get_ylabel() and "[Hz]" in fig2.axes[0].get_xlabel()
    with pytest.raises(ValueError, match="freq_hz"):
        plot_stabilisation(d, G=gn)


def test_bad_orders_rejected():
    with pytest.raises(ValueError, match="orders"):
        stabilisation_diagram(F_HZ, np.ones((F_HZ.size, 1, 1)), orders=[0, 2])
