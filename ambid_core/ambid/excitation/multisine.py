"""Multisines: synthesis, phase choices and MIMO phase matrices.

A multisine of period N samples on lines k_l (DFT bins) is

    x[n] = sum_l A_l Re(P_l exp(j 2 pi k_l n / N)),   n = 0 .. N-1,

with amplitude A_l [A] and unit phasor P_l = exp(j phi_l). It is built by an
inverse real FFT, so it is exactly periodic in N and its DFT holds energy at
the lines k_l only.

Phase choices (Pintelon & Schoukens 2012, sec. 5.2): random (uniform on
[0, 2 pi)), Schroeder (1970, closed form for any amplitude spectrum) and
crest-factor optimised: iterative clipping (Van der Ouderaa, Schoukens &
Renneboog 1988) followed by L_p-norm minimisation with growing p, which
tends to the L_inf (peak) norm (Guillaume, Schoukens, Pintelon & Kollar
1991).

MIMO (Dobrowiecki, Schoukens & Guillaume 2006): with Nu inputs and Ne = Nu
experiments, the phasors at line k over (input, experiment) form
T_k = diag(exp(j phi_k)) W, W[i, e] = exp(-j 2 pi i e / Nu), so
T_k T_k^H = Nu I (T_k / sqrt(Nu) is unitary).
"""

from __future__ import annotations

import numpy as np

from ambid.disk_cache import cached_array

MIMO_MULTISINE = ("orthogonal", "one_at_a_time")
PHASES = ("random", "schroeder", "crest_optimised")


