"""Physical-model updating with confidence intervals (ambid.fit.updating)."""

import numpy as np
import pytest
from ambid.fit import update_parameters
from ambid.fit.updating import NotIdentifiable
from ambid.fit.blas_threads import single_threaded_blas
from ambid.statespace import StateSpace

F_HZ = np.linspace(5.0, 500.0, 150)
MASS, INERTIA, Z_AB = 10.0, 0.15, (-0.15, 0.2)
TRUE = np.array([200.0, 4.0e5, 1500.0])  # ki [N/A], ks [N/m], amplifier bandwidth [Hz]
NAMES = ("ki", "ks", "amp_hz")


def plane(ki, ks, amp_hz, mass=MASS, inertia=INERTIA) -> StateSpace:
    """One plane of a rigid rotor on two AMBs: x'' = W (ks x + ki i), first-order amplifiers.

    x are the bearing displacements [m], W = T M^-1 T^T the inverse mass in
    bearing coordinates, i the amplifier output currents [A].
    """
    t = np.array([[1.0, Z_AB[0]], [1.0, Z_AB[1]]])
    w = t @ np.diag([1 / mass, 1 / inertia]) @ t.T
    wa = 2 * np.pi * amp_hz
    a = np.zeros((6, 6))
    a[:2, 2:4] = np.eye(2)
    a[2:4, :2] = ks * w
    a[2:4, 4:] = ki * w
    a[4:, 4:] = -wa * np.eye(2)
    b = np.zeros((6, 2))
    b[4:] = wa * np.eye(2)
    c = np.zeros((2, 6))
    c[:, :2] = np.eye(2)
    return StateSpace(a, b, c, np.zeros((2, 2)))


def closed_form(theta, f=F_HZ):
    """G(s) = (s^2 I - ks W)^-1 W ki wa / (s + wa), independent of the state space."""
    ki, ks, amp_hz = theta
    t = np.array([[1.0, Z_AB[0]], [1.0, Z_AB[1]]])
    w = t @ np.diag([1 / MASS, 1 / INERTIA]) @ t.T
    s = 2j * np.pi * f[:, None, None]
    wa = 2 * np.pi * amp_hz
    return np.linalg.solve(s**2 * np.eye(2) - ks * w, np.broadcast_to(w, (f.size, 2, 2))) * ki * wa / (s + wa)


@pytest.fixture(autouse=True)
def _one_blas_thread():
    # StateSpace.freqresp makes one small solve per line; busy-waiting OpenBLAS threads
    # on a loaded machine make that 50x slower
    with single_threaded_blas():
        yield


@pytest.fixture(scope="module")
def measured():
    g = closed_form(TRUE)
    rng = np.random.default_rng(0)
    var = (0.01 * np.abs(g).mean(axis=(1, 2))) ** 2
    var = np.broadcast_to(var[:, None, None], g.shape).copy()
    return g + np.sqrt(var / 2) * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape)), var


def test_plant_model_matches_closed_form():
    np.testing.assert_allclose(plane(*TRUE).freqresp(F_HZ), closed_form(TRUE), rtol=1e-9)


def test_update_from_20_percent_off_recovers_truth_with_intervals(measured):
    g, var = measured
    start = TRUE * np.array([0.8, 1.2, 0.8])
    res = update_parameters(lambda th: plane(*th), start, F_HZ, g, var, names=NAMES)
    assert res.success and res.names == NAMES
    np.testing.assert_allclose(res.theta, TRUE, rtol=0.02)
    assert np.all((res.ci95[:, 0] < TRUE) & (TRUE < res.ci95[:, 1]))
    assert np.all(res.std > 0) and np.all(res.std < 0.02 * TRUE)
    np.testing.assert_allclose(np.diag(res.correlation), 1.0)
    np.testing.assert_allclose(res.correlation, res.correlation.T)
    assert np.all(np.abs(res.correlation) <= 1 + 1e-12)
    # right model and right variances: 2V ~ chi-square(N - p)
    assert abs(2 * res.cost - res.dof) < 5 * np.sqrt(2 * res.dof)
    # trusting var instead of the residual gives nearly the same intervals
    res2 = update_parameters(closed_form, start, F_HZ, g, var, names=NAMES, scale_covariance=False)
    np.testing.assert_allclose(res2.std, res.std, rtol=0.1)
    d = res.to_dict()
    assert [p["name"] for p in d["parameters"]] == list(NAMES)


