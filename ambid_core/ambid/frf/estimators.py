"""Nonparametric FRF estimators for the full MIMO matrix, open or closed loop.

Conventions. The plant P maps the applied current u (Nu inputs) to the
measured displacement y (Ny outputs). The controller C maps y to the control
current, ``ic = -C y``, and the excitation r is added to it, so
``u = ic + r = r - C y``. Noise on y is fed back through C, so u is
correlated with the noise: in closed loop only :func:`indirect` (dividing
through the known excitation r) is consistent; :func:`h1` tends to ``-C^-1``
where the noise dominates.

Periodic estimators take period spectra from
:func:`ambid.frf.periods.period_spectra`, shape (M, Ne, P, L, n_ch)
(realisations, experiments, periods, lines, channels). At each line the Ne
experiments are stacked as columns: ``Y_k`` is (Ny, Ne) and ``U_k`` (Nu, Ne)
for record ``k = (m, p)``, so ``Y_k = G U_k`` is solved for G with Ne >= Nu
experiments whose reference matrix is invertible (orthogonal multisines or
one input at a time). Cross-spectra are sums over records,
``S_yu = sum_k Y_k U_k^H``. Every estimator returns G of shape (L, Ny, Nu) in
the unit of y per unit of u (e.g. m/A).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "h1", "h2", "arithmetic_mean", "log_mean", "errors_in_variables", "indirect",
    "per_period_frf", "multiple_coherence", "sine_amplitude", "stepped_sine_frf",
    "SpectralFrf", "welch_frf",
]

# Reciprocal condition number below which a per-line matrix is treated as singular.
_RCOND_MIN = 1e-10


# --------------------------------------------------------------------------- helpers

def _spectra(name: str, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    if x.ndim != 5:
        raise ValueError(f"{name} must be period spectra of shape (M, Ne, P, L, n_ch), got shape "
                         f"{x.shape}; use period_spectra(split_periods(...), lines)")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or inf; clean the time data before estimating")
    return x.astype(complex, copy=False)


def _matched(**arrays: np.ndarray) -> dict[str, np.ndarray]:
    """Validate spectra and check they share (M, Ne, P, L); a reference with P = 1
    is broadcast over the periods (a periodic excitation is the same in each)."""
    out = {k: _spectra(k, v) for k, v in arrays.items()}
    first_name, first = next(iter(out.items()))
    for name, x in out.items():
        if x.shape[:4] != first.shape[:4]:
            if x.shape[2] == 1 and x.shape[:2] + x.shape[3:4] == first.shape[:2] + first.shape[3:4]:
                out[name] = np.broadcast_to(x, first.shape[:4] + x.shape[4:])
                continue
            raise ValueError(f"{name} has (M, Ne, P, L) = {x.shape[:4]} but {first_name} has "
                             f"{first.shape[:4]}; both must come from the same experiment and lines")
    return out


def _records(x: np.ndarray) -> np.ndarray:
    """(M, Ne, P, L, ch) -> (M, P, L, ch, Ne): one (ch, Ne) matrix per record and line."""
    return np.moveaxis(x, 1, -1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sum over records and experiments of a b^H: (M, Ne, P, L, na), (.., nb) -> (L, na, nb)."""
    return np.einsum("mepla,meplb->lab", a, b.conj())


