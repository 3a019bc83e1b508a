"""Linear steps of the common-denominator fit: coefficients and pole relocation.

Internal to :mod:`ambid.fit`. All quantities are in the scaled variable
s~ = s / omega_scale and the data are flattened to E = Ny Nu entries:
``g`` (E, L) complex, weights ``w`` (E, L) = 1 / sqrt(var).

Pole relocation is relaxed vector fitting (Gustavsen & Semlyen 1999,
Gustavsen 2006) with the per-entry reduction of fast vector fitting
(Deschrijver et al. 2008). A vector-fitting step solves the weighted
linearised equation

    w (N(s) - G(s) sigma(s)) ~ 0,    sigma = d~ + sum_k c~_k phi_k(s),

in the partial-fraction basis phi_k of the current poles: the first step is
Levy's linearised least squares, and the iteration is the Sanathanan-Koerner
iteration written in a rational basis whose poles move to the zeros of sigma
(Hendrickx & Dhaene 2006), which keeps it well conditioned at high order.
Poles are not flipped into the left half plane: an AMB plant is unstable.

Speed: the basis is first orthonormalised once (QR) under the weight w_bar
averaged over the entries; each entry then only differs by its relative
weight rho_e = w_e / w_bar, and its normal matrix in that orthonormal basis,
Q0^T rho_e^2 Q0, has the condition number of rho_e^2 only (1 for equal
variances), so it is formed by matrix products instead of E tall QRs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ambid.fit import basis as fb


@dataclass(frozen=True)
class WeightedData:
    """Scaled, flattened fit data.

    Attributes
    ----------
    s
        (L,) complex scaled Laplace variable j f / f_scale.
    g
        (E, L) complex data per matrix entry (delay already removed).
    w
        (E, L) weights 1 / sqrt(var).
    has_feedthrough
        fit a constant term D per entry (relative degree 0).
    relative_degree
        0 (proper), 1 (strictly proper), r >= 2 adds r - 1
        linear constraints on the coefficients (vanishing Laurent moments).
    """

    s: np.ndarray
    g: np.ndarray
    w: np.ndarray
    has_feedthrough: bool
    relative_degree: int

    @property
    def n_constraints(self) -> int:
        return max(self.relative_degree - 1, 0)


@dataclass(frozen=True)
class LinearSolution:
    """Best coefficients for fixed poles.

    Attributes
    ----------
    coef
        (E, n) coefficients on the pole basis (constraints applied).
    feedthrough
        (E,) constant terms (zeros without feed-through).
    free
        (E, n_free) the unconstrained unknowns z (coef = z @ null.T).
    null
        (n, n_free) null-space map of the constraints (identity without).
    q0
        (2L, k) orthonormal basis of the w_bar-weighted, real-stacked columns.
    rho
        (E, L) relative weights w / w_bar.
    normal
        (E, k, k) per-entry normal matrices Q0^T rho^2 Q0.
    residual
        (E, L) complex weighted residual w (G_model - G).
    cost
        sum |G_model - G|^2 / var = sum |residual|^2.
    """

    coef: np.ndarray
    feedthrough: np.ndarray
    free: np.ndarray
    null: np.ndarray
    q0: np.ndarray
    rho: np.ndarray
    normal: np.ndarray
    residual: np.ndarray
    cost: float


def stack_real(x: np.ndarray) -> np.ndarray:
    """(..., L, k) complex -> (..., 2L, k) real: real parts over imaginary parts."""
    return np.concatenate([x.real, x.imag], axis=-2)


def dependent_columns(lin: np.ndarray, quad: np.ndarray, n_constraints: int) -> np.ndarray:
    """Columns eliminated by the moment constraints (pivoted QR, best conditioned)."""
    mom = fb.laurent_moments(lin, quad, n_constraints)
    _, _, piv = linalg.qr(mom, pivoting=True, mode="economic")
    return np.sort(piv[:n_constraints])


def null_map(lin: np.ndarray, quad: np.ndarray, n_constraints: int, dep: np.ndarray) -> np.ndarray:
    """N (n, n - n_constraints) with moments @ N = 0: c = N z, the dep rows solved.

    Smooth (rational) in the factor parameters for a fixed ``dep``, so it can
    be differentiated by complex step.
    """
    n = lin.size + 2 * quad.shape[0]
    if n_constraints == 0:
        return np.eye(n)
    mom = fb.laurent_moments(lin, quad, n_constraints)
    free = np.setdiff1d(np.arange(n), dep)
    out = np.zeros((n, free.size), dtype=mom.dtype)
    out[free, np.arange(free.size)] = 1.0
    out[dep] = -np.linalg.solve(mom[:, dep], mom[:, free])
    return out


def weighted_basis(data: WeightedData, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormalise columns (L, k) under the entry-averaged weight.

    Returns
    -------
    (q0 (2L, k), t0 (k, k) upper triangular with stack(w_bar cols) = q0 t0,
    w_bar (L,), rho (E, L) = w / w_bar).
    """
    w_bar = np.sqrt(np.mean(data.w ** 2, axis=0))
    q0, t0 = np.linalg.qr(stack_real(w_bar[:, None] * cols))
    return q0, t0, w_bar, data.w / w_bar


