"""Parameter covariance of a least-squares fit whose data errors are correlated within a row of the FRF.

A fit weighted entry by entry, ``r = w (G_model - G)``, takes the errors of
the entries as independent. In closed loop they are not: the entries of one
output row share that output's noise through ``U^-1``
(:func:`ambid.frf.uncertainty.row_covariance`). The estimate stays what it
is; its covariance is the sandwich with the known error covariance,

    cov = B M B,  B = (J^T J)^-1,  M = sum over lines and rows of A^T Omega A,

A the Jacobian rows of one output row (real parts over imaginary parts),
``Omega = 1/2 [[Re C_w, -Im C_w], [Im C_w, Re C_w]]`` the real-stacked
covariance of its weighted residual, ``C_w = diag(w) C diag(w)``. It is
scaled by the generalised chi^2 per degree of freedom,
``2 sum e^H C_w^-1 e / (N - p)``, about 1 when C and the model are right.
"""

from __future__ import annotations

import numpy as np

__all__ = ["row_sandwich", "line_sandwich", "realisation_inflation", "combined_dof"]


def row_sandwich(j_re: np.ndarray, j_im: np.ndarray, residual: np.ndarray, w: np.ndarray,
                 row_cov: np.ndarray, bread: np.ndarray, n_parameters: int) -> np.ndarray:
    """Covariance B M B * chi^2_g / dof of the module docstring.

    Parameters
    ----------
    j_re, j_im
        (L, Ny, Nu, P) derivatives of the weighted residual's real
        and imaginary parts w.r.t. the P parameters.
    residual
        (L, Ny, Nu) complex weighted residual at the optimum.
    w
        (L, Ny, Nu) the fit's weights.
    row_cov
        (L, Ny, Nu, Nu) complex covariance of the entries of each row [unit of G squared].
    bread
        (P, P) (J^T J)^-1.
    n_parameters
        p, every real parameter of the fit (for the degrees of freedom).

    Returns
    -------
    (P, P) covariance.
    """
    cw = w[..., :, None] * row_cov * w[..., None, :]
    omega = 0.5 * np.block([[cw.real, -cw.imag], [cw.imag, cw.real]])          # (L, Ny, 2Nu, 2Nu)
    a = np.concatenate([j_re, j_im], axis=2)                                   # (L, Ny, 2Nu, P)
    meat = np.einsum("lyap,lyab,lybq->pq", a, omega, a, optimize=True)
    e = residual[..., None]
    chi2 = 2 * float(np.real(np.sum(np.conj(e) * np.linalg.solve(cw, e))))
    n_res = 2 * residual.size
    return bread @ meat @ bread * chi2 / max(n_res - n_parameters, 1)


def line_sandwich(j_re: np.ndarray, j_im: np.ndarray, residual: np.ndarray, w: np.ndarray,
                  row_cov: np.ndarray, bread: np.ndarray, n_parameters: int, window: int = 3) -> np.ndarray:
    """:func:`row_sandwich` with the rows of a line correlated too.

    The stochastic nonlinear distortion of one realisation moves every output
    at once (one magnet force reaches both sensors of a plane), so the rows
    of G are not independent either. The weighted covariance of a line is
    taken as ``C[(i, .), (k, .)] = rho_ik L_i L_k^H`` with ``L_i L_i^H`` row
    i's weighted covariance and rho the rows' correlation, estimated from the
    residual: each row whitened by ``L_i^-1`` gives Nu samples of the rows'
    Ny-vector per line, pooled over the ``window`` lines either side.
    Arguments as for :func:`row_sandwich`.
    """
    n_lines, ny, nu = residual.shape
    cw = w[..., :, None] * row_cov * w[..., None, :]
    chol = np.linalg.cholesky(cw + 1e-12 * np.eye(nu) * np.real(np.trace(cw, axis1=-2, axis2=-1))[..., None, None])
    white = np.linalg.solve(chol, residual[..., None])[..., 0]                     # (L, Ny, Nu)
    prod = np.einsum("lij,lkj->lik", white, np.conj(white))                         # (L, Ny, Ny)
    csum = np.cumsum(np.concatenate([np.zeros((1, ny, ny)), prod]), axis=0)
    lo = np.clip(np.arange(n_lines) - window, 0, n_lines)
    hi = np.clip(np.arange(n_lines) + window + 1, 0, n_lines)
    pooled = csum[hi] - csum[lo]
    d = np.sqrt(np.real(np.diagonal(pooled, axis1=1, axis2=2)))
    rho = pooled / (d[:, :, None] * d[:, None, :])
    # C (L, Ny*Nu, Ny*Nu): rho_ik L_i L_k^H
    c = np.einsum("lik,lijm,lknm->lijkn", rho, chol, np.conj(chol)).reshape(n_lines, ny * nu, ny * nu)
    omega = 0.5 * np.block([[c.real, -c.imag], [c.imag, c.real]])                  # (L, 2E, 2E)
    a = np.concatenate([j_re.reshape(n_lines, ny * nu, -1), j_im.reshape(n_lines, ny * nu, -1)], axis=1)
    meat = np.einsum("lap,lab,lbq->pq", a, omega, a, optimize=True)
    e = residual.reshape(n_lines, ny * nu, 1)
    chi2 = 2 * float(np.real(np.sum(np.conj(e) * np.linalg.solve(c, e))))
    n_res = 2 * residual.size
    return bread @ meat @ bread * chi2 / max(n_res - n_parameters, 1)


