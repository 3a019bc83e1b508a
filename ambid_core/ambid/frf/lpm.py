"""The local polynomial (LPM) and local rational (LRM) methods: FRF, noise covariance and transient removal.

For records that are not a steady periodic experiment: random noise, PRBS,
chirps, a record started mid-run, several experiments in one record, or a
periodic experiment measured without settling periods. References: Pintelon
& Schoukens, *System Identification: A Frequency Domain Approach*, 2nd ed.
(2012), ch. 7; Pintelon, Schoukens, Vandersteen & Barbé, "Estimation of
nonparametric noise and FRF models for multivariable systems", MSSP 24
(2010), Parts I and II; McKelvey & Guérin, "Non-parametric frequency response
estimation using a local rational model", SYSID 2012.

Model. With the DFT ``X(k) = n^-1/2 sum_t x(t) exp(-2j pi k t / n)`` of an
n-sample record (so white noise of variance s^2 has ``E|X(k)|^2 = s^2``),
the signals z (Nz channels) driven by the references x (Nx channels) obey,
at every bin k, exactly::

    Z(k) = G(k) X(k) + T(k) + V(k)

where T is the transient: the difference of the system's initial and final
states seen through the record's window (leakage is the same term), a
smooth function of frequency like G itself. Around a centre bin k the LPM
writes ``G(k + s) = sum_j g_j s^j`` and ``T(k + s) = sum_j t_j s^j``
(degree R, ``s = -h..h``, a window of ``w = 2 h + 1`` bins) and solves for the
g_j and t_j by least squares; the residuals give the noise covariance
``C_V(k) = E[V V^H]`` (Nz x Nz) with ``q = Ne (w - (R + 1)) - (R + 1) Nx``
degrees of freedom (Ne experiments pooled: one G, a transient each). The
LRM divides both by a local denominator ``1 + sum_i d_i s^i`` shared by all
channels (linear least squares after multiplying out, McKelvey & Guérin),
which follows a resonance much narrower than the window that a polynomial
cannot.

Closed loop, indirect (:func:`local_frf` with ``r``): z = [y; u] are
regressed on the known excitation r, and ``G = G_yr G_ur^-1``; the noise on
y and u, correlated through the loop, enters only through C_V, so the
estimate is consistent in closed loop. Its noise variance, to first order,
row i and column j::

    var G_ij = (a_i C_V a_i^H) (M^T Q conj(M))_jj,  a_i = [e_i^T, -G_i],  M = G_ur^-1,

Q the (s^0) block of ``(X~^H X~)^-1`` of the regression.
With the variance estimated from q degrees of freedom,
``|G_ij - G0_ij|^2 / var G_ij`` follows F(2, 2q) (for Gaussian noise, at
high signal-to-noise ratio): :func:`f_quantile` gives the radius of a
circle that covers with a stated probability.

Estimates are given at the centres of non-overlapping windows, so they and
their errors are independent from line to line (a fit that takes them as
independent judges its own uncertainty right).

Periodic records (:func:`periodic_transient_removal`): a segment of P >= 2
periods of a periodic excitation measured from its start (no settling
periods). Its DFT over all P N samples holds the excitation and the
steady-state response only at every P-th bin (the period lines); the bins
in between hold the transient and the noise alone. The LPM fits the
transient there, around each line, and subtracts its value at the line;
the residuals give the noise covariance of the corrected line spectrum.
One rational model of the transient across the whole spectrum
(:mod:`ambid.frf.transient_model`, what a streamed experiment uses) adds
less noise; these local fits remain where its bins are too few.

Pure numpy; everything is vectorised over lines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special  # not scipy.stats: ~0.6 s to import on the path of `ambid fit`

__all__ = ["METHODS", "LocalFrf", "TransientFree", "local_frf", "window_centres", "periodic_transient_removal",
           "periodic_window", "line_noise", "f_quantile", "dof_of", "half_width_for"]

#: 'lpm': local polynomials; 'lrm': local rational models; 'auto': the LRM at the lines where its smaller
#: residual is significant (an F test at 0.1 %), the LPM elsewhere
METHODS = ("lpm", "lrm", "auto")
#: residual degrees of freedom a default window leaves at least
DEFAULT_DOF = 8
_RCOND_MIN = 1e-10


@dataclass(frozen=True)
class LocalFrf:
    """An FRF estimated by the local polynomial or rational method.

    Attributes
    ----------
    freq_hz
        (L,) centre frequency of each window [Hz].
    bins
        (L,) its DFT bin of the n-sample record.
    frf
        (L, Ny, Nu) G [unit of y / unit of u]; NaN where G_ur is singular.
    var
        (L, Ny, Nu) noise variance of G [(unit of G)^2], first order.
    row_cov
        (L, Ny, Nu, Nu) covariance of the entries of each row of G.
    frf_zr
        (L, Nz, Nx) the FRF of the regressed signals z on the
        references x ([y; u] on r in closed loop; y on u in open loop).
    noise_cov
        (L, Nz, Nz) covariance of the noise of Z at one bin,
        E[V V^H] [(unit of z)^2, DFT scaled by n^-1/2].
    transient
        (Ne, L, Nz) the transient T at the centre bin, per
        experiment [unit of z, same DFT scaling].
    power
        (L, Nz) mean of |Z|^2 over the window and the experiments
        [(unit of z)^2, same scaling]: ``1 - noise / power`` is the
        share of z the references explain (a coherence).
    dof
        (L,) q, residual degrees of freedom of ``noise_cov`` at each line.
    rational
        (L,) bool, the LRM was used at that line.
    method
        one of :data:`METHODS`.
    degree
        R, degree of the local polynomials.
    half_width
        h; the window is 2 h + 1 bins.
    n_samples
        n, samples per record.
    n_experiments
        Ne, records pooled.
    output_names, input_names
        (Ny,), (Nu,) labels (may be empty).
    """

    freq_hz: np.ndarray
    bins: np.ndarray
    frf: np.ndarray
    var: np.ndarray
    row_cov: np.ndarray
    frf_zr: np.ndarray
    noise_cov: np.ndarray
    transient: np.ndarray
    power: np.ndarray
    dof: np.ndarray
    rational: np.ndarray
    method: str
    degree: int
    half_width: int
    n_samples: int
    n_experiments: int
    output_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()

    @property
    def sensitivity(self) -> np.ndarray:
        """(L, Nu, Nu) r -> u in closed loop (the lower block of frf_zr) [A/A]."""
        ny = self.frf.shape[1]
        return self.frf_zr[:, ny:, :]


def dof_of(half_width: int, degree: int, n_refs: int, n_experiments: int = 1) -> int:
    """Residual degrees of freedom q of a window: ``Ne (2 h + 1 - (R + 1)) - (R + 1) Nx``.

    Examples
    --------
    >>> dof_of(3, 2, 1)                # 7 bins less 3 coefficients each for G and the transient
    1
    """
    return n_experiments * (2 * half_width + 1 - (degree + 1)) - (degree + 1) * n_refs


def half_width_for(degree: int, n_refs: int, n_experiments: int = 1, dof: int = DEFAULT_DOF) -> int:
    """The smallest half width h whose window leaves at least ``dof`` degrees of freedom.

    Examples
    --------
    >>> half_width_for(2, 1), half_width_for(2, 4)
    (7, 11)
    >>> dof_of(half_width_for(2, 4), 2, 4) >= DEFAULT_DOF
    True
    """
    h = 1
    while dof_of(h, degree, n_refs, n_experiments) < dof:
        h += 1
    return h


def f_quantile(level: float, dof) -> np.ndarray | float:
    """k such that ``P(|G - G0|^2 <= k var) = level`` for a complex estimate whose variance has q dof.

    ``|dG|^2 / var`` follows F(2, 2q) when var is estimated with q complex
    degrees of freedom independently of G (least squares, Gaussian noise).
    ``dof`` may be an array (one q per line).

    Examples
    --------
    >>> round(float(f_quantile(0.95, 10)), 4)
    3.4928
    """
    q = np.asarray(dof)
    if not 0 < level < 1 or np.any(q < 1):
        raise ValueError(f"need 0 < level < 1 and dof >= 1, got {level}, {dof}")
    k = special.fdtri(2, 2 * q, level)
    return float(k) if np.ndim(k) == 0 else k


# ------------------------------------------------------------------ helpers

def _records(name: str, x: np.ndarray | None, n_ch: int | None = None) -> np.ndarray | None:
    """(n, ch) or (Ne, n, ch) -> (Ne, n, ch) float; NaN/inf refused."""
    if x is None:
        return None
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"{name} must have shape (n_samples, n_ch) or (Ne, n_samples, n_ch), got {np.shape(x)}")
    if n_ch is not None and a.shape[2] != n_ch:
        raise ValueError(f"{name} must have {n_ch} channels, got {a.shape[2]}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf; clean the record before estimating")
    return a


def _right_solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """a b^-1 for stacks (..., n, k), (..., k, k), and b^-1; NaN where b is (near) singular."""
    sv = np.linalg.svd(b, compute_uv=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        bad = ~(sv[..., -1] / sv[..., 0] > _RCOND_MIN)
    eye = np.eye(b.shape[-1])
    inv = np.linalg.inv(np.where(bad[..., None, None], eye, b))
    inv = np.where(bad[..., None, None], np.nan, inv)
    return a @ inv, inv


def _basis(offsets: np.ndarray, degree: int, scale: float) -> np.ndarray:
    """(w, R + 1) local polynomial basis (s / scale)^j (scaled for conditioning)."""
    return (offsets[:, None] / scale) ** np.arange(degree + 1)[None, :]


def _projector(k_t: np.ndarray) -> np.ndarray:
    """Orthogonal projector (w, w) onto the complement of the columns of k_t (w, R + 1)."""
    q, _ = np.linalg.qr(k_t)
    return np.eye(k_t.shape[0]) - q @ q.T


# ------------------------------------------------------------------ arbitrary excitation

def window_centres(n_samples: int, fs_hz: float, band_hz: tuple[float, float] | None, half_width: int) -> np.ndarray:
    """(L,) DFT bins (of n samples) at the centres of the non-overlapping windows of 2 h + 1 bins tiling the band.

    Raises
    ------
    ValueError
        the band holds fewer bins than one window.

    Examples
    --------
    >>> window_centres(1000, 1000.0, (10.0, 50.0), 3)   # windows of 7 bins of 1 Hz, none overlapping
    array([13, 20, 27, 34, 41])
    """
    n, h = int(n_samples), int(half_width)
    w = 2 * h + 1
    k_lo, k_hi = 1, (n - 1) // 2
    if band_hz is not None:
        k_lo = max(k_lo, int(np.ceil(band_hz[0] * n / fs_hz - 1e-9)))
        k_hi = min(k_hi, int(np.floor(band_hz[1] * n / fs_hz + 1e-9)))
    if k_hi - k_lo + 1 < w:
        raise ValueError(f"the band holds {max(k_hi - k_lo + 1, 0)} bins of the {n}-sample record, fewer than one "
                         f"window of {w}; record longer or widen the band")
    return np.arange(k_lo + h, k_hi - h + 1, w, dtype=np.int64)


def local_frf(y: np.ndarray, u: np.ndarray, r: np.ndarray | None = None, *, fs_hz: float,
              band_hz: tuple[float, float] | None = None, degree: int = 2, half_width: int | None = None,
              method: str = "lpm", dof: int = DEFAULT_DOF, output_names=(), input_names=()) -> LocalFrf:
    """FRF u -> y with its noise covariance from records of any excitation (module docstring).

    Args:
        y: outputs, (n, Ny) or (Ne, n, Ny) [unit of y, e.g. m].
        u: inputs, same leading shape, Nu channels [e.g. A].
        r: the known excitation, same shape as u: closed loop, indirect
            (``G = G_yr G_ur^-1``). None: open loop, u is the reference.
        fs_hz: sample rate [Hz].
        band_hz: (f_lo, f_hi) band of the window centres [Hz]; default all
            bins from the first window to Nyquist.
        degree: R, degree of the local polynomials (2 is the usual choice).
        half_width: h (window 2 h + 1 bins); default the least leaving
            ``dof`` degrees of freedom (:func:`half_width_for`).
        method: 'lpm' (local polynomial), 'lrm' (local rational: better
            where a resonance is narrower than the window) or 'auto' (the LRM
            where it pays, :data:`METHODS`).
        dof: residual degrees of freedom of the default window.
        output_names, input_names: labels.

    Returns:
        :class:`LocalFrf`, one estimate per non-overlapping window in the band.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if isinstance(degree, bool) or int(degree) != degree or degree < 0:
        raise ValueError(f"degree must be an integer >= 0, got {degree!r}")
    if not fs_hz > 0:
        raise ValueError(f"fs_hz must be > 0, got {fs_hz}")
    y = _records("y", y)
    u = _records("u", u)
    r = _records("r", r, u.shape[2])
    if u.shape[:2] != y.shape[:2] or (r is not None and r.shape != u.shape):
        raise ValueError("y, u (and r) must share (Ne, n_samples), got "
                         + ", ".join(f"{k}{v.shape}" for k, v in (("y", y), ("u", u), ("r", r)) if v is not None))
    ne, n, ny = y.shape
    nu = u.shape[2]
    z = np.concatenate([y, u], axis=2) if r is not None else y
    x = r if r is not None else u
    nx = x.shape[2]
    h = half_width_for(degree, nx, ne, dof) if half_width is None else int(half_width)
    q = dof_of(h, degree, nx, ne)
    if h < 1 or q - (degree if method != "lpm" else 0) < 1:
        raise ValueError(f"a window of {2 * h + 1} bins with degree {degree} leaves {q} degrees of freedom for "
                         f"{nx} references and {ne} experiment(s); widen half_width")
    w = 2 * h + 1
    centres = window_centres(n, fs_hz, band_hz, h)
    zf = np.fft.fft(z, axis=1) / np.sqrt(n)
    xf = np.fft.fft(x, axis=1) / np.sqrt(n)
    offsets = np.arange(-h, h + 1)
    idx = centres[:, None] + offsets[None, :]                              # (L, w)
    zw = zf[:, idx]                                                         # (Ne, L, w, Nz)
    xw = xf[:, idx]                                                         # (Ne, L, w, Nx)
    k_t = _basis(offsets.astype(float), degree, max(h, 1))                 # (w, R+1)
    proj = _projector(k_t)
    # regressors: x(k+s) (s/h)^j, j = 0..R, the s^0 block first (it is G at the centre)
    xr = np.concatenate([xw * k_t[None, None, :, j, None] for j in range(degree + 1)], axis=3)
    xt = proj @ xr                                                          # transient projected out
    zt = proj @ zw
    n_lines = centres.size
    xs = np.moveaxis(xt, 0, 1).reshape(n_lines, ne * w, -1)                # experiments stacked
    zs = np.moveaxis(zt, 0, 1).reshape(n_lines, ne * w, z.shape[2])
    xp = np.linalg.pinv(xs)                                                 # (L, p, Ne w)
    theta = xp @ zs                                                         # (L, p, Nz): the LPM
    resid = zs - xs @ theta
    q_line = np.full(n_lines, q)
    d2 = np.ones((n_lines, ne * w))                                         # |D(s)|^2 at each stacked bin
    d_poly = np.ones((n_lines, w), complex)
    if method != "lpm":
        theta, resid, d2, d_poly, q_line = _rational_where_it_pays(
            method, proj, zw, k_t, zs, xs, xp, theta, resid, d2, d_poly, q_line, degree, q)
    c_v = (np.swapaxes(resid, 1, 2) @ resid.conj()) / q_line[:, None, None]
    # the errors of theta are xp (D V): its covariance is xp diag|D|^2 xp^H times C_V
    q_full = (xp * d2[:, None, :]) @ np.swapaxes(xp.conj(), -1, -2)
    q_g = q_full[:, :nx, :nx]
    g_zr = np.swapaxes(theta[:, :nx, :], 1, 2)                              # (L, Nz, Nx)
    # transient at the centre, per experiment: M(0) of D Z = N X + M (D = 1 for the LPM)
    rest = d_poly[None, :, :, None] * zw - xr @ theta[None]
    transient = np.tensordot(rest, np.linalg.pinv(k_t)[0], axes=([2], [0]))
    if r is not None:
        g, m = _right_solve(g_zr[:, :ny, :], g_zr[:, ny:, :])
        a = np.concatenate([np.broadcast_to(np.eye(ny), (n_lines, ny, ny)), -g], axis=2)   # (L, Ny, Nz)
    else:
        g, m = g_zr, np.broadcast_to(np.eye(nu), (n_lines, nu, nu))
        a = np.broadcast_to(np.eye(ny), (n_lines, ny, ny))
    out_var = np.real(np.einsum("lia,lab,lib->li", a, c_v, a.conj()))       # (L, Ny)
    in_cov = np.einsum("lpj,lpq,lqk->ljk", m, q_g, m.conj())                 # (L, Nu, Nu)
    row_cov = out_var[:, :, None, None] * in_cov[:, None, :, :]
    var = np.real(np.diagonal(row_cov, axis1=2, axis2=3)).copy()
    return LocalFrf(freq_hz=centres * fs_hz / n, bins=centres.astype(np.int64), frf=g, var=var, row_cov=row_cov,
                    frf_zr=g_zr, noise_cov=c_v, transient=transient,
                    power=np.mean(np.abs(zw) ** 2, axis=(0, 2)), dof=q_line.astype(np.int64),
                    rational=q_line < q, method=method, degree=int(degree),
                    half_width=h, n_samples=n, n_experiments=ne, output_names=tuple(output_names),
                    input_names=tuple(input_names))


