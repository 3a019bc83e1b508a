"""The transient of periodic segments measured without settling periods, by one rational model across the spectrum.

A segment of P periods of a periodic excitation, measured from the switch of
the excitation (no settling periods), is the loop's periodic steady state
plus its free response from the difference of the initial state and the
steady state's, ``C A^t e``. With the unscaled DFT of the n = P N samples,
``X(k) = sum_t x(t) zeta_k^t``, ``zeta_k = exp(-2j pi k / n)``, every bin
holds exactly::

    X(k) = X_p(k) + T(k),    T_c(k) = C_c (I - zeta_k A)^-1 (I - A^n) e = I_c(zeta_k) / A(zeta_k)

(the free response's end state ``A^n e`` is what the record's window cuts
off: transient and leakage are one term). ``A(zeta) = det(I - zeta A)`` is
the closed loop's characteristic polynomial, common to every channel,
segment and experiment; deg I_c < deg A. X_p is zero except at the period
lines k = P l, so the bins between the lines hold T and the noise alone,
over the whole spectrum. (Pintelon & Schoukens, *System Identification: A
Frequency Domain Approach*, 2nd ed., 2012: the transient term shares the
system's denominator.)

Estimation (:func:`global_transient_removal`):

1. The poles (the roots of A) by vector fitting in the z domain (Gustavsen &
   Semlyen, IEEE Trans. Power Delivery 14, 1999; the relaxed form,
   Gustavsen, ibid. 21, 2006) on the bins between the lines of all segments
   and channels at once, up to 1.5 times the highest line, each bin weighted
   by the inverse of the noise's standard deviation there
   (:func:`ambid.frf.lpm.line_noise`). T is written in partial fractions,
   ``T_c(zeta) = sum_i r_ci / (1 - p_i zeta) + sum_m d_cm zeta^m``: the
   polynomial part (degree ``n_poly``) takes the poles that die within a few
   samples and those above the fitted bins.
2. Per segment and channel the residues r and d (real coefficients for the
   conjugate pairs: the signal is real) by weighted linear least squares on
   the same bins, and T subtracted at the lines. A few dozen parameters per
   channel against hundreds of bins: the subtraction adds about 1 % to the
   variance of the median line (more at the lowest lines and near lightly
   damped poles), where local polynomial fits add 13 to 18 %.
3. The noise covariance of each line, from the residuals of the bins
   between the lines around it (:func:`ambid.frf.lpm.periodic_window`), plus the
   covariance of the subtracted transient: T_hat is linear in the noise of
   the fitted bins (not of the line), so to first order ``E[dT_a dT_b^*] =
   phi^T R_a^-1 Q_a^T S_ab Q_b R_b^-T conj(phi)`` exactly, with S_ab the
   noise's cross-spectrum (smoothed residuals pooled over the segments). The
   poles are taken as known: fitted on all segments at once, their error is
   second order.
4. Where the model misses the bins around a line (a lightly nonlinear loop's
   transient is not exactly rational; a pole the fit did not place), a local
   polynomial fitted to the model's residuals there is significant (F test
   at 0.1 %): it is added to the model at that line, with the local
   method's variance.

Pure numpy; vectorised over segments and lines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special  # not scipy.stats: ~0.6 s to import on the path of `ambid fit`

from ambid.frf.lpm import (METHODS, TransientFree, _TransientFit, _time_noise, line_noise, periodic_transient_removal,
                           periodic_window)

__all__ = ["TransientModel", "TransientFits", "GlobalTransientFree", "SegmentTransients", "vector_fit_poles",
           "fit_transients", "global_transient_removal", "fit_band_bins", "spectrum_top", "check_model_size",
           "DEFAULT_PAIRS", "DEFAULT_REAL", "DEFAULT_POLY", "BAND_MARGIN", "N_ITERATIONS"]

#: starting poles of the vector fit: complex pairs and real poles, log-spaced over the fitted band (the default
#: rig's closed loop has 6 pole pairs and 2 real poles slower than 1 ms below 1.5 kHz; spare poles cost little,
#: too few merge close modes)
DEFAULT_PAIRS, DEFAULT_REAL = 16, 4
#: degree of the polynomial part (poles faster than a few samples, poles above the fitted bins)
DEFAULT_POLY = 2
#: the fit covers the bins up to this multiple of the highest line (a lightly damped pole just above the band
#: shapes the transient inside it)
BAND_MARGIN = 1.5
#: vector-fitting iterations (the default experiment's FRF error is the same from 3 to 12; 8 leaves a margin for
#: loops with more poles)
N_ITERATIONS = 8
#: poles this fast (|p|, per sample) die within a sample or two: the polynomial part takes them
_P_MIN = 0.3
#: level of the F test for a local correction
_ALPHA = 1e-3
#: half width [bins] of the running mean that smooths the residuals' cross-spectrum
_SMOOTH_BINS = 20


@dataclass(frozen=True)
class TransientModel:
    """The poles of the transient and the form of its partial fractions.

    Attributes
    ----------
    poles
        (n,) z-domain poles of the segment's sampling, one of each conjugate pair (Im >= 0), |p| < 1.
    n_poly
        degree of the polynomial part.
    """

    poles: np.ndarray
    n_poly: int

    @property
    def n_params(self) -> int:
        """Real coefficients per channel and segment: one per real pole, two per pair, n_poly + 1."""
        n_cplx = int(np.count_nonzero(self.poles.imag > 0))
        return self.poles.size + n_cplx + self.n_poly + 1

    def basis(self, zeta: np.ndarray) -> np.ndarray:
        """(K, n_params) complex basis at zeta (K,): 1/(1 - p zeta) for real p; f + g and j (f - g) for a pair
        (f, g its two partial fractions); zeta^m, m = 0..n_poly. Real coefficients make a real signal's T."""
        return _basis(self.poles, zeta, self.n_poly)


