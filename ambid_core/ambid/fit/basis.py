"""Real rational basis of a common denominator split into low-order factors.

The denominator d(s) is kept as a product of real factors: first-order
(a real pole a) and second-order ``q(s) = s^2 + a1 s + a0`` (a complex
pair, or two real poles once a pair has split). Each factor contributes
basis functions with real coefficients,

    1 / (1 - b s) = -a / (s - a),  b = 1 / a   (first order)
    1 / q(s),  s / q(s)                         (second order),

so a common-denominator model of one matrix entry is sum_k c_k phi_k(s) (+ D).
This is the partial-fraction basis of vector fitting written per factor:
well conditioned when s is scaled to |s| <= 1 and the poles lie near the
band. A first-order factor is parametrised by its inverse pole b, so a
real pole can leave the band on one side and come back on the other
(b crosses 0, the pole passes through infinity): without pole flipping an
amplifier pole fitted at +a must be able to reach -a. A complex pair can
split into two real poles (the discriminant of q changes sign smoothly).

The factor parameters are stacked as ``theta = [b_1..b_n1, a1_1, a0_1, ...]``.
Everything here works in the scaled variable (s / omega_scale); the callers
scale and unscale.
"""

from __future__ import annotations

import numpy as np

# relative size of an imaginary part below which a pole counts as real
_REAL_TOL = 1e-9


