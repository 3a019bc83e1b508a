"""Non-multisine excitation waveforms: binary sequences, sweeps, noise, sines.

All functions are deterministic; the random ones take a numpy Generator or
integer seed keys. Waveforms are normalised to a peak of 1; the design
scales them to amperes.

- MLS / PRBS: maximum-length sequence of a linear feedback shift register
  (period 2^n - 1), optionally held for ``clock_divider`` samples per bit.
- DIBS: discrete-interval binary sequence whose power is concentrated on
  chosen harmonics, by alternating between the binary signal and a
  multisine with the wanted amplitudes and the binary signal's phases
  (Van den Bos & Krol 1979; Pintelon & Schoukens 2012, sec. 5.2.4).
- Swept sine: linear or logarithmic chirp lasting one period.
- Filtered noise: white Gaussian noise through a Kaiser-window FIR band-pass,
  computable for any sample range without generating what lies before it.
- Stepped sine: per-line segment layout with exact integer periods.
"""

from __future__ import annotations

import math

import numpy as np

# Feedback lags of maximal-length LFSRs (primitive trinomials/pentanomials):
# a[t] = XOR over lags L of a[t - L]. Period 2^n - 1 is checked by the tests.
MLS_TAPS = {
    2: (2, 1), 3: (3, 2), 4: (4, 3), 5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4),
    9: (9, 5), 10: (10, 7), 11: (11, 9), 12: (12, 11, 10, 4), 13: (13, 12, 11, 8),
    14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4), 17: (17, 14), 18: (18, 11),
    19: (19, 18, 17, 14), 20: (20, 17), 21: (21, 19), 22: (22, 21), 23: (23, 18),
}


def mls(order: int) -> np.ndarray:
    """Maximum-length sequence of an LFSR of the given order.

    Parameters
    ----------
    order
        register length n, 2 <= n <= 23.

    Returns
    -------
    (2^n - 1,) bool bits; 2^(n-1) of them are True.

    Examples
    --------
    >>> mls(3).astype(int)             # period 2**3 - 1
    array([1, 1, 1, 0, 0, 1, 0])
    """
    if order not in MLS_TAPS:
        raise ValueError(f"MLS order must be an integer in [2, 23], got {order!r}")
    taps = MLS_TAPS[order]
    length = 2**order - 1
    bits = np.zeros(length + order, dtype=bool)
    bits[:order] = True  # any non-zero initial state
    step = min(taps)  # a[t] needs a[t - min(taps)] at most: vectorise in blocks
    for t0 in range(order, length, step):
        t1 = min(t0 + step, length)
        acc = np.zeros(t1 - t0, dtype=bool)
        for lag in taps:
            acc ^= bits[t0 - lag:t1 - lag]
        bits[t0:t1] = acc
    return bits[:length]


def binary_levels(bits: np.ndarray) -> tuple[float, float]:
    """Levels (high, low) of a zero-mean binary signal with peak 1.

    With c1 ones and c0 zeros, high * c1 + low * c0 = 0 and max(|high|,
    |low|) = 1, so the DC line of the binary signal is exactly zero (an MLS
    has one more one than zeros: its levels are 1 - 2^(1-n) and -1).

    Parameters
    ----------
    bits
        (N,) bool.

    Returns
    -------
    (high, low) levels [-].

    Examples
    --------
    >>> binary_levels(mls(3))             # (high, low): a zero-mean signal of peak 1
    (0.75, -1.0)
    """
    c1 = int(np.count_nonzero(bits))
    c0 = bits.size - c1
    if c1 == 0 or c0 == 0:
        raise ValueError("a binary excitation needs both levels; the sequence is constant")
    return (1.0, -c1 / c0) if c1 <= c0 else (c0 / c1, -1.0)


def binary_waveform(bits: np.ndarray, clock_divider: int = 1) -> np.ndarray:
    """Zero-mean waveform of peak 1 from bits, each held ``clock_divider`` samples.

    Returns
    -------
    (clock_divider * bits.size,) float.

    Examples
    --------
    >>> import numpy as np
    >>> binary_waveform(np.array([1, 0, 1]), clock_divider=2)
    array([ 0.5,  0.5, -1. , -1. ,  0.5,  0.5])
    """
    high, low = binary_levels(bits)
    return np.repeat(np.where(bits, high, low), clock_divider)