def _basis(poles: np.ndarray, zeta: np.ndarray, n_poly: int) -> np.ndarray:
    cplx = poles.imag > 0
    f = 1.0 / (1.0 - poles[None, :] * zeta[:, None])                          # (K, n)
    g = 1.0 / (1.0 - np.conj(poles[None, cplx]) * zeta[:, None])
    fc = f[:, cplx]
    return np.concatenate([f[:, ~cplx], fc + g, 1j * (fc - g), zeta[:, None] ** np.arange(n_poly + 1)], axis=1)


def _stack(x: np.ndarray) -> np.ndarray:
    """Complex (..., K, m) -> real (..., 2K, m): real parts over imaginary parts (least squares with real unknowns)."""
    return np.concatenate([x.real, x.imag], axis=-2)


def _clean_poles(z: np.ndarray) -> np.ndarray:
    """Poles from the zeros of sigma: reflected into the unit circle, the fastest dropped, one of each pair,
    distinct."""
    z = np.asarray(z, complex)
    out = np.abs(z) >= 1.0
    z[out] = 1.0 / np.conj(z[out])
    z = z[np.abs(z) >= _P_MIN]
    tol = 1e-9
    real = np.abs(z.imag) <= tol * np.maximum(np.abs(z), 1.0)
    reals = np.sort(z[real].real)
    pairs = z[~real & (z.imag > 0)]
    keep = []
    for p in reals:   # two real zeros at one place (a pair split by rounding) would make the basis singular
        if not keep or abs(p - keep[-1]) > 1e-7:
            keep.append(p)
    pairs = pairs[np.argsort(np.angle(pairs))]
    kp = []
    for p in pairs:
        if not kp or abs(p - kp[-1]) > 1e-7:
            kp.append(p)
    return np.concatenate([np.asarray(keep, complex), np.asarray(kp, complex)])


def _start_poles(f_lo: float, f_hi: float, n_samples: int, n_pairs: int, n_real: int) -> np.ndarray:
    """Starting poles log-spaced over [f_lo, f_hi] (frequencies in bins of the segment), damping 1 %."""
    f = np.geomspace(f_lo, f_hi, n_pairs) / n_samples * 2 * np.pi            # rad/sample
    pairs = np.exp((-0.01 + 1j) * f)
    reals = np.exp(-np.geomspace(f_lo, f_hi, n_real) / n_samples * 2 * np.pi) if n_real else np.zeros(0)
    return np.concatenate([reals.astype(complex), pairs])


