"""Common-denominator MIMO rational model fitted to a measured FRF matrix.

    G(s) = exp(-s tau) (N(s) / d(s)) = exp(-s tau) (D + sum_k R_k / (s - p_k)),

with one denominator d(s) = prod_k (s - p_k) shared by all Ny x Nu entries,
s = j 2 pi f (continuous time). The fit runs in three stages on the
frequency-scaled variable s / (2 pi f_max):

1. Levy / Sanathanan-Koerner: relaxed vector fitting (pole relocation in a
   partial-fraction basis, :mod:`ambid.fit.vector_fitting`), weighted by
   1 / var. Unstable poles are kept (an AMB plant has real poles in the
   right half plane from the negative magnet stiffness).
2. Maximum-likelihood refinement (:mod:`ambid.fit.refine`): Levenberg-
   Marquardt on the poles, numerator by variable projection, minimising
   sum |G_model - G|^2 / var over lines and entries.
3. Poles and residue matrices out, as a :class:`RationalModel`.

References: Pintelon & Schoukens, System Identification: A Frequency Domain
Approach, 2nd ed. (2012), ch. 7-9; Gustavsen & Semlyen (1999), IEEE Trans.
Power Delivery 14(3); Verboven et al. (2005) on common-denominator modal
fitting.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ambid.fit import basis as fb
from ambid.fit.blas_threads import single_threaded_blas
from ambid.fit.refine import factor_covariance
from ambid.fit.refine import refine as ml_refine
from ambid.fit.vector_fitting import WeightedData, starting_poles, vector_fit

__all__ = ["RationalModel", "FitResult", "fit_common_denominator"]


@dataclass(frozen=True)
class RationalModel:
    """Pole-residue form of a common-denominator continuous-time model.

    Attributes
    ----------
    poles
        (n,) complex s-plane poles [rad/s], closed under conjugation
        (pairs adjacent, Im > 0 first); real poles have Im = 0.
    residues
        (n, Ny, Nu) complex residue matrices [unit of G * rad/s];
        conjugate for conjugate poles, real for real poles.
    feedthrough
        (Ny, Nu) real constant term D [unit of G].
    delay_s
        pure delay tau [s] multiplying the whole model.
    input_names, output_names, input_units, output_units
        channel labels
        (optional, carried into the state-space realisation).
    """

    poles: np.ndarray
    residues: np.ndarray
    feedthrough: np.ndarray
    delay_s: float = 0.0
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())
    input_units: tuple[str, ...] = field(default=())
    output_units: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        p = np.asarray(self.poles, dtype=complex).ravel()
        r = np.asarray(self.residues, dtype=complex)
        d = np.atleast_2d(np.asarray(self.feedthrough, dtype=float))
        if r.ndim != 3 or r.shape[0] != p.size or r.shape[1:] != d.shape:
            raise ValueError(f"RationalModel: residues must be (n, Ny, Nu) = ({p.size}, *{d.shape}), "
                             f"got {r.shape}; feedthrough is (Ny, Nu)")
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(r)) and np.all(np.isfinite(d))):
            raise ValueError("RationalModel: poles, residues and feedthrough must be finite")
        if not (np.isfinite(self.delay_s) and self.delay_s >= 0):
            raise ValueError(f"RationalModel: delay_s must be >= 0, got {self.delay_s}")
        scale = max(np.abs(p).max(initial=0.0), 1.0)
        if not np.allclose(np.sort_complex(p), np.sort_complex(p.conj()), rtol=0, atol=1e-9 * scale):
            raise ValueError("RationalModel: poles must be closed under conjugation (a real system)")
        object.__setattr__(self, "poles", p)
        object.__setattr__(self, "residues", r)
        object.__setattr__(self, "feedthrough", d)
        for attr, size in (("input_names", d.shape[1]), ("output_names", d.shape[0]),
                           ("input_units", d.shape[1]), ("output_units", d.shape[0])):
            names = tuple(getattr(self, attr))
            if names and len(names) != size:
                raise ValueError(f"RationalModel: {attr} has {len(names)} entries for {size} channels")
            object.__setattr__(self, attr, names)

    @property
    def order(self) -> int:
        """Degree n of the common denominator."""
        return self.poles.size

    @property
    def n_outputs(self) -> int:
        return self.feedthrough.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.feedthrough.shape[1]

    def denominator(self) -> np.ndarray:
        """Monic d(s) coefficients, highest power first, (n + 1,) real [s in rad/s]."""
        return np.real(np.poly(self.poles)) if self.order else np.ones(1)

    def freqresp(self, freq_hz: np.ndarray) -> np.ndarray:
        """G(j 2 pi f) at ``freq_hz`` (L,) [Hz], shape (L, Ny, Nu) complex."""
        f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        s = 2j * np.pi * f
        g = (1.0 / (s[:, None] - self.poles[None, :])) @ self.residues.reshape(self.order, -1)
        g = g.reshape(f.size, *self.feedthrough.shape) + self.feedthrough
        if self.delay_s:
            g = g * np.exp(-s * self.delay_s)[:, None, None]
        return g


@dataclass(frozen=True)
class FitResult:
    """A fitted :class:`RationalModel` with its cost and counts.

    Attributes
    ----------
    model
        the fitted model.
    cost
        V = sum |G_model - G|^2 / var over lines and entries at the end.
    cost_linear
        V after the vector-fitting (SK) stage, before refinement.
    n_residuals
        number of real residuals N = 2 L Ny Nu.
    n_parameters
        number of free real parameters p (poles, numerators, D).
    n_vf_iterations
        vector-fitting steps taken.
    n_refine_evaluations
        cost evaluations of the ML refinement (0 if off).
    message
        the refinement's stop reason.
    weighted
        True when ``var`` was given (cost then ~ chi-square / 2).
    mode_std
        one row per second-order factor of the denominator with a
        complex pole pair: (natural frequency [Hz], its std [Hz], damping
        ratio [-], its std [-], degrees of freedom of those variances
        (inf: many)), from the factors' covariance
        (:func:`ambid.fit.refine.factor_covariance`) by the delta method;
        (K, 5), empty when the covariance is not available.
    """

    model: RationalModel
    cost: float
    cost_linear: float
    n_residuals: int
    n_parameters: int
    n_vf_iterations: int
    n_refine_evaluations: int
    message: str
    weighted: bool
    mode_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))

    def mode_interval(self, freq_hz: float, damping: float) -> tuple[float, float, float] | None:
        """(freq std [Hz], damping std [-], their degrees of freedom) of the fitted mode at
        (freq_hz, damping), or None."""
        if self.mode_std.shape[0] == 0:
            return None
        d = np.abs(self.mode_std[:, 0] - freq_hz) / max(freq_hz, 1e-12) + np.abs(self.mode_std[:, 2] - damping)
        k = int(np.argmin(d))
        if d[k] > 1e-6:
            return None
        return float(self.mode_std[k, 1]), float(self.mode_std[k, 3]), float(self.mode_std[k, 4])

    @property
    def dof(self) -> int:
        """Degrees of freedom N - p of the residual."""
        return self.n_residuals - self.n_parameters

    @property
    def chi2_per_dof(self) -> float:
        """2 V / (N - p): about 1 for a right model and right noise variances.

        Each real residual component has variance 1/2 when ``var`` is the
        variance of the complex FRF, so 2 V is chi-square with N - p degrees
        of freedom.
        """
        return 2.0 * self.cost / max(self.dof, 1)


def _check_inputs(freq_hz, g, var) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size < 2:
        raise ValueError(f"freq_hz must be a 1-D array of at least 2 lines, got shape {f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError("freq_hz must be finite and >= 0 [Hz]")
    if np.unique(f).size != f.size:
        raise ValueError("freq_hz has repeated lines; average them first")
    gm = np.asarray(g)
    if gm.ndim == 1:
        gm = gm[:, None, None]
    if gm.ndim != 3 or gm.shape[0] != f.size:
        raise ValueError(f"G must be (L, Ny, Nu) with L = len(freq_hz) = {f.size}, got shape {gm.shape}")
    if not np.all(np.isfinite(gm)):
        raise ValueError("G contains NaN or Inf; drop those lines (and their freq_hz) first")
    v = None
    if var is not None:
        v = np.asarray(var, dtype=float)
        if v.ndim == 1 and gm.shape[1:] == (1, 1):
            v = v[:, None, None]
        if v.shape != gm.shape:
            raise ValueError(f"var must have the shape of G {gm.shape}, got {v.shape}")
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError("var must be finite and > 0 [unit of G squared]; floor zero variances "
                             "(e.g. at 1e-6 of the median) or pass var=None for uniform weights")
    return f, gm.astype(complex), v


def _prepare_fit_data(freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None = None, *,
                     relative_degree: int = 0, delay_s: float = 0.0) -> tuple[WeightedData, float]:
    """Validate, scale and flatten fit data (used by the fit and order selection).

    Returns
    -------
    (data, omega_scale): the internal :class:`WeightedData` and the
    frequency scale 2 pi f_max [rad/s].
    """
    f, gm, v = _check_inputs(freq_hz, G, var)
    if relative_degree not in range(0, 8):
        raise ValueError(f"relative_degree must be an integer 0..7, got {relative_degree}")
    if not (np.isfinite(delay_s) and delay_s >= 0):
        raise ValueError(f"delay_s must be >= 0 [s], got {delay_s}")
    if f.max() <= 0:
        raise ValueError("freq_hz needs at least one line above 0 Hz")
    w_scale = 2 * np.pi * f.max()
    if delay_s:
        gm = gm * np.exp(2j * np.pi * f * delay_s)[:, None, None]
    e = gm.shape[1] * gm.shape[2]
    g = gm.reshape(f.size, e).T
    w = np.ones_like(g.real) if v is None else 1.0 / np.sqrt(v.reshape(f.size, e).T)
    data = WeightedData(s=1j * f / f.max(), g=g, w=w, has_feedthrough=relative_degree == 0,
                        relative_degree=int(relative_degree))
    return data, w_scale


def fit_common_denominator(freq_hz: np.ndarray, G: np.ndarray, var: np.ndarray | None = None, *,
                           order: int, relative_degree: int = 0, delay_s: float = 0.0,
                           initial_poles: np.ndarray | None = None, n_vf_iterations: int = 30,
                           refine: bool = True, max_refine_evaluations: int = 100,
                           input_names: tuple[str, ...] = (), output_names: tuple[str, ...] = (),
                           input_units: tuple[str, ...] = (), output_units: tuple[str, ...] = (),
                           row_covariance: np.ndarray | None = None,
                           realisations: np.ndarray | None = None) -> FitResult:
    """Fit a common-denominator model of ``order`` poles to a measured FRF matrix.

    Parameters
    ----------
    freq_hz
        (L,) lines [Hz], >= 0, distinct.
    G
        (L, Ny, Nu) complex FRF [e.g. m/A] (a (L,) SISO FRF is accepted).
    var
        (L, Ny, Nu) noise variance of G, E|G - E G|^2 [unit of G squared];
        None weights every line and entry equally (the cost is then not
        a chi-square).
    order
        number of poles n (degree of d(s)).
    relative_degree
        0 proper (with D), 1 strictly proper (D = 0),
        r >= 2 forces G ~ s^-r at high frequency (linear constraints).
    delay_s
        known pure delay tau [s]; the model is exp(-s tau) N/d.
    initial_poles
        (n,) complex [rad/s] start for vector fitting
        (default: lightly damped pairs log-spaced over the band).
    n_vf_iterations
        most vector-fitting (SK) steps.
    refine
        run the ML refinement after vector fitting.
    max_refine_evaluations
        most cost evaluations in the refinement.
    input_names, output_names, input_units, output_units
        labels kept
        on the model.
    row_covariance
        (L, Ny, Nu, Nu) complex covariance of the entries of
        each row of G (:func:`ambid.frf.uncertainty.row_covariance`) for
        the modes' intervals; None takes the residuals' line sums
        (:func:`ambid.fit.refine.factor_covariance`).
    realisations
        (M, L, Ny, Nu) the realisations' FRFs whose mean G is;
        their scatter may widen the modes' intervals (with ``row_covariance``).

    Returns
    -------
    :class:`FitResult`.
    """
    with single_threaded_blas():
        return _fit(freq_hz, G, var, order, relative_degree, delay_s, initial_poles, n_vf_iterations,
                    refine, max_refine_evaluations,
                    (tuple(input_names), tuple(output_names), tuple(input_units), tuple(output_units)),
                    row_covariance, realisations)


def _fit(freq_hz, G, var, order, relative_degree, delay_s, initial_poles, n_vf_iterations, refine,
         max_refine_evaluations, labels, row_covariance=None, realisations=None) -> FitResult:
    if int(order) != order or order < 1:
        raise ValueError(f"order must be a positive integer, got {order}")
    order = int(order)
    data, w_scale = _prepare_fit_data(freq_hz, G, var, relative_degree=relative_degree, delay_s=delay_s)
    e, n_lines = data.g.shape
    n_cols = order + 1 + int(data.has_feedthrough)
    if 2 * n_lines < n_cols + order:
        raise ValueError(f"order {order} needs at least {(n_cols + order + 1) // 2} lines, got {n_lines}; "
                         "lower the order or add lines")
    if data.n_constraints >= order:
        raise ValueError(f"relative_degree {relative_degree} needs order > {data.n_constraints}, got {order}")
    f = np.asarray(freq_hz, dtype=float)
    if initial_poles is None:
        f_pos = f[f > 0]
        lo = max(f_pos.min(), f_pos.max() / 1e3) / f.max()
        poles0 = starting_poles(order, lo, 1.0)
    else:
        poles0 = np.asarray(initial_poles, dtype=complex).ravel() / w_scale
        if poles0.size != order:
            raise ValueError(f"initial_poles has {poles0.size} poles for order {order}")
        if not np.all(np.isfinite(poles0)):
            raise ValueError("initial_poles must be finite")
        gaps = np.abs(poles0[:, None] - poles0[None, :]) + np.eye(order)
        if np.any(gaps <= 1e-9 * np.maximum(np.abs(poles0)[:, None], 1e-3)):
            raise ValueError("initial_poles repeats a pole; the partial-fraction basis needs distinct poles")
    lin, quad, sol, n_vf = vector_fit(data, poles0, n_vf_iterations)
    cost_linear = sol.cost
    n_eval, message = 0, "no refinement"
    if refine:
        ref = ml_refine(data, lin, quad, max_nfev=max_refine_evaluations)
        lin, quad, sol, n_eval, message = ref.lin, ref.quad, ref.solution, ref.n_evaluations, ref.message
    poles, res = fb.coefficients_to_residues(lin, quad, sol.coef)
    ny, nu = np.shape(G)[1:] if np.ndim(G) == 3 else (1, 1)
    model = RationalModel(poles=poles * w_scale, residues=(res * w_scale).reshape(order, ny, nu),
                          feedthrough=sol.feedthrough.reshape(ny, nu), delay_s=float(delay_s),
                          input_names=labels[0], output_names=labels[1],
                          input_units=labels[2], output_units=labels[3])
    n_par = order + e * (order - data.n_constraints + int(data.has_feedthrough))
    deviations = None
    if realisations is not None:
        gm = np.asarray(realisations)
        dev = (gm - gm.mean(axis=0)) * np.exp(2j * np.pi * f * delay_s)[None, :, None, None]
        deviations = dev.reshape(gm.shape[0], f.size, e).transpose(0, 2, 1)            # (M, E, L)
    mode_std = _mode_std(data, lin, quad, sol, n_par, w_scale, row_covariance, deviations)
    return FitResult(mode_std=mode_std, model=model, cost=sol.cost, cost_linear=cost_linear, n_residuals=2 * n_lines * e,
                     n_parameters=n_par, n_vf_iterations=n_vf, n_refine_evaluations=n_eval,
                     message=str(message), weighted=var is not None)


def _mode_std(data: WeightedData, lin: np.ndarray, quad: np.ndarray, sol, n_par: int,
              w_scale: float, row_covariance: np.ndarray | None = None,
              deviations: np.ndarray | None = None) -> np.ndarray:
    """FitResult.mode_std: delta method on q(s) = s^2 + a1 s + a0 (scaled s), omega = sqrt(a0),
    zeta = a1 / (2 sqrt(a0))."""
    if quad.shape[0] == 0:
        return np.zeros((0, 5))
    try:
        cov, dof = factor_covariance(data, lin, quad, sol, n_par, row_covariance=row_covariance,
                                     deviations=deviations)
    except (np.linalg.LinAlgError, ValueError):
        return np.zeros((0, 5))
    rows = []
    for k, (a1, a0) in enumerate(quad):
        if not (a0 > 0 and a1 * a1 < 4 * a0):
            continue   # two real poles
        i = lin.size + 2 * k
        c = cov[i:i + 2, i:i + 2]   # [a1, a0]
        r = np.sqrt(a0)
        g_w = np.array([0.0, 1 / (2 * r)])
        g_z = np.array([1 / (2 * r), -a1 / (4 * r**3)])
        to_hz = w_scale / (2 * np.pi)
        rows.append((r * to_hz, np.sqrt(max(g_w @ c @ g_w, 0.0)) * to_hz, a1 / (2 * r),
                     np.sqrt(max(g_z @ c @ g_z, 0.0)), float(min(dof[i], dof[i + 1]))))
    return np.array(rows).reshape(-1, 5)
