"""Design functions: excitations stated in the user's terms.

Each ``design_*`` returns an ``ExcitationDesign`` scaled so that its peak on
each input equals ``peak_current_a`` (the current available for excitation
on that input [A]), with its measurement time known before anything runs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .design import ExcitationDesign
from .lines import AmplitudeShape, band_bins, detection_lines, line_set, n_per_period, shape_amplitudes
from .multisine import MIMO_MULTISINE, PHASES, experiment_shifts, mimo_phasors, optimise_crest_phases, schroeder_phases
from .synchronous import (DEFAULT_GUARD_BINS, DEFAULT_HARMONICS, DEFAULT_MAX_PERIOD_CHANGE, commensurate_period,
                          harmonic_bins, steer_lines, synchronous_options)
from .signals import (binary_waveform, dibs_bits, mls, noise_filter_spec, noise_taps, stepped_sine_layout,
                      swept_sine_period)

MIMO_BINARY = ("one_at_a_time", "orthogonal")
MIMO_NOISE = ("simultaneous", "one_at_a_time")


# ---- argument checks ------------------------------------------------------
def _inputs(input_names: Sequence[str], peak_current_a: float | Sequence[float]
            ) -> tuple[tuple[str, ...], np.ndarray]:
    if isinstance(input_names, str) or len(input_names) == 0:
        raise ValueError("input_names must be a non-empty sequence of names, e.g. "
                         "('x_a', 'y_a', 'x_b', 'y_b')")
    names = tuple(str(s) for s in input_names)
    if len(set(names)) != len(names):
        raise ValueError(f"input_names must be unique, got {names}")
    peaks = np.asarray(peak_current_a, dtype=float)
    if peaks.ndim > 1 or (peaks.ndim == 1 and peaks.size != len(names)):
        raise ValueError(f"peak_current_a must be a scalar or one value per input "
                         f"({len(names)}), got shape {peaks.shape}")
    peaks = np.broadcast_to(peaks, (len(names),)).astype(float)
    if not np.all(np.isfinite(peaks)) or np.any(peaks <= 0):
        raise ValueError(f"peak_current_a must be finite and > 0 [A], got {peaks.tolist()}")
    return names, peaks


def _count(name: str, value: int, minimum: int) -> int:
    if (isinstance(value, bool) or not np.isfinite(value) or int(value) != value
            or value < minimum):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _seed(seed: int) -> int:
    if isinstance(seed, bool) or not np.isfinite(seed) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _choice(name: str, value: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
    return value


def _sylvester(nu: int) -> np.ndarray:
    if nu & (nu - 1):
        raise ValueError(f"orthogonal binary/swept designs use a Hadamard matrix, which needs a "
                         f"power-of-two number of inputs (got {nu}); use mimo='one_at_a_time'")
    h = np.ones((1, 1))
    while h.shape[0] < nu:
        h = np.block([[h, h], [h, -h]])
    return h


def _binary_mixing(mimo: str, nu: int) -> np.ndarray:
    """(Ne, Nu) signs: identity (one at a time) or Sylvester-Hadamard (orthogonal)."""
    _choice("mimo", mimo, MIMO_BINARY)
    return np.eye(nu) if mimo == "one_at_a_time" else _sylvester(nu).T


def _periodic_figures(d: ExcitationDesign) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(peak, rms, crest) per input over every (m, e) period where it is excited."""
    nu = d.n_inputs
    peak, rms, crest = np.zeros(nu), np.zeros(nu), np.zeros(nu)
    for m in range(d.n_realisations):
        for e in range(d.n_experiments):
            x = d.period(m, e)
            pk = np.max(np.abs(x), axis=0)
            r = np.sqrt(np.mean(x**2, axis=0))
            on = r > 0
            peak = np.maximum(peak, pk)
            rms = np.maximum(rms, r)
            crest[on] = np.maximum(crest[on], pk[on] / r[on])
    return peak, rms, crest


def _finish(d: ExcitationDesign, **changes) -> ExcitationDesign:
    """Rebuild with changes and with figures computed from the waveform."""
    fields = {k: getattr(d, k) for k in d.__dataclass_fields__}
    fields.update(changes)
    out = ExcitationDesign(**fields)
    peak, rms, crest = _periodic_figures(out)
    fields.update(peak_a=peak, rms_a=rms, crest_factor=crest)
    return ExcitationDesign(**fields)