def _rho2_stacked(rho: np.ndarray) -> np.ndarray:
    return np.concatenate([rho, rho], axis=1) ** 2


def solve_coefficients(data: WeightedData, lin: np.ndarray, quad: np.ndarray,
                       dep: np.ndarray | None = None) -> LinearSolution:
    """Weighted least-squares coefficients per entry for fixed poles."""
    phi = fb.basis(data.s, lin, quad)
    nc = data.n_constraints
    if nc:
        if dep is None:
            dep = dependent_columns(lin, quad, nc)
        null = null_map(lin, quad, nc, dep).real
    else:
        null = np.eye(phi.shape[1])
    cols = phi @ null
    if data.has_feedthrough:
        cols = np.concatenate([cols, np.ones((data.s.size, 1))], axis=1)
    n_l = data.s.size
    q0, t0, w_bar, rho = weighted_basis(data, cols)
    rho2 = _rho2_stacked(rho)
    normal = np.matmul(q0.T[None] * rho2[:, None, :], q0)
    wg = w_bar * data.g
    b = np.concatenate([wg.real, wg.imag], axis=1)
    y = np.linalg.solve(normal, ((rho2 * b) @ q0)[..., None])[..., 0]
    # one step of iterative refinement on the normal equations
    y -= np.linalg.solve(normal, ((rho2 * (y @ q0.T - b)) @ q0)[..., None])[..., 0]
    q0c = q0[:n_l] + 1j * q0[n_l:]
    resid = rho * (y @ q0c.T - wg)
    try:
        x = linalg.solve_triangular(t0, y.T, check_finite=False).T
    except linalg.LinAlgError:
        # coinciding poles repeat a column: any coefficients giving the same fit will do
        x = np.linalg.lstsq(t0, y.T, rcond=None)[0].T
    n_free = null.shape[1]
    z = x[:, :n_free]
    d = x[:, n_free] if data.has_feedthrough else np.zeros(x.shape[0])
    return LinearSolution(coef=z @ null.T, feedthrough=d, free=z, null=null, q0=q0, rho=rho,
                          normal=normal, residual=resid,
                          cost=float(np.sum(resid.real ** 2 + resid.imag ** 2)))


