"""Common-denominator fit of MIMO FRFs (ambid.fit.common_denominator)."""

import warnings

import numpy as np
import pytest
from ambid.fit import benchmark_fit, fit_common_denominator, modal_summary, synthetic_amb_plant
from ambid.statespace import StateSpace, block_diag

F_HZ = np.linspace(10.0, 1000.0, 1000)


def amb_plane(ks=4.0e5, ki=200.0, mass=10.0, inertia=0.15, z_bearings=(-0.15, 0.2), bending_hz=300.0,
              zeta=0.008, bending_shape=(1.0, -0.8), modal_mass=3.0, amp_hz=1500.0) -> StateSpace:
    """One plane of a rigid rotor on two AMBs plus one bending mode and amplifiers.

    Inputs: current references [A] of bearings A and B; outputs: displacements
    at A and B [m]. Bearing forces ks x + ki i (negative stiffness ks > 0),
    amplifiers first order at amp_hz.
    """
    t = np.column_stack([[1.0, 1.0], z_bearings, bending_shape])  # (centre, tilt, eta) -> bearings
    minv = np.diag(1.0 / np.array([mass, inertia, modal_mass]))
    wb = 2 * np.pi * bending_hz
    k = np.diag([0.0, 0.0, modal_mass * wb**2]) - ks * t.T @ t
    c = np.diag([0.0, 0.0, 2 * zeta * modal_mass * wb])
    wa = 2 * np.pi * amp_hz
    a = np.zeros((8, 8))
    a[:3, 3:6] = np.eye(3)
    a[3:6, :3] = -minv @ k
    a[3:6, 3:6] = -minv @ c
    a[3:6, 6:] = ki * minv @ t.T
    a[6:, 6:] = -wa * np.eye(2)
    b = np.zeros((8, 2))
    b[6:] = wa * np.eye(2)
    cm = np.zeros((2, 8))
    cm[:, :3] = t
    return StateSpace(a, b, cm, np.zeros((2, 2)))


def amb_plant() -> StateSpace:
    """4x4 plant: identical x and y planes (a non-rotating symmetric rotor)."""
    return block_diag(amb_plane(), amb_plane())


def frf(ss: StateSpace, f: np.ndarray) -> np.ndarray:
    """C (sI - A)^-1 B + D through the eigendecomposition, all lines at once."""
    lam, v = np.linalg.eig(ss.a)
    cv, wb = ss.c @ v, np.linalg.solve(v, ss.b)
    h = 1.0 / (2j * np.pi * f[:, None] - lam[None, :])
    return np.einsum("pk,lk,km->lpm", cv, h, wb) + ss.d


def distinct_poles(ss: StateSpace) -> np.ndarray:
    p = ss.poles()
    out = []
    for q in p[np.argsort(np.abs(p))]:
        if not any(abs(q - o) < 1e-6 * abs(q) for o in out):
            out.append(q)
    return np.array(out)


def noisy(g, rel, seed):
    rng = np.random.default_rng(seed)
    sig = rel * np.sqrt(np.mean(np.abs(g) ** 2, axis=(1, 2)))
    var = np.broadcast_to(sig[:, None, None] ** 2, g.shape).copy()
    return g + np.sqrt(var / 2) * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape)), var