def _common(band_hz, resolution_hz, fs_hz):
    n = n_per_period(fs_hz, resolution_hz)
    k_lo, k_hi = band_bins(band_hz, float(fs_hz), n)
    return n, k_lo, k_hi


# ---- multisine ------------------------------------------------------------
def design_multisine(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                     input_names: Sequence[str], peak_current_a: float | Sequence[float],
                     n_periods: int = 4, n_realisations: int = 1, n_transient_periods: int = 1,
                     grid: str = "random_odd", spacing: str = "linear",
                     phases: str = "random", mimo: str = "orthogonal",
                     amplitude_shape: AmplitudeShape = None, seed: int = 0,
                     n_lines: int | None = None, group_size: int = 3, speed_rpm: float = 0.0,
                     n_harmonics: int = DEFAULT_HARMONICS, guard_bins: int = DEFAULT_GUARD_BINS,
                     max_period_change: float = DEFAULT_MAX_PERIOD_CHANGE) -> ExcitationDesign:
    """Periodic multisine, single or multiple input.

    Args:
        band_hz: (f_lo, f_hi) band to excite [Hz], f_hi < fs/2.
        resolution_hz: line spacing fs/N [Hz]; fs/resolution must be an integer.
        fs_hz: sample rate [Hz].
        input_names: (Nu,) input names.
        peak_current_a: peak current available for excitation, scalar or (Nu,) [A].
        n_periods: P steady-state periods per segment.
        n_realisations: M independent phase realisations.
        n_transient_periods: Pt periods per segment discarded for transients.
        grid: 'random_odd', 'odd' or 'full'.
        spacing: 'linear' or 'log' (quasi-log, about ``n_lines`` lines, default 100).
        phases: 'random', 'schroeder' or 'crest_optimised' (seeded start).
        mimo: 'orthogonal' (Dobrowiecki et al. 2006) or 'one_at_a_time'.
        amplitude_shape: None (flat), callable f(freq_hz) or (freq_hz, amp) table.
        seed: seed of the random grid choice and phases.
        n_lines: number of lines for log spacing.
        group_size: random-odd group length.
        speed_rpm: rotor speed [rpm]; > 0 steers the lines clear of the synchronous harmonics
            1..n_harmonics (:mod:`ambid.excitation.synchronous`): the period is changed by at most
            ``max_period_change`` so that they fall on lines, excited lines within ``guard_bins`` of one
            move, and the design's ``options["synchronous"]`` says what moved and names the
            disturbance lines.

    Returns:
        ExcitationDesign of kind 'multisine' with Ne = Nu experiments.

    Examples
    --------
    Two inputs, 10-100 Hz at 5 Hz resolution, sampled at 1 kHz, periods of 200 samples:

    >>> d = design_multisine((10.0, 100.0), 5.0, 1000.0, ["u_a_x", "u_b_x"], 0.2, n_periods=2, seed=1)
    >>> d.kind, d.n_per_period, d.input_names
    ('multisine', 200, ('u_a_x', 'u_b_x'))
    >>> d.excited_lines                   # bins of 5 Hz, odd ones, one of each group of three left out
    array([ 3,  7,  9, 13, 15, 17])
    >>> d.freq_hz[:3], d.total_samples
    (array([15., 35., 45.]), 1200)
    """
    names, peaks = _inputs(input_names, peak_current_a)
    n, k_lo, k_hi = _common(band_hz, resolution_hz, fs_hz)
    p = _count("n_periods", n_periods, 1)
    m = _count("n_realisations", n_realisations, 1)
    pt = _count("n_transient_periods", n_transient_periods, 0)
    _choice("phases", phases, PHASES)
    _choice("mimo", mimo, MIMO_MULTISINE)
    seed = _seed(seed)
    rng = np.random.default_rng(seed)
    sync = None
    speed_rpm = float(speed_rpm)
    if not np.isfinite(speed_rpm) or speed_rpm < 0:
        raise ValueError(f"speed_rpm must be finite and >= 0 [rpm], got {speed_rpm!r}")
    if speed_rpm > 0:
        n_harmonics = _count("n_harmonics", n_harmonics, 1)
        guard_bins = _count("guard_bins", guard_bins, 0)
        requested = n
        n = commensurate_period(speed_rpm, fs_hz, n, max_period_change) or n
        k_lo, k_hi = band_bins(band_hz, float(fs_hz), n)
    lines = line_set(k_lo, k_hi, grid, spacing, n_lines, group_size, rng)
    odd, even = detection_lines(lines, k_lo, k_hi)
    if speed_rpm > 0:
        harm = harmonic_bins(speed_rpm, fs_hz, n, n_harmonics)
        steered = steer_lines(lines, k_lo, k_hi, n, harm, guard_bins)
        lines, odd, even = steered.excited, steered.detection_odd, steered.detection_even
        if lines.size == 0:
            raise ValueError(f"at {speed_rpm:g} rpm every line of the band lies within {guard_bins} bin(s) of a "
                             "synchronous harmonic; refine the resolution or lower guard_bins")
        sync = synchronous_options(speed_rpm, n_harmonics, guard_bins, harm, steered, requested, n)
    shape = shape_amplitudes(amplitude_shape, lines * (fs_hz / n))
    nu = len(names)
    if phases == "schroeder":
        phi = np.broadcast_to(schroeder_phases(lines, shape), (m, nu, lines.size))
    else:
        phi = rng.uniform(0, 2 * np.pi, (m, nu, lines.size))
        if phases == "crest_optimised":
            phi = np.array([[optimise_crest_phases(n, lines, shape, phi[r, i],
                                                   experiment_shifts(nu, i, mimo))
                             for i in range(nu)] for r in range(m)])
    unit = ExcitationDesign(
        kind="multisine", fs_hz=fs_hz, n_per_period=n, n_periods=p, n_transient_periods=pt,
        n_realisations=m, n_experiments=nu, input_names=names, excited_lines=lines,
        detection_lines_odd=odd, detection_lines_even=even,
        amplitudes_a=np.tile(shape, (nu, 1)), phasors=mimo_phasors(phi, mimo),
        peak_a=np.zeros(nu), rms_a=np.zeros(nu), crest_factor=np.zeros(nu),
        band_hz=band_hz, seed=seed,
        options={"grid": grid, "spacing": spacing, "phases": phases, "mimo": mimo,
                 "group_size": group_size, "shaped": amplitude_shape is not None,
                 **({"synchronous": sync} if sync else {})})
    peak0, _, _ = _periodic_figures(unit)
    return _finish(unit, amplitudes_a=unit.amplitudes_a * (peaks / peak0)[:, None])