def vector_fit_poles(spectra: np.ndarray, weight: np.ndarray, bins: np.ndarray, n_samples: int,
                     n_pairs: int = DEFAULT_PAIRS, n_real: int = DEFAULT_REAL, n_poly: int = DEFAULT_POLY,
                     n_iter: int = N_ITERATIONS) -> TransientModel:
    """The poles shared by transients seen at bins that hold nothing else, by relaxed vector fitting.

    Each iteration solves, by linear least squares over all records at once,
    ``sigma(zeta) T_r(zeta) ~ N_r(zeta)`` with ``sigma = d + sum_i c_i / (1 - p_i zeta)``
    and each record's numerator N_r in the current partial fractions
    (eliminated record by record), under ``Re sum_k sigma(zeta_k) = K``; the
    zeros of sigma are the next poles.

    Parameters
    ----------
    spectra
        (S, K, C) unscaled DFT of S records of C channels at ``bins`` [unit of each channel].
    weight
        (K, C) > 0, 1 / the noise's standard deviation at each bin [1 / unit].
    bins
        (K,) DFT bins of the n-sample records, 0 < k < n/2.
    n_samples
        n.
    n_pairs, n_real
        starting complex pairs and real poles, log-spaced over the bins.
    n_poly
        degree of the polynomial part.
    n_iter
        iterations.

    Returns
    -------
    :class:`TransientModel`.
    """
    y = np.asarray(spectra, complex)
    w = np.asarray(weight, float)
    bins = np.asarray(bins)
    _, n_bins, n_ch = y.shape
    zeta = np.exp(-2j * np.pi * bins / n_samples)
    poles = _start_poles(float(bins.min()), float(bins.max()), n_samples, n_pairs, n_real)
    wy = w[None] * y                                                           # (S, K, C)
    power = np.sum(np.abs(wy) ** 2, axis=0)                                     # (K, C)
    lam = np.sqrt(power.sum()) / n_bins                                         # the relaxation row's weight
    for _ in range(n_iter):
        phi = _basis(poles, zeta, n_poly)                                       # (K, nf)
        sig = np.concatenate([_basis(poles, zeta, -1), np.ones((n_bins, 1))], axis=1)   # (K, ns): sigma's basis
        ns = sig.shape[1]
        blocks = []
        for c in range(n_ch):
            q, _ = np.linalg.qr(_stack(w[:, c, None] * phi))                   # (2K, nf)
            m = _stack(wy[:, :, c, None] * sig[None])                           # (S, 2K, ns): [Re; Im](w Y_s sig)
            # the numerators eliminated by projecting each record's M on the complement of Q, formed explicitly,
            # and reduced to R by QR (per record, then stacked): the normal equations' M^T M - M^T Q Q^T M cancel
            # to rounding where the model fits (noise-free data), and the poles then followed the last digits
            proj = m - q @ (q.T @ m)
            blocks.append(np.linalg.qr(np.linalg.qr(proj, mode="r").reshape(-1, ns), mode="r"))   # (ns, ns)
        # the relaxation row, Re sum_k sigma(zeta_k) = K, weighted as one more equation
        row = np.real(sig.sum(axis=0))
        a = np.concatenate(blocks + [lam * row[None]], axis=0)
        rhs = np.zeros(a.shape[0])
        rhs[-1] = lam * n_bins
        scale = np.sqrt(np.maximum(np.sum(a ** 2, axis=0), 1e-300))
        coef = np.linalg.lstsq(a / scale, rhs, rcond=None)[0] / scale
        poles = _sigma_zeros(poles, coef[:-1], coef[-1])
    return TransientModel(poles=poles, n_poly=int(n_poly))


def _sigma_zeros(poles: np.ndarray, c: np.ndarray, d: float) -> np.ndarray:
    """Zeros of sigma(zeta) = d + sum_i c_i / (1 - p_i zeta) (coefficients in :func:`_basis`'s order).

    In z = 1 / zeta, 1 / (1 - p / z) = 1 + p / (z - p): sigma = D + sum_i c_i p_i / (z - p_i), D = d + sum c_i, a
    state-space form whose zeros are the eigenvalues of diag(p) - 1 (c p)^T / D.
    """
    cplx = poles.imag > 0
    n_r, n_c = int(np.count_nonzero(~cplx)), int(np.count_nonzero(cplx))
    res = np.concatenate([c[:n_r], c[n_r:n_r + n_c] + 1j * c[n_r + n_c:], c[n_r:n_r + n_c] - 1j * c[n_r + n_c:]])
    p = np.concatenate([poles[~cplx], poles[cplx], np.conj(poles[cplx])])
    total = d + res.sum()
    if not abs(total) > 0:
        return poles
    zeros = np.linalg.eigvals(np.diag(p) - np.outer(np.ones(p.size), res * p) / total)
    new = _clean_poles(zeros)
    return new if new.size else poles


