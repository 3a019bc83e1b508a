"""`ExcitationDesign`: everything needed to generate and process an experiment.

Sample layout (the FRF code and the ROS generator rely on it). An
experiment is a sequence of segments, realisation-major::

    for m in range(M):            # realisations
        for e in range(Ne):       # experiments (MIMO)
            Pt transient periods, then P steady-state periods, each p_m samples

For every kind but the stepped sine p_m = N, Pt and P are the same for all
segments and the total is M * Ne * (Pt + P) * N samples. Periodic kinds
repeat their period within a segment. Kind by kind:

- 'multisine': x_i[n] = sum_l A[i, l] Re(P[m, e, i, l] exp(j 2 pi k_l n / N)).
- 'prbs', 'dibs': a zero-mean binary waveform b_m (one per realisation)
  scaled per input and signed by the mixing matrix:
  x_i = scale[i] * mixing[e, i] * b_m.
- 'swept_sine': the same with one sweep per period.
- 'noise': not periodic; each segment is one continuous stream of filtered
  noise (its own stream per (m, e) and input), clipped at the peak; the
  "periods" are the N-sample blocks the FRF code averages over (with a
  window), the transient blocks hold the filter's start-up.
- 'recorded': an excitation found in a rig's record that does not repeat
  itself (noise, chirps, a record started mid-run): no waveform to
  generate, one segment of ``N = n_per_period`` samples, the whole record;
  the FRF comes from the local polynomial method (:mod:`ambid.frf.lpm`) at
  the window centres ``excited_lines`` (DFT bins of N), with the settings
  in ``options['lpm']``.
- 'stepped_sine': realisation m is line m (M = L lines); experiment e
  excites input e with A[e, m] sin(2 pi k_m n / N). Its period p_m =
  N / gcd(N, k_m) samples holds an integer number of cycles; Pt_m periods
  settle (>= settle_s) and P_m periods are measured (>= n_cycles cycles);
  see ``segment_layout``.

``samples(start, n)`` computes any block without materialising the
experiment: it keeps at most one period (the last (m, e) used) in a cache.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ambid.jsonable import to_jsonable

from .multisine import multisine_period
from .signals import binary_waveform, filtered_noise, noise_taps, swept_sine_period

KINDS = ("multisine", "stepped_sine", "swept_sine", "noise", "prbs", "dibs", "recorded")
FORMAT = "ambid.excitation.design/1"


class SegmentIndex(NamedTuple):
    """Where a sample lies: realisation m, experiment e, period (transients first)."""

    m: int
    e: int
    period: int


def _int_array(x: Any) -> np.ndarray:
    a = np.array(x, dtype=np.int64).reshape(-1)
    a.setflags(write=False)
    return a


def _float_array(x: Any) -> np.ndarray:
    a = np.array(x, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ExcitationDesign:
    """A designed excitation; build it with the ``design_*`` functions.

    Attributes
    ----------
    kind
        one of KINDS.
    fs_hz
        sample rate [Hz].
    n_per_period
        N, samples per period; lines are DFT bins of N.
    n_periods
        P, steady-state periods per segment (stepped sine: the
        minimum measured cycles per line; see ``segment_layout``).
    n_transient_periods
        Pt, transient periods per segment (stepped
        sine: 0; its settling is per line in ``segment_layout``).
    n_realisations
        M (stepped sine: the number of lines).
    n_experiments
        Ne.
    input_names
        (Nu,) names of the inputs.
    excited_lines
        (L,) int DFT bins carrying the excitation (for
        'prbs' every line with power; for 'dibs' the lines the power was
        concentrated on; for 'swept_sine' and 'noise' the band's lines).
    detection_lines_odd, detection_lines_even
        unexcited odd and even
        lines within the band (empty where a kind has none).
    amplitudes_a
        (Nu, L) amplitude of each line per input [A] (for
        'noise' the expected RMS line amplitude of one N-block).
    phasors
        (M, Ne, Nu, L) complex phase factors for 'multisine'
        (0 where an input is not excited), else None; the matrix over
        (input, experiment) at line l is ``phasors[m, :, :, l].T``.
    peak_a, rms_a
        (Nu,) peak and RMS of each input while excited [A]
        (noise: RMS before clipping).
    crest_factor
        (Nu,) peak / RMS, worst period [-].
    band_hz
        (f_lo, f_hi) band of interest [Hz].
    seed
        integer seed the random choices came from (None if none).
    options
        JSON-safe design choices (grid, spacing, phases, mimo, ...).
    source
        JSON-safe kind-specific data that regenerates the waveform.
    """

    kind: str
    fs_hz: float
    n_per_period: int
    n_periods: int
    n_transient_periods: int
    n_realisations: int
    n_experiments: int
    input_names: tuple[str, ...]
    excited_lines: np.ndarray
    detection_lines_odd: np.ndarray
    detection_lines_even: np.ndarray
    amplitudes_a: np.ndarray
    phasors: np.ndarray | None
    peak_a: np.ndarray
    rms_a: np.ndarray
    crest_factor: np.ndarray
    band_hz: tuple[float, float]
    seed: int | None
    options: dict = field(default_factory=dict)
    source: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        setf = object.__setattr__
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        setf(self, "fs_hz", float(self.fs_hz))
        for name in ("n_per_period", "n_periods", "n_realisations", "n_experiments",
                     "n_transient_periods"):
            value, least = getattr(self, name), 0 if name == "n_transient_periods" else 1
            if isinstance(value, bool) or int(value) != value or value < least:
                raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")
            setf(self, name, int(value))
        setf(self, "input_names", tuple(str(s) for s in self.input_names))
        setf(self, "band_hz", (float(self.band_hz[0]), float(self.band_hz[1])))
        for name in ("excited_lines", "detection_lines_odd", "detection_lines_even"):
            setf(self, name, _int_array(getattr(self, name)))
        for name in ("amplitudes_a", "peak_a", "rms_a", "crest_factor"):
            setf(self, name, _float_array(getattr(self, name)))
        for name in ("fs_hz", "amplitudes_a", "peak_a", "rms_a", "crest_factor", "phasors"):
            value = getattr(self, name)
            if value is not None and not np.all(np.isfinite(value)):
                raise ValueError(f"{name} holds NaN or inf")
        nu, n_lines = len(self.input_names), self.excited_lines.size
        if self.amplitudes_a.shape != (nu, n_lines):
            raise ValueError(f"amplitudes_a must have shape (Nu, L) = {(nu, n_lines)}, "
                             f"got {self.amplitudes_a.shape}")
        if self.phasors is not None:
            ph = np.array(self.phasors, dtype=complex)
            want = (self.n_realisations, self.n_experiments, nu, n_lines)
            if ph.shape != want:
                raise ValueError(f"phasors must have shape (M, Ne, Nu, L) = {want}, got {ph.shape}")
            ph.setflags(write=False)
            setf(self, "phasors", ph)
        # private copies: the caller's dicts cannot change a frozen design
        setf(self, "options", to_jsonable(self.options))
        setf(self, "source", to_jsonable(self.source))
        layout = self._make_layout()
        for a in layout:
            a.setflags(write=False)
        setf(self, "_layout", layout)
        if self.kind == "noise":
            setf(self, "_taps", noise_taps(self.source["filter"], self.fs_hz))
        seg_len = np.repeat(layout[0] * (layout[1] + layout[2]), self.n_experiments)
        setf(self, "_seg_start", np.concatenate(([0], np.cumsum(seg_len))))
        # (key, period) of the last (m, e) generated; replaced whole, so a
        # reader in another thread never sees a key with another's period.
        setf(self, "_cache", (None, None))

    # ---- layout -----------------------------------------------------------
    @property
    def n_inputs(self) -> int:
        """Nu, number of inputs."""
        return len(self.input_names)

    @property
    def freq_hz(self) -> np.ndarray:
        """(L,) frequency of each excited line [Hz]."""
        return self.excited_lines * (self.fs_hz / self.n_per_period)

    @property
    def is_periodic(self) -> bool:
        """True unless the kind is 'noise' or 'recorded'."""
        return self.kind not in ("noise", "recorded")

    def segment_layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-realisation layout (period_samples, transient_periods, periods), each (M,) int.

        Every experiment e of realisation m has the same layout.
        """
        return self._layout

    def _make_layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.kind == "stepped_sine":
            s = self.source
            out = tuple(np.array(s[k], dtype=np.int64)
                        for k in ("period_samples", "transient_periods", "periods"))
            if any(a.shape != (self.n_realisations,) for a in out):
                raise ValueError("a stepped-sine source needs period_samples, transient_periods "
                                 "and periods for each line (realisation)")
            return out
        m = self.n_realisations
        return (np.full(m, self.n_per_period, dtype=np.int64),
                np.full(m, self.n_transient_periods, dtype=np.int64),
                np.full(m, self.n_periods, dtype=np.int64))

    @property
    def dt_s(self) -> float:
        """Sample period [s] = 1 / fs_hz: the one place a design's rate becomes a period."""
        return 1.0 / self.fs_hz

    @property
    def total_samples(self) -> int:
        """Length of the whole experiment [samples]."""
        return int(self._seg_start[-1])

    @property
    def measurement_time_s(self) -> float:
        """Length of the whole experiment [s] = total_samples / fs_hz."""
        return self.total_samples / self.fs_hz

    def segment_start(self, m: int, e: int) -> int:
        """First sample of segment (m, e) relative to the experiment start."""
        return int(self._seg_start[m * self.n_experiments + e])

    def segment_of(self, sample_offset: int) -> SegmentIndex:
        """(m, e, period index counting transient periods) of a sample offset."""
        off = int(sample_offset)
        if not 0 <= off < self.total_samples:
            raise ValueError(
                f"sample_offset {off} outside the experiment [0, {self.total_samples})")
        s = int(np.searchsorted(self._seg_start, off, side="right")) - 1
        m, e = divmod(s, self.n_experiments)
        period = int(self.segment_layout()[0][m])
        return SegmentIndex(m, e, (off - int(self._seg_start[s])) // period)

    # ---- waveform ---------------------------------------------------------
    def period(self, m: int, e: int) -> np.ndarray:
        """One period of segment (m, e), shape (p_m, Nu) [A] (periodic kinds)."""
        if not self.is_periodic:
            raise ValueError("a noise design has no period; use samples()")
        key = (int(m), int(e))
        if not (0 <= key[0] < self.n_realisations and 0 <= key[1] < self.n_experiments):
            raise ValueError(f"segment (m, e) = {key} outside (M, Ne) = "
                             f"{(self.n_realisations, self.n_experiments)}")
        cached = self._cache
        if cached[0] == key:
            return cached[1]
        out = self._make_period(*key)
        out.setflags(write=False)
        object.__setattr__(self, "_cache", (key, out))
        return out

    def _make_period(self, m: int, e: int) -> np.ndarray:
        n, src = self.n_per_period, self.source
        if self.kind == "multisine":
            return multisine_period(n, self.excited_lines, self.amplitudes_a, self.phasors[m, e]).T
        if self.kind == "stepped_sine":
            p = int(src["period_samples"][m])
            out = np.zeros((p, self.n_inputs))
            out[:, e] = self.amplitudes_a[e, m] * np.sin(
                2 * np.pi * self.excited_lines[m] * np.arange(p) / n)
            return out
        if self.kind in ("prbs", "dibs"):
            bits = np.unpackbits(np.frombuffer(bytes.fromhex(src["bits_hex"][m]), dtype=np.uint8))
            base = binary_waveform(bits[:src["n_bits"]].astype(bool), src["clock_divider"])
        else:  # swept_sine
            base = swept_sine_period(n, self.fs_hz, src["f_start_hz"], src["f_stop_hz"], src["law"])
        gain = np.asarray(src["scale_a"]) * np.asarray(src["mixing"])[e]
        return base[:, None] * gain[None, :]

    def _noise(self, m: int, e: int, lo: int, hi: int) -> np.ndarray:
        src = self.source
        white = filtered_noise(self._taps, (int(self.seed), m, e), lo, hi, self.n_per_period,
                               self.n_inputs)
        gain = np.asarray(src["sigma_white_a"]) * np.asarray(src["mixing"])[e]
        clip = np.asarray(self.peak_a)
        return np.clip(white * gain, -clip, clip)

    def samples(self, start: int, n: int) -> np.ndarray:
        """Excitation for sample offsets [start, start + n) of the experiment.

        Parameters
        ----------
        start
            first sample offset, >= 0.
        n
            number of samples, >= 0, start + n <= total_samples.

        Returns
        -------
        (n, Nu) excitation [A]; contiguous calls join without gap or overlap.
        """
        start, n = int(start), int(n)
        if start < 0 or n < 0 or start + n > self.total_samples:
            raise ValueError(f"samples({start}, {n}) reaches outside the experiment "
                             f"[0, {self.total_samples}); keep 0 <= start and "
                             "start + n <= total_samples")
        out = np.zeros((n, self.n_inputs))
        stop = start + n
        s = int(np.searchsorted(self._seg_start, start, side="right")) - 1
        periods = self.segment_layout()[0]
        while n and s < self._seg_start.size - 1 and self._seg_start[s] < stop:
            seg0 = int(self._seg_start[s])
            a, b = max(start, seg0), min(stop, int(self._seg_start[s + 1]))
            m, e = divmod(s, self.n_experiments)
            if self.is_periodic:
                idx = np.arange(a - seg0, b - seg0) % int(periods[m])
                out[a - start:b - start] = self.period(m, e)[idx]
            elif self.kind == "recorded":
                raise ValueError("a recorded excitation has no waveform to generate: it is in the record")
            else:
                out[a - start:b - start] = self._noise(m, e, a - seg0, b - seg0)
            s += 1
        return out

    def blocks(self, block_size: int):
        """Yield (start, samples (n, Nu)) blocks covering the whole experiment."""
        if int(block_size) < 1:
            raise ValueError(f"block_size must be >= 1, got {block_size!r}")
        for start in range(0, self.total_samples, int(block_size)):
            yield start, self.samples(start, min(int(block_size), self.total_samples - start))

    def reference_spectrum(self, m: int, e: int) -> np.ndarray:
        """Complex line amplitudes of segment (m, e) over one N-sample window.

        Returns
        -------
        (Nu, L) complex: 2/N * DFT of N steady-state samples at the
        excited lines [A] (a multisine gives amplitudes_a * phasors[m, e]).
        """
        if not self.is_periodic:
            raise ValueError("a noise design has no fixed reference spectrum; measure r instead")
        p = self.period(m, e)
        x = np.tile(p, (self.n_per_period // p.shape[0], 1))
        return (np.fft.rfft(x, axis=0)[self.excited_lines] * (2 / self.n_per_period)).T

    # ---- serialisation ----------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-safe dict (lists, str, float, int, None); ``from_dict`` inverts it exactly."""
        d = {"format": FORMAT, "kind": self.kind, "fs_hz": self.fs_hz,
             "n_per_period": int(self.n_per_period), "n_periods": int(self.n_periods),
             "n_transient_periods": int(self.n_transient_periods),
             "n_realisations": int(self.n_realisations), "n_experiments": int(self.n_experiments),
             "input_names": list(self.input_names),
             "excited_lines": self.excited_lines.tolist(),
             "detection_lines_odd": self.detection_lines_odd.tolist(),
             "detection_lines_even": self.detection_lines_even.tolist(),
             "amplitudes_a": self.amplitudes_a.tolist(),
             "phasors": None if self.phasors is None else
             {"real": self.phasors.real.tolist(), "imag": self.phasors.imag.tolist()},
             "peak_a": self.peak_a.tolist(), "rms_a": self.rms_a.tolist(),
             "crest_factor": self.crest_factor.tolist(), "band_hz": list(self.band_hz),
             "seed": self.seed, "options": to_jsonable(self.options),
             "source": to_jsonable(self.source)}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ExcitationDesign":
        """Rebuild a design from ``to_dict`` output (also after a JSON round trip)."""
        if d.get("format") != FORMAT:
            raise ValueError(f"not an excitation design dict (format {d.get('format')!r}, "
                             f"expected {FORMAT!r})")
        ph = d["phasors"]
        kwargs = {k: d[k] for k in (
            "kind", "fs_hz", "n_per_period", "n_periods", "n_transient_periods", "n_realisations",
            "n_experiments", "input_names", "excited_lines", "detection_lines_odd",
            "detection_lines_even", "amplitudes_a", "peak_a", "rms_a", "crest_factor",
            "band_hz", "seed", "options", "source")}
        kwargs["phasors"] = None if ph is None else (
            np.array(ph["real"], dtype=float) + 1j * np.array(ph["imag"], dtype=float))
        return cls(**kwargs)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ExcitationDesign):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # mutable-looking array fields: not hashable


def _amps(x: float) -> str:
    """Current for a message: 3 decimals at most, at least one (4.0, 2.25)."""
    text = f"{x:.3f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def check_headroom(design: ExcitationDesign, current_limit_a: float | np.ndarray,
                   working_current_a: float | np.ndarray) -> np.ndarray:
    """Refuse a design whose peak plus the working current exceeds the current limit.

    Parameters
    ----------
    design
        the excitation design.
    current_limit_a
        amplifier current limit, scalar or (Nu,) [A].
    working_current_a
        controller's peak working (control) current,
        scalar or (Nu,) [A], >= 0.

    Returns
    -------
    (Nu,) margin limit - working - excitation peak [A] (all >= 0).

    Raises
    ------
    ValueError
        naming each input that lacks headroom and the largest
        peak_current_a it can take.
    """
    nu = design.n_inputs
    limit = np.broadcast_to(np.asarray(current_limit_a, dtype=float), (nu,))
    work = np.broadcast_to(np.asarray(working_current_a, dtype=float), (nu,))
    if not (np.all(np.isfinite(limit)) and np.all(np.isfinite(work))):
        raise ValueError("current_limit_a and working_current_a must be finite")
    if np.any(limit <= 0) or np.any(work < 0):
        raise ValueError("current_limit_a must be > 0 and working_current_a >= 0")
    margin = limit - work - design.peak_a
    bad = [f"input {name!r}: excitation peak {_amps(pk)} A + working current {_amps(w)} A exceeds "
           f"the {_amps(lim)} A limit; at most {_amps(max(lim - w, 0.0))} A is available for "
           "excitation"
           for name, pk, w, lim, mg in zip(design.input_names, design.peak_a, work, limit, margin)
           if mg < -1e-12 * lim]
    if bad:
        raise ValueError("; ".join(bad) + ": lower peak_current_a")
    return margin