# ---- stepped sine ---------------------------------------------------------
def design_stepped_sine(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                        input_names: Sequence[str], peak_current_a: float | Sequence[float],
                        settle_s: float = 0.5, n_cycles: int = 10, grid: str = "full",
                        spacing: str = "linear", n_lines: int | None = None,
                        amplitude_shape: AmplitudeShape = None,
                        lines: Sequence[int] | None = None) -> ExcitationDesign:
    """Stepped sine, one input at a time, on the lines of the resolution grid.

    Per line k and input e: a settling wait of at least ``settle_s`` and then
    at least ``n_cycles`` measured cycles, both whole periods of the sine's
    exact sample period N / gcd(N, k) (layout in ``ExcitationDesign``).

    Parameters
    ----------
    band_hz, resolution_hz, fs_hz, input_names, peak_current_a
        as in
        ``design_multisine``.
    settle_s
        settling wait per line [s], >= 0.
    n_cycles
        minimum cycles measured per line, >= 1.
    grid
        'full' or 'odd'.
    spacing, n_lines, amplitude_shape
        as in ``design_multisine``.
    lines
        explicit DFT bins to measure (e.g. a multisine's
        ``excited_lines``, for a like-for-like comparison); they must lie
        in the band; ``grid``, ``spacing`` and ``n_lines`` are then unused.

    Returns
    -------
    ExcitationDesign of kind 'stepped_sine' (M = L lines, Ne = Nu).
    """
    names, peaks = _inputs(input_names, peak_current_a)
    n, k_lo, k_hi = _common(band_hz, resolution_hz, fs_hz)
    _choice("grid", grid, ("full", "odd"))
    settle_s = float(settle_s)
    if not np.isfinite(settle_s) or settle_s < 0:
        raise ValueError(f"settle_s must be finite and >= 0 [s], got {settle_s!r}")
    cycles = _count("n_cycles", n_cycles, 1)
    if lines is None:
        lines = line_set(k_lo, k_hi, grid, spacing, n_lines)
    else:
        lines = np.unique(np.asarray(lines, dtype=np.int64))
        if lines.size == 0 or lines[0] < k_lo or lines[-1] > k_hi:
            raise ValueError(f"lines must be a non-empty set of bins within the band "
                             f"[{k_lo}, {k_hi}], got {lines.tolist()[:5]}...")
    shape = shape_amplitudes(amplitude_shape, lines * (fs_hz / n))
    period, transient, periods = stepped_sine_layout(lines, n, fs_hz, settle_s, cycles)
    # scale each line so its sampled (not continuous) peak is the wanted one
    sampled_peak = np.array([np.max(np.abs(np.sin(2 * np.pi * k * np.arange(p) / n)))
                             for k, p in zip(lines, period)])
    amps = peaks[:, None] * (shape / sampled_peak)[None, :]
    nu = len(names)
    unit = ExcitationDesign(
        kind="stepped_sine", fs_hz=fs_hz, n_per_period=n, n_periods=cycles, n_transient_periods=0,
        n_realisations=lines.size, n_experiments=nu, input_names=names, excited_lines=lines,
        detection_lines_odd=[], detection_lines_even=[], amplitudes_a=amps, phasors=None,
        peak_a=np.zeros(nu), rms_a=np.zeros(nu), crest_factor=np.zeros(nu),
        band_hz=band_hz, seed=None,
        options={"grid": grid, "spacing": spacing, "mimo": "one_at_a_time",
                 "shaped": amplitude_shape is not None},
        source={"settle_s": settle_s, "n_cycles": cycles, "period_samples": period.tolist(),
                "transient_periods": transient.tolist(), "periods": periods.tolist()})
    return _finish(unit)


