"""The uncertainty formulas against exact covariances of known linear systems.

Each test builds data from a linear system whose covariance is written here
in closed form (not by ambid), then checks ambid's estimate of it: its
mean, its own scatter (the degrees of freedom) and the coverage of the
intervals built from it.
"""

import numpy as np
from ambid.fit import update_parameters
from ambid.fit.blas_threads import single_threaded_blas
from ambid.frf import frf_noise_variance, noise_std_interval, period_mean_variance, row_covariance
from scipy import stats


def _cn(rng, *shape):
    """Circular complex Gaussian, E|x|^2 = 1."""
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)


def test_variance_of_a_period_mean_and_its_degrees_of_freedom():
    # x_p = mu + sigma e_p: var(mean) = sigma^2 / P; the estimate is sigma^2 / P chi2(2 (P - 1)) / (2 (P - 1))
    p, sigma, cells = 5, 0.7, 4000
    rng = np.random.default_rng(11)
    mu = _cn(rng, 1, 1, 1, cells, 1) * 3
    x = mu + sigma * _cn(rng, 1, 1, p, cells, 1)
    mean, var = period_mean_variance(x)
    ratio = var.real.ravel() / (sigma**2 / p)
    assert abs(ratio.mean() - 1) < 4 * np.sqrt(1 / (p - 1) / cells)
    # the estimate's own relative variance is 1 / (P - 1): 2 (P - 1) real degrees of freedom
    assert abs(ratio.var() * (p - 1) - 1) < 0.1
    # and the mean really scatters by sigma^2 / P
    emp = np.mean(np.abs(mean - mu[:, :, 0]) ** 2)
    assert abs(emp / (sigma**2 / p) - 1) < 0.06


def test_closed_loop_indirect_frf_noise_variance_is_exact_to_first_order():
    # 2 x 2 plant G in a loop u = r + K y, output noise v (variance s2 per channel): Y = G U + V exactly,
    # so G_p - G = V_p R_p^H (U_p R_p^H)^-1 and, to first order, var(G_ij) = s2 sum_e |U0^-1_ej|^2 / P
    p, n_lines, s2 = 6, 3000, 1e-6
    rng = np.random.default_rng(12)
    g = _cn(rng, n_lines, 2, 2) + 2 * np.eye(2)
    k = 0.3 * _cn(rng, n_lines, 2, 2)
    phase = np.exp(2j * np.pi * rng.uniform(size=(n_lines, 1)))
    r = phase[:, :, None] * np.array([[1, 1], [1, -1]])            # (L, Nu, Ne), orthogonal experiments
    sens = np.linalg.inv(np.eye(2) - k @ g)
    v = np.sqrt(s2) * _cn(rng, p, n_lines, 2, 2)                   # (P, L, Ny, Ne)
    u = sens @ (r + k @ v)
    y = g @ u + v
    u0 = sens @ r
    # to ambid's layout (M, Ne, P, L, ch)
    lay = lambda a: np.moveaxis(a, -1, 0)[None]                  # (1, Ne, P, L, ch)
    y5, u5 = lay(y), lay(u)
    r5 = np.moveaxis(r, -1, 0)[None, :, None]                    # (1, Ne, 1, L, Nu)
    g_m, var_n = frf_noise_variance(y5, u5, r5)
    u0_inv = np.linalg.inv(u0)                                     # (L, Ne, Nu)
    exact = s2 * np.sum(np.abs(u0_inv) ** 2, axis=1)[:, None, :] / p   # (L, 1, Nu) -> same for each output
    exact = np.broadcast_to(exact, (n_lines, 2, 2))
    ratio = var_n[0] / exact
    assert abs(ratio.mean() - 1) < 0.03
    assert abs(ratio.var() * (p - 1) - 1) < 0.1                  # 2 (P - 1) degrees of freedom
    err = np.abs(g_m[0] - g) ** 2 / exact
    assert abs(err.mean() - 1) < 0.05
    # a +-2 sigma band with the estimated variance: P(|e|^2 < 4 s^2_hat) = 1 - (1 + 4 / (P - 1))^-(P - 1)
    cover = np.mean(np.abs(g_m[0] - g) ** 2 <= 4 * var_n[0])
    assert abs(cover - (1 - (1 + 4 / (p - 1)) ** -(p - 1))) < 0.01