def multisine_period(n: int, lines: np.ndarray, amplitudes: np.ndarray,
                     phasors: np.ndarray) -> np.ndarray:
    """One period of a multisine.

    Parameters
    ----------
    n
        samples per period N.
    lines
        (L,) DFT bins, 1 <= k < N/2.
    amplitudes
        (..., L) amplitude of each line [A].
    phasors
        (..., L) complex phase factors (|P| = 1, or 0 for a line not
        excited), broadcastable with ``amplitudes``.

    Returns
    -------
    (..., N) samples [A].
    """
    coef = np.asarray(amplitudes) * np.asarray(phasors)
    spec = np.zeros(coef.shape[:-1] + (n // 2 + 1,), dtype=complex)
    spec[..., lines] = coef * (n / 2)
    return np.fft.irfft(spec, n, axis=-1)


def crest_factor(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Crest factor max|x| / rms(x) along ``axis`` [-].

    Examples
    --------
    >>> import numpy as np
    >>> round(float(crest_factor(np.sin(2 * np.pi * np.arange(100) / 100))), 4)   # a sine: sqrt(2)
    1.4142
    """
    x = np.asarray(x, dtype=float)
    return np.max(np.abs(x), axis=axis) / np.sqrt(np.mean(x**2, axis=axis))


def schroeder_phases(lines: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
    """Schroeder (1970) phases for any line set and amplitude spectrum.

    phi_l = -2 pi sum_{i<l} (k_l - k_i) p_i with power fractions
    p_i = A_i^2 / sum A^2, in harmonic numbers k (so gaps in the grid are
    respected); for a flat full grid k = 1..F this is -pi k (k - 1) / F, a
    quasi-linear sweep.

    Parameters
    ----------
    lines
        (L,) sorted DFT bins.
    amplitudes
        (L,) line amplitudes (any unit).

    Returns
    -------
    (L,) phases [rad].

    Examples
    --------
    Eight equal lines: in phase their peaks add up (crest factor 4); Schroeder's phases spread them.

    >>> import numpy as np
    >>> lines, amplitudes = np.arange(1, 9), np.ones(8)
    >>> in_phase = multisine_period(64, lines, amplitudes, np.ones(8))
    >>> spread = multisine_period(64, lines, amplitudes, np.exp(1j * schroeder_phases(lines, amplitudes)))
    >>> round(float(crest_factor(in_phase)), 2), round(float(crest_factor(spread)), 2)
    (4.0, 1.71)
    """
    k = np.asarray(lines, dtype=float)
    a = np.asarray(amplitudes, dtype=float)
    p = a**2 / np.sum(a**2)
    # sum_{i<l} (k_l - k_i) p_i = k_l * cumsum(p)[l-1] - cumsum(k p)[l-1]
    cp = np.concatenate(([0.0], np.cumsum(p)[:-1]))
    ckp = np.concatenate(([0.0], np.cumsum(k * p)[:-1]))
    return np.mod(-2 * np.pi * (k * cp - ckp), 2 * np.pi)


def _stacked(n: int, lines: np.ndarray, amps: np.ndarray, phases: np.ndarray,
             shifts: np.ndarray) -> np.ndarray:
    """Signals (S, N) of one phase vector under S constant phase shifts."""
    return multisine_period(n, lines, amps, np.exp(1j * (phases[None, :] + shifts[:, None])))


def optimise_crest_phases(n: int, lines: np.ndarray, amplitudes: np.ndarray,
                          initial_phases: np.ndarray, shifts: np.ndarray | None = None,
                          n_clip_iterations: int = 100,
                          p_schedule: tuple[int, ...] = (16, 64, 256),
                          max_iterations: int = 100) -> np.ndarray:
    """Crest-factor optimised phases (clipping, then L_p minimisation).

    The peak minimised is that of the sampled signal, over all ``shifts``:
    the waveforms x_s[n] = sum_l A_l cos(2 pi k_l n/N + phi_l + shift_s),
    which is how one input looks in the experiments of an orthogonal MIMO
    design. Deterministic for given initial phases.

    Parameters
    ----------
    n
        samples per period N.
    lines
        (L,) DFT bins.
    amplitudes
        (L,) amplitudes (any unit; only the shape matters).
    initial_phases
        (L,) starting phases [rad] (e.g. random, seeded).
    shifts
        (S,) constant phase shifts [rad]; default (0,).
    n_clip_iterations
        iterations of the clipping algorithm.
    p_schedule
        L_p norms minimised in turn (growing p -> L_inf).
    max_iterations
        conjugate-gradient iterations per p.

    Returns
    -------
    (L,) phases [rad] with the lowest crest factor found: computed once per set of arguments and
    kept on disk (:mod:`ambid.disk_cache`, the same array to the bit), as it costs seconds and a
    design repeats run after run.
    """
    lines = np.asarray(lines)
    amps = np.asarray(amplitudes, dtype=float)
    shifts = np.zeros(1) if shifts is None else np.unique(np.mod(np.asarray(shifts, float), np.pi))
    initial = np.asarray(initial_phases, dtype=float)
    return cached_array("crest_phases", __file__,
                        (n, lines, amps, initial, shifts, n_clip_iterations, tuple(p_schedule), max_iterations),
                        lambda: _optimise(n, lines, amps, initial, shifts, n_clip_iterations, p_schedule,
                                          max_iterations))


def _optimise(n: int, lines: np.ndarray, amps: np.ndarray, initial_phases: np.ndarray, shifts: np.ndarray,
              n_clip_iterations: int, p_schedule: tuple[int, ...], max_iterations: int) -> np.ndarray:
    """:func:`optimise_crest_phases` computed."""
    from scipy.optimize import minimize

    rms = np.sqrt(np.sum(amps**2) / 2)

    def peak(ph: np.ndarray) -> float:
        return float(np.max(np.abs(_stacked(n, lines, amps, ph, shifts))))

    phases = np.mod(np.asarray(initial_phases, dtype=float), 2 * np.pi)
    best, best_peak = phases, peak(phases)
    derotate = np.exp(-1j * shifts)[:, None]
    for _ in range(n_clip_iterations):
        x = _stacked(n, lines, amps, phases, shifts)
        level = 0.9 * np.max(np.abs(x))
        clipped = np.fft.rfft(np.clip(x, -level, level), axis=-1)[:, lines]
        phases = np.angle(np.sum(clipped * derotate, axis=0))
        pk = peak(phases)
        if pk < best_peak:
            best, best_peak = phases, pk

    def lp_cost(ph: np.ndarray, p: float) -> tuple[float, np.ndarray]:
        x = _stacked(n, lines, amps, ph, shifts)
        mx = np.max(np.abs(x))
        u = x / mx
        au = np.abs(u)
        total = np.sum(au**p)
        cost = np.log(mx / rms) + np.log(total / x.size) / p
        # d cost / dx = sign(x) |x|^(p-1) / sum |x|^p, written in u = x / max|x|
        w = np.sign(u) * au ** (p - 1) / (mx * total)
        wf = np.fft.rfft(w, axis=-1)[:, lines]
        rot = np.exp(1j * (ph[None, :] + shifts[:, None]))
        grad = -amps * np.sum(np.imag(rot * np.conj(wf)), axis=0)
        return float(cost), grad

    phases = best.copy()
    for p in p_schedule:
        # CG, not L-BFGS-B: the latter's many tiny threaded BLAS calls stall on
        # shared cores (measured 10x slower here) for no better result.
        res = minimize(lp_cost, phases, args=(float(p),), jac=True, method="CG",
                       options={"maxiter": max_iterations})
        phases = np.mod(res.x, 2 * np.pi)
        pk = peak(phases)
        if pk < best_peak:
            best, best_peak = phases, pk
    return np.mod(best, 2 * np.pi)


def dft_weights(nu: int) -> np.ndarray:
    """Phase-only DFT matrix W[i, e] = exp(-j 2 pi i e / Nu), shape (Nu, Nu).

    W W^H = Nu I, so W / sqrt(Nu) is unitary.

    Examples
    --------
    >>> import numpy as np
    >>> np.round(dft_weights(2).real)     # two inputs: the second experiment flips the second input
    array([[ 1.,  1.],
           [ 1., -1.]])
    """
    i = np.arange(nu)
    return np.exp(-2j * np.pi * np.outer(i, i) / nu)


def mimo_phasors(phases: np.ndarray, mimo: str) -> np.ndarray:
    """Phasors over (realisation, experiment, input, line).

    Parameters
    ----------
    phases
        (M, Nu, L) per-input line phases [rad].
    mimo
        'orthogonal' (T_k = diag(exp(j phases)) W, Ne = Nu) or
        'one_at_a_time' (experiment e excites input e only, Ne = Nu).

    Returns
    -------
    (M, Ne, Nu, L) complex; T_k for realisation m is
    ``out[m, :, :, l].T`` (input x experiment).
    """
    ph = np.exp(1j * np.asarray(phases, dtype=float))
    m, nu, _ = ph.shape
    if mimo == "orthogonal":
        weights = dft_weights(nu).T  # (Ne, Nu): weight of input i in experiment e
    elif mimo == "one_at_a_time":
        weights = np.eye(nu)
    else:
        raise ValueError(f"mimo must be one of {MIMO_MULTISINE}, got {mimo!r}")
    return ph[:, None, :, :] * weights[None, :, :, None]


def experiment_shifts(nu: int, input_index: int, mimo: str) -> np.ndarray:
    """Constant phase shifts [rad] one input sees over the experiments.

    Parameters
    ----------
    nu
        number of inputs.
    input_index
        input i.
    mimo
        'orthogonal' or 'one_at_a_time'.

    Returns
    -------
    (S,) shifts: angle(W[i, e]) over e for orthogonal designs, (0,) else.
    """
    if mimo == "orthogonal":
        return np.angle(dft_weights(nu)[input_index])
    return np.zeros(1)