# ---- swept sine -----------------------------------------------------------
def design_swept_sine(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                      input_names: Sequence[str], peak_current_a: float | Sequence[float],
                      n_periods: int = 4, n_realisations: int = 1, n_transient_periods: int = 1,
                      law: str = "linear", mimo: str = "one_at_a_time") -> ExcitationDesign:
    """Periodic swept sine: one sweep from band_hz[0] to band_hz[1] per period.

    The sweep lasts 1 / resolution_hz; it is exactly periodic but, unlike a
    multisine, not band-limited (some power lies outside the band and
    between the lines' neighbours). Realisations repeat the same sweep.

    Parameters
    ----------
    band_hz, resolution_hz, fs_hz, input_names, peak_current_a, n_periods, n_realisations, n_transient_periods
        as in ``design_multisine``.
    law
        'linear' or 'log'.
    mimo
        'one_at_a_time' or 'orthogonal' (Hadamard signs; Nu a power of 2).

    Returns
    -------
    ExcitationDesign of kind 'swept_sine'.
    """
    names, peaks = _inputs(input_names, peak_current_a)
    n, k_lo, k_hi = _common(band_hz, resolution_hz, fs_hz)
    mixing = _binary_mixing(mimo, len(names))
    _choice("law", law, ("linear", "log"))
    base = swept_sine_period(n, float(fs_hz), band_hz[0], band_hz[1], law)
    lines = np.arange(k_lo, k_hi + 1)
    line_amp = np.abs(np.fft.rfft(base)[lines]) * (2 / n)
    nu = len(names)
    unit = ExcitationDesign(
        kind="swept_sine", fs_hz=fs_hz, n_per_period=n,
        n_periods=_count("n_periods", n_periods, 1),
        n_transient_periods=_count("n_transient_periods", n_transient_periods, 0),
        n_realisations=_count("n_realisations", n_realisations, 1), n_experiments=mixing.shape[0],
        input_names=names, excited_lines=lines, detection_lines_odd=[], detection_lines_even=[],
        amplitudes_a=peaks[:, None] * line_amp[None, :], phasors=None,
        peak_a=np.zeros(nu), rms_a=np.zeros(nu), crest_factor=np.zeros(nu),
        band_hz=band_hz, seed=None, options={"law": law, "mimo": mimo},
        source={"f_start_hz": float(band_hz[0]), "f_stop_hz": float(band_hz[1]), "law": law,
                "scale_a": peaks.tolist(), "mixing": mixing.tolist()})
    return _finish(unit)