def test_linear_least_squares_parameter_covariance_is_exact():
    # G(theta) = sum_k theta_k B_k(f): cov = (J^T J)^-1 / 2 with J the real-stacked weighted basis
    f = np.linspace(10.0, 500.0, 80)
    s = 2j * np.pi * f / 500.0
    basis = np.stack([np.ones_like(s), s, 1 / (1 + s), s**2 / (1 + s)])        # (p, L)
    mix = np.array([[[1.0, 0.5], [0.2, -1.0]], [[0.3, 1.0], [1.0, 0.1]], [[2.0, 0], [0, 2.0]],
                    [[0.5, 0.5], [-0.5, 0.5]]])                               # (p, 2, 2)
    b = np.einsum("kl,kij->klij", basis, mix)                                 # (p, L, 2, 2)
    theta = np.array([1.0, -0.5, 2.0, 0.3])
    g0 = np.einsum("k,klij->lij", theta, b)
    var = (0.02 * (1 + np.abs(g0))) ** 2
    w = 1 / np.sqrt(var)
    jc = (w[None] * b).reshape(4, -1).T
    jr = np.vstack([jc.real, jc.imag])
    exact = np.linalg.inv(jr.T @ jr) / 2
    model = lambda th: np.einsum("k,klij->lij", th, b)
    rng = np.random.default_rng(13)
    n_draws, hits, est, claimed = 150, np.zeros(4), [], []
    with single_threaded_blas():
        for i in range(n_draws):
            g = g0 + np.sqrt(var) * _cn(rng, *g0.shape)
            res = update_parameters(model, theta * 1.1, f, g, var, scale_covariance=i % 2 == 0)
            if i % 2:
                np.testing.assert_allclose(res.covariance, exact, rtol=1e-5)
            est.append(res.theta)
            claimed.append(res.std)
            hits += (res.ci95[:, 0] <= theta) & (theta <= res.ci95[:, 1])
    est = np.array(est)
    d = np.sqrt(np.diag(exact))
    # the sample covariance of 150 draws, normalised by the exact standard deviations: within ~0.3
    assert np.max(np.abs(np.cov(est.T) / np.outer(d, d) - exact / np.outer(d, d))) < 0.3
    assert np.all(np.abs(est.std(axis=0, ddof=1) / np.mean(claimed, axis=0) - 1) < 0.2)
    # Clopper-Pearson 99.9 % interval of the coverage holds 0.95
    lo = stats.beta.ppf(0.0005, hits, n_draws - hits + 1)
    hi = stats.beta.ppf(0.9995, hits + 1, n_draws - hits)
    assert np.all((lo <= 0.95) & (0.95 <= hi)), hits / n_draws


def test_row_covariance_of_the_closed_loop_indirect_frf():
    # the within-row covariance conj((S S^H)^-1) (scaled) against the per-period errors of a simulated loop
    p, n_lines, s2 = 400, 3, 1e-6
    rng = np.random.default_rng(14)
    g = _cn(rng, n_lines, 2, 2) + 2 * np.eye(2)
    k = 0.8 * _cn(rng, n_lines, 2, 2)
    r = np.array([[1, 1], [1, -1]])[None] * np.ones((n_lines, 1, 1))
    sens = np.linalg.inv(np.eye(2) - k @ g)
    v = np.sqrt(s2) * _cn(rng, p, n_lines, 2, 2)
    u = sens @ (r + k @ v)
    y = g @ u + v
    err = (y @ np.linalg.inv(u)) - g                                   # per-period indirect solutions' errors
    emp = np.einsum("plij,plik->lijk", err, err.conj()) / p            # (L, Ny, Nu, Nu), E[e_j e_k*]
    var = np.real(np.diagonal(emp, axis1=2, axis2=3))
    pred = row_covariance(np.broadcast_to(var.mean(axis=2, keepdims=True), var.shape), sens)
    scale = np.sqrt(np.abs(np.diagonal(pred, axis1=2, axis2=3)))
    corr = lambda c: c / (scale[..., :, None] * scale[..., None, :])
    assert np.max(np.abs(corr(emp) - corr(pred))) < 0.15        # 400 periods: sampling error ~0.05
    assert np.max(np.abs(corr(pred)[..., 0, 1])) > 0.3          # and the correlation is not small here