def _right_divide(a: np.ndarray, b: np.ndarray, what: str, strict: bool = True) -> np.ndarray:
    """a b^-1 for stacks of matrices, a (..., n, k), b (..., k, k).

    Ill-conditioned b raises (strict) or gives NaN rows (not strict)."""
    sv = np.linalg.svd(b, compute_uv=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        rcond = sv[..., -1] / sv[..., 0]
    bad = ~(rcond > _RCOND_MIN)
    if strict and np.any(bad):
        where = np.argwhere(bad)
        raise ValueError(
            f"{what} is singular or ill-conditioned (reciprocal condition "
            f"{np.nanmin(rcond):.3g}) at {len(where)} matrix/line index(es), first "
            f"{where[:5].tolist()}: every input must be excited at every line used; run Ne >= Nu "
            "experiments with an invertible reference matrix (orthogonal multisines or one input "
            "at a time) and pass only excited lines")
    b_safe = np.where(bad[..., None, None], np.eye(b.shape[-1]), b)
    out = np.swapaxes(np.linalg.solve(np.swapaxes(b_safe, -1, -2), np.swapaxes(a, -1, -2)), -1, -2)
    if np.any(bad):
        out = np.where(bad[..., None, None], np.nan, out)
    return out


def _check_enough_experiments(n_exp: int, n_in: int) -> None:
    if n_exp < n_in:
        raise ValueError(f"{n_exp} experiment(s) cannot separate {n_in} inputs: per-period MIMO "
                         "estimates need Ne >= Nu experiments (orthogonal multisines or one input "
                         "at a time)")


def _solve_over_experiments(yk: np.ndarray, uk: np.ndarray, rk: np.ndarray, what: str) -> np.ndarray:
    """``(Y R^H)(U R^H)^-1`` per record and line, the Ne experiments the columns: yk (..., Ny, Ne),
    uk and rk (..., Nu, Ne) -> (..., Ny, Nu)."""
    rk_h = np.conj(np.swapaxes(rk, -1, -2))
    return _right_divide(yk @ rk_h, uk @ rk_h, what)


# --------------------------------------------------------------------------- periodic estimators

def h1(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """H1 estimator ``G = S_yu S_uu^-1`` (least squares in the output noise).

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).

    Returns
    -------
    G (L, Ny, Nu). Biased in closed loop: tends to ``-C^-1`` where the
    fed-back noise dominates u.
    """
    s = _matched(y=y, u=u)
    return _right_divide(_cross(s["y"], s["u"]), _cross(s["u"], s["u"]), "S_uu")


def h2(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """H2 estimator ``G = S_yy S_uy^-1`` (least squares in the input noise).

    For MIMO it is defined only for a square plant (Ny == Nu), since S_uy must
    be inverted; non-square systems raise ``ValueError``.

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).

    Returns
    -------
    G (L, Ny, Nu).
    """
    s = _matched(y=y, u=u)
    ny, nu = s["y"].shape[-1], s["u"].shape[-1]
    if ny != nu:
        raise ValueError(f"H2 needs a square system (Ny == Nu) to invert S_uy, got Ny={ny}, Nu={nu}; "
                         "use h1, errors_in_variables or indirect")
    return _right_divide(_cross(s["y"], s["y"]), _cross(s["u"], s["y"]), "S_uy")


def per_period_frf(y: np.ndarray, u: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:
    """FRF from each period alone, solved over the Ne experiments.

    ``G_k = (Y_k R_k^H)(U_k R_k^H)^-1`` for record k = (m, p); with r = None,
    R_k = U_k (then ``G_k = Y_k U_k^+``, equal to ``Y_k U_k^-1`` when Ne == Nu,
    and also equal to the r-based one when Ne == Nu).

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).
    r
        reference (excitation) spectra (M, Ne, P or 1, L, Nu), optional.

    Returns
    -------
    G_k (M, P, L, Ny, Nu).
    """
    s = _matched(y=y, u=u) if r is None else _matched(y=y, u=u, r=r)
    _check_enough_experiments(s["y"].shape[1], s["u"].shape[-1])
    uk = _records(s["u"])
    return _solve_over_experiments(_records(s["y"]), uk, _records(s["r"]) if r is not None else uk,
                                   "U R^H per period")


def arithmetic_mean(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Arithmetic mean over all periods and realisations of per-period FRFs.

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).

    Returns
    -------
    G (L, Ny, Nu) = mean_k Y_k U_k^+ (see :func:`per_period_frf`).
    """
    return per_period_frf(y, u).mean(axis=(0, 1))


def log_mean(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Logarithmic (geometric) mean of per-period FRFs, element by element.

    ``G = exp(mean_k log G_k)`` per element of the per-period matrix solutions
    ``G_k = Y_k U_k^+``. To avoid phase wrapping the complex log is taken
    relative to the arithmetic mean ``Ga``:
    ``G = Ga exp(mean_k log(G_k / Ga))``, which equals the geometric mean
    with each element's phase unwrapped around ``Ga`` (valid while the
    per-period phases stay within +-pi of it). An element whose arithmetic
    mean is exactly 0 is returned as 0.

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).

    Returns
    -------
    G (L, Ny, Nu).
    """
    gk = per_period_frf(y, u)
    ga = gk.mean(axis=(0, 1))
    zero = ga == 0
    ref = np.where(zero, 1.0, ga)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.log(gk / ref).mean(axis=(0, 1))
    return np.where(zero, 0.0, ref * np.exp(rel))


def errors_in_variables(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Errors-in-variables estimator: ratio of period-averaged spectra.

    Per realisation m, ``G_m = Ybar_m Ubar_m^+`` with Ybar_m, Ubar_m the means
    over the P periods (Ny x Ne, Nu x Ne; ``Ubar^+ = Ubar^-1`` when
    Ne == Nu); the result is the mean over realisations (averaging spectra
    across realisations would cancel their random phases).

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).

    Returns
    -------
    G (L, Ny, Nu).
    """
    s = _matched(y=y, u=u)
    _check_enough_experiments(s["y"].shape[1], s["u"].shape[-1])
    ybar = _records(s["y"].mean(axis=2, keepdims=True))[:, 0]
    ubar = _records(s["u"].mean(axis=2, keepdims=True))[:, 0]
    return _solve_over_experiments(ybar, ubar, ubar, "Ubar Ubar^H").mean(axis=0)


def indirect(y: np.ndarray, u: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Closed-loop indirect estimator through the known excitation, ``S_yr S_ur^-1``.

    Equivalent per line to ``(Y R^-1)(U R^-1)^-1`` over the Ne experiments:
    the ratio of the estimates of the process sensitivity (r -> y) and the
    input sensitivity (r -> u). r is noise-free, so the noise correlated with
    u through the feedback averages out: consistent in closed loop.

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    u
        input spectra (M, Ne, P, L, Nu).
    r
        excitation spectra (M, Ne, P or 1, L, Nu).

    Returns
    -------
    G (L, Ny, Nu).
    """
    s = _matched(y=y, u=u, r=r)
    return _right_divide(_cross(s["y"], s["r"]), _cross(s["u"], s["r"]), "S_ur")


def multiple_coherence(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Multiple coherence of each output with all inputs x.

    ``gamma_i^2 = [S_yx S_xx^-1 S_xy]_ii / [S_yy]_ii``, the fraction of the
    power of output i explained linearly by x (ordinary coherence when x has
    one channel). In closed loop use x = r (the excitation); with x = u the
    fed-back noise is partly "explained" and the coherence is optimistic.

    Parameters
    ----------
    y
        output spectra (M, Ne, P, L, Ny).
    x
        input or excitation spectra (M, Ne, P or 1, L, Nx).

    Returns
    -------
    Coherence (L, Ny) in [0, 1].
    """
    s = _matched(y=y, x=x)
    return _coherence(_cross(s["y"], s["x"]), _cross(s["x"], s["x"]), _cross(s["y"], s["y"]))


def _coherence(s_yx: np.ndarray, s_xx: np.ndarray, s_yy: np.ndarray, strict: bool = True) -> np.ndarray:
    explained = _right_divide(s_yx, s_xx, "S_xx", strict=strict) @ np.conj(np.swapaxes(s_yx, -1, -2))
    num = np.real(np.diagonal(explained, axis1=-2, axis2=-1))
    den = np.real(np.diagonal(s_yy, axis1=-2, axis2=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.clip(num / den, 0.0, 1.0)


# --------------------------------------------------------------------------- stepped sine

def sine_amplitude(x: np.ndarray, freq_hz: float, fs_hz: float, n_settle: int = 0) -> np.ndarray:
    """Complex amplitude of the component at ``freq_hz`` after a settling wait.

    Least-squares fit of ``a cos(w t) + b sin(w t) + c`` to the samples from
    ``n_settle`` on (t = n / fs from the first sample of the record, so the
    phase is referred to the record start); returns ``a - j b`` so that
    ``A cos(w t + phi)`` gives ``A exp(j phi)`` (the scaling of
    :func:`ambid.frf.periods.period_spectra`). Over an integer number of
    periods this equals the single-bin DFT.

    Parameters
    ----------
    x
        samples (..., n_samples, n_ch), any unit.
    freq_hz
        frequency, 0 < freq_hz < fs_hz / 2 [Hz].
    fs_hz
        sample rate [Hz].
    n_settle
        samples skipped at the start (settling wait).

    Returns
    -------
    Complex amplitudes (..., n_ch), in the unit of x.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim < 2:
        raise ValueError(f"x must have shape (..., n_samples, n_ch), got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x contains NaN or inf; clean the record before estimating")
    if not (fs_hz > 0 and 0 < freq_hz < fs_hz / 2):
        raise ValueError(f"need fs_hz > 0 and 0 < freq_hz < fs_hz/2, got freq_hz={freq_hz}, fs_hz={fs_hz}")
    n_total = x.shape[-2]
    if not 0 <= n_settle < n_total:
        raise ValueError(f"n_settle must lie in [0, {n_total}) for a record of {n_total} samples, "
                         f"got {n_settle}")
    t = np.arange(n_settle, n_total) / fs_hz
    if t.size * freq_hz / fs_hz < 1.0:
        raise ValueError(f"only {t.size} samples after settling: less than one period of "
                         f"{freq_hz} Hz at {fs_hz} Hz; record longer")
    w = 2 * np.pi * freq_hz
    design = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    coef = np.linalg.pinv(design) @ x[..., n_settle:, :]
    return coef[..., 0, :] - 1j * coef[..., 1, :]


def stepped_sine_frf(y_records: Sequence[np.ndarray], u_records: Sequence[np.ndarray],
                     freq_hz: np.ndarray, fs_hz: float, n_settle: int | Sequence[int] = 0,
                     r_records: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """FRF matrix from stepped-sine records, one record set per frequency.

    At line l the complex amplitudes (:func:`sine_amplitude`) of the Ne
    experiments are stacked as columns, Y (Ny, Ne), U (Nu, Ne), R (Nu, Ne),
    and ``G = (Y R^H)(U R^H)^-1`` (indirect, closed-loop consistent) or, with
    r_records None, ``G = Y U^+``.

    Parameters
    ----------
    y_records
        L arrays (Ne, n_samples_l, Ny) of outputs.
    u_records
        L arrays (Ne, n_samples_l, Nu) of applied inputs.
    freq_hz
        excitation frequencies (L,) [Hz].
    fs_hz
        sample rate [Hz].
    n_settle
        settling samples skipped, one int or one per frequency.
    r_records
        L arrays (Ne, n_samples_l, Nu) of excitation, optional.

    Returns
    -------
    G (L, Ny, Nu).
    """
    freq_hz = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    n_lines = freq_hz.size
    settle = np.asarray(n_settle, dtype=int)
    if settle.ndim > 1 or settle.size not in (1, n_lines):
        raise ValueError(f"n_settle must be one int or one per frequency ({n_lines}), got {n_settle!r}")
    settle = np.broadcast_to(settle.reshape(-1), (n_lines,))
    groups = {"y_records": y_records, "u_records": u_records}
    if r_records is not None:
        groups["r_records"] = r_records
    for name, recs in groups.items():
        if len(recs) != n_lines:
            raise ValueError(f"{name} has {len(recs)} records but freq_hz has {n_lines} frequencies")
    out = []
    for i in range(n_lines):
        amp = {}
        for name, recs in groups.items():
            rec = np.asarray(recs[i])
            if rec.ndim != 3:
                raise ValueError(f"{name}[{i}] must have shape (Ne, n_samples, n_ch), got {rec.shape}")
            amp[name] = np.swapaxes(sine_amplitude(rec, freq_hz[i], fs_hz, int(settle[i])), 0, 1)
        if len({a.shape[1] for a in amp.values()}) != 1:
            raise ValueError(f"records at line {i} disagree on the number of experiments Ne")
        ref_h = np.conj(amp.get("r_records", amp["u_records"])).T
        _check_enough_experiments(amp["y_records"].shape[1], amp["u_records"].shape[0])
        out.append(_right_divide(amp["y_records"] @ ref_h, amp["u_records"] @ ref_h,
                                 f"U R^H at {freq_hz[i]} Hz"))
    return np.stack(out)


# --------------------------------------------------------------------------- Welch (swept sine, noise)

@dataclass(frozen=True)
class SpectralFrf:
    """FRF from averaged, windowed, overlapped spectra.

    Attributes
    ----------
    freq_hz
        frequency grid (F,) [Hz], bins of fs / n_per_segment.
    frf
        G (F, Ny, Nu); NaN at bins where the input (or reference)
        cross-spectral matrix is singular (not excited).
    coherence
        multiple coherence (F, Ny) of y with the reference used
        (r for the indirect estimate, u for H1).
    n_segments
        number of averaged segments (over all experiments).
    """

    freq_hz: np.ndarray
    frf: np.ndarray
    coherence: np.ndarray
    n_segments: int


def _segment_spectra(x: np.ndarray, n_per_segment: int, step: int, win: np.ndarray) -> np.ndarray:
    """(Ne, n, ch) -> (Ne, n_seg, F, ch) windowed, mean-removed segment spectra."""
    seg = np.lib.stride_tricks.sliding_window_view(x, n_per_segment, axis=1)[:, ::step]
    seg = seg - seg.mean(axis=-1, keepdims=True)
    return np.swapaxes(np.fft.rfft(seg * win, axis=-1), -1, -2)


def welch_frf(y: np.ndarray, u: np.ndarray, fs_hz: float, n_per_segment: int,
              r: np.ndarray | None = None, overlap: float = 0.5,
              freq_range_hz: tuple[float, float] | None = None) -> SpectralFrf:
    """Welch-type FRF for non-periodic excitation (random noise, swept sine).

    Hann-windowed segments of ``n_per_segment`` samples overlapping by
    ``overlap``, mean removed; cross-spectra summed over segments and
    experiments. With r given: indirect ``G = S_yr S_ur^-1`` (closed-loop
    consistent); without: H1 ``G = S_yu S_uu^-1``. Several experiments (e.g.
    one swept input at a time) are pooled so that S_ur is invertible.

    Parameters
    ----------
    y
        outputs (n_samples, Ny) or (Ne, n_samples, Ny).
    u
        applied inputs, same leading shape, Nu channels.
    fs_hz
        sample rate [Hz].
    n_per_segment
        segment length (frequency resolution fs / n_per_segment).
    r
        excitation, same shape as u, optional.
    overlap
        fraction of overlap between segments, in [0, 1).
    freq_range_hz
        (f_lo, f_hi) bins kept [Hz]; default all rfft bins.

    Returns
    -------
    :class:`SpectralFrf`.
    """
    arrays = {"y": y, "u": u} if r is None else {"y": y, "u": u, "r": r}
    sig = {}
    for name, a in arrays.items():
        a = np.asarray(a, dtype=float)
        if a.ndim == 2:
            a = a[None]
        if a.ndim != 3:
            raise ValueError(f"{name} must have shape (n_samples, n_ch) or (Ne, n_samples, n_ch), "
                             f"got {np.shape(arrays[name])}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN or inf; clean the record before estimating")
        sig[name] = a
    if len({a.shape[:2] for a in sig.values()}) != 1:
        raise ValueError("y, u (and r) must share (Ne, n_samples), got "
                         + ", ".join(f"{k}{v.shape}" for k, v in sig.items()))
    if r is not None and sig["r"].shape != sig["u"].shape:
        raise ValueError(f"r must have the shape of u {sig['u'].shape}, got {sig['r'].shape}")
    n_samples = sig["y"].shape[1]
    if not 2 <= n_per_segment <= n_samples:
        raise ValueError(f"n_per_segment must lie in [2, n_samples={n_samples}], got {n_per_segment}")
    if not 0 <= overlap < 1:
        raise ValueError(f"overlap must lie in [0, 1), got {overlap}")
    if not fs_hz > 0:
        raise ValueError(f"fs_hz must be > 0, got {fs_hz}")
    step = max(1, int(round(n_per_segment * (1 - overlap))))
    win = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n_per_segment) / n_per_segment)  # periodic Hann
    freq = np.fft.rfftfreq(n_per_segment, 1 / fs_hz)
    keep = np.ones(freq.size, bool)
    if freq_range_hz is not None:
        keep = (freq >= freq_range_hz[0]) & (freq <= freq_range_hz[1])
        if not keep.any():
            raise ValueError(f"freq_range_hz {freq_range_hz} holds no bin of the grid "
                             f"0..{freq[-1]} Hz step {freq[1]} Hz")
    spec = {k: _segment_spectra(a, n_per_segment, step, win)[:, :, keep] for k, a in sig.items()}

    def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.einsum("esfa,esfb->fab", a, b.conj())

    ref = spec["r"] if r is not None else spec["u"]
    s_yref, s_refref = cross(spec["y"], ref), cross(ref, ref)
    g = _right_divide(s_yref, cross(spec["u"], ref), "S_ur" if r is not None else "S_uu", strict=False)
    coh = _coherence(s_yref, s_refref, cross(spec["y"], spec["y"]), strict=False)
    return SpectralFrf(freq_hz=freq[keep], frf=g, coherence=coh,
                       n_segments=int(spec["y"].shape[0] * spec["y"].shape[1]))