def _rational_where_it_pays(method: str, proj: np.ndarray, zw: np.ndarray, k_t: np.ndarray, zs: np.ndarray,
                            xs: np.ndarray, xp: np.ndarray, theta: np.ndarray, resid: np.ndarray, d2: np.ndarray,
                            d_poly: np.ndarray, q_line: np.ndarray, degree: int, q: int) -> tuple:
    """The local rational method's estimate where it is used (every line for 'lrm', where it pays for 'auto').

    Returns theta, residual, |D|^2 at each stacked bin, D over the window and degrees of freedom per line.
    """
    ne, n_lines, w = zw.shape[:3]
    n_stack = ne * w
    nz = zw.shape[3]
    psi = proj @ (zw[..., None] * k_t[None, None, :, None, 1:]).reshape(ne, n_lines, w, nz * degree)
    psi = np.moveaxis(psi, 0, 1).reshape(n_lines, n_stack, nz, degree)
    scale = np.sqrt(np.maximum(np.mean(np.abs(resid) ** 2, axis=1), 1e-300))     # (L, Nz)
    p_x = np.eye(n_stack)[None] - xs @ xp
    d = _denominator(resid, (p_x @ psi.reshape(n_lines, n_stack, nz * degree)).reshape(psi.shape), scale)
    zd = zs + (psi @ d[:, None, :, None])[..., 0]                       # D(s) Z, transient projected out
    theta_r = xp @ zd
    dp = 1.0 + k_t[:, 1:] @ d[..., None]                                # (L, w, 1)
    dp = dp[..., 0]
    d2_r = np.tile(np.abs(dp) ** 2, (1, ne))
    resid_r = (zd - xs @ theta_r) / np.sqrt(d2_r)[..., None]           # the residual D V, back to V
    weight = 1.0 / scale[:, None, :] ** 2
    use = np.full(n_lines, method == "lrm")
    if method == "auto":
        use = _rational_pays(np.sum(np.abs(resid) ** 2 * weight, axis=(1, 2)),
                             np.sum(np.abs(resid_r) ** 2 * weight, axis=(1, 2)), degree, q - degree, zw.shape[3])
    theta = np.where(use[:, None, None], theta_r, theta)
    resid = np.where(use[:, None, None], resid_r, resid)
    d2 = np.where(use[:, None], d2_r, d2)
    d_poly = np.where(use[:, None], dp, d_poly)
    q_line = np.where(use, q - degree, q)
    return theta, resid, d2, d_poly, q_line