# ---- binary sequences -----------------------------------------------------
def _binary_design(kind: str, bits_per_realisation: list[np.ndarray], clock_divider: int,
                   fs_hz: float, names, peaks, lines, band_bins_, p, pt, mimo, seed,
                   options, band_hz=None) -> ExcitationDesign:
    mixing = _binary_mixing(mimo, len(names))
    n = bits_per_realisation[0].size * clock_divider
    spectra = np.array([np.abs(np.fft.rfft(binary_waveform(b, clock_divider))[lines])
                        for b in bits_per_realisation]) * (2 / n)
    odd, even = detection_lines(lines, *band_bins_)
    nu = len(names)
    unit = ExcitationDesign(
        kind=kind, fs_hz=fs_hz, n_per_period=n, n_periods=p, n_transient_periods=pt,
        n_realisations=len(bits_per_realisation), n_experiments=mixing.shape[0],
        input_names=names, excited_lines=lines, detection_lines_odd=odd,
        detection_lines_even=even,
        amplitudes_a=peaks[:, None] * spectra.mean(axis=0)[None, :], phasors=None,
        peak_a=np.zeros(nu), rms_a=np.zeros(nu), crest_factor=np.zeros(nu),
        band_hz=band_hz or (band_bins_[0] * fs_hz / n, band_bins_[1] * fs_hz / n), seed=seed,
        options=dict(options, mimo=mimo),
        source={"n_bits": int(bits_per_realisation[0].size), "clock_divider": clock_divider,
                "bits_hex": [np.packbits(b).tobytes().hex() for b in bits_per_realisation],
                "scale_a": peaks.tolist(), "mixing": mixing.tolist()})
    return _finish(unit)