#: the sandwich's weight in :func:`realisation_inflation`, as degrees of freedom of the realisations' scatter
SANDWICH_DOF = 2.0


def realisation_inflation(scores: np.ndarray, cov: np.ndarray,
                          sandwich_dof: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Each parameter's variance from the sandwich and the realisations' scatter together, >= the sandwich.

    The stochastic nonlinear distortion of one realisation is partly
    coherent over the lines (the magnets' effective stiffness differs a
    little from one random-phase realisation to the next), which no
    line-by-line covariance holds. The M realisations' own FRFs G_m show it:
    their deviations from the mean, mapped through the fit's linearisation
    (``scores``: d_m = (J^T J)^-1 J^T w (G_m - mean G_m)), scatter with the
    covariance M cov if ``cov`` is right. Parameter k's ratio

        kappa_k = sum_m d_mk^2 / (M (M - 1) cov_kk)      M - 1 degrees of freedom

    is about 1 then, and reaches some parameters (a lightly damped mode's
    damping) far more than others. The variance is the pooled estimate of the
    two, the sandwich weighted as ``SANDWICH_DOF`` degrees of freedom (it can
    miss the coherent part, so it is not trusted as fully as its many lines
    would say), and never below the sandwich (which holds the known noise):

        factor_k = max(1, (SANDWICH_DOF + (M - 1) kappa_k) / (SANDWICH_DOF + M - 1))

    Its degrees of freedom, for the interval's Student t, are what the
    pooled estimate has (Satterthwaite): the sandwich's own
    ``sandwich_dof`` (its lines less the parameters) and the scatter's M - 1,

        nu_k = (S + (M - 1) kappa)^2 / (S^2 / sandwich_dof + (M - 1) kappa^2),   S = SANDWICH_DOF,

    near ``sandwich_dof`` where the scatter agrees with the sandwich, and
    down to M - 1 where it alone sets the variance; ``sandwich_dof`` where the
    floor holds. (Student's t of SANDWICH_DOF + M - 1 = 4 degrees of freedom, as
    if both parts were 2-degree estimates, widened intervals whose sigma was
    right by 41 %: 99 % coverage instead of 95 %.)

    Parameters
    ----------
    scores
        (M, p) linearised deviations d_m of the parameters, M >= 2.
    cov
        (p, p) covariance of the parameters of the mean.
    sandwich_dof
        degrees of freedom of ``cov`` (inf: known).

    Returns
    -------
    (factors, dof): (p,) factors for the variances (scale cov by
    sqrt(f_i f_j)), and (p,) the degrees of freedom of each variance.
    """
    m, p = scores.shape
    if m < 2:
        return np.ones(p), np.full(p, float(sandwich_dof))
    single = np.sum(scores**2, axis=0) / (m * (m - 1) * np.diag(cov))
    pooled = (SANDWICH_DOF + (m - 1) * single) / (SANDWICH_DOF + m - 1)
    factors = np.maximum(pooled, 1.0)
    with np.errstate(divide="ignore"):
        nu = (SANDWICH_DOF + (m - 1) * single) ** 2 / (SANDWICH_DOF**2 / sandwich_dof + (m - 1) * single**2)
    return factors, np.where(pooled > 1.0, nu, float(sandwich_dof))


def combined_dof(var_estimated: np.ndarray, dof: np.ndarray, var_known: np.ndarray) -> np.ndarray:
    """Degrees of freedom of a variance that is an estimated part (``dof``) plus a known part
    (Satterthwaite): (a + b)^2 / (a^2 / dof); inf where the estimated part is 0 or its dof infinite."""
    a = np.asarray(var_estimated, dtype=float)
    b = np.asarray(var_known, dtype=float)
    d = np.asarray(dof, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (a + b) ** 2 / (a**2 / d)
    return np.where((a > 0) & np.isfinite(d), out, np.inf)