def _denominator(zbar: np.ndarray, psibar: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The local denominator's coefficients d (L, Rd) shared by the channels, by linear least squares.

    ``D(s) Z = N(s) X + M(s)`` with ``D(s) = 1 + sum_i d_i (s/h)^i`` is
    linear in (N, M, d) (McKelvey & Guérin): with N and M projected out,
    ``zbar = -psibar d + e``. The channels are weighted by ``1 / scale`` (the
    LPM's residual level), so that no unit dominates d.

    Parameters
    ----------
    zbar
        (L, V, Nz) data with the numerators projected out.
    psibar
        (L, V, Nz, Rd) the denominator's regressors (s/h)^i Z, projected alike.
    scale
        (L, Nz) each channel's residual level.
    """
    n_lines, v, nz, rd = psibar.shape
    psi = (psibar / scale[:, None, :, None]).reshape(n_lines, v * nz, rd)
    zb = (zbar / scale[:, None, :]).reshape(n_lines, v * nz, 1)
    psi_h = np.conj(np.swapaxes(psi, 1, 2))
    a_mat = psi_h @ psi
    b_vec = (psi_h @ zb)[..., 0]
    ridge = (1e-12 * np.real(np.trace(a_mat, axis1=1, axis2=2))[:, None, None] + 1e-300) * np.eye(a_mat.shape[-1])
    return -np.linalg.solve(a_mat + ridge, b_vec[..., None])[..., 0]


def _rational_pays(rss_lpm: np.ndarray, rss_lrm: np.ndarray, n_extra: int, dof_lrm: int, n_ch: int,
                   alpha: float = 1e-3) -> np.ndarray:
    """(L,) bool: the rational model's smaller residual is significant (F test at level alpha).

    The LPM is the LRM with d = 0; the weighted residual sums (each channel
    divided by its LPM residual level) have about Nz q complex degrees of
    freedom, the denominator adds Rd complex parameters.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        f = ((rss_lpm - rss_lrm) / n_extra) / (rss_lrm / (n_ch * dof_lrm))
    return np.nan_to_num(f, nan=0.0) > special.fdtri(2 * n_extra, 2 * n_ch * dof_lrm, 1 - alpha)


# ------------------------------------------------------------------ periodic records without settling periods

@dataclass(frozen=True)
class TransientFree:
    """Line spectra of periodic segments with their transient removed (:func:`periodic_transient_removal`).

    Attributes
    ----------
    spectra
        (..., L, ch) the mean over the P periods of each line, in
        the amplitude scaling of :func:`ambid.frf.periods.period_spectra`
        (2/N times the DFT of one period), transient removed [unit of x].
    noise_cov
        (..., L, ch, ch) covariance of the noise of ``spectra``
        [(unit of x)^2], from the residuals at the bins between the lines.
    dof
        (..., L) degrees of freedom of ``noise_cov``.
    rational
        (..., L) bool, the transient was fitted by a local rational model there.
    noise_var_time
        (..., ch) variance of each channel's noise in the
        time domain [(unit of x)^2], from the same residuals over every
        bin up to Nyquist (Parseval).
    transient
        (..., L, ch) the transient removed at each line (same scaling as spectra).
    """

    spectra: np.ndarray
    noise_cov: np.ndarray
    dof: np.ndarray
    rational: np.ndarray
    noise_var_time: np.ndarray
    transient: np.ndarray


def periodic_window(n_periods: int, half_width: int = 2) -> np.ndarray:
    """Bin offsets (relative to a line P l) of the window between the lines: |s| < (h + 1) P, s not a multiple of P."""
    p, h = int(n_periods), int(half_width)
    s = np.arange(-(h + 1) * p + 1, (h + 1) * p)
    return s[s % p != 0]


class _TransientFit:
    """The local fit of a transient alone (no regressors) on a fixed window of offsets."""

    def __init__(self, offsets: np.ndarray, degree: int, method: str) -> None:
        self.offsets = np.asarray(offsets)
        self.k_t = _basis(offsets.astype(float), degree, float(np.abs(offsets).max()))
        self.pinv = np.linalg.pinv(self.k_t)                                   # (R+1, w)
        self.resid_op = np.eye(offsets.size) - self.k_t @ self.pinv
        self.degree, self.method = degree, method
        self.q = offsets.size - (degree + 1)
        if self.q - (degree if method != "lpm" else 0) < 1:
            raise ValueError(f"{offsets.size} bins between the lines leave no degrees of freedom for degree "
                             f"{degree}; widen half_width")

    def __call__(self, win: np.ndarray) -> tuple[np.ndarray, ...]:
        """win (..., w, ch) -> T(0) (..., ch), residuals as V (..., w, ch), |D|^2 (..., w), dof (...), rational (...)."""
        shape, (w, n_ch) = win.shape[:-2], win.shape[-2:]
        flat = win.reshape((-1, w, n_ch))                                       # (F, w, ch)
        t0 = self.pinv[0] @ flat                                                 # (F, ch)
        res = self.resid_op @ flat
        d2 = np.ones((flat.shape[0], w))
        q = np.full(flat.shape[0], self.q)
        use = np.zeros(flat.shape[0], bool)
        if self.method != "lpm":
            r = self.degree
            scale = np.sqrt(np.maximum(np.mean(np.abs(res) ** 2, axis=1), 1e-300))
            psi = flat[..., None] * self.k_t[None, :, None, 1:]                 # (F, w, ch, R)
            psibar = (self.resid_op @ psi.reshape(-1, w, n_ch * r)).reshape(psi.shape)
            d = _denominator(res, psibar, scale)
            zd = flat + np.einsum("fwai,fi->fwa", psi, d, optimize=True)        # D(s) Z
            dp = 1.0 + d @ self.k_t[:, 1:].T                                    # (F, w)
            res_r = (self.resid_op @ zd) / np.abs(dp)[..., None]
            use = np.full(flat.shape[0], self.method == "lrm")
            if self.method == "auto":
                weight = 1.0 / scale[:, None, :] ** 2
                use = _rational_pays(np.sum(np.abs(res) ** 2 * weight, axis=(1, 2)),
                                     np.sum(np.abs(res_r) ** 2 * weight, axis=(1, 2)), r, self.q - r, n_ch)
            t0 = np.where(use[:, None], self.pinv[0] @ zd, t0)                  # M(0) = T(0) D(0), D(0) = 1
            res = np.where(use[:, None, None], res_r, res)
            d2 = np.where(use[:, None], np.abs(dp) ** 2, d2)
            q = np.where(use, self.q - r, q)
        return (t0.reshape(shape + (n_ch,)), res.reshape(shape + (w, n_ch)), d2.reshape(shape + (w,)),
                q.reshape(shape), use.reshape(shape))


_SMOOTH = 10


def _running_median(x: np.ndarray, half: int) -> np.ndarray:
    """Median over the 2 half + 1 neighbours along axis -2 (fewer at the ends)."""
    n = x.shape[-2]
    pad = np.concatenate([np.repeat(x[..., :1, :], half, axis=-2), x, np.repeat(x[..., -1:, :], half, axis=-2)],
                         axis=-2)
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1, axis=-2)   # (..., n, ch, 2h+1)
    return np.median(win, axis=-1)[..., :n, :]


def line_noise(spec: np.ndarray, n_per_period: int, n_periods: int, fit: _TransientFit | None = None,
               half_width: int = 2) -> np.ndarray:
    """Noise variance of one bin of a segment's DFT around every period line, from local fits between the lines.

    Parameters
    ----------
    spec
        (..., P N, ch) unscaled DFT of segments of P periods of N samples [unit of x].
    n_per_period, n_periods
        N, P.
    fit
        the local polynomial fit to use (default degree 2 over :func:`periodic_window` (P, half_width)).

    Returns
    -------
    (..., N/2 + 1, ch) E|V(P l)|^2 at the lines l = 0..N/2 [(unit of x)^2, unscaled DFT], from the residuals
    of the bins between the lines; a running median over 2 * 10 + 1 lines (scaled to the mean of chi^2 with
    2 q dof) keeps the smooth noise spectrum, not the windows a sharp transient still leaks into.
    """
    n, p = int(n_per_period), int(n_periods)
    fit = _TransientFit(periodic_window(p, half_width), 2, "lpm") if fit is None else fit
    offsets = fit.offsets
    all_lines = np.arange(n // 2 + 1)
    _, res_all, _, dof_all, _ = fit(spec[..., (p * all_lines[:, None] + offsets[None, :]) % (p * n), :])
    per_bin = np.sum(np.abs(res_all) ** 2, axis=-2) / dof_all[..., None]   # (..., N/2+1, ch)
    return _running_median(per_bin, _SMOOTH) / ((2 * special.gammaincinv(fit.q, 0.5)) / (2 * fit.q))


def _time_noise(per_bin: np.ndarray, n_per_period: int) -> np.ndarray:
    """(..., ch) mean over the two-sided spectrum of :func:`line_noise` (Parseval: N P times the time variance)."""
    n = int(n_per_period)
    all_lines = np.arange(n // 2 + 1)
    weight = np.where((all_lines == 0) | (2 * all_lines == n), 1.0, 2.0)
    return np.einsum("l,...lc->...c", weight, per_bin) / weight.sum()


def periodic_transient_removal(x: np.ndarray, n_per_period: int, lines: np.ndarray, degree: int = 2,
                               half_width: int = 2, method: str = "auto") -> TransientFree:
    """Remove the transient from P >= 2 periods of a periodic experiment measured from its start.

    The segment's DFT over all P N samples is the excitation's response at
    the bins P l, and transient plus noise at the other bins. Around each
    line the transient is fitted over the bins between the period lines
    within ``half_width`` lines on each side (:func:`periodic_window`), by a
    polynomial of degree R, or a rational function where that pays (a
    lightly damped closed-loop pole makes the transient sharper than the
    window), and its value at P l subtracted. Bins beyond 0 or Nyquist are
    taken from the two-sided DFT (a real signal's spectrum and its transient
    run on smoothly there).

    Parameters
    ----------
    x
        (..., P N, ch) time samples of one or more segments, each from the
        first sample of its excitation [unit of x].
    n_per_period
        N.
    lines
        (L,) period lines l (DFT bins of one period), 0 <= l <= N/2.
    degree
        R.
    half_width
        lines on each side whose in-between bins are used.
    method
        one of :data:`METHODS`.

    Returns
    -------
    :class:`TransientFree`; its noise covariance has
    ``q = len(periodic_window(P, half_width)) - (R + 1)`` degrees of
    freedom (R fewer where the rational model was used).
    """
    x = np.asarray(x, dtype=float)
    n = int(n_per_period)
    if x.ndim < 2 or n < 1 or x.shape[-2] % n or x.shape[-2] // n < 2:
        raise ValueError(f"x must be (..., P N, ch) with P >= 2 periods of N = {n} samples, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x contains NaN or inf; clean the record before estimating")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    p = x.shape[-2] // n
    n_seg = p * n
    lines = np.asarray(lines, dtype=np.int64)
    if lines.ndim != 1 or (lines.size and (lines.min() < 0 or lines.max() > n // 2)):
        raise ValueError(f"lines must be 1-D bins in [0, {n // 2}], got {lines!r}")
    offsets = periodic_window(p, half_width)
    fit = _TransientFit(offsets, degree, method)
    spec = np.fft.fft(x, axis=-2)                                           # (..., P N, ch), unscaled
    centre = p * lines
    t_hat, res, d2, dof, rational = fit(spec[..., (centre[:, None] + offsets[None, :]) % n_seg, :])
    cov_bin = np.einsum("...lva,...lvb->...lab", res, res.conj()) / dof[..., None, None]
    # var(T_hat(0)) per unit of noise variance per bin: sum_s |pinv_0s|^2 |D(s)|^2
    lever = np.einsum("w,...w->...", fit.pinv[0] ** 2, d2)
    # amplitude scaling of period_spectra for the mean over P periods: 2/(N P) (1/(N P) at DC and Nyquist)
    sc = np.where((lines == 0) | (2 * lines == n), 1.0, 2.0) / n_seg
    spectra = (spec[..., centre, :] - t_hat) * sc[:, None]
    noise_cov = cov_bin * ((1.0 + lever) * sc ** 2)[..., None, None]
    # time-domain noise: windows centred on every line 0..N/2 tile the two-sided spectrum (Parseval)
    mean_bin = _time_noise(line_noise(spec, n, p, fit), n)
    return TransientFree(spectra=spectra, noise_cov=noise_cov, dof=dof, rational=rational,
                         noise_var_time=mean_bin / n_seg, transient=t_hat * sc[:, None])
