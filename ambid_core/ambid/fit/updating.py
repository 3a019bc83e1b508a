"""Physical-model updating against a measured FRF matrix, with uncertainties.

Given a parametrised model theta -> StateSpace (continuous) or theta -> FRF,
the parameters are the maximum a posteriori (MAP) estimate of weighted
nonlinear least squares with an optional normal prior per parameter,

    V(theta) = sum_lines sum_entries |G(theta) - G_meas|^2 / var
               + sum_k (x_k - m_k)^2 / (2 s_k^2),

x_k = theta_k / scale_k, or ln theta_k for a prior stated in the logarithm
(:class:`Prior`), solved by scipy's trust-region least squares (bounds
allowed). The covariance is the linearised posterior's: with J the weighted
data Jacobian (central differences at the optimum), P = diag(1 / s^2) the
prior's precision and B = (J^T J + P / 2)^-1,

    cov = B (M + P / 4) B,

M the covariance of the data's score J^T r: s^2 J^T J with s^2 = V / (N - p)
from the residual (``covariance="jacobian"``; 1/2, the value for correct
variances, with ``scale_covariance=False``), or a sandwich (per line, or with
the rows' known covariance). Without a prior this is the usual
s^2 (J^T J)^-1; a direction the data cannot tell keeps the prior's width.
95 % intervals use Student's t with the variance's degrees of freedom (normal
where the variance is known, :func:`ambid.fit.correlated.realisation_inflation`
where the realisations' scatter joins it); in ln theta for a log prior. Without
a prior on every parameter, a rank-deficient Jacobian (a parameter combination
that does not change the FRF, e.g. the current gain and the mass of a rigid
rotor, which enter only as ki / m) is reported as :class:`NotIdentifiable`
naming that combination.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import special  # not scipy.stats (~0.6 s to import); scipy.optimize is imported where it is used

from ambid.fit.blas_threads import single_threaded_blas
from ambid.fit.correlated import combined_dof, line_sandwich, realisation_inflation
from ambid.statespace import StateSpace

__all__ = ["NotIdentifiable", "Prior", "UpdateResult", "update_parameters"]


@dataclass(frozen=True)
class Prior:
    """Independent normal priors of the parameters: the MAP term of :func:`update_parameters`.

    Attributes
    ----------
    mean
        (p,) prior means [parameter units].
    std
        (p,) prior standard deviations [parameter units], of ln(theta)
        where ``log``; inf: no prior on that parameter (flat).
    log
        (p,) bool: the prior is normal in ln(theta) (theta > 0); those
        parameters are estimated in ln(theta), their intervals too.

    Examples
    --------
    >>> Prior.flat(2)                     # no prior: least squares
    Prior(mean=array([0., 0.]), std=array([inf, inf]), log=array([False, False]))
    """

    mean: np.ndarray
    std: np.ndarray
    log: np.ndarray

    @staticmethod
    def flat(p: int) -> "Prior":
        """No prior on any of p parameters."""
        return Prior(np.zeros(p), np.full(p, np.inf), np.zeros(p, dtype=bool))


@dataclass(frozen=True)
class UpdateResult:
    """Updated parameters with their uncertainty.

    Attributes
    ----------
    names
        (p,) parameter names.
    theta
        (p,) estimates [parameter units].
    theta0
        (p,) start values.
    std
        (p,) standard deviations.
    ci95
        (p, 2) 95 % intervals [low, high] (in ln theta for a log prior, then exponentiated).
    covariance
        (p, p) covariance of theta.
    correlation
        (p, p) correlation matrix.
    cost
        the data part of V at the optimum (sum |G(theta) - G|^2 / var).
    n_residuals
        N = 2 L Ny Nu real residuals.
    jacobian_singular_values
        (p,) singular values of the weighted
        Jacobian (with the prior's rows) w.r.t. the scaled parameters, descending.
    success
        the optimiser reported convergence.
    message
        the optimiser's stop reason.
    n_evaluations
        model evaluations in the optimisation.
    inflation
        the largest factor the realisations' scatter widened a standard deviation by (1: none).
    prior_ratio
        (p,) posterior over prior standard deviation (nan: no prior); near 1 the prior
        dominates, near 0 the data.
    dof
        (p,) degrees of freedom of each variance (inf: the normal quantile).
    log
        (p,) bool: estimated and bounded in ln theta.
    """

    names: tuple[str, ...]
    theta: np.ndarray
    theta0: np.ndarray
    std: np.ndarray
    ci95: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    cost: float
    n_residuals: int
    jacobian_singular_values: np.ndarray
    success: bool
    message: str
    n_evaluations: int
    inflation: float = 1.0
    prior_ratio: np.ndarray | None = None
    variance_dof: np.ndarray | None = None
    log: np.ndarray | None = None

    @property
    def dof(self) -> int:
        """Degrees of freedom N - p of the residual."""
        return self.n_residuals - self.theta.size

    @property
    def chi2_per_dof(self) -> float:
        """2 V / (N - p); about 1 when the model and the variances are right."""
        return 2.0 * self.cost / max(self.dof, 1)

    def to_dict(self) -> dict:
        """JSON-safe summary: one entry per parameter plus the fit figures."""
        ratio = self.prior_ratio if self.prior_ratio is not None else np.full(self.theta.size, np.nan)
        return dict(parameters=[dict(name=n, value=float(v), start=float(v0), std=float(s),
                                     ci95=[float(lo), float(hi)],
                                     prior_ratio=None if not np.isfinite(r) else float(r))
                                for n, v, v0, s, (lo, hi), r in zip(self.names, self.theta, self.theta0,
                                                                    self.std, self.ci95, ratio)],
                    correlation=self.correlation.tolist(), cost=self.cost, chi2_per_dof=self.chi2_per_dof,
                    dof=self.dof, success=self.success, message=self.message)


def _frf(model: Callable, theta: np.ndarray, f: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    out = model(theta)
    if isinstance(out, StateSpace):
        if out.dt != 0:
            raise ValueError("model(theta) returned a discrete StateSpace; updating needs a continuous one "
                             "(dt = 0) or an FRF array")
        g = out.freqresp(f)
    else:
        g = np.asarray(out)
    if g.shape != shape:
        raise ValueError(f"model(theta) gives an FRF of shape {g.shape}, the data are {shape}")
    return g


def _central_jacobian(resid: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    # the step suits models evaluated to ~1e-12 (state-space solves); truncation error ~1e-8
    h = 1e-4 * np.maximum(np.abs(x), 1.0)
    cols = []
    for k in range(x.size):
        e = np.zeros(x.size)
        e[k] = h[k]
        cols.append((resid(x + e) - resid(x - e)) / (2 * h[k]))
    return np.column_stack(cols)


class NotIdentifiable(ValueError):
    """The data cannot tell some parameters apart; ``parameters`` are those in the direction that leaves
    the FRF unchanged, the largest share first."""

    def __init__(self, message: str, parameters: tuple[str, ...]) -> None:
        super().__init__(message)
        self.parameters = parameters


def _check_rank(jac: np.ndarray, names: tuple[str, ...], rcond: float,
                where: str) -> tuple[np.ndarray, np.ndarray]:
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    if sv[0] == 0 or sv[-1] < rcond * sv[0]:
        null = vt[-1] / np.abs(vt[-1]).max()
        combo = " ".join(f"{c:+.2f}*{n}" for c, n in zip(null, names) if abs(c) > 0.05)
        involved = tuple(names[k] for k in np.argsort(-np.abs(null)) if abs(null[k]) > 0.05)
        raise NotIdentifiable(
            f"parameters not identifiable from these data ({where}): the Jacobian w.r.t. the relative-scaled "
            f"parameters has singular-value ratio {sv[-1] / max(sv[0], 1e-300):.1e} < rcond = {rcond:.0e}; "
            f"changing ({combo}) (relative steps) leaves the FRF unchanged. Give those parameters a "
            "tolerance (a prior), fix one at a known value, or add data that separates them", involved)
    return sv, vt


def update_parameters(model: Callable[[np.ndarray], StateSpace | np.ndarray], theta0: Sequence[float],
                      freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None = None, *,
                      names: Sequence[str] | None = None, scales: Sequence[float] | None = None,
                      bounds: tuple[Sequence[float], Sequence[float]] | None = None,
                      prior: Prior | None = None,
                      rcond: float = 1e-6, scale_covariance: bool = True, covariance: str = "jacobian",
                      row_covariance: np.ndarray | None = None, realisations: np.ndarray | None = None,
                      max_evaluations: int = 200, covariance_only: bool = False) -> UpdateResult:
    """Fit the parameters of a physical model to a measured FRF matrix (MAP with ``prior``).

    Args:
        model: theta (p,) -> continuous :class:`StateSpace` with Ny outputs
            and Nu inputs, or -> FRF (L, Ny, Nu) at ``freq_hz``.
        theta0: (p,) start values [parameter units].
        freq_hz: (L,) lines [Hz].
        G: (L, Ny, Nu) measured FRF.
        var: (L, Ny, Nu) noise variance of G, E|G - E G|^2; None weights
            everything equally (then keep ``scale_covariance``).
        names: (p,) parameter names (default theta0, theta1, ...).
        scales: (p,) typical magnitudes, > 0 (default |theta0|, 1 where 0);
            not used for parameters with a log prior.
        bounds: (lower (p,), upper (p,)) in parameter units, or None.
        prior: normal priors (:class:`Prior`), or None (flat: least squares).
        rcond: smallest singular-value ratio of the scaled Jacobian accepted
            as identifiable.
        scale_covariance: estimate s^2 from the residual (True) or trust
            ``var`` (False); for ``covariance="jacobian"``.
        covariance: ``"jacobian"``: s^2 J^T J as the data's score covariance,
            residuals independent with the variances ``var`` (up to s^2);
            ``"sandwich"``: sum_l s_l s_l^T N / (N - p), s_l = J_l^T r_l
            the score of line l: lines independent, but the entries of one
            line may be correlated (closed loop) and the model may miss part
            of the data; intervals then use Student's t with L - p degrees of
            freedom; ``"rows"``: the sandwich with the known covariance of
            the entries of each row, ``row_covariance``
            (:func:`ambid.fit.correlated.line_sandwich`).
        row_covariance: (L, Ny, Nu, Nu) complex covariance of the entries of
            each row of G, for ``covariance="rows"``.
        realisations: (M, L, Ny, Nu) the FRFs of the M realisations whose
            mean G is; their scatter joins the data's covariance
            (:func:`ambid.fit.correlated.realisation_inflation`).
        max_evaluations: most model evaluations in the optimisation.
        covariance_only: keep theta0 (no optimisation); only its covariance.

    Returns:
        :class:`UpdateResult`.

    Raises:
        ValueError: bad shapes, non-finite values, or (:class:`NotIdentifiable`)
            parameters without a prior that the data cannot identify.

    Examples
    --------
    The gain and corner frequency of a first-order lag, fitted to its exact FRF from a start of one each:

    >>> import numpy as np
    >>> f = np.linspace(1.0, 10.0, 20)
    >>> def lag(theta):                   # theta: gain, corner [Hz] -> FRF (L, 1, 1)
    ...     return (theta[0] / (1j * f / theta[1] + 1))[:, None, None]
    >>> fit = update_parameters(lag, [1.0, 1.0], f, lag(np.array([2.0, 3.0])), names=["gain", "corner_hz"])
    >>> fit.names, np.round(fit.theta, 6), fit.success
    (('gain', 'corner_hz'), array([2., 3.]), True)
    """
    th0, nm, pm, ps, lg, sc = _checked_parameters(theta0, names, prior, scales)
    p = th0.size
    f, g, w = _checked_data(freq_hz, G, var)
    lb, ub = _checked_bounds(bounds, th0)
    _check_options(covariance, row_covariance, g.shape, rcond)
    xc = _Scaled(lg, sc)
    xlb, xub = xc.bounds(lb, ub)
    has_prior = np.isfinite(ps)
    xm, xs, jp = xc.prior(pm, ps, has_prior)

    def resid_data(x: np.ndarray) -> np.ndarray:
        e = w * (_frf(model, xc.to_theta(x), f, g.shape) - g)
        return np.concatenate([e.real.ravel(), e.imag.ravel()])

    def resid(x: np.ndarray) -> np.ndarray:
        return np.concatenate([resid_data(x), (jp * np.where(has_prior, x - xm, 0.0))[has_prior]])

    prior_rows = np.diag(jp)[has_prior]
    x, nfev, ok, msg, r, jac = _optimise(resid_data, resid, xc.to_x(th0), (xlb, xub), prior_rows, nm, rcond,
                                         covariance_only, not has_prior.all(), max_evaluations)
    sv, vt = _check_rank(np.vstack([jac, prior_rows]), nm, rcond, "at the optimum")
    cost = float(r @ r)
    bread = (vt.T / sv**2) @ vt                       # (J^T J + P / 2)^-1
    cov_data, data_dof = _data_covariance(covariance, jac, r, g, w, row_covariance, bread, p,
                                          scale_covariance, cost)
    cov_data, dofs, inflation = ((cov_data, np.full(p, data_dof), 1.0) if realisations is None
                                 else _inflated(realisations, w, jac, bread, cov_data, data_dof))
    # the prior's part: its score (x* - m) / s^2 has covariance P, B (P / 4) B in the units of V
    cov_prior = bread @ np.diag(jp**2 / 2) @ bread
    cov_x = cov_data + cov_prior
    # the prior's part is known exactly: the variance's degrees of freedom grow with its share
    dofs = combined_dof(np.diag(cov_data), dofs, np.diag(cov_prior))
    theta, std, ci, cov, corr, ratio = _in_parameter_units(xc, x, cov_x, dofs, has_prior, xs)
    return UpdateResult(names=nm, theta=theta, theta0=th0, std=std, ci95=ci, covariance=cov, correlation=corr,
                        cost=cost, n_residuals=r.size, jacobian_singular_values=sv, success=ok,
                        message=msg, n_evaluations=nfev, inflation=inflation, prior_ratio=ratio,
                        variance_dof=dofs, log=lg)


def _in_parameter_units(xc: _Scaled, x: np.ndarray, cov_x: np.ndarray, dofs: np.ndarray, has_prior: np.ndarray,
                        xs: np.ndarray) -> tuple:
    """theta, its std, 95 % intervals (Student's t), covariance and correlation, and the prior ratio, from x."""
    std_x = np.sqrt(np.diag(cov_x))
    theta = xc.to_theta(x)
    jt = np.where(xc.lg, theta, xc.sc)                 # d theta / d x
    cov = cov_x * jt[:, None] * jt[None, :]
    std = np.sqrt(np.diag(cov))
    corr = cov / np.outer(std, std)
    half = special.stdtrit(dofs, 0.975) * std_x
    ci = np.column_stack([xc.to_theta(x - half), xc.to_theta(x + half)])
    ratio = np.where(has_prior, std_x / np.where(has_prior, xs, 1.0), np.nan)
    return theta, std, ci, cov, corr, ratio


def _checked_parameters(theta0, names, prior, scales) -> tuple:
    """Start values, names, prior (mean, std, log) and scales, checked; each (p,)."""
    th0 = np.asarray(theta0, dtype=float).ravel()
    p = th0.size
    if p == 0 or not np.all(np.isfinite(th0)):
        raise ValueError("theta0 must be a non-empty array of finite values")
    nm = tuple(names) if names is not None else tuple(f"theta{k}" for k in range(p))
    if len(nm) != p:
        raise ValueError(f"names has {len(nm)} entries for {p} parameters")
    pr = Prior.flat(p) if prior is None else prior
    pm, ps, lg = (np.asarray(pr.mean, dtype=float).ravel(), np.asarray(pr.std, dtype=float).ravel(),
                  np.asarray(pr.log, dtype=bool).ravel())
    if not (pm.shape == ps.shape == lg.shape == (p,)) or np.any(~(ps > 0)) or not np.all(np.isfinite(pm)):
        raise ValueError(f"prior must give {p} finite means and standard deviations > 0 (inf: none)")
    if np.any(lg & ((th0 <= 0) | (pm <= 0))):
        raise ValueError("a prior in the logarithm needs a positive mean and start value")
    sc = np.where(th0 != 0, np.abs(th0), 1.0) if scales is None else np.asarray(scales, dtype=float).ravel()
    if sc.shape != (p,) or not np.all(np.isfinite(sc)) or np.any(sc <= 0):
        raise ValueError(f"scales must be {p} finite values > 0")
    return th0, nm, pm, ps, lg, np.where(lg, 1.0, sc)


def _check_options(covariance: str, row_covariance, shape: tuple[int, ...], rcond: float) -> None:
    if covariance not in ("jacobian", "sandwich", "rows"):
        raise ValueError(f"covariance must be 'jacobian', 'sandwich' or 'rows', got {covariance!r}")
    if covariance == "rows" and (row_covariance is None or np.shape(row_covariance) != shape + shape[-1:]):
        raise ValueError(f"covariance='rows' needs row_covariance of shape {shape + shape[-1:]}")
    if not (0 < rcond < 1):
        raise ValueError(f"rcond must be in (0, 1), got {rcond}")


def _optimise(resid_data: Callable, resid: Callable, x0: np.ndarray, xbounds: tuple, prior_rows: np.ndarray,
              nm: tuple[str, ...], rcond: float, covariance_only: bool, check_start: bool,
              max_evaluations: int) -> tuple:
    """The MAP estimate in x from x0: (x, evaluations, success, message, data residual, its Jacobian)."""
    with single_threaded_blas():
        r0 = resid_data(x0)
        if not np.all(np.isfinite(r0)):
            raise ValueError("model(theta0) gives a non-finite FRF")
        if covariance_only:
            x, nfev, ok, msg = x0, 1, True, "covariance at the given values"
        else:
            if check_start:
                # fail early (and cheaply) when the start already shows a parameter combination without effect
                _check_rank(np.vstack([_central_jacobian(resid_data, x0), prior_rows]), nm, rcond, "at the start")
            from scipy import optimize  # here: ~0.2 s to import, and only estimating parameters needs it
            res = optimize.least_squares(resid, x0, bounds=xbounds, method="trf", x_scale=1.0,
                                         max_nfev=max_evaluations, xtol=1e-12, ftol=1e-12, gtol=1e-12)
            x, nfev, ok, msg = res.x, int(res.nfev), bool(res.success), str(res.message)
        return x, nfev, ok, msg, resid_data(x), _central_jacobian(resid_data, x)


def _checked_data(freq_hz, G, var) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lines (L,) [Hz], FRF (L, Ny, Nu) and its residual weights 1/sqrt(var), checked."""
    f = np.asarray(freq_hz, dtype=float).ravel()
    g = np.asarray(G)
    if g.ndim != 3 or g.shape[0] != f.size:
        raise ValueError(f"G must be (L, Ny, Nu) with L = len(freq_hz) = {f.size}, got {g.shape}")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(g))):
        raise ValueError("freq_hz and G must be finite")
    if var is None:
        return f, g, np.ones(g.shape)
    v = np.asarray(var, dtype=float)
    if v.shape != g.shape or not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"var must be finite, > 0 and of shape {g.shape}")
    return f, g, 1.0 / np.sqrt(v)


def _checked_bounds(bounds, th0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (p,) in parameter units (infinite when None)."""
    p = th0.size
    if bounds is None:
        return np.full(p, -np.inf), np.full(p, np.inf)
    lb, ub = (np.broadcast_to(np.asarray(b, dtype=float), (p,)).copy() for b in bounds)
    if np.any(lb >= ub) or np.any(th0 < lb) or np.any(th0 > ub):
        raise ValueError("bounds must satisfy lower < upper with theta0 inside")
    return lb, ub


@dataclass(frozen=True)
class _Scaled:
    """The optimiser's coordinates x: theta / scale, or ln theta for a log prior."""

    lg: np.ndarray
    sc: np.ndarray

    def to_x(self, th: np.ndarray) -> np.ndarray:
        return np.where(self.lg, np.log(np.where(self.lg, th, 1.0)), th / self.sc)

    def to_theta(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.lg, np.exp(np.where(self.lg, x, 0.0)), x * self.sc)

    def prior(self, pm: np.ndarray, ps: np.ndarray, has_prior: np.ndarray) -> tuple[np.ndarray, ...]:
        """The prior's mean and std in x, and its residual's weight 1 / (sqrt(2) s) (0 without a prior)."""
        xm = np.where(self.lg, np.log(np.where(self.lg, pm, 1.0)), pm / self.sc)
        xs = np.where(self.lg, ps, ps / self.sc)
        # a normal prior's term in V: (x - m)^2 / (2 s^2), a real residual of variance 1/2 like the data's
        return xm, xs, np.where(has_prior, 1.0 / (np.sqrt(2.0) * xs), 0.0)

    def bounds(self, lb: np.ndarray, ub: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lg, sc = self.lg, self.sc
        with np.errstate(divide="ignore"):
            xlb = np.where(lg, np.log(np.maximum(lb, 0.0)), lb / sc)
        xub = np.where(lg, np.log(np.where(lg & (ub > 0), ub, 1.0)), ub / sc)
        return xlb, np.where(lg & ~(ub > 0), np.inf, xub)


def _data_covariance(covariance: str, jac: np.ndarray, r: np.ndarray, g: np.ndarray, w: np.ndarray,
                     row_covariance, bread: np.ndarray, p: int, scale_covariance: bool,
                     cost: float) -> tuple[np.ndarray, float]:
    """The data's part of the covariance of x (p, p) and its degrees of freedom."""
    n_res = r.size
    dof = n_res - p
    n_lines = g.shape[0]
    half_n = n_res // 2
    if covariance == "rows":
        jr, ji = (a.reshape(g.shape + (p,)) for a in (jac[:half_n], jac[half_n:]))
        cov_data = line_sandwich(jr, ji, (r[:half_n] + 1j * r[half_n:]).reshape(g.shape), w,
                                 np.asarray(row_covariance), bread, p)
        return cov_data, float(max(n_lines - p, 1))
    if covariance == "sandwich":
        contrib = jac * r[:, None]
        score = (contrib[:half_n] + contrib[half_n:]).reshape(n_lines, -1, p).sum(axis=1)   # (L, p)
        cov_data = bread @ (score.T @ score) @ bread * n_res / max(dof, 1)
        return cov_data, float(max(n_lines - p, 1))
    cov_data = bread @ (jac.T @ jac) @ bread * (cost / max(dof, 1) if scale_covariance else 0.5)
    return cov_data, (float(max(dof, 1)) if scale_covariance else np.inf)


def _inflated(realisations, w: np.ndarray, jac: np.ndarray, bread: np.ndarray, cov_data: np.ndarray,
              data_dof: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The data's covariance widened by the scatter of the realisations, its dofs and the inflation."""
    gm = np.asarray(realisations)
    dev = w * (gm - gm.mean(axis=0))
    d = np.concatenate([dev.real.reshape(len(gm), -1), dev.imag.reshape(len(gm), -1)], axis=1)
    factors, dofs = realisation_inflation(d @ jac @ bread, cov_data, data_dof)
    return cov_data * np.sqrt(np.outer(factors, factors)), dofs, float(np.sqrt(factors.max()))