def split_poles(poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group conjugate-closed poles into first- and second-order real factors.

    Parameters
    ----------
    poles
        (n,) complex, closed under conjugation.

    Returns
    -------
    (lin, quad): lin (n1,) inverse real poles b = 1 / a, quad (n2, 2)
    rows [a1, a0] of s^2 + a1 s + a0 for the complex pairs,
    n1 + 2 n2 = n.
    """
    p = np.asarray(poles, dtype=complex).ravel()
    is_real = np.abs(p.imag) <= _REAL_TOL * np.maximum(np.abs(p), 1e-300)
    upper = p[~is_real & (p.imag > 0)]
    n_lower = int(np.count_nonzero(~is_real & (p.imag < 0)))
    if n_lower != upper.size:
        raise ValueError(f"poles are not closed under conjugation ({upper.size} with Im > 0, "
                         f"{n_lower} with Im < 0); pass both members of every complex pair")
    real = np.sort(p[is_real].real)
    real = np.where(real == 0, 1e-12, real)  # a pole at s = 0 exactly: nudge, b = 1/a must exist
    quad = np.array([(-2.0 * q.real, abs(q) ** 2) for q in upper], dtype=float).reshape(-1, 2)
    return 1.0 / real, quad


def pack(lin: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """Parameter vector theta (n1 + 2 n2,) from the factors."""
    return np.concatenate([np.asarray(lin, dtype=float), np.asarray(quad, dtype=float).ravel()])


def unpack(theta: np.ndarray, n_lin: int) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack`."""
    return theta[:n_lin], theta[n_lin:].reshape(-1, 2)


def _inverse(lin: np.ndarray) -> np.ndarray:
    # b = 0 is a pole at infinity; keep it finite (huge) so residues stay defined
    return 1.0 / np.where(lin == 0, 1e-300, lin)


def factor_roots(lin: np.ndarray, quad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots of every factor: (real poles (n1,), quad roots (n2, 2)) complex.

    Each complex pair is ordered (Im > 0, Im < 0); real roots of a split
    pair by value.
    """
    a1, a0 = quad[:, 0], quad[:, 1]
    disc = np.sqrt((a1 * a1 - 4.0 * a0).astype(complex))
    r1 = 0.5 * (-a1 + disc)
    r2 = 0.5 * (-a1 - disc)
    # make complex pairs exact conjugates and real roots exactly real
    cplx = a1 * a1 - 4.0 * a0 < 0
    r1 = np.where(cplx, r1.real + 1j * np.abs(r1.imag), r1.real + 0j)
    r2 = np.where(cplx, np.conj(r1), r2.real + 0j)
    return _inverse(np.asarray(lin, dtype=float)).astype(complex), np.stack([r1, r2], axis=-1).reshape(-1, 2)


def basis(s: np.ndarray, lin: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """Basis functions at s (L,) complex, shape (L, n1 + 2 n2).

    Column order: the first-order factors 1 / (1 - b s), then [1/q, s/q]
    per second-order factor.
    """
    cols = [1.0 / (1.0 - lin[None, :] * s[:, None])]
    if quad.size:
        q = s[:, None] ** 2 + quad[None, :, 0] * s[:, None] + quad[None, :, 1]
        cols.append(np.stack([1.0 / q, s[:, None] / q], axis=-1).reshape(s.size, -1))
    return np.concatenate(cols, axis=1)


def basis_derivative(s: np.ndarray, lin: np.ndarray, quad: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """d(sum_k coef_k phi_k(s)) / d theta for each coefficient set.

    Parameters
    ----------
    s
        (L,) complex.
    lin, quad
        the factors (n1,), (n2, 2).
    coef
        (E, n1 + 2 n2) real coefficients on the basis.

    Returns
    -------
    (E, L, n1 + 2 n2) complex; the last axis runs over theta.
    """
    n1 = lin.size
    e = coef.shape[0]
    out = np.empty((e, s.size, n1 + 2 * quad.shape[0]), dtype=complex)
    # d/db [c / (1 - b s)] = c s / (1 - b s)^2
    out[:, :, :n1] = coef[:, None, :n1] * (s[:, None] / (1.0 - lin[None, :] * s[:, None]) ** 2)[None]
    if quad.size:
        q = s[:, None] ** 2 + quad[None, :, 0] * s[:, None] + quad[None, :, 1]
        alpha, beta = coef[:, n1::2], coef[:, n1 + 1::2]
        # num / q with num = alpha + beta s: d/da1 = -num s / q^2, d/da0 = -num / q^2
        dq = -(alpha[:, None, :] + beta[:, None, :] * s[None, :, None]) / (q * q)[None]
        out[:, :, n1::2] = dq * s[None, :, None]
        out[:, :, n1 + 1::2] = dq
    return out


def laurent_moments(lin: np.ndarray, quad: np.ndarray, count: int) -> np.ndarray:
    """Coefficients of s^-(m+1), m = 0..count-1, of every basis function at s -> inf.

    A model sum_k c_k phi_k has relative degree >= r exactly when
    ``moments[:r-1] @ c == 0`` (and there is no feed-through). Works for
    complex parameters too (used for complex-step derivatives).

    Returns
    -------
    (count, n1 + 2 n2), same dtype as the parameters.
    """
    dtype = np.result_type(lin, quad, float)
    out = np.zeros((count, lin.size + 2 * quad.shape[0]), dtype=dtype)
    m = np.arange(count)[:, None]
    # 1 / (1 - b s) = -sum_m b^-(m+1) s^-(m+1)
    out[:, :lin.size] = -(1.0 / lin[None, :]) ** (m + 1)
    if quad.size and count:
        a1, a0 = quad[:, 0], quad[:, 1]
        # 1/q: u0 = 0, u1 = 1; s/q: t0 = 1, t1 = -a1; both x_m = -a1 x_{m-1} - a0 x_{m-2}
        u_prev, u = np.zeros_like(a1), np.zeros_like(a1)
        t_prev, t = np.zeros_like(a1), np.ones_like(a1)
        cols_u, cols_t = slice(lin.size, None, 2), slice(lin.size + 1, None, 2)
        out[0, cols_u], out[0, cols_t] = u, t
        u_prev, u = u, np.ones_like(a1)
        t_prev, t = t, -a1
        for k in range(1, count):
            out[k, cols_u], out[k, cols_t] = u, t
            u_prev, u = u, -a1 * u - a0 * u_prev
            t_prev, t = t, -a1 * t - a0 * t_prev
    return out


def companion(lin: np.ndarray, quad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with (sI - A)^-1 b = basis(s) as a column, block diagonal.

    First order: A = [a], b = [-a] with a = 1 / b_lin, so
    (s - a)^-1 (-a) = 1 / (1 - b_lin s); second order: A = [[0, 1], [-a0, -a1]],
    b = [0, 1], so (sI - A)^-1 b = [1, s] / q.
    """
    n = lin.size + 2 * quad.shape[0]
    a = np.zeros((n, n))
    b = np.zeros(n)
    pole = _inverse(lin)
    a[np.arange(lin.size), np.arange(lin.size)] = pole
    b[:lin.size] = -pole
    for j, (a1, a0) in enumerate(quad):
        k = lin.size + 2 * j
        a[k:k + 2, k:k + 2] = [[0.0, 1.0], [-a0, -a1]]
        b[k + 1] = 1.0
    return a, b


def coefficients_to_residues(lin: np.ndarray, quad: np.ndarray,
                             coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poles and residues of sum_k coef_k phi_k.

    Parameters
    ----------
    coef
        (E, n1 + 2 n2) real coefficients.

    Returns
    -------
    (poles (n,), residues (n, E)) complex, conjugate pairs adjacent.
    Two nearly equal real roots of a second-order factor give large
    opposite residues (a double pole has none); the sum stays right.
    """
    lin_r, quad_r = factor_roots(lin, quad)
    n1 = lin.size
    poles = np.concatenate([lin_r, quad_r.ravel()])
    res = np.empty((poles.size, coef.shape[0]), dtype=complex)
    res[:n1] = -coef[:, :n1].T * lin_r[:, None]  # c / (1 - b s) = (-c a) / (s - a)
    if quad.size:
        p1, p2 = quad_r[:, 0], quad_r[:, 1]
        alpha, beta = coef[:, n1::2].T, coef[:, n1 + 1::2].T  # (n2, E)
        gap = p1 - p2
        res[n1::2] = (alpha + beta * p1[:, None]) / gap[:, None]
        res[n1 + 1::2] = -(alpha + beta * p2[:, None]) / gap[:, None]
    return poles, res