def dibs_bits(n: int, lines: np.ndarray, amplitudes: np.ndarray, rng: np.random.Generator,
              n_iterations: int = 100) -> tuple[np.ndarray, float]:
    """DIBS of period n with power concentrated on ``lines``.

    Starts from a random-phase multisine with the wanted amplitudes, then
    alternates: take the binary signal sign(x), keep its phases at the lines,
    impose the wanted amplitudes there and zero elsewhere. The iterate with
    the largest power fraction on the lines is kept. A grid of odd lines
    only (with even n) gives a half-wave antisymmetric signal, so the binary
    signal has no even-line power at all.

    Parameters
    ----------
    n
        period [samples] (one bit per sample).
    lines
        (L,) DFT bins.
    amplitudes
        (L,) wanted relative amplitudes.
    rng
        random generator (initial phases).
    n_iterations
        iterations (>= 1).

    Returns
    -------
    (bits (n,) bool, fraction of the AC power on ``lines`` [-]).
    """
    if n_iterations < 1:
        raise ValueError(f"n_iterations must be >= 1, got {n_iterations!r}")
    lines = np.asarray(lines)
    amps = np.asarray(amplitudes, dtype=float)
    coef = amps * np.exp(1j * rng.uniform(0, 2 * np.pi, lines.size))
    best_bits, best_frac = None, -1.0
    for _ in range(n_iterations):
        spec = np.zeros(n // 2 + 1, dtype=complex)
        spec[lines] = coef
        bits = np.fft.irfft(spec, n) >= 0
        if bits.all() or not bits.any():
            bits = bits.copy()
            bits[0] = not bits[0]
        frac, bin_spec = _power_fraction(binary_waveform(bits), lines)
        if frac > best_frac:
            best_bits, best_frac = bits, frac
        coef = amps * np.exp(1j * np.angle(bin_spec[lines]))
    return best_bits, best_frac


def _power_fraction(x: np.ndarray, lines: np.ndarray) -> tuple[float, np.ndarray]:
    """Share of the power of x (N,) on the DFT lines (all < N/2) and rfft(x)."""
    spec = np.fft.rfft(x)
    total = np.sum(x**2) * x.size  # Parseval: sum |X_k|^2 over all N bins
    return float(2 * np.sum(np.abs(spec[lines]) ** 2) / total), spec


def swept_sine_period(n: int, fs_hz: float, f_start_hz: float, f_stop_hz: float,
                      law: str = "linear") -> np.ndarray:
    """One sweep lasting one period, normalised to a sampled peak of 1.

    Instantaneous frequency from f_start to f_stop over T = n / fs; the
    phase starts at 0 (sin), so the waveform starts at 0.

    Parameters
    ----------
    n
        samples per sweep.
    fs_hz
        sample rate [Hz].
    f_start_hz, f_stop_hz
        start and stop frequency [Hz] (> 0 for log).
    law
        'linear' or 'log'.

    Returns
    -------
    (n,) float.
    """
    t = np.arange(n) / fs_hz
    dur = n / fs_hz
    if law == "linear":
        phase = 2 * np.pi * (f_start_hz * t + (f_stop_hz - f_start_hz) * t**2 / (2 * dur))
    elif law == "log":
        if f_start_hz <= 0:
            raise ValueError("a logarithmic sweep needs band_hz[0] > 0")
        ratio = f_stop_hz / f_start_hz
        phase = 2 * np.pi * f_start_hz * dur / np.log(ratio) * (ratio ** (t / dur) - 1)
    else:
        raise ValueError(f"law must be 'linear' or 'log', got {law!r}")
    x = np.sin(phase)
    return x / np.max(np.abs(x))


def noise_filter_spec(band_hz: tuple[float, float], fs_hz: float,
                      max_taps: int = 4001) -> dict:
    """Kaiser-window FIR band-pass (low-pass if band_hz[0] == 0) for noise.

    The transition bands (60 dB) lie outside the band, half as wide as the
    narrowest of: the band, the gap below it and the gap to Nyquist; the
    filter is capped at ``max_taps`` taps (then the edges are softer).

    Returns
    -------
    JSON-safe dict: n_taps, cutoffs_hz, beta, pass_zero (for ``noise_taps``).
    """
    f_lo, f_hi = float(band_hz[0]), float(band_hz[1])
    gaps = [f_hi - f_lo, fs_hz / 2 - f_hi] + ([f_lo] if f_lo > 0 else [])
    width = 0.5 * min(gaps)
    from scipy.signal import kaiserord  # scipy.signal costs ~0.3 s to import: only where a noise design needs it

    n_taps, beta = kaiserord(60.0, width / (fs_hz / 2))
    n_taps = min(n_taps | 1, max_taps | 1)  # odd length: a type I filter can pass any band
    if f_lo > 0:
        cutoffs = [max(f_lo - width / 2, 1e-6 * fs_hz), f_hi + width / 2]
    else:
        cutoffs = [f_hi + width / 2]
    return {"n_taps": int(n_taps), "cutoffs_hz": cutoffs, "beta": float(beta),
            "pass_zero": bool(f_lo == 0)}


def noise_taps(spec: dict, fs_hz: float) -> np.ndarray:
    """FIR taps (T,) from a ``noise_filter_spec`` dict."""
    from scipy.signal import firwin

    return firwin(spec["n_taps"], spec["cutoffs_hz"], window=("kaiser", spec["beta"]),
                  pass_zero=spec["pass_zero"], fs=fs_hz)


def filtered_noise(taps: np.ndarray, key: tuple[int, ...], start: int, stop: int,
                   chunk: int, n_channels: int) -> np.ndarray:
    """Samples [start, stop) of a filtered white-noise stream.

    The white noise is cut in chunks of ``chunk`` samples; chunk j is drawn
    from ``default_rng((*key, j))``, so any range is computed from the chunks
    it needs only: memory and time do not grow with ``start``. The stream
    starts at sample 0 with zero history (the filter's transient lies there).

    Parameters
    ----------
    taps
        (T,) FIR taps.
    key
        non-negative integers naming the stream (seed, realisation, ...).
    start, stop
        sample range, 0 <= start <= stop.
    chunk
        white-noise chunk length [samples].
    n_channels
        independent channels.

    Returns
    -------
    (stop - start, n_channels) filtered noise (unit-variance white input).
    """
    if stop <= start:
        return np.zeros((0, n_channels))
    lo = max(0, start - taps.size + 1)
    j0, j1 = lo // chunk, (stop - 1) // chunk
    white = np.concatenate([np.random.default_rng((*key, j)).standard_normal((chunk, n_channels))
                            for j in range(j0, j1 + 1)])
    white = white[lo - j0 * chunk:stop - j0 * chunk]
    from scipy.signal import fftconvolve

    return fftconvolve(white, taps[:, None], axes=0)[start - lo:stop - lo]


def stepped_sine_layout(lines: np.ndarray, n: int, fs_hz: float, settle_s: float,
                        n_cycles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment layout of a stepped sine on the lines of a period of n samples.

    A sine on bin k of n repeats exactly after p = n / gcd(n, k) samples,
    which hold c = k / gcd(n, k) cycles. Each line's segment is Pt settling
    periods (at least ``settle_s``) and then P measured periods (at least
    ``n_cycles`` cycles), all of p samples: the sine runs on without a jump.

    Parameters
    ----------
    lines
        (L,) DFT bins of the n-sample grid.
    n
        grid period [samples].
    fs_hz
        sample rate [Hz].
    settle_s
        settling wait per line [s], >= 0.
    n_cycles
        minimum measured cycles per line, >= 1.

    Returns
    -------
    (period_samples p, transient_periods Pt, periods P), each (L,) int64.
    """
    lines = np.asarray(lines, dtype=np.int64)
    g = np.gcd(lines, n)
    period = n // g
    cycles = lines // g
    periods = -(-n_cycles // cycles)  # ceil
    transient = np.array([math.ceil(settle_s * fs_hz / p - 1e-9) for p in period], dtype=np.int64)
    return period, np.maximum(transient, 0), periods