def test_sandwich_with_correlated_rows_claims_the_right_spread():
    # linear model, errors correlated within each row: the row sandwich's std matches the scatter,
    # the independent-residual covariance does not
    f = np.linspace(10.0, 500.0, 40)
    s = 2j * np.pi * f / 500.0
    basis = np.stack([np.ones_like(s), s, 1 / (1 + s)])
    mix = np.array([[[1.0, 0.9], [0.2, -1.0]], [[0.3, 1.0], [1.0, 0.1]], [[1.0, 0.8], [0.7, 1.0]]])
    b = np.einsum("kl,kij->klij", basis, mix)
    theta = np.array([1.0, -0.5, 2.0])
    g0 = np.einsum("k,klij->lij", theta, b)
    c_row = np.array([[1.0, 0.95], [0.95, 1.0]]) * 1e-4                # (Nu, Nu), the same for every row and line
    row_cov = np.broadcast_to(c_row, (f.size, 2, 2, 2)).astype(complex)
    var = np.full(g0.shape, 1e-4)
    chol = np.linalg.cholesky(c_row)
    model = lambda th: np.einsum("k,klij->lij", th, b)
    rng = np.random.default_rng(15)
    est, s_rows, s_jac = [], [], []
    with single_threaded_blas():
        for _ in range(120):
            e = np.einsum("jk,lik->lij", chol, _cn(rng, f.size, 2, 2))
            res_r = update_parameters(model, theta * 1.1, f, g0 + e, var, covariance="rows", row_covariance=row_cov)
            res_j = update_parameters(model, theta * 1.1, f, g0 + e, var)
            est.append(res_r.theta)
            s_rows.append(res_r.std)
            s_jac.append(res_j.std)
    spread = np.std(est, axis=0, ddof=1)
    assert np.all(np.abs(spread / np.sqrt(np.mean(np.square(s_rows), axis=0)) - 1) < 0.2)
    assert np.any(np.abs(spread / np.sqrt(np.mean(np.square(s_jac), axis=0)) - 1) > 0.3)


def test_noise_std_interval_of_a_coloured_noise_covers_its_std():
    # AR(1) noise x[n] = a x[n-1] + e[n]: var = s^2 / (1 - a^2) in closed form. Its samples are correlated, so
    # the interval must come from the segments' scatter: 95 % of the trials' intervals hold the true std, and
    # the claimed sd matches the estimates' scatter. Chi2 with the samples' N (P - 1) degrees of freedom
    # claims a sd sqrt((1 + a^2) / (1 - a^2)) = 4.4 times too small here (a = 0.9).
    a, s, trials, segs, p, n = 0.9, 0.3, 400, 8, 3, 256
    rng = np.random.default_rng(5)
    e = rng.standard_normal((trials, segs, p * n + 200)) * s
    from scipy.signal import lfilter

    x = lfilter([1.0], [1.0, -a], e, axis=-1)[..., 200:].reshape(trials, segs, p, n)
    seg_var = x.var(axis=2, ddof=1).mean(axis=-1)                       # (trials, segs), as the stream keeps
    true_std = s / np.sqrt(1 - a**2)
    est = np.sqrt(seg_var.mean(axis=1))
    sd, ci = zip(*(noise_std_interval(v[:, None]) for v in seg_var))
    sd, ci = np.array(sd)[:, 0], np.array(ci)[:, 0]
    covered = np.mean((ci[:, 0] <= true_std) & (true_std <= ci[:, 1]))
    assert 0.92 <= covered <= 0.98
    ratio = np.sqrt(np.mean((est - true_std) ** 2) / np.mean(sd**2))
    assert 0.85 < ratio < 1.15
    naive_sd = true_std / np.sqrt(2 * segs * n * (p - 1))
    assert np.sqrt(np.mean((est - true_std) ** 2)) > 3 * naive_sd
    # one segment: no scatter, no interval
    assert np.all(np.isnan(noise_std_interval(seg_var[:1, :1])[1]))