def test_std_matches_the_scatter_over_noise_realisations():
    # the Jacobian-based standard deviation against the spread of 12 repeated fits (ks only)
    g0 = closed_form(TRUE)
    var = np.broadcast_to(((0.03 * np.abs(g0).mean(axis=(1, 2))) ** 2)[:, None, None], g0.shape).copy()
    rng = np.random.default_rng(5)
    est, std = [], []
    for _ in range(12):
        g = g0 + np.sqrt(var / 2) * (rng.standard_normal(g0.shape) + 1j * rng.standard_normal(g0.shape))
        res = update_parameters(lambda th: closed_form([TRUE[0], th[0], TRUE[2]]), [TRUE[1] * 1.1], F_HZ, g, var)
        est.append(res.theta[0])
        std.append(res.std[0])
    spread = np.std(est, ddof=1)
    # 12 samples: the sample std is within about +-45 % of the true one at 95 %
    assert 0.55 < spread / np.mean(std) < 1.6


def test_frf_callable_gives_the_same_answer(measured):
    g, var = measured
    start = TRUE * np.array([1.2, 0.8, 1.2])
    a = update_parameters(lambda th: plane(*th), start, F_HZ, g, var)
    b = update_parameters(closed_form, start, F_HZ, g, var)
    np.testing.assert_allclose(a.theta, b.theta, rtol=1e-6)
    np.testing.assert_allclose(a.std, b.std, rtol=1e-3)


def test_non_identifiable_parameters_are_named(measured):
    # ki, ks, mass and inertia only enter as ki / M and ks / M: scaling all four changes nothing
    g, var = measured
    with pytest.raises(ValueError, match="not identifiable") as err:
        update_parameters(lambda th: plane(th[0], th[1], TRUE[2], mass=th[2], inertia=th[3]),
                          [TRUE[0], TRUE[1], MASS, INERTIA], F_HZ, g, var, names=("ki", "ks", "mass", "inertia"))
    for name in ("ki", "ks", "mass", "inertia"):
        assert name in str(err.value)
    assert isinstance(err.value, NotIdentifiable) and set(err.value.parameters) == {"ki", "ks", "mass", "inertia"}


@pytest.mark.parametrize("kwargs,msg", [
    (dict(names=("a",)), "names"),
    (dict(scales=[1.0, -1.0, 1.0]), "scales"),
    (dict(var=np.ones((3, 2, 2))), "var"),
    (dict(bounds=([0, 0, 0], [1, 1, 1])), "bounds"),
    (dict(theta0=[np.nan, 1.0, 1.0]), "theta0"),
])
def test_bad_input_is_rejected(measured, kwargs, msg):
    g, var = measured
    args = dict(theta0=TRUE, var=var)
    args.update(kwargs)
    with pytest.raises(ValueError, match=msg):
        update_parameters(lambda th: plane(*th), args.pop("theta0"), F_HZ, g, args.pop("var"), **args)


def test_wrong_model_output_is_rejected(measured):
    g, var = measured
    with pytest.raises(ValueError, match="discrete"):
        update_parameters(lambda th: plane(*th).to_discrete(1e-4), TRUE, F_HZ, g, var)
    with pytest.raises(ValueError, match="shape"):
        update_parameters(lambda th: closed_form(th)[:, :1], TRUE, F_HZ, g, var)


def _lagged(theta, f=F_HZ):
    """closed_form with a pure delay: [ki, ks, amp_hz, delay_s, damping]. Far below the amplifier's corner
    its lag and the delay both turn the phase by about 2 pi f tau: the data tell their sum, not their split.
    ``damping`` adds a velocity term c = damping * 2 sqrt(ks / m) to the rigid rotor."""
    ki, ks, amp_hz, delay, zeta = theta
    t = np.array([[1.0, Z_AB[0]], [1.0, Z_AB[1]]])
    w = t @ np.diag([1 / MASS, 1 / INERTIA]) @ t.T
    s = 2j * np.pi * f[:, None, None]
    wa = 2 * np.pi * amp_hz
    c = zeta * 2 * np.sqrt(ks / MASS)
    return (np.linalg.solve(s**2 * np.eye(2) + c * s * np.eye(2) - ks * w, np.broadcast_to(w, (f.size, 2, 2)))
            * ki * wa / (s + wa) * np.exp(-s * delay))


