"""FRF estimation while the measurement streams in, one block at a time.

:class:`FrfStream` takes blocks ``(first_index, data)`` of any size, aligned
by absolute sample index to an :class:`ambid.excitation.ExcitationDesign`
that starts at ``start_index``. It cuts them at the design's period
boundaries (realisation-major layout, see :mod:`ambid.frf.periods`), drops
the transient periods and keeps of each steady-state period only its DFT at
the excited and detection lines (:func:`ambid.frf.periods.period_spectra`
scaling). Raw samples are held for one period at most, so memory is set by
the design (lines x periods x channels), not by the record length.

Data columns are, in this order: the Ny outputs y [m], the Nu applied
inputs u [A] and the Nu excitation (reference) channels r [A], with u and
r in the order of the design's inputs (:func:`match_inputs`).

Validity. The unit of an estimate is the record (m, p): period p of
realisation m measured in all Ne experiments. A gap in the sample indices
(a block that does not start where the previous one ended) drops every
period it touches; those periods are listed in a :class:`Gap` and never
enter an estimate. A realisation enters the estimates once the stream has
passed its end. Pooled estimators (indirect, H1, H2, the means), the
coherence and the input sensitivity use all kept records; the EIV ratio,
the noise and total variances and the distortion levels are formed per
realisation from its own records, as the robust method does; the output
noise is the period-to-period scatter of each completed segment. With no
gap, :meth:`FrfStream.estimate` equals the batch functions of
:mod:`ambid.frf` on the whole record (to rounding).

Kinds. Periodic designs with one period length (multisine, PRBS, DIBS,
swept sine) pool all records; the stepped sine is estimated line by line
(realisation m is line m, with its own period); for 'noise' the N-sample
blocks are Hann-windowed with their mean removed (a Welch estimate without
overlap, as :func:`ambid.frf.estimators.welch_frf`), only the indirect
and H1 estimators apply and period scatter gives no noise variance.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ambid.excitation.design import ExcitationDesign
from ambid.frf.directional import DirectionalFrf, directional_frf, has_planes
from ambid.frf.estimators import (arithmetic_mean, errors_in_variables, h1, h2, indirect, log_mean,
                                  multiple_coherence, per_period_frf)
from ambid.frf.sensitivity import input_sensitivity, iso14839_zone, sensitivity_peak
from ambid.frf.transient_model import SegmentTransients
from ambid.frf.uncertainty import DistortionLevels, distortion_levels, frf_noise_variance, noise_std_interval

__all__ = ["ESTIMATORS", "Gap", "BlockReport", "StreamProgress", "SynchronousResponse", "FrfResult", "FrfStream",
           "match_inputs", "loop_consistency"]

#: Estimator names, as in the FrfEstimate message.
ESTIMATORS = ("indirect", "h1", "h2", "arithmetic_mean", "log_mean", "eiv")
_NON_PERIODIC_ESTIMATORS = ("indirect", "h1")
_PREFIXES = ("ic_", "u_", "r_", "i_")


@dataclass(frozen=True)
class Gap:
    """Samples missing from the stream inside the experiment.

    Attributes
    ----------
    start_index
        absolute sample index of the first missing sample.
    n_samples
        number of missing samples.
    periods
        steady-state periods dropped because of it, as (m, e, p)
        (realisation, experiment, period counted after the transients).
    """

    start_index: int
    n_samples: int
    periods: tuple[tuple[int, int, int], ...]


@dataclass(frozen=True)
class BlockReport:
    """What one :meth:`FrfStream.add` call completed.

    Attributes
    ----------
    periods_completed
        steady-state periods completed (and kept).
    realisations_completed
        realisations the stream passed the end of.
    gaps
        gaps found (before this block's data).
    finished
        the stream reached the end of the experiment.
    """

    periods_completed: int
    realisations_completed: tuple[int, ...]
    gaps: tuple[Gap, ...]
    finished: bool


@dataclass(frozen=True)
class StreamProgress:
    """Where a stream is.

    Attributes
    ----------
    samples_done
        samples of the experiment passed (received or lost).
    total_samples
        samples of the experiment (after any truncation).
    periods_done
        steady-state periods kept so far.
    periods_total
        steady-state periods in the experiment.
    realisations_done
        realisations passed.
    n_realisations
        realisations within the experiment.
    time_left_s
        (total_samples - samples_done) / fs [s].
    finished
        the end was reached.
    """

    samples_done: int
    total_samples: int
    periods_done: int
    periods_total: int
    realisations_done: int
    n_realisations: int
    time_left_s: float
    finished: bool


@dataclass(frozen=True)
class SynchronousResponse:
    """The spinning rotor's synchronous response at the disturbance lines of a design steered clear of
    the harmonics k * Omega (:mod:`ambid.excitation.synchronous`): the complex mean over every record
    (period, experiment, realisation), phase-locked to the experiment's start when the harmonics fall on
    lines.

    Attributes
    ----------
    harmonic
        (D,) harmonic number k.
    freq_hz
        (D,) frequency of the disturbance line [Hz].
    lines
        (D,) its DFT bin.
    amplitude
        (D, C) |mean| of the line's complex amplitude per channel [m for y, A for u].
    phase_rad
        (D, C) its phase at the experiment's first sample [rad] (cosine reference).
    amplitude_std
        (D, C) standard uncertainty of each component of the complex mean, from the
        record-to-record scatter, and so of the amplitude where it is well above this [unit of the
        channel] (an amplitude within a few of these is biased upwards, as any |mean| is).
    channel_names
        (C,) the outputs, then the inputs.
    n_records
        records averaged.
    on_lines
        the harmonics fall exactly on lines (else leakage blurs amplitude and phase).
    """

    harmonic: np.ndarray
    freq_hz: np.ndarray
    lines: np.ndarray
    amplitude: np.ndarray
    phase_rad: np.ndarray
    amplitude_std: np.ndarray
    channel_names: tuple[str, ...]
    n_records: int
    on_lines: bool


@dataclass(frozen=True)
class FrfResult:
    """An FRF estimate with its uncertainty and the loop's figures.

    Attributes
    ----------
    estimator
        one of :data:`ESTIMATORS`.
    freq_hz
        (L,) line frequencies [Hz].
    lines
        (L,) DFT bins of the design's N-sample period.
    frf
        G (L, Ny, Nu), u -> y [unit of y / unit of u, e.g. m/A].
    var_noise
        (L, Ny, Nu) noise variance of G from period scatter
        [(m/A)^2] (the robust method's, see :mod:`ambid.frf.uncertainty`;
        with unequal record counts the one-record variance is pooled
        over realisations); NaN when no realisation has two records,
        and for the noise kind.
    var_total
        (L, Ny, Nu) total variance of G from realisation scatter
        (noise + stochastic nonlinear) [(m/A)^2]; NaN with M < 2.
    coherence
        (L, Ny) multiple coherence of y with r [-].
    sensitivity
        (L, Nu, Nu) input sensitivity r -> u [A/A].
    sensitivity_peak
        (Nu,) peak |S_ii| per input [-, absolute gain].
    sensitivity_peak_hz
        (Nu,) where the peak is [Hz].
    iso_zone
        ISO 14839-3 zone of the worst input ('A'..'D').
    distortion
        detection-line levels, or None without detection lines
        or with P < 2.
    noise_std
        (Ny,) output noise standard deviation from the
        period-to-period scatter of the time samples [unit of y]; NaN
        when not defined.
    noise_std_ci95
        (Ny, 2) its 95 % interval [unit of y], NaN with
        fewer than 2 segments (:func:`ambid.frf.uncertainty.noise_std_interval`).
    noise_std_sd
        (Ny,) the estimate's standard deviation [unit of y], NaN
        with fewer than 2 segments.
    output_names, input_names
        (Ny,), (Nu,) channel names.
    n_realisations
        realisations used.
    n_periods
        records (m, p) used, summed over realisations.
    n_experiments
        Ne.
    gaps
        every gap found so far.
    complete
        the whole experiment was processed.
    synchronous
        the synchronous response at the disturbance lines of a design steered clear of a
        spinning rotor's harmonics, or None (no such lines); those lines are in neither the FRF,
        its noise estimate nor the distortion levels.
    frf_realisations
        (M, L, Ny, Nu) G_m of each realisation (periodic
        multi-line designs), else None: the realisation-to-realisation
        scatter of anything computed from G.
    """

    estimator: str
    freq_hz: np.ndarray
    lines: np.ndarray
    frf: np.ndarray
    var_noise: np.ndarray
    var_total: np.ndarray
    coherence: np.ndarray
    sensitivity: np.ndarray
    sensitivity_peak: np.ndarray
    sensitivity_peak_hz: np.ndarray
    iso_zone: str
    distortion: DistortionLevels | None
    noise_std: np.ndarray
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    n_realisations: int
    n_periods: int
    n_experiments: int
    gaps: tuple[Gap, ...]
    complete: bool
    synchronous: SynchronousResponse | None = None
    frf_realisations: np.ndarray | None = None
    noise_std_ci95: np.ndarray | None = None
    noise_std_sd: np.ndarray | None = None

    def directional(self) -> DirectionalFrf | None:
        """Forward and backward whirl FRFs (:mod:`ambid.frf.directional`) of the radial bearing planes the
        channels name (x and y of a bearing among outputs and inputs), with the noise variance; None
        without such a plane."""
        if not has_planes(self.output_names, self.input_names):
            return None
        return directional_frf(self.freq_hz, self.frf, self.var_noise, self.output_names, self.input_names)

    @property
    def relative_noise_std(self) -> float:
        """Median over lines and elements of sqrt(var_noise) / |G| [-]; NaN if unknown."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.sqrt(self.var_noise) / np.abs(self.frf)
        rel = rel[np.isfinite(rel)]
        return float(np.median(rel)) if rel.size else float("nan")

    @property
    def nonlinear_ratio(self) -> float:
        """Median of var_total / var_noise [-] (about 1 for a linear system); NaN if unknown."""
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = self.var_total / self.var_noise
        ratio = ratio[np.isfinite(ratio)]
        return float(np.median(ratio)) if ratio.size else float("nan")


def axis_tag(name: str) -> str:
    """The axis a channel name tags: ``u_a_x`` -> ``a_x`` (prefixes u_, r_, ic_, i_); a bare name as it is."""
    for prefix in _PREFIXES:
        if name.startswith(prefix):
            return name[len(prefix):]
    return name


def match_inputs(design_inputs: Sequence[str], inputs: Sequence[str],
                 references: Sequence[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The u and r channels that carry the design's inputs, in the design's order.

    A design input is matched by its axis tag (the name without a ``u_``,
    ``r_``, ``ic_`` or ``i_`` prefix: ``u_a_x`` and ``a_x`` both tag
    ``a_x``) to ``inputs[i]`` and ``references[i]``. If the tags do not all
    match but the counts are equal, the channels are taken in order.

    Parameters
    ----------
    design_inputs
        (Nu,) the design's input names.
    inputs
        applied-current channel names u, e.g. ``u_a_x``.
    references
        excitation channel names r, one per input, same order.

    Returns
    -------
    (u names, r names), each (Nu,), ordered like ``design_inputs``.
    """
    inputs, references = tuple(inputs), tuple(references)
    if len(inputs) != len(references):
        raise ValueError(f"inputs {list(inputs)} and references {list(references)} must pair up "
                         "one to one (u_i is the current r_i is added to)")
    tags = [axis_tag(n) for n in inputs]
    wanted = [axis_tag(n) for n in design_inputs]
    if all(tags.count(t) == 1 for t in wanted):
        idx = [tags.index(t) for t in wanted]
        return tuple(inputs[i] for i in idx), tuple(references[i] for i in idx)
    if len(design_inputs) == len(inputs):
        return inputs, references
    raise ValueError(f"the design excites inputs {list(design_inputs)} but the channels given are "
                     f"inputs {list(inputs)}, references {list(references)}; pass the u and r "
                     "channels of the design's inputs")


def loop_consistency(frf: np.ndarray, sensitivity: np.ndarray, c_jw: np.ndarray) -> np.ndarray:
    """How well the measured G and S agree with a known controller C.

    With ``u = r - C y`` exactly (a linear, unsaturated controller fed with
    the measured y), the indirect G and the measured input sensitivity S
    satisfy ``S = (I + C G)^-1`` at every line, whatever the noise. A large
    deviation means the controller description is not what ran, or the
    loop saturated.

    Parameters
    ----------
    frf
        G (L, Ny, Nu) [m/A].
    sensitivity
        S (L, Nu, Nu) [A/A].
    c_jw
        controller FRF (L, Nu, Ny) in the ``u = r - C y`` convention
        [A/m] (the negative of a model that outputs ic).

    Returns
    -------
    (L,) relative deviation ||S - (I + C G)^-1||_F / ||S||_F [-].
    """
    frf, sensitivity, c_jw = np.asarray(frf), np.asarray(sensitivity), np.asarray(c_jw)
    n_lines, ny, nu = frf.shape
    if sensitivity.shape != (n_lines, nu, nu) or c_jw.shape != (n_lines, nu, ny):
        raise ValueError(f"need frf (L, Ny, Nu), sensitivity (L, Nu, Nu), c_jw (L, Nu, Ny); got "
                         f"{frf.shape}, {sensitivity.shape}, {c_jw.shape}")
    model = np.linalg.inv(np.eye(nu) + c_jw @ frf)
    return np.linalg.norm(sensitivity - model, axis=(1, 2)) / np.linalg.norm(sensitivity, axis=(1, 2))


def _estimate(name: str, y: np.ndarray, u: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Pooled estimators on (M, Ne, P, L, ch) spectra."""
    if name == "indirect":
        return indirect(y, u, r)
    if name == "h1":
        return h1(y, u)
    if name == "h2":
        return h2(y, u)
    if name == "arithmetic_mean":
        return arithmetic_mean(y, u)
    if name == "log_mean":
        return log_mean(y, u)
    raise AssertionError(name)


class FrfStream:
    """Incremental period spectra of one experiment; estimates at any time.

    Parameters
    ----------
    design
        the experiment's excitation design.
    output_names
        (Ny,) names of the y channels (labels).
    input_names
        (Nu,) names of the u channels, one per design input.
    reference_names
        (Nu,) names of the r channels, one per design input.
    start_index
        absolute sample index of the experiment's first sample.
    total_samples
        stop the experiment early after this many samples
        (default the design's whole length).

    Mutable: :meth:`add` changes it. Not thread-safe.
    """

    def __init__(self, design: ExcitationDesign, output_names: Sequence[str],
                 input_names: Sequence[str], reference_names: Sequence[str],
                 start_index: int = 0, total_samples: int | None = None) -> None:
        if not isinstance(design, ExcitationDesign):
            raise ValueError(f"design must be an ExcitationDesign, got {type(design).__name__}; "
                             "use ExcitationDesign.from_dict for a dict")
        self.design = design
        self.output_names = tuple(str(n) for n in output_names)
        self.input_names = tuple(str(n) for n in input_names)
        self.reference_names = tuple(str(n) for n in reference_names)
        ny, nu = len(self.output_names), len(self.input_names)
        if ny < 1:
            raise ValueError("output_names must name at least one y channel")
        if nu != design.n_inputs or len(self.reference_names) != nu:
            raise ValueError(f"the design has {design.n_inputs} inputs {list(design.input_names)}: "
                             f"give one u and one r channel for each (got inputs "
                             f"{list(self.input_names)}, references {list(self.reference_names)})")
        names = self.output_names + self.input_names + self.reference_names
        if len(set(names)) != len(names):
            raise ValueError(f"channel names must be distinct, got {list(names)}")
        if isinstance(start_index, bool) or int(start_index) != start_index or start_index < 0:
            raise ValueError(f"start_index must be an integer >= 0, got {start_index!r}")
        self.start_index = int(start_index)
        self._ny, self._nu = ny, nu
        self._n_ch = ny + 2 * nu
        d = design
        self._stepped = d.kind == "stepped_sine"
        self._periodic = d.is_periodic
        self._p, self._pt, self._np = (np.asarray(a, dtype=np.int64) for a in d.segment_layout())
        ne = d.n_experiments
        seg_len = np.repeat(self._p * (self._pt + self._np), ne)
        self._seg_start = np.concatenate(([0], np.cumsum(seg_len)))
        self._real_end = self._seg_start[ne::ne]
        # plain ints for the per-block bookkeeping (numpy scalars cost ~10x more per operation)
        self._seg_start_l = self._seg_start.tolist()
        self._real_end_l = self._real_end.tolist()
        self._p_l, self._pt_l = self._p.tolist(), self._pt.tolist()
        # lines analysed per realisation: (bins of that realisation's period, line count of each kind)
        if self._stepped:
            bins = d.excited_lines * self._p // d.n_per_period
            if np.any(bins * d.n_per_period != d.excited_lines * self._p):
                raise ValueError("stepped-sine layout: a period does not hold whole cycles of its line")
            self._bins = [np.array([b]) for b in bins]
            self._n_exc, self._n_odd, self._n_even = 1, 0, 0
            self._sync = None
        else:
            # a design steered clear of a spinning rotor's harmonics names its disturbance lines: analysed
            # after the detection lines, for the synchronous response alone
            self._sync = d.options.get("synchronous") or None
            dist = np.asarray(self._sync["disturbance_lines"] if self._sync else [], dtype=np.int64)
            all_lines = np.concatenate([d.excited_lines, d.detection_lines_odd,
                                        d.detection_lines_even, dist]).astype(np.int64)
            self._bins = [all_lines] * d.n_realisations
            self._n_exc, self._n_odd = d.excited_lines.size, d.detection_lines_odd.size
            self._n_even = d.detection_lines_even.size
        # period_spectra's scaling per line (2/N, 1/N at DC and Nyquist), applied to the rfft in _period_done
        self._scale = []
        for pm, b in zip(self._p.tolist(), self._bins):
            if b.size and (b.min() < 0 or b.max() > pm // 2):
                raise ValueError(f"lines {b.min()}..{b.max()} outside [0, N/2] for a period of N = {pm}")
            scale = np.where((b == 0) | (2 * b == pm), 1.0 / pm, 2.0 / pm)
            self._scale.append(scale[:, None])
        self._spec = [np.zeros((ne, int(pm), b.size, self._n_ch), complex)
                      for pm, b in zip(self._np, self._bins)]
        self._valid = [np.zeros((ne, int(pm)), bool) for pm in self._np]
        self._window = (None if self._periodic else
                        0.5 - 0.5 * np.cos(2 * np.pi * np.arange(d.n_per_period) / d.n_per_period))
        # measured without settling periods: each segment's transient is removed by one rational model of all the
        # segments' transients (ambid.frf.transient_model) instead of waiting for it
        self._transients = (SegmentTransients(d.n_per_period, d.n_periods, self._bins[0], ny + nu)
                            if self._periodic and not self._stepped and d.n_transient_periods == 0
                            and d.n_periods >= 2 else None)
        # the output noise without settling periods: the period scatter of each segment's second half, where
        # the transient has died away (P >= 4); with fewer periods, the local fits' residuals (a little high
        # where a transient is too sharp for them)
        self._noise_from = d.n_periods // 2 if self._transients is not None and d.n_periods >= 4 else None
        p_max = int(self._p.max())
        self._buf = np.zeros((p_max, self._n_ch))
        self._buf_key: tuple[int, int] | None = None  # (segment, period incl. transients)
        self._buf_fill = 0
        # output noise: Welford over the periods of the current segment, then summed per segment
        self._w_seg = -1
        self._w_count = 0
        # channel-major (ny, N): the updates then run along contiguous rows (3x faster than (N, ny))
        self._w_mean = np.zeros((ny, p_max))
        self._w_m2 = np.zeros((ny, p_max))
        self._noise_var_sum = np.zeros(ny)
        self._noise_segments = 0
        self._noise_seg_vars: list[np.ndarray] = []   # (ny,) per segment: the interval's scatter
        self._next: int | None = None
        self._pos = 0  # experiment offset passed (received or lost)
        self._seg_done = 0
        self._real_done = 0
        self._periods_done = 0
        self._gaps: list[Gap] = []
        self._end = int(self._seg_start[-1])
        if total_samples is not None:
            self.truncate(total_samples)

    # ---- channels ---------------------------------------------------------
    @property
    def channel_names(self) -> tuple[str, ...]:
        """Column order :meth:`add` expects: outputs, inputs, references."""
        return self.output_names + self.input_names + self.reference_names

    def columns(self, channel_names: Sequence[str]) -> np.ndarray:
        """Indices into ``channel_names`` (a block's columns) of :attr:`channel_names`.

        Raises
        ------
        ValueError
            naming the channels the block lacks.
        """
        names = list(channel_names)
        missing = [n for n in self.channel_names if n not in names]
        if missing:
            raise ValueError(f"block lacks channel(s) {missing}; it has {names}")
        return np.array([names.index(n) for n in self.channel_names], dtype=np.int64)

    def check_sample_period(self, sample_period_s: float) -> None:
        """Raise ValueError if a block's sample period [s] is not the design's 1 / fs."""
        if not abs(float(sample_period_s) * self.design.fs_hz - 1.0) < 1e-6:
            raise ValueError(f"sample period {sample_period_s!r} s does not match the design's "
                             f"1/{self.design.fs_hz:g} Hz; the design was made for another rate")

    # ---- progress ---------------------------------------------------------
    @property
    def end_index(self) -> int:
        """Absolute index one past the experiment's last sample."""
        return self.start_index + self._end

    @property
    def gaps(self) -> tuple[Gap, ...]:
        return tuple(self._gaps)

    @property
    def finished(self) -> bool:
        return self._pos >= self._end

    def progress(self) -> StreamProgress:
        """Counts and time left of the experiment."""
        n_real = int(np.count_nonzero(self._real_end <= self._end))
        total = 0
        for s in range(self._seg_start.size - 1):  # steady-state periods inside [0, end)
            m = s // self.design.n_experiments
            first = self._seg_start[s] + self._pt[m] * self._p[m]
            total += int(np.clip((self._end - first) // self._p[m], 0, self._np[m]))
        return StreamProgress(samples_done=min(self._pos, self._end), total_samples=self._end,
                              periods_done=self._periods_done, periods_total=total,
                              realisations_done=min(self._real_done, n_real), n_realisations=n_real,
                              time_left_s=max(self._end - self._pos, 0) / self.design.fs_hz,
                              finished=self.finished)

    def truncate(self, total_samples: int) -> None:
        """End the experiment after ``total_samples`` samples (a stopped experiment).

        Realisations not complete by then never enter an estimate.
        """
        if isinstance(total_samples, bool) or int(total_samples) != total_samples:
            raise ValueError(f"total_samples must be an integer, got {total_samples!r}")
        n = int(total_samples)
        if not 0 <= n <= int(self._seg_start[-1]):
            raise ValueError(f"total_samples {n} outside [0, {int(self._seg_start[-1])}] (the design's "
                             "length)")
        self._end = n

    # ---- feeding ------------------------------------------------------------
    def add(self, first_index: int, data: np.ndarray) -> BlockReport:
        """Feed a block of consecutive samples.

        Parameters
        ----------
        first_index
            absolute sample index of the block's first row.
        data
            (n, Ny + 2 Nu) samples, columns as :attr:`channel_names`
            [m for y, A for u and r].

        Returns
        -------
        :class:`BlockReport`.

        Raises
        ------
        ValueError
            bad shape, NaN/inf, or a block starting before the
            end of the previous one (overlap or out of order); the stream
            is unchanged then.
        """
        if isinstance(first_index, bool) or int(first_index) != first_index or first_index < 0:
            raise ValueError(f"first_index must be an integer >= 0, got {first_index!r}")
        first_index = int(first_index)
        data = np.asarray(data, dtype=float)
        if data.ndim != 2 or data.shape[1] != self._n_ch:
            raise ValueError(f"data must have shape (n, {self._n_ch}) with columns "
                             f"{list(self.channel_names)}, got {data.shape}")
        if not math.isfinite(data.sum()) and not np.all(np.isfinite(data)):  # sum: fast path
            raise ValueError("data contains NaN or inf; the block cannot be used")
        if self._next is not None and first_index < self._next:
            raise ValueError(f"block starts at sample {first_index} but samples up to "
                             f"{self._next - 1} were already added: blocks must come in index order "
                             "without overlap")
        report = {"periods": 0, "realisations": [], "gaps": []}
        expected = self.start_index if self._next is None else self._next
        if first_index > expected:
            self._gap(expected, first_index, report)
        self._next = first_index + data.shape[0]
        a = first_index - self.start_index
        off, stop = max(a, 0), min(a + data.shape[0], self._end)
        if off > self._pos:
            self._advance(off, report)
        ne = self.design.n_experiments
        while off < stop:
            s = bisect.bisect_right(self._seg_start_l, off) - 1
            m = s // ne
            pm = self._p_l[m]
            seg0 = self._seg_start_l[s]
            j = (off - seg0) // pm
            p_start = seg0 + j * pm
            take = min(stop, p_start + pm) - off
            if j >= self._pt_l[m]:
                if off == p_start:
                    self._buf_key, self._buf_fill = (s, j), 0
                if self._buf_key == (s, j) and self._buf_fill == off - p_start:
                    self._buf[self._buf_fill:self._buf_fill + take] = data[off - a:off - a + take]
                    self._buf_fill += take
                    if self._buf_fill == pm:
                        self._period_done(s, j)
                        report["periods"] += 1
            off += take
            self._advance(off, report)
        return BlockReport(report["periods"], tuple(report["realisations"]), tuple(report["gaps"]),
                           self.finished)

    def _gap(self, lo: int, hi: int, report: dict) -> None:
        """Samples [lo, hi) (absolute) are missing: drop the partial period, list the periods hit."""
        self._buf_key = None
        a, b = max(lo - self.start_index, 0), min(hi - self.start_index, self._end)
        if a >= b:
            return
        periods = []
        ne = self.design.n_experiments
        s0 = int(np.searchsorted(self._seg_start, a, side="right")) - 1
        for s in range(s0, self._seg_start.size - 1):
            seg0 = int(self._seg_start[s])
            if seg0 >= b:
                break
            m, e = divmod(s, ne)
            pm, pt = int(self._p[m]), int(self._pt[m])
            j_lo, j_hi = max(a - seg0, 0) // pm, (min(b, int(self._seg_start[s + 1])) - 1 - seg0) // pm
            periods += [(m, e, j - pt) for j in range(max(j_lo, pt), j_hi + 1)]
        gap = Gap(start_index=self.start_index + a, n_samples=b - a, periods=tuple(periods))
        self._gaps.append(gap)
        report["gaps"].append(gap)

    def _period_done(self, s: int, j: int) -> None:
        m, e = divmod(s, self.design.n_experiments)
        pm = int(self._p[m])
        x = self._buf[:pm]
        if self._window is not None:
            x = (x - x.mean(axis=0)) * self._window[:, None]
        p = j - int(self._pt[m])
        # period_spectra(x[None, None, None], bins)[0, 0, 0], bit for bit, without its per-call checks
        np.multiply(np.fft.rfft(x, axis=0)[self._bins[m]], self._scale[m], out=self._spec[m][e, p])
        self._valid[m][e, p] = True
        self._periods_done += 1
        self._buf_key = None
        if self._transients is not None and self._transients.add(s, p, x) and self._noise_from is None:
            v = self._transients.noise_var_time(s)[:self._ny]
            self._noise_var_sum += v
            self._noise_segments += 1
            self._noise_seg_vars.append(v)
        if self._periodic and (self._transients is None or (self._noise_from is not None and p >= self._noise_from)):
            if self._w_seg != s:
                self._w_seg, self._w_count = s, 0
                self._w_mean[:] = 0.0
                self._w_m2[:] = 0.0
            y = self._buf[:pm, :self._ny].T
            self._w_count += 1
            delta = y - self._w_mean[:, :pm]
            self._w_mean[:, :pm] += delta / self._w_count
            self._w_m2[:, :pm] += delta * (y - self._w_mean[:, :pm])

    def _advance(self, off: int, report: dict) -> None:
        """The stream has passed experiment offset ``off``: close segments and realisations."""
        self._pos = max(self._pos, off)
        reached = min(self._pos, self._end)
        seg_start, n_seg = self._seg_start_l, len(self._seg_start_l) - 1
        while self._seg_done < n_seg and seg_start[self._seg_done + 1] <= reached:
            if self._w_seg == self._seg_done and self._w_count >= 2:
                pm = self._p_l[self._seg_done // self.design.n_experiments]
                var = np.ascontiguousarray((self._w_m2[:, :pm] / (self._w_count - 1)).T)
                self._noise_var_sum += var.mean(axis=0)   # (N, ny) as before: the same summation order
                self._noise_segments += 1
                self._noise_seg_vars.append(var.mean(axis=0))
            self._seg_done += 1
        real_end = self._real_end_l
        while self._real_done < len(real_end) and real_end[self._real_done] <= reached:
            report["realisations"].append(self._real_done)
            self._real_done += 1

    # ---- estimating ---------------------------------------------------------
    def _records(self, m: int) -> np.ndarray:
        """(Ne, K, L, ch) spectra of the records of realisation m kept in all experiments."""
        return self._spec[m][:, self._valid[m].all(axis=0)]

    @property
    def records_done(self) -> int:
        """Records (m, p) complete in all Ne experiments so far, the running realisation's included."""
        return int(sum(np.count_nonzero(v.all(axis=0)) for v in self._valid))

    def estimate(self, estimator: str = "indirect", partial: bool = False) -> FrfResult | None:
        """The FRF from the realisations passed so far, or None if there is none yet.

        Parameters
        ----------
        estimator
            one of :data:`ESTIMATORS` (the noise kind takes
            'indirect' or 'h1').
        partial
            also use the records of the realisation still running
            (a live preview after every record; the final estimate is the
            same either way, since the last realisation has then passed).

        Returns
        -------
        :class:`FrfResult`, or None before the first realisation with a
        complete record.

        Raises
        ------
        ValueError
            unknown estimator, or an estimator that cannot be
            formed from these data (e.g. h2 with Ny != Nu, an input not
            excited).
        """
        if estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
        if not self._periodic and estimator not in _NON_PERIODIC_ESTIMATORS:
            raise ValueError(f"a noise excitation is not periodic: use one of "
                             f"{_NON_PERIODIC_ESTIMATORS}, not {estimator!r}")
        last = min(self._real_done + (1 if partial else 0), len(self._valid))
        used = [m for m in range(last)
                if self._real_end[m] <= self._end and self._valid[m].all(axis=0).any()]
        if self._transients is not None:   # a segment with a gap has no transient-free spectrum
            ne = self.design.n_experiments
            used = [m for m in used if all(self._transients.complete(m * ne + e) for e in range(ne))]
        if not used:
            return None
        ny, nu = self._ny, self._nu
        groups = [self._records(m)[None] for m in used]          # each (1, Ne, K_m, L, ch)
        if self._transients is not None:                          # one transient-free record per segment
            groups = [self._transient_free(m)[None] for m in used]
        if self._stepped:   # one line per realisation: estimate line by line
            parts = [self._figures(estimator, [g], [m]) for g, m in zip(groups, used)]
            fig = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]
                   if k not in ("distortion", "frf_realisations")}
            fig["distortion"] = fig["frf_realisations"] = None
            lines = self.design.excited_lines[used]
        else:
            fig = self._figures(estimator, groups, used)
            lines = self.design.excited_lines
        peak, idx = sensitivity_peak(fig["sensitivity"])
        freq = lines * (self.design.fs_hz / self.design.n_per_period)
        noise_std = (np.sqrt(self._noise_var_sum / self._noise_segments) if self._noise_segments
                     else np.full(ny, np.nan))
        noise_sd, noise_ci = noise_std_interval(np.array(self._noise_seg_vars).reshape(-1, ny))
        return FrfResult(
            estimator=estimator, freq_hz=freq, lines=np.asarray(lines, dtype=np.int64),
            frf=fig["frf"], var_noise=fig["var_noise"], var_total=fig["var_total"],
            coherence=fig["coherence"], sensitivity=fig["sensitivity"], sensitivity_peak=peak,
            sensitivity_peak_hz=freq[idx], iso_zone=iso14839_zone(peak.max()),
            distortion=fig["distortion"], noise_std=noise_std, output_names=self.output_names,
            input_names=self.input_names, n_realisations=len(used),
            n_periods=int(sum(g.shape[2] for g in groups)), n_experiments=self.design.n_experiments,
            gaps=self.gaps, complete=self.finished, frf_realisations=fig["frf_realisations"],
            synchronous=None if self._sync is None else self._synchronous(groups),
            noise_std_ci95=noise_ci, noise_std_sd=noise_sd)

    def _synchronous(self, groups: list[np.ndarray]) -> SynchronousResponse | None:
        """Mean and scatter of the disturbance lines over all records (y and u channels)."""
        first = self._n_exc + self._n_odd + self._n_even
        d = self.design
        if len(self._bins[0]) == first:
            return None
        nc = self._ny + self._nu
        x = np.concatenate([g[0, :, :, first:, :nc].reshape(-1, len(self._bins[0]) - first, nc) for g in groups])
        k = x.shape[0]
        mean = x.mean(axis=0)
        std = (np.sqrt(np.sum(np.abs(x - mean) ** 2, axis=0) / (2 * (k - 1) * k)) if k >= 2
               else np.full(mean.shape, np.nan))
        lines = np.asarray(self._sync["disturbance_lines"], dtype=np.int64)
        return SynchronousResponse(
            harmonic=np.asarray(self._sync["disturbance_harmonics"], dtype=np.int64),
            freq_hz=lines * (d.fs_hz / d.n_per_period), lines=lines, amplitude=np.abs(mean),
            phase_rad=np.angle(mean), amplitude_std=std, channel_names=self.output_names + self.input_names,
            n_records=k, on_lines=bool(self._sync["on_lines"]))

    def _figures(self, estimator: str, groups: list[np.ndarray], used: list[int]) -> dict:
        """Estimates from per-realisation spectra groups (1, Ne, K_m, L, ch)."""
        ny, nu, n_exc, n_odd = self._ny, self._nu, self._n_exc, self._n_odd

        def split(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            x = x[:, :, :, :n_exc]
            return x[..., :ny], x[..., ny:ny + nu], x[..., ny + nu:]

        pooled = np.concatenate(groups, axis=2)                  # records of all realisations
        y, u, r = split(pooled)
        if estimator == "eiv":
            frf = np.mean([errors_in_variables(*split(g)[:2]) for g in groups], axis=0)
        else:
            frf = _estimate(estimator, y, u, r)
        shape = frf.shape
        var_noise = np.full(shape, np.nan)
        var_total = np.full(shape, np.nan)
        distortion = g_m = None
        if self._transients is not None:
            var_noise, var_total, distortion, g_m = self._transient_figures(groups, used, split, shape)
        elif self._periodic:
            # G_m per realisation; the noise variance of one record's solution, s2_m = K_m var_n(G_m),
            # is pooled over the realisations (weights K_m - 1), so that a realisation a gap left
            # with one record still gets var_n(G_m) = s2 / K_m. Equal K_m: the robust method's.
            g_m, s2, dof = [], np.zeros(shape), 0
            for g in groups:
                k = g.shape[2]
                if k >= 2:
                    gm, vn = frf_noise_variance(*split(g))
                    s2 = s2 + (k - 1) * (k * vn[0])
                    dof += k - 1
                else:
                    gm = per_period_frf(*split(g))[:, 0]
                g_m.append(gm[0])
            g_m, n = np.array(g_m), len(groups)
            if dof:
                s2 = s2 / dof
                var_noise = np.mean([s2 / g.shape[2] for g in groups], axis=0) / n
            if n >= 2:
                var_total = g_m.var(axis=0, ddof=1) / n
            det = [g for g in groups if g.shape[2] >= 2]
            if det and not self._stepped:
                n_even = self._n_even
                levels = [distortion_levels(g[:, :, :, n_exc:n_exc + n_odd, :ny],
                                            g[:, :, :, n_exc + n_odd:n_exc + n_odd + n_even, :ny]) for g in det]
                distortion = _mean_levels(levels)
        return {"frf": frf, "var_noise": var_noise, "var_total": var_total,
                "coherence": multiple_coherence(y, r), "sensitivity": input_sensitivity(u, r),
                "distortion": distortion, "frf_realisations": g_m}

    def _transient_free(self, m: int) -> np.ndarray:
        """(Ne, 1, L, ch) line spectra of realisation m's segments, transient removed."""
        ne = self.design.n_experiments
        return np.stack([self._transients.spectra(m * ne + e) for e in range(ne)])[:, None]

    def _transient_figures(self, groups: list[np.ndarray], used: list[int], split, shape) -> tuple:
        """var_noise, var_total, distortion levels and G_m from the transient-free spectra and the noise
        covariance of the local fits: per realisation ``var G_ij = sum_e (a_i C_e a_i^H) |W_ej|^2``,
        ``a_i = [e_i, -G_i]``, ``W = R^H (U R^H)^-1`` (first order, :mod:`ambid.frf.lpm`)."""
        ny, nu, n_exc, n_odd, n_even = self._ny, self._nu, self._n_exc, self._n_odd, self._n_even
        ne = self.design.n_experiments
        g_m, v_m, odd, even = [], [], [], []
        for g, m in zip(groups, used):
            y, u, r = (np.moveaxis(a[0, :, 0], 0, -1) for a in split(g))      # (L, ch, Ne)
            r_h = np.conj(np.swapaxes(r, -1, -2))
            w = r_h @ np.linalg.inv(u @ r_h)                                   # (L, Ne, Nu)
            gm = y @ w
            cov = np.stack([self._transients.results[m * ne + e].noise_cov[:n_exc] for e in range(ne)], axis=1)
            a = np.concatenate([np.broadcast_to(np.eye(ny), (n_exc, ny, ny)), -gm], axis=2)
            out = np.real(np.einsum("lia,leab,lib->lie", a, cov, a.conj()))    # (L, Ny, Ne)
            g_m.append(gm)
            v_m.append(np.einsum("lie,lej->lij", out, np.abs(w) ** 2))
            levels = []
            for lo, hi in ((n_exc, n_exc + n_odd), (n_exc + n_odd, n_exc + n_odd + n_even)):
                spec = g[0, :, 0, lo:hi, :ny]                                  # (Ne, Ld, Ny)
                var = np.stack([np.real(np.diagonal(self._transients.results[m * ne + e].noise_cov[lo:hi, :ny, :ny],
                                                    axis1=1, axis2=2)) for e in range(ne)])
                levels.append((np.abs(spec) ** 2, var))
            odd.append(levels[0])
            even.append(levels[1])
        g_m, n = np.array(g_m), len(used)
        var_noise = np.mean(v_m, axis=0) / n
        var_total = g_m.var(axis=0, ddof=1) / n if n >= 2 else np.full(shape, np.nan)

        def level(parts):
            power = np.mean([p for p, _ in parts], axis=(0, 1))
            noise = np.mean([v for _, v in parts], axis=(0, 1))
            return power, noise

        distortion = None
        if n_odd or n_even:
            (op, on), (ep, en) = level(odd), level(even)
            distortion = _mean_levels([DistortionLevels(op, on, ep, en, op[:0, 0], ep[:0, 0])])
        return var_noise, var_total, distortion, g_m


def _mean_levels(levels: list[DistortionLevels]) -> DistortionLevels:
    """Average detection-line levels over realisations (each is a mean over its experiments)."""
    def mean(name: str) -> np.ndarray:
        return np.mean([getattr(lv, name) for lv in levels], axis=0)

    def db(power: np.ndarray, noise: np.ndarray) -> np.ndarray:
        if power.shape[0] == 0:
            return np.full(power.shape[1], np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            return 10 * np.log10(power.sum(axis=0) / noise.sum(axis=0))

    odd, odd_n, even, even_n = (mean(k) for k in ("odd_power", "odd_noise_power", "even_power",
                                                  "even_noise_power"))
    return DistortionLevels(odd_power=odd, odd_noise_power=odd_n, even_power=even,
                            even_noise_power=even_n, odd_db=db(odd, odd_n), even_db=db(even, even_n))