@dataclass(frozen=True)
class TransientFits:
    """The weighted least-squares fits of one model to every record (:func:`fit_transients`).

    Attributes
    ----------
    q
        (C, K, nf) per channel the rows of Q of ``[Re; Im](w phi) = Q R``, as complex numbers
        (row k of the real part + j row k of the imaginary part) [-].
    r
        (C, nf, nf) per channel R [1 / unit of the channel].
    coef
        (S, nf, C) the real coefficients of each record and channel, :meth:`TransientModel.basis` order
        [unit of the channel].
    resid
        (S, K, C) the residuals Y - T at the fitted bins [unit of the channel, unscaled DFT].
    leverage
        (K, C) the share of a bin's noise power the fit takes, ``(h_re + h_im) / 2`` (summing to
        nf / 2 over the bins) [-].
    """

    q: np.ndarray
    r: np.ndarray
    coef: np.ndarray
    resid: np.ndarray
    leverage: np.ndarray


def fit_transients(model: TransientModel, spectra: np.ndarray, weight: np.ndarray, bins: np.ndarray,
                   n_samples: int) -> TransientFits:
    """Each record's and channel's coefficients by weighted least squares, with its residuals and leverages.

    Parameters
    ----------
    model
        the poles.
    spectra
        (S, K, C) unscaled DFT at ``bins`` [unit of each channel].
    weight
        (K, C) 1 / the noise's standard deviation [1 / unit].
    bins
        (K,) DFT bins of the n-sample records.
    n_samples
        n.
    """
    y = np.asarray(spectra, complex)
    n_bins, n_ch = weight.shape
    phi = model.basis(np.exp(-2j * np.pi * np.asarray(bins) / n_samples))
    qs, rs, coefs, lev = [], [], [], []
    for c in range(n_ch):
        q, r = np.linalg.qr(_stack(weight[:, c, None] * phi))
        data = _stack((weight[None, :, c] * y[:, :, c]).T)                     # (2K, S)
        coefs.append(np.linalg.solve(r, q.T @ data).T)                          # (S, nf)
        qs.append(q[:n_bins] + 1j * q[n_bins:])
        rs.append(r)
        lev.append(0.5 * np.sum(q[:n_bins] ** 2 + q[n_bins:] ** 2, axis=1))
    coef = np.stack(coefs, axis=-1)                                             # (S, nf, C)
    resid = y - np.einsum("kf,sfc->skc", phi, coef)
    return TransientFits(q=np.stack(qs), r=np.stack(rs), coef=coef, resid=resid, leverage=np.stack(lev, axis=1))