def relocate_poles(data: WeightedData, lin: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """One relaxed vector-fitting step: the zeros of sigma, (n,) complex (scaled).

    Returns the new poles, closed under conjugation (eigenvalues of a real
    matrix).
    """
    phi = fb.basis(data.s, lin, quad)
    n = phi.shape[1]
    n_l = data.s.size
    # sigma columns [phi, 1]; the model columns are the same (with D) or phi alone,
    # i.e. the first nm orthonormal columns, as t0 is triangular
    k = np.concatenate([phi, np.ones((n_l, 1))], axis=1)
    q0, t0, _, rho = weighted_basis(data, k)
    q0c = q0[:n_l] + 1j * q0[n_l:]
    nm = n + 1 if data.has_feedthrough else n
    z = np.concatenate([np.broadcast_to(q0c[None, :, :nm], (data.g.shape[0], n_l, nm)),
                        -data.g[:, :, None] * q0c[None]], axis=2)
    z = stack_real(rho[:, :, None] * z)
    h = np.matmul(z.transpose(0, 2, 1), z)
    # fast VF: eliminate each entry's numerator, keep the Schur complement on sigma
    h11, h12, h22 = h[:, :nm, :nm], h[:, :nm, nm:], h[:, nm:, nm:]
    schur = (h22 - np.matmul(h12.transpose(0, 2, 1), np.linalg.solve(h11, h12))).sum(axis=0)
    lam, vec = np.linalg.eigh(0.5 * (schur + schur.T))
    rows = np.sqrt(np.clip(lam, 0.0, None))[:, None] * vec.T  # rows^T rows = schur, unknowns t0 c
    # relaxation (Gustavsen 2006): mean of Re sigma over the lines equals 1
    scale = np.sqrt(np.sum((data.w * np.abs(data.g)) ** 2)) / n_l
    relax = scale * np.concatenate([phi.real.sum(axis=0), [n_l]])
    relax_t = linalg.solve_triangular(t0, relax, trans="T", check_finite=False)
    m = np.vstack([rows, relax_t])
    rhs = np.zeros(m.shape[0])
    rhs[-1] = scale * n_l
    cn = np.linalg.norm(m, axis=0)
    cn[cn == 0] = 1.0
    c = linalg.solve_triangular(t0, np.linalg.lstsq(m / cn, rhs, rcond=None)[0] / cn, check_finite=False)
    c_sig, d_sig = c[:n], c[n]
    if not np.isfinite(d_sig) or abs(d_sig) < 1e-8 * max(np.abs(c_sig).max(initial=0.0), 1e-300):
        # relaxed solution degenerate: fall back to sigma = 1 + sum c~ phi
        rows_c = rows @ t0
        c_sig = np.linalg.lstsq(rows_c[:, :n], -rows_c[:, n], rcond=None)[0]
        d_sig = 1.0
    a_c, b_c = fb.companion(lin, quad)
    return np.linalg.eigvals(a_c - np.outer(b_c, c_sig) / d_sig)


def starting_poles(order: int, w_min: float, w_max: float) -> np.ndarray:
    """Vector-fitting start: lightly damped pairs log-spaced over [w_min, w_max].

    Scaled units. An odd order adds one real pole at -sqrt(w_min w_max).
    """
    n_pairs = order // 2
    beta = np.geomspace(w_min, w_max, n_pairs) if n_pairs else np.zeros(0)
    pairs = np.stack([-beta / 100 + 1j * beta, -beta / 100 - 1j * beta], axis=1).ravel()
    real = [-np.sqrt(w_min * w_max)] if order % 2 else []
    return np.concatenate([pairs, np.asarray(real, dtype=complex)])


def vector_fit(data: WeightedData, poles0: np.ndarray, n_iter: int,
               rtol: float = 1e-2) -> tuple[np.ndarray, np.ndarray, LinearSolution, int]:
    """Iterate pole relocation; keep the iterate with the lowest weighted cost.

    Stops after ``n_iter`` steps, when the cost has changed by less than
    ``rtol`` (relative) in two steps in a row (one small step can be a
    pause before a pole pair splits), or when it has not improved on the
    best for three steps (noisy data make vector fitting wander about the
    optimum).

    Returns
    -------
    (lin, quad, solution, steps) of the best iterate.
    """
    lin, quad = fb.split_poles(poles0)
    best = (lin, quad, solve_coefficients(data, lin, quad))
    prev_cost = best[2].cost
    since_best = n_small = steps = 0
    for steps in range(1, n_iter + 1):
        poles = relocate_poles(data, lin, quad)
        if not np.all(np.isfinite(poles)):
            break
        lin, quad = fb.split_poles(poles)
        sol = solve_coefficients(data, lin, quad)
        if sol.cost < best[2].cost:
            best = (lin, quad, sol)
            since_best = 0
        else:
            since_best += 1
        n_small = n_small + 1 if abs(sol.cost - prev_cost) <= rtol * prev_cost else 0
        if n_small >= 2 or since_best >= 3:
            break
        prev_cost = sol.cost
    return best[0], best[1], best[2], steps