def test_weights_not_read_from_the_realisations_scatter_keep_that_scatter_honest():
    # G_mpl = theta h_l + d_ml + n_mpl: M realisations (distortion d, fixed within one) of P periods (noise n).
    # var(mean G) = (sd^2 + sn^2 / P) / M. A weighted mean theta_hat's variance is read from the realisations'
    # scatter mapped through the fit (as ambid.fit.correlated does). Weights from that same scatter (var_total)
    # make it read small (a line whose realisations happen to disagree gets a small weight); those of
    # fit_weight_variance (the noise x the distortion share of the neighbouring lines) do not.
    from ambid.frf import fit_weight_variance

    m, p, n_lines, trials = 3, 4, 60, 3000
    rng = np.random.default_rng(19)
    f = np.linspace(0.0, 1.0, n_lines)
    h = (1 + 2 * f) * np.exp(2j * np.pi * f)
    sn2 = (0.05 * (1 + 3 * f**2)) ** 2                       # noise variance per period, smooth over the lines
    sd2 = 1.5 * sn2 / p                                      # distortion 1.5 x the noise of a period mean
    g = (h + np.sqrt(sd2) * _cn(rng, trials, m, 1, n_lines)) + np.sqrt(sn2) * _cn(rng, trials, m, p, n_lines)
    # (trials, M, P, L)
    gm = g.mean(axis=2)                                      # realisation means (trials, M, L)
    gbar = gm.mean(axis=1)
    var_noise = np.sum(np.abs(g - gm[:, :, None]) ** 2, axis=2).mean(axis=1) / (p * (p - 1)) / m
    var_total = np.sum(np.abs(gm - gbar[:, None]) ** 2, axis=1) / (m * (m - 1))
    exact = (sd2 + sn2 / p) / m

    def claimed_and_actual(v):
        w = np.abs(h) ** 2 / v                                 # (trials, L)
        theta = np.sum(np.conj(h) * gbar / v, axis=1) / w.sum(axis=1)
        d = np.sum(np.conj(h)[None, None] * (gm - gbar[:, None]) / v[:, None], axis=2) / w.sum(axis=1)[:, None]
        claimed = np.sum(np.abs(d) ** 2, axis=1) / (m * (m - 1))
        return claimed.mean(), np.mean(np.abs(theta - 1) ** 2)

    own = claimed_and_actual(var_total)
    fwv = np.stack([fit_weight_variance(var_noise[t][:, None, None], var_total[t][:, None, None])[:, 0, 0]
                    for t in range(trials)])
    ours = claimed_and_actual(fwv)
    best = 1 / np.sum(np.abs(h) ** 2 / exact)                 # the variance with the exact weights
    assert own[0] / own[1] < 0.5                              # the scatter reads far too small with its own weights
    assert abs(ours[0] / ours[1] - 1) < 0.1                   # and right with weights it did not set
    assert ours[1] < 1.4 * best < 2 * best < own[1]           # and the estimate is far closer to the best one
    # the weight: the noise pooled over the inputs x the share averaged over the +-3 neighbours (the line
    # itself left out), floored at 1
    vn = np.array([1.0, 2.0, 4.0, 1.0, 1.0, 1.0, 1.0, 1.0])[:, None, None] * np.array([[[1.0, 3.0]]])
    vt = vn * np.array([3.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.2])[:, None, None]
    out = fit_weight_variance(vn, vt)
    share = np.array([3.0, 1, 1, 1, 1, 1, 1, 0.2])
    mean_share = [np.delete(share[max(0, i - 3):i + 4], min(i, 3)).mean() for i in range(8)]
    np.testing.assert_allclose(out[:, 0, 0], vn.mean(axis=2)[:, 0] * np.maximum(mean_share, 1.0))
    np.testing.assert_array_equal(out[:, 0, :], out[:, 0, :1] * np.ones((1, 2)))