def design_prbs(fs_hz: float, order: int, input_names: Sequence[str],
                peak_current_a: float | Sequence[float], clock_divider: int = 1,
                n_periods: int = 4, n_realisations: int = 1, n_transient_periods: int = 1,
                mimo: str = "one_at_a_time", seed: int = 0) -> ExcitationDesign:
    """Periodic PRBS (maximum-length sequence) with zero-mean levels.

    The period is N = clock_divider * (2^order - 1) samples; every DFT line
    below N/2 except multiples of 2^order - 1 carries power (the lines are
    all ``excited_lines``; the hold shapes them like sinc). Realisations are
    seeded cyclic shifts of the sequence.

    Parameters
    ----------
    fs_hz
        sample rate [Hz].
    order
        LFSR order, 2..23.
    input_names, peak_current_a
        as in ``design_multisine``.
    clock_divider
        samples per bit, >= 1.
    n_periods, n_realisations, n_transient_periods
        as in ``design_multisine``.
    mimo
        'one_at_a_time' or 'orthogonal' (Hadamard signs; Nu a power of 2).
    seed
        seed of the realisations' shifts.

    Returns
    -------
    ExcitationDesign of kind 'prbs'.
    """
    names, peaks = _inputs(input_names, peak_current_a)
    fs_hz = float(fs_hz)
    if not np.isfinite(fs_hz) or fs_hz <= 0:
        raise ValueError(f"fs_hz must be finite and > 0, got {fs_hz!r}")
    d = _count("clock_divider", clock_divider, 1)
    m = _count("n_realisations", n_realisations, 1)
    seed = _seed(seed)
    base = mls(_count("order", order, 2))
    n_bits = base.size
    n = d * n_bits
    shifts = np.random.default_rng(seed).integers(0, n_bits, m)
    bits = [np.roll(base, int(s)) for s in shifts]
    k = np.arange(1, (n - 1) // 2 + 1)
    lines = k[k % n_bits != 0]
    if lines.size == 0:
        raise ValueError("the PRBS has no excited line; raise order")
    return _binary_design("prbs", bits, d, fs_hz, names, peaks, lines,
                          (int(lines[0]), int(lines[-1])),
                          _count("n_periods", n_periods, 1),
                          _count("n_transient_periods", n_transient_periods, 0), mimo, seed,
                          {"order": int(order), "clock_divider": d})


def design_dibs(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                input_names: Sequence[str], peak_current_a: float | Sequence[float],
                n_periods: int = 4, n_realisations: int = 1, n_transient_periods: int = 1,
                grid: str = "odd", spacing: str = "linear", mimo: str = "one_at_a_time",
                amplitude_shape: AmplitudeShape = None, seed: int = 0,
                n_lines: int | None = None, group_size: int = 3,
                n_iterations: int = 100) -> ExcitationDesign:
    """Discrete-interval binary sequence with power concentrated on a line set.

    A binary signal cannot keep all its power on a sub-band: the fraction on
    the lines is in ``options['power_fraction']`` (per realisation). With the
    odd grids and even N the even lines stay exactly unexcited.

    Parameters
    ----------
    band_hz, resolution_hz, fs_hz, input_names, peak_current_a, n_periods, n_realisations, n_transient_periods, grid, spacing, amplitude_shape, seed, n_lines, group_size
        as in ``design_multisine``.
    mimo
        'one_at_a_time' or 'orthogonal' (Hadamard signs; Nu a power of 2).
    n_iterations
        DIBS iterations per realisation.

    Returns
    -------
    ExcitationDesign of kind 'dibs'; ``amplitudes_a`` is the mean over
    realisations (``reference_spectrum`` gives each exactly).
    """
    names, peaks = _inputs(input_names, peak_current_a)
    n, k_lo, k_hi = _common(band_hz, resolution_hz, fs_hz)
    m = _count("n_realisations", n_realisations, 1)
    seed = _seed(seed)
    rng = np.random.default_rng(seed)
    lines = line_set(k_lo, k_hi, grid, spacing, n_lines, group_size, rng)
    shape = shape_amplitudes(amplitude_shape, lines * (fs_hz / n))
    runs = [dibs_bits(n, lines, shape, rng, _count("n_iterations", n_iterations, 1))
            for _ in range(m)]
    return _binary_design("dibs", [b for b, _ in runs], 1, float(fs_hz), names, peaks, lines,
                          (k_lo, k_hi), _count("n_periods", n_periods, 1),
                          _count("n_transient_periods", n_transient_periods, 0), mimo, seed,
                          {"grid": grid, "spacing": spacing, "group_size": group_size,
                           "power_fraction": [f for _, f in runs]}, band_hz=band_hz)


# ---- noise ----------------------------------------------------------------
def design_noise(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                 input_names: Sequence[str], peak_current_a: float | Sequence[float],
                 n_periods: int = 8, n_realisations: int = 1, n_transient_periods: int = 1,
                 mimo: str = "simultaneous", crest_factor: float = 3.5,
                 seed: int = 0) -> ExcitationDesign:
    """Band-limited Gaussian noise (Kaiser FIR), clipped at the peak current.

    The RMS is peak / crest_factor; samples beyond the peak are clipped
    (2 Q(crest_factor) of them for Gaussian noise: 4.7e-4 at 3.5). The
    N-sample blocks ("periods", N = fs / resolution) are what the FRF
    estimator averages (windowed: noise leaks).

    Parameters
    ----------
    band_hz, resolution_hz, fs_hz, input_names, peak_current_a
        as in
        ``design_multisine``; band_hz[0] = 0 gives low-pass noise.
    n_periods
        steady-state blocks per segment.
    n_realisations
        independent noise records.
    n_transient_periods
        blocks discarded at each segment start (>= the
        filter length is advisable).
    mimo
        'simultaneous' (independent noise on every input, Ne = 1) or
        'one_at_a_time' (Ne = Nu).
    crest_factor
        peak / RMS, > 1.
    seed
        noise seed.

    Returns
    -------
    ExcitationDesign of kind 'noise'.
    """
    names, peaks = _inputs(input_names, peak_current_a)
    n, k_lo, k_hi = _common(band_hz, resolution_hz, fs_hz)
    _choice("mimo", mimo, MIMO_NOISE)
    crest = float(crest_factor)
    if not np.isfinite(crest) or crest <= 1:
        raise ValueError(f"crest_factor must be finite and > 1, got {crest_factor!r}")
    nu = len(names)
    mixing = np.ones((1, nu)) if mimo == "simultaneous" else np.eye(nu)
    spec = noise_filter_spec(band_hz, float(fs_hz))
    taps = noise_taps(spec, float(fs_hz))
    sigma = peaks / crest
    sigma_white = sigma / np.sqrt(np.sum(taps**2))
    lines = np.arange(k_lo, k_hi + 1)
    from scipy.signal import freqz  # imported only by a noise design (it costs ~0.3 s)

    gain = np.abs(freqz(taps, worN=lines * (float(fs_hz) / n), fs=float(fs_hz))[1])
    return ExcitationDesign(
        kind="noise", fs_hz=fs_hz, n_per_period=n, n_periods=_count("n_periods", n_periods, 1),
        n_transient_periods=_count("n_transient_periods", n_transient_periods, 0),
        n_realisations=_count("n_realisations", n_realisations, 1), n_experiments=mixing.shape[0],
        input_names=names, excited_lines=lines, detection_lines_odd=[], detection_lines_even=[],
        amplitudes_a=(2 * sigma_white / np.sqrt(n))[:, None] * gain[None, :], phasors=None,
        peak_a=peaks, rms_a=sigma, crest_factor=np.full(nu, crest), band_hz=band_hz,
        seed=_seed(seed), options={"mimo": mimo},
        source={"filter": spec, "sigma_white_a": sigma_white.tolist(), "mixing": mixing.tolist()})
