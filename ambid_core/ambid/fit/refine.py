"""Maximum-likelihood refinement of a common-denominator model.

Internal to :mod:`ambid.fit`. Minimises the noise-weighted output-error cost

    V(theta) = sum_lines sum_entries |G_model - G_meas|^2 / var

over the denominator factors theta (see :mod:`ambid.fit.basis`) with the
numerator coefficients eliminated by variable projection (Golub & Pereyra
1973): for given poles they are the weighted linear least-squares solution,
so Levenberg-Marquardt only sees the n pole parameters. The Jacobian is
Kaufman's approximation, -P_perp (dA/dtheta) c, computed analytically, which
keeps an order-24, 4x4, 2000-line refinement to a fraction of a second per
step. With Gaussian noise of known variance this is the frequency-domain
ML estimator for an FRF measured with errors in the output only
(Pintelon & Schoukens 2012, sec. 9.11). Nothing constrains stability.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ambid.fit import basis as fb
from ambid.fit.correlated import line_sandwich, realisation_inflation
from ambid.fit.vector_fitting import (LinearSolution, WeightedData, dependent_columns, null_map, solve_coefficients,
                                      stack_real)


@dataclass(frozen=True)
class Refined:
    """Result of :func:`refine`: factors, coefficients and optimiser report."""

    lin: np.ndarray
    quad: np.ndarray
    solution: LinearSolution
    n_evaluations: int
    message: str


def _normal_equations(data: WeightedData, theta: np.ndarray, n_lin: int, sol: LinearSolution,
                      dep: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """J^T J (P, P) and J^T r (P,) of the projected residual, Kaufman's J.

    U_e = w_e dm_e / dtheta is the model derivative at fixed coefficients
    (real-stacked) and J_e = P_perp U_e its part outside the weighted
    columns, which rho_e Q0 span (Q0 orthonormal). So
    J_e^T J_e = U_e^T U_e - Z_e^T H_e^-1 Z_e with Z_e = Q0^T rho_e U_e and
    H_e = Q0^T rho_e^2 Q0, and J_e^T r_e = U_e^T r_e because r_e is
    orthogonal to the columns.
    """
    u, z = _weighted_derivative(data, theta, n_lin, sol, dep)
    utu = np.matmul(u.transpose(0, 2, 1), u)
    jtj = (utu - np.matmul(z.transpose(0, 2, 1), np.linalg.solve(sol.normal, z))).sum(axis=0)
    res = sol.residual
    jtr = np.einsum("eip,ei->p", u, np.concatenate([res.real, res.imag], axis=1))
    return jtj, jtr


def _weighted_derivative(data: WeightedData, theta: np.ndarray, n_lin: int, sol: LinearSolution,
                         dep: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """U (E, 2L, P), the weighted real-stacked model derivative at fixed coefficients, and
    Z = Q0^T rho U (E, k, P), its coordinates on the entries' weighted columns."""
    lin, quad = fb.unpack(theta, n_lin)
    dm = fb.basis_derivative(data.s, lin, quad, sol.coef)
    nc = data.n_constraints
    if nc:
        # c = N(theta) z: add Phi (dN/dtheta_k) z, dN by complex step (N is rational in theta)
        h = 1e-20
        phi = fb.basis(data.s, lin, quad)
        dn = np.stack([null_map(*fb.unpack(theta + 1j * h * e_k, n_lin), nc, dep).imag / h
                       for e_k in np.eye(theta.size)])  # (P, n, n_free)
        dc = np.matmul(dn[None], sol.free[:, None, :, None])[..., 0]  # (E, P, n)
        dm = dm + np.matmul(phi[None], dc.transpose(0, 2, 1))
    u = stack_real(data.w[:, :, None] * dm)  # (E, 2L, P)
    rho2 = np.concatenate([sol.rho, sol.rho], axis=1)
    z = np.matmul(sol.q0.T[None], rho2[:, :, None] * u)  # (E, k, P)
    return u, z