def _smooth_bins(x: np.ndarray, half: int) -> np.ndarray:
    """Running mean over 2 half + 1 bins along axis 0 (fewer at the ends)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:], x.dtype), x]), axis=0)
    n = x.shape[0]
    lo = np.clip(np.arange(n) - half, 0, n)
    hi = np.clip(np.arange(n) + half + 1, 0, n)
    return (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1))


def _cross_spectrum(fits: TransientFits) -> np.ndarray:
    """(K, C, C) the noise's cross-spectrum E[V_a V_b^*] at each fitted bin, from the residuals pooled over records
    (each bin's power lost to the fit put back) and smoothed over 2 * 20 + 1 bins."""
    e = fits.resid
    raw = np.einsum("ska,skb->kab", e, e.conj()) / e.shape[0]
    keep = np.sqrt(np.maximum(1.0 - fits.leverage, 0.05))                     # (K, C)
    return _smooth_bins(raw / (keep[:, :, None] * keep[:, None, :]), _SMOOTH_BINS)


def _subtraction_covariance(model: TransientModel, fits: TransientFits, weight: np.ndarray, cross: np.ndarray,
                            zeta_lines: np.ndarray) -> np.ndarray:
    """(L, C, C) covariance E[dT_a dT_b^*] of the transient subtracted at each line (same for every record).

    ``b_c = R_c^-1 Q_c^T [Re; Im](w_c Y_c)``, so ``Cov(b_a, b_b) = R_a^-1 Q_a^T S_ab Q_b R_b^-T`` with S_ab the
    stacked noise's covariance, whose 2 x 2 block at a bin is ``w_a w_b / 2 [[Re s, -Im s], [Im s, Re s]]``
    (circular noise, s = E[V_a V_b^*]): ``Q_a^T S_ab Q_b = 1/2 Re sum_k w_a w_b s conj(q_a)^T q_b``.
    """
    n_ch = weight.shape[1]
    phi = model.basis(zeta_lines)                                               # (L, nf)
    psi = np.stack([np.linalg.solve(fits.r[c].T, phi.T).T for c in range(n_ch)])   # (C, L, nf): phi^T R_c^-1
    wq = weight.T[:, :, None] * fits.q                                          # (C, K, nf)
    out = np.empty((zeta_lines.size, n_ch, n_ch), complex)
    for a in range(n_ch):
        for b in range(a, n_ch):
            mid = 0.5 * np.real((wq[a].conj().T * cross[:, a, b]) @ wq[b])      # (nf, nf)
            out[:, a, b] = np.sum((psi[a] @ mid) * psi[b].conj(), axis=1)
            out[:, b, a] = out[:, a, b].conj()
    return out


def fit_band_bins(n_per_period: int, n_periods: int, lines: np.ndarray, margin: float = BAND_MARGIN) -> np.ndarray:
    """(K,) the bins the model is fitted on: between the period lines, from bin 1 to ``margin`` times the highest
    line (at most below Nyquist)."""
    n, p = int(n_per_period), int(n_periods)
    top = min(int(np.ceil(margin * p * max(int(np.max(lines)), 1))), (p * n - 1) // 2)
    k = np.arange(1, top + 1)
    return k[k % p != 0]


@dataclass(frozen=True)
class GlobalTransientFree(TransientFree):
    """:class:`ambid.frf.lpm.TransientFree` of the global model, with the model and where it was corrected locally.

    Attributes (beyond TransientFree's; ``rational`` is all False here):
        model: the poles (:class:`TransientModel`).
        local: (..., L) bool, a local polynomial on the model's residuals was added at that line (F test).
        lever: (L, ch) variance the subtraction adds to a line, over the line's own noise variance [-] (median
            over the records), what the intervals carry.
    """

    model: TransientModel | None = None
    local: np.ndarray | None = None
    lever: np.ndarray | None = None


def global_transient_removal(x: np.ndarray, n_per_period: int, lines: np.ndarray, *,
                             n_pairs: int = DEFAULT_PAIRS, n_real: int = DEFAULT_REAL, n_poly: int = DEFAULT_POLY,
                             half_width: int = 2, n_iter: int = N_ITERATIONS,
                             margin: float = BAND_MARGIN) -> GlobalTransientFree:
    """Remove the transient from S segments of P >= 2 periods, each measured from its excitation's start.

    One rational model for all (module docstring): the poles by vector
    fitting over every segment and channel, the residues per segment and
    channel, the transient subtracted at the period lines, its noise put into
    each line's covariance; a local correction where the model misses.

    Parameters
    ----------
    x
        (S, P N, ch) or (P N, ch) time samples of the segments [unit of each channel].
    n_per_period
        N.
    lines
        (L,) period lines l analysed, 0 < l < N/2.
    n_pairs, n_real, n_poly
        the vector fit's starting poles and polynomial degree.
    half_width
        lines on each side whose in-between bins give a line's noise (:func:`periodic_window`).
    n_iter
        vector-fitting iterations.
    margin
        the fit covers bins up to ``margin`` times the highest line.

    Returns
    -------
    :class:`GlobalTransientFree` with (S, L, ch) spectra in the amplitude scaling of
    :func:`ambid.frf.periods.period_spectra` (2 / (N P) times the DFT), (S, L, ch, ch) noise covariance,
    (S, L) degrees of freedom, (S, ch) time-domain noise variance.

    Raises
    ------
    ValueError
        bad shapes, fewer than 2 periods, lines at 0 or N/2, NaN, or too few bins for the model.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 2:
        x = x[None]
    n = int(n_per_period)
    if x.ndim != 3 or n < 1 or x.shape[1] % n or x.shape[1] // n < 2:
        raise ValueError(f"x must be (S, P N, ch) with P >= 2 periods of N = {n} samples, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x contains NaN or inf; clean the record before estimating")
    p = x.shape[1] // n
    lines = _check_lines(lines, n)
    check_model_size(n, p, lines, n_pairs, n_real, n_poly, margin)
    spec = np.fft.fft(x, axis=1)
    noise_lines = line_noise(spec, n, p, _TransientFit(periodic_window(p, half_width), 2, "lpm"))
    top = spectrum_top(n, p, lines, half_width, margin)
    return _remove(spec[:, :top], n, p, lines, noise_lines, n_pairs=n_pairs, n_real=n_real, n_poly=n_poly,
                   half_width=half_width, n_iter=n_iter, margin=margin)


def _check_lines(lines: np.ndarray, n: int) -> np.ndarray:
    lines = np.asarray(lines, dtype=np.int64)
    if lines.ndim != 1 or not lines.size or lines.min() < 1 or 2 * lines.max() >= n:
        raise ValueError(f"lines must be 1-D bins in [1, {(n - 1) // 2}], got {lines!r}")
    return lines


def check_model_size(n_per_period: int, n_periods: int, lines: np.ndarray, n_pairs: int = DEFAULT_PAIRS,
                     n_real: int = DEFAULT_REAL, n_poly: int = DEFAULT_POLY, margin: float = BAND_MARGIN) -> None:
    """ValueError if the bins between the lines are too few (under 4 per coefficient) for the model."""
    n_bins = fit_band_bins(n_per_period, n_periods, lines, margin).size
    n_params = 2 * n_pairs + n_real + n_poly + 1
    if n_bins < 4 * n_params:
        raise ValueError(f"{n_bins} bins between the lines up to {margin:g} x the highest line are too few for a "
                         f"model of {n_params} coefficients per channel; measure more periods or a finer "
                         "resolution, or use the local method")


def spectrum_top(n_per_period: int, n_periods: int, lines: np.ndarray, half_width: int = 2,
                 margin: float = BAND_MARGIN) -> int:
    """The bins 0..top-1 of a segment's DFT the removal reads: the fitted bins and every line's window."""
    p = int(n_periods)
    return int(max(fit_band_bins(n_per_period, p, lines, margin).max(), p * (int(np.max(lines)) + half_width + 1))) + 1


def _remove(spec: np.ndarray, n: int, p: int, lines: np.ndarray, noise_lines: np.ndarray, *, n_pairs: int,
            n_real: int, n_poly: int, half_width: int, n_iter: int, margin: float) -> GlobalTransientFree:
    """The removal on the DFT's first bins (S, top, ch) of S segments and their local noise (S, N/2 + 1, ch)."""
    n_seg, _, n_ch = spec.shape
    ns = p * n
    bins = fit_band_bins(n, p, lines, margin)
    noise_var_time = _time_noise(noise_lines, n) / ns
    # the first weights: the local fits' noise, pooled over the segments
    pooled = np.mean(noise_lines, axis=0)                                       # (N/2+1, ch)
    var0 = np.stack([np.interp(bins / p, np.arange(n // 2 + 1), pooled[:, c]) for c in range(n_ch)], axis=1)
    floor = 1e-30 * np.max(var0, axis=0, initial=0.0) + 1e-300
    weight = 1.0 / np.sqrt(np.maximum(var0, floor))
    y = spec[:, bins, :]
    model = vector_fit_poles(y, weight, bins, ns, n_pairs, n_real, n_poly, n_iter)
    fits = fit_transients(model, y, weight, bins, ns)
    # the final weights from the model's own residuals (the local fits overstate the noise where the transient is
    # sharp), then the final coefficients
    cross = _cross_spectrum(fits)
    weight = 1.0 / np.sqrt(np.maximum(np.real(np.diagonal(cross, axis1=1, axis2=2)), floor))
    fits = fit_transients(model, y, weight, bins, ns)
    cross = _cross_spectrum(fits)

    zeta_lines = np.exp(-2j * np.pi * p * lines / ns)
    t_hat = np.einsum("lf,sfc->slc", model.basis(zeta_lines), fits.coef)      # (S, L, ch)
    d_cov = _subtraction_covariance(model, fits, weight, cross, zeta_lines)   # (L, ch, ch)

    # each line's noise: the model's residuals at the bins between the lines around it
    offsets = periodic_window(p, half_width)
    win = p * lines[:, None] + offsets[None, :]                                # (L, w)
    pos = np.minimum(np.searchsorted(bins, win), bins.size - 1)
    inside = bins[pos] == win                                                   # a window reaching below bin 1
    pos = np.where(inside, pos, 0)
    res_w = fits.resid[:, pos, :] * inside[None, :, :, None]                   # (S, L, w, ch)
    keep = np.where(inside[..., None], 1.0 - fits.leverage[pos], 0.0)         # (L, w, ch)
    q_eff = np.min(np.sum(keep, axis=1), axis=-1)                              # (L,) complex dof
    cov_line = np.einsum("slwa,slwb->slab", res_w, res_w.conj()) / q_eff[None, :, None, None]

    # where a local polynomial on those residuals is significant, the model misses: add it there
    local, t_loc, cov_loc, dof_loc = _local_correction(res_w, inside, cov_line, q_eff, offsets)
    t_hat = t_hat + np.where(local[..., None], t_loc, 0.0)
    cov = np.where(local[..., None, None], cov_loc, cov_line + d_cov[None])
    dof = np.where(local, dof_loc, np.floor(q_eff)[None, :]).astype(np.int64)

    sc = 2.0 / ns
    line_var = np.real(np.diagonal(cov_line, axis1=-2, axis2=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        lever = np.median(np.real(np.diagonal(d_cov, axis1=-2, axis2=-1))[None] / line_var, axis=0)
    return GlobalTransientFree(spectra=(spec[:, p * lines, :] - t_hat) * sc, noise_cov=cov * sc ** 2, dof=dof,
                               rational=np.zeros(dof.shape, bool), noise_var_time=noise_var_time,
                               transient=t_hat * sc, model=model, local=local, lever=lever)


def _local_correction(res_w: np.ndarray, inside: np.ndarray, cov_line: np.ndarray, q_eff: np.ndarray,
                      offsets: np.ndarray) -> tuple[np.ndarray, ...]:
    """Where a local polynomial (degree 2) on the model's residuals around a line is significant.

    The residual sums of the model (about q dof) and of the polynomial fitted to its residuals (3 fewer), each
    channel divided by its own level, give ``F = ((rss_0 - rss_1) / (3 C)) / (rss_1 / (C q_1))``, compared with
    F(6 C, 2 C q_1) at :data:`_ALPHA`.

    Returns
    -------
    local (S, L) bool, the polynomial's value at the line (S, L, ch), the local method's covariance there
    (S, L, ch, ch) and its dof (S, L).
    """
    fit = _TransientFit(offsets, 2, "lpm")
    t0, res1, _, q1, _ = fit(res_w)                                            # (S, L, ch), (S, L, w, ch)
    n_ch = res_w.shape[-1]
    level = np.maximum(np.real(np.diagonal(cov_line, axis1=-2, axis2=-1)), 1e-300)   # (S, L, ch)
    rss0 = np.sum(np.abs(res_w) ** 2 / level[:, :, None, :], axis=(2, 3))
    rss1 = np.sum(np.abs(res1) ** 2 / level[:, :, None, :], axis=(2, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = ((rss0 - rss1) / (3.0 * n_ch)) / (rss1 / (n_ch * q1))
    full = np.all(inside, axis=1)[None, :]                                      # windows cut at bin 0: no test
    local = (np.nan_to_num(f, nan=0.0) > special.fdtri(6 * n_ch, 2 * n_ch * q1, 1 - _ALPHA)) & full
    lever = float(fit.pinv[0] @ fit.pinv[0])
    cov1 = np.einsum("slwa,slwb->slab", res1, res1.conj()) / q1[..., None, None] * (1.0 + lever)
    return local, t0, cov1, q1


class SegmentTransients:
    """The periods of each segment of a streamed experiment, and their transient removed.

    For a periodic design measured without settling periods (Pt = 0, P >= 2):
    the P periods of segment s come in order through :meth:`add`. When the
    last one arrives, the segment's DFT is kept at the bins the removal reads
    (:func:`spectrum_top`) with its local noise (:func:`ambid.frf.lpm.line_noise`);
    :attr:`results` then removes the transient of every complete segment by one
    model (:func:`global_transient_removal`), fitted again only when a segment
    was added. Where the design's bins are too few for the model (or
    ``method`` is one of :data:`ambid.frf.lpm.METHODS`), each segment's
    transient is removed by local fits (:func:`ambid.frf.lpm.periodic_transient_removal`)
    as it completes. Memory: one segment's samples, plus per segment its first
    bins (about 1.5 P times the highest line) and L lines. A segment missing
    a period (a gap) is left out.

    Parameters
    ----------
    n_per_period
        N.
    n_periods
        P >= 2.
    lines
        (L,) period lines analysed.
    n_noisy
        the first ``n_noisy`` channels carry noise and a transient
        (y and u); the others (the excitation r, exactly periodic) are
        taken as the mean over the periods.
    method
        'global' (the model across the spectrum) or a local method of :data:`ambid.frf.lpm.METHODS`.
    """

    def __init__(self, n_per_period: int, n_periods: int, lines: np.ndarray, n_noisy: int,
                 method: str = "global") -> None:
        if n_periods < 2:
            raise ValueError(f"transient removal needs P >= 2 periods per segment, got {n_periods}")
        if method != "global" and method not in METHODS:
            raise ValueError(f"method must be 'global' or one of {METHODS}, got {method!r}")
        self.n, self.p, self.n_noisy = int(n_per_period), int(n_periods), int(n_noisy)
        self.lines = np.asarray(lines, dtype=np.int64)
        if method == "global":
            try:
                _check_lines(self.lines, self.n)
                check_model_size(self.n, self.p, self.lines)
            except ValueError:   # too few bins for the model, or a line at 0 or N/2: local fits
                method = "auto"
        self.method = method
        self._top = spectrum_top(self.n, self.p, self.lines) if method == "global" else 0
        self._fit = _TransientFit(periodic_window(self.p), 2, "lpm")
        self._seg: int | None = None
        self._buf: np.ndarray | None = None
        self._next = 0
        self._spec: dict[int, np.ndarray] = {}          # segment -> (top, n_noisy) first bins of its DFT
        self._noise: dict[int, np.ndarray] = {}         # segment -> (N/2+1, n_noisy) local noise per bin
        self._time: dict[int, np.ndarray] = {}          # segment -> (n_noisy,) time-domain noise variance
        self._results: dict[int, TransientFree] = {}    # segment -> noisy channels' result
        self._fitted: tuple[int, ...] = ()
        self.exact: dict[int, np.ndarray] = {}          # segment -> (L, ch - n_noisy) mean of the exact channels

    def add(self, segment: int, period: int, samples: np.ndarray) -> bool:
        """Period ``period`` (0..P-1) of ``segment``: samples (N, ch). True when the segment was completed."""
        if segment != self._seg or period != self._next:
            self._seg, self._next = segment, 0
            if period != 0:           # a period is missing: this segment cannot be used
                self._buf = None
                return False
            self._buf = np.empty((self.p * self.n, samples.shape[1]))
        if self._buf is None:
            return False
        self._buf[period * self.n:(period + 1) * self.n] = samples
        self._next += 1
        if self._next < self.p:
            return False
        x = self._buf
        if self.method == "global":
            spec = np.fft.fft(x[:, :self.n_noisy], axis=0)
            self._spec[segment] = spec[:self._top]
            self._noise[segment] = line_noise(spec, self.n, self.p, self._fit)
            self._time[segment] = _time_noise(self._noise[segment], self.n) / (self.p * self.n)
        else:
            self._results[segment] = periodic_transient_removal(x[:, :self.n_noisy], self.n, self.lines,
                                                                method=self.method)
            self._time[segment] = self._results[segment].noise_var_time
        if x.shape[1] > self.n_noisy:
            k = np.fft.rfft(x[:, self.n_noisy:], axis=0)[self.p * self.lines]
            sc = np.where((self.lines == 0) | (2 * self.lines == self.n), 1.0, 2.0) / (self.p * self.n)
            self.exact[segment] = k * sc[:, None]
        else:
            self.exact[segment] = np.zeros((self.lines.size, 0), complex)
        self._buf, self._seg = None, None
        return True

    def complete(self, segment: int) -> bool:
        return segment in self._time

    def noise_var_time(self, segment: int) -> np.ndarray:
        """(n_noisy,) a completed segment's time-domain noise variance from its local fits [(unit)^2]."""
        return self._time[segment]

    @property
    def results(self) -> dict[int, TransientFree]:
        """Segment -> its noisy channels' transient-free line spectra, for every completed segment."""
        done = tuple(sorted(self._spec))
        if self.method == "global" and done and done != self._fitted:
            g = _remove(np.stack([self._spec[s] for s in done]), self.n, self.p, self.lines,
                        np.stack([self._noise[s] for s in done]), n_pairs=DEFAULT_PAIRS, n_real=DEFAULT_REAL,
                        n_poly=DEFAULT_POLY, half_width=2, n_iter=N_ITERATIONS, margin=BAND_MARGIN)
            self._results = {s: GlobalTransientFree(
                spectra=g.spectra[i], noise_cov=g.noise_cov[i], dof=g.dof[i], rational=g.rational[i],
                noise_var_time=g.noise_var_time[i], transient=g.transient[i], model=g.model, local=g.local[i],
                lever=g.lever) for i, s in enumerate(done)}
            self._fitted = done
        return self._results

    def spectra(self, segment: int) -> np.ndarray:
        """(L, ch) line spectra of a completed segment, transient removed (amplitude scaling)."""
        return np.concatenate([self.results[segment].spectra, self.exact[segment]], axis=1)