def match(fitted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """For each true pole the nearest fitted pole."""
    return np.array([fitted[np.argmin(np.abs(fitted - q))] for q in true])


@pytest.fixture(scope="module")
def plant_frf():
    p = amb_plant()
    return p, distinct_poles(p), frf(p, F_HZ)


def test_plant_is_open_loop_unstable_with_seven_distinct_poles(plant_frf):
    # the test plant itself: two real RHP poles, one bending pair, one amplifier pole
    _, poles, _ = plant_frf
    assert poles.size == 7
    assert np.count_nonzero((poles.imag == 0) & (poles.real > 0)) == 2
    bend = poles[poles.imag > 0][0]
    assert abs(abs(bend) / (2 * np.pi) - 290) < 15 and 0.005 < -bend.real / abs(bend) < 0.01


def test_noise_free_fit_is_exact_at_the_true_order(plant_frf):
    _, poles, g = plant_frf
    res = fit_common_denominator(F_HZ, g, order=7)
    err = np.abs(res.model.freqresp(F_HZ) - g).max() / np.abs(g).max()
    assert err < 1e-11  # measured 7e-14
    np.testing.assert_allclose(match(res.model.poles, poles), poles, rtol=1e-10)
    assert not res.weighted and res.model.order == 7


def test_noisy_fit_recovers_modes_unstable_poles_and_chi_square(plant_frf):
    _, poles, g = plant_frf
    gn, var = noisy(g, 0.02, seed=11)
    res = fit_common_denominator(F_HZ, gn, var, order=7)
    summary = modal_summary(res.model)
    bend = poles[poles.imag > 0][0]
    (mode,) = summary.modes
    assert abs(mode.freq_hz / (abs(bend) / (2 * np.pi)) - 1) < 0.005
    assert abs(mode.damping / (-bend.real / abs(bend)) - 1) < 0.10
    rhp = np.sort(poles[(poles.imag == 0) & (poles.real > 0)].real)
    fitted_rhp = np.array([r.pole_rad_s for r in summary.real_poles if r.unstable])
    assert fitted_rhp.size == 2
    np.testing.assert_allclose(np.sort(fitted_rhp), rhp, rtol=0.03)
    lhp_rigid = poles[(poles.imag == 0) & (poles.real < 0) & (np.abs(poles) < 1000)]
    np.testing.assert_allclose(match(res.model.poles, lhp_rigid).real, lhp_rigid.real, rtol=0.03)
    # 2V is chi-square with N - p degrees of freedom at the ML estimate
    dof = res.dof
    assert res.n_residuals == 2 * F_HZ.size * 16
    assert abs(2 * res.cost - dof) < 5 * np.sqrt(2 * dof)
    assert res.cost <= res.cost_linear


def test_refinement_reaches_the_cost_of_a_fit_started_at_the_truth(plant_frf):
    # the ML stage should find the same minimum as a start from the true poles
    _, poles, g = plant_frf
    f = F_HZ[::2]
    gn, var = noisy(g[::2], 0.05, seed=3)
    res = fit_common_denominator(f, gn, var, order=7)
    ref = fit_common_denominator(f, gn, var, order=7, initial_poles=poles)
    assert res.cost <= ref.cost * (1 + 1e-6)


def test_relative_degree_and_delay_options(plant_frf):
    _, poles, g = plant_frf
    tau = 2e-4
    gd = g * np.exp(-2j * np.pi * F_HZ * tau)[:, None, None]
    res = fit_common_denominator(F_HZ, gd, order=7, relative_degree=3, delay_s=tau)
    m = res.model
    assert np.abs(m.freqresp(F_HZ) - gd).max() / np.abs(g).max() < 1e-8
    assert m.delay_s == tau and np.all(m.feedthrough == 0)
    # relative degree 3: the s^-1 and s^-2 Laurent coefficients vanish
    scale = np.abs(m.residues).max() * np.abs(m.poles).max()
    assert np.abs(m.residues.sum(axis=0)).max() < 1e-10 * scale
    assert np.abs((m.residues * m.poles[:, None, None]).sum(axis=0)).max() < 1e-10 * scale * np.abs(m.poles).max()
    # ignoring the delay leaves a visible misfit at the same order
    plain = fit_common_denominator(F_HZ, gd, order=7)
    assert np.abs(plain.model.freqresp(F_HZ) - gd).max() / np.abs(g).max() > 1e-6


def test_siso_fit_and_strictly_proper():
    # a SISO FRF (L,) with one complex pair and one real pole, strictly proper
    f = np.linspace(1.0, 100.0, 200)
    s = 2j * np.pi * f
    p1, p2 = -20 + 300j, -150.0
    g = 3e3 / ((s - p1) * (s - np.conj(p1))) + 40.0 / (s - p2)
    res = fit_common_denominator(f, g, order=3, relative_degree=1)
    assert res.model.freqresp(f).shape == (200, 1, 1)
    np.testing.assert_allclose(res.model.freqresp(f)[:, 0, 0], g, rtol=1e-9)
    np.testing.assert_allclose(np.sort_complex(res.model.poles), np.sort_complex([p2, p1, np.conj(p1)]),
                               rtol=1e-9)


@pytest.mark.parametrize("kwargs,msg", [
    (dict(G=np.ones((5, 2, 2))), "L = len"),
    (dict(var=-np.ones((10, 2, 2))), "var"),
    (dict(var=np.ones((10, 2))), "var"),
    (dict(G=np.full((10, 2, 2), np.nan)), "NaN"),
    (dict(order=0), "order"),
    (dict(order=30), "lines"),
    (dict(relative_degree=9), "relative_degree"),
    (dict(delay_s=-1.0), "delay_s"),
    (dict(initial_poles=np.array([1 + 1j, 2.0, 3.0])), "conjugation"),
    (dict(initial_poles=np.array([-1 + 1j, -1 - 1j, -1 + 1j, -1 - 1j]), order=4), "repeats"),
    (dict(freq_hz=np.r_[np.arange(9.0), 3.0]), "repeated"),
])
def test_bad_input_is_rejected(kwargs, msg):
    args = dict(freq_hz=np.arange(1.0, 11.0), G=np.ones((10, 2, 2), dtype=complex), var=None, order=3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=msg):
        fit_common_denominator(args.pop("freq_hz"), args.pop("G"), args.pop("var"), **args)


def test_benchmark_helper_runs_and_order_30_fits_without_warnings():
    # not a timing test: the helper's figures must be sane, and a 30th-order (over-)fit of its
    # 21-pole plant over 10-1000 Hz must run without any ill-conditioning warning
    assert distinct_poles(synthetic_amb_plant()).size == 21
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = benchmark_fit(n_lines=200, order=30, noise_rel=0.01, seed=1)
    assert out["time_s"] > 0 and out["n_lines"] == 200 and out["order"] == 30
    assert out["max_rel_error"] < 0.01 and abs(out["chi2_per_dof"] - 1) < 0.2