def refine(data: WeightedData, lin: np.ndarray, quad: np.ndarray, max_nfev: int = 100,
           rtol: float = 1e-5) -> Refined:
    """Levenberg-Marquardt on the factor parameters with variable projection.

    Marquardt's diagonal scaling and Nielsen's damping update; stops when a
    step lowers the cost by less than ``rtol`` (relative), when the step is
    below 1e-10 of the parameters, or after ``max_nfev`` cost evaluations.
    """
    n_lin = lin.size
    theta = fb.pack(lin, quad)
    nc = data.n_constraints
    dep = dependent_columns(lin, quad, nc) if nc else None
    sol = solve_coefficients(data, lin, quad, dep=dep)
    n_eval, mu, nu = 1, 1e-3, 2.0
    message = f"stopped after {max_nfev} evaluations"
    while n_eval < max_nfev:
        jtj, jtr = _normal_equations(data, theta, n_lin, sol, dep)
        # Marquardt scaling: unit diagonal, so mu is relative and the solve stays conditioned
        diag = np.diag(jtj)
        sc = 1.0 / np.sqrt(np.maximum(diag, 1e-14 * max(diag.max(), 1e-300)))
        jtj_s = jtj * sc[:, None] * sc[None, :]
        improved = False
        while n_eval < max_nfev:
            mu = max(mu, 1e-10)
            try:
                step = -sc * linalg.solve(jtj_s + mu * np.eye(sc.size), sc * jtr, assume_a="pos",
                                          check_finite=False)
            except (linalg.LinAlgError, ValueError):
                mu, nu = mu * nu, nu * 2
                if mu > 1e12:
                    break
                continue
            theta_new = theta + step
            new = solve_coefficients(data, *fb.unpack(theta_new, n_lin), dep=dep)
            n_eval += 1
            predicted = -2.0 * step @ jtr - step @ jtj @ step
            if np.isfinite(new.cost) and new.cost < sol.cost:
                rho = (sol.cost - new.cost) / max(predicted, 1e-300)
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                improved = True
                break
            mu, nu = mu * nu, nu * 2
            if mu > 1e12:
                break
        if not improved:
            message = "no further decrease of the cost"
            break
        gain = sol.cost - new.cost
        small_step = np.linalg.norm(step) <= 1e-10 * (np.linalg.norm(theta) + 1e-10)
        theta, sol = theta_new, new
        if gain <= rtol * sol.cost or small_step:
            message = "converged: relative cost decrease below rtol" if not small_step else "converged: step tiny"
            break
    lin_r, quad_r = fb.unpack(theta, n_lin)
    return Refined(lin_r.copy(), quad_r.copy(), sol, n_eval, message)



def factor_covariance(data: WeightedData, lin: np.ndarray, quad: np.ndarray, sol: LinearSolution,
                      n_parameters: int, sandwich: bool = True,
                      row_covariance: np.ndarray | None = None,
                      deviations: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the factor parameters theta = [lin, quad] at a fit, (P, P) in scaled units.

    J is the variable-projection Jacobian (Kaufman's, the numerators
    profiled out: P_perp U of :func:`_normal_equations`), r the weighted
    residual, N its length, p = ``n_parameters`` all real parameters.

    * ``sandwich`` (default): (J^T J)^-1 (sum_l s_l s_l^T) (J^T J)^-1 N / (N - p)
      with s_l = J_l^T r_l the score of line l (its 2 Ny Nu residuals): the
      lines are independent, but a line's entries are not (in closed loop
      the output noise reaches every entry through the same U^-1) and the
      model may miss some of the data; the line sums carry both.
    * else: s^2 (J^T J)^-1 with s^2 = V / (N - p) (independent residuals).

    With ``row_covariance`` (L, Ny, Nu, Nu), the known covariance of the
    entries of each row of G, the sandwich takes it instead of the residuals
    (:func:`ambid.fit.correlated.line_sandwich`). ``deviations`` (M, E, L),
    the realisations' G_m minus their mean in the data's layout (delay
    removed), widen it where their scatter exceeds it
    (:func:`ambid.fit.correlated.realisation_inflation`).

    Returns
    -------
    (cov (P, P), dof (P,)): the degrees of freedom of each variance (inf:
    many, use the normal quantile).
    """
    theta = fb.pack(lin, quad)
    nc = data.n_constraints
    dep = dependent_columns(lin, quad, nc) if nc else None
    u, z = _weighted_derivative(data, theta, lin.size, sol, dep)
    rho2 = np.concatenate([sol.rho, sol.rho], axis=1)
    j = u - rho2[:, :, None] * np.matmul(sol.q0[None], np.linalg.solve(sol.normal, z))   # P_perp U, (E, 2L, P)
    jtj = np.einsum("eip,eiq->pq", j, j)
    bread = linalg.pinvh(jtj)
    n_res = j.shape[0] * j.shape[1]
    if row_covariance is not None:
        rc = np.asarray(row_covariance)
        n_lines, ny, nu = rc.shape[:3]

        def lines_first(x: np.ndarray) -> np.ndarray:   # (E, L, ...) -> (L, Ny, Nu, ...)
            return np.moveaxis(x, 0, 1).reshape((n_lines, ny, nu) + x.shape[2:])

        cov = line_sandwich(lines_first(j[:, :n_lines]), lines_first(j[:, n_lines:]), lines_first(sol.residual),
                            lines_first(data.w), rc, bread, n_parameters)
        dof = np.full(cov.shape[0], np.inf)
        if deviations is not None:
            dw = data.w[None] * deviations
            d = np.concatenate([dw.real, dw.imag], axis=2)                               # (M, E, 2L)
            # the sandwich's meat sums over the lines: their number less the factors' is its dof
            factors, dof = realisation_inflation(np.einsum("mei,eip->mp", d, j) @ bread, cov,
                                                 float(max(n_lines - bread.shape[0], 1)))
            cov = cov * np.sqrt(np.outer(factors, factors))
        return cov, dof
    many = np.full(bread.shape[0], np.inf)
    if not sandwich:
        return sol.cost / max(n_res - n_parameters, 1) * bread, many
    res = sol.residual
    r = np.concatenate([res.real, res.imag], axis=1)                                       # (E, 2L)
    n_lines = res.shape[1]
    contrib = (j * r[:, :, None]).sum(axis=0)                                              # (2L, P)
    score = contrib[:n_lines] + contrib[n_lines:]                                          # per line
    return bread @ (score.T @ score) @ bread * n_res / max(n_res - n_parameters, 1), many