def test_map_intervals_cover_the_truth_drawn_from_the_prior():
    # the field as validate sees it, on a small model: each draw's truth lies off the nominal by a draw from
    # the prior (data-sheet tolerances), the FRF has known noise; the MAP's 95 % intervals must hold the
    # truth 95 % of the time for every parameter, the data-told ones (ki, ks), the ones the prior dominates
    # (the lag's split between amplifier and delay) and the one in between (a small damping, log prior)
    from ambid.fit.updating import Prior
    from ambid.plant.tolerances import Z95
    from scipy import stats

    f = np.linspace(5.0, 300.0, 60)           # well below the 5 kHz amplifier corner
    nominal = np.array([200.0, 4.0e5, 5000.0, 5e-5, 0.002])
    rel = np.array([0.05, 0.10, 0.30, np.nan, np.nan]) / Z95
    sd = np.array([rel[0] * nominal[0], rel[1] * nominal[1], rel[2] * nominal[2], 2.5e-5, np.log(3) / Z95])
    log = np.array([False, False, False, False, True])
    rng = np.random.default_rng(26)
    n_draws, hits, z, ratio = 300, np.zeros(5), [], []
    for _ in range(n_draws):
        u = sd * rng.standard_normal(5)
        truth = np.where(log, nominal * np.exp(np.where(log, u, 0.0)), nominal + u)
        g0 = _lagged(truth, f)
        var = np.broadcast_to(((0.01 * np.abs(g0).mean(axis=(1, 2))) ** 2)[:, None, None], g0.shape).copy()
        g = g0 + np.sqrt(var / 2) * (rng.standard_normal(g0.shape) + 1j * rng.standard_normal(g0.shape))
        # the prior is centred on the nominal; the update starts there (the truth is not known)
        res = update_parameters(lambda th: _lagged(th, f), nominal, f, g, var, prior=Prior(nominal, sd, log),
                                scale_covariance=False, bounds=([1.0, 1.0, 10.0, -1e-3, 0.0], [1e4, 1e8, 1e6, 1e-3, 1.0]))
        hits += (res.ci95[:, 0] <= truth) & (truth <= res.ci95[:, 1])
        z.append((res.theta - truth) / res.std)
        ratio.append(res.prior_ratio)
    ratio = np.mean(ratio, axis=0)
    # the gains are the data's (posterior / prior width ~0.03); the amplifier's small lag is the prior's (~0.94):
    # the delay takes the phase the data show; the damping lies in between (~0.7)
    assert np.all(ratio[:2] < 0.1) and ratio[2] > 0.85 and ratio[3] < 0.4 and 0.4 < ratio[4] < 0.9, ratio
    # every parameter's coverage: its Clopper-Pearson 99 % interval holds 0.95
    lo = stats.beta.ppf(0.005, hits, n_draws - hits + 1)
    hi = stats.beta.ppf(0.995, hits + 1, n_draws - hits)
    assert np.all((lo <= 0.95) & (0.95 <= hi)), hits / n_draws
    # and the claimed standard deviations are the errors' (empirical / claimed within 0.8-1.25)
    emp = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((0.8 < emp) & (emp < 1.25)), emp


def test_prior_term_gives_the_exact_posterior_of_a_linear_model():
    # linear model, normal prior: the posterior covariance is (2 J^T J + P)^-1 (real-stacked, weighted J)
    # exactly, and a parameter the data do not see at all keeps its prior mean and width
    from ambid.fit.updating import Prior

    f = np.linspace(10.0, 500.0, 40)
    s = 2j * np.pi * f / 500.0
    basis = np.stack([np.ones_like(s), s, 1 / (1 + s), 0 * s])                    # the last one: no effect
    b = basis[:, :, None, None] * np.array([[1.0, 0.5], [0.2, -1.0]])
    model = lambda th: np.einsum("k,klij->lij", th, b)
    var = np.full((f.size, 2, 2), 1e-2)
    theta = np.array([1.0, -0.5, 2.0, 3.0])
    prior = Prior(np.array([1.1, 0.0, 2.0, 2.5]), np.array([0.1, 10.0, np.inf, 0.4]), np.zeros(4, dtype=bool))
    rng = np.random.default_rng(3)
    g = model(theta) + np.sqrt(var / 2) * (rng.standard_normal(var.shape) + 1j * rng.standard_normal(var.shape))
    res = update_parameters(model, [1.0, 1.0, 1.0, 1.0], f, g, var, prior=prior, scale_covariance=False,
                            scales=np.ones(4))
    jc = (b / np.sqrt(var)[None]).reshape(4, -1).T
    j = np.vstack([jc.real, jc.imag])
    p = np.diag(np.where(np.isfinite(prior.std), 1 / prior.std**2, 0.0))
    post = np.linalg.inv(2 * j.T @ j + p)
    np.testing.assert_allclose(res.covariance, post, rtol=1e-6, atol=1e-12)
    gw = g / np.sqrt(var)
    mean = post @ (2 * j.T @ np.concatenate([gw.real.ravel(), gw.imag.ravel()]) + p @ prior.mean)
    np.testing.assert_allclose(res.theta, mean, rtol=1e-6, atol=1e-9)
    assert res.theta[3] == pytest.approx(2.5) and res.std[3] == pytest.approx(0.4)
    assert res.prior_ratio[3] == pytest.approx(1.0) and np.isnan(res.prior_ratio[2])
