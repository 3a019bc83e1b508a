"""The multisine design of an experiment, found again from its recorded excitation (and response).

A rig's log holds the excitation r it injected, not the design behind it.
:class:`DesignFinder` is fed the record in row chunks (memory: one period of
r and y per experiment segment plus each segment's spectrum, flat in the
record's length) and finds:

* the start row: the first row where any input is non-zero;
* the period N: the smallest lag at which r repeats itself (all inputs,
  within ``rel_tol`` of its peak, which admits a float32 logger);
* the segments: runs of identical periods; each realisation of each
  experiment is one run, all runs of the same length Pt + P;
* the excited lines: DFT bins of a period with amplitude above ``rel_tol``
  of the largest; amplitudes and phasors (2/N times the DFT at the lines);
* experiments and realisations: Nu consecutive segments whose phase
  matrix over (input, experiment) is Nu times unitary at every line
  (Dobrowiecki et al. 2006; the DFT weights ambid uses, a Hadamard matrix,
  any input order) are one realisation of an orthogonal design; Nu segments each
  exciting one input, one of a one-at-a-time design; else every segment is
  a realisation of one simultaneous experiment;
* the transient periods Pt, which the excitation does not show (a transient
  period is the same waveform as a steady one): given, or the periods at the
  start of each segment in which the response y still changes from period to
  period by more than ``transient_factor`` times the noise scatter of the
  last periods (the least periods for which every segment has settled);
* the detection lines: the unexcited lines in the band, the band being
  given (its bins, :func:`ambid.excitation.lines.band_bins`) or spanning
  the excited lines.

Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .design import ExcitationDesign
from .designers import _finish
from .lines import band_bins, detection_lines

__all__ = ["MAX_PERIOD", "DesignNotFound", "FoundDesign", "DesignFinder"]

#: the longest period searched [samples] (0.1 Hz resolution at 100 kHz)
MAX_PERIOD = 1_000_000


class DesignNotFound(ValueError):
    """The excitation record holds no periodic multisine design; the message names the row and the fix."""


@dataclass
class FoundDesign:
    """What :meth:`DesignFinder.finish` found.

    Attributes
    ----------
    design
        the reconstructed design.
    start_row
        record row of the experiment's first sample.
    end_row
        one past its last sample.
    transient_from
        'given' or 'response' (estimated from y).
    notes
        what was found, a line each.
    """

    design: ExcitationDesign
    start_row: int
    end_row: int
    transient_from: str
    notes: list[str] = field(default_factory=list)


class DesignFinder:
    """Stream r (and y) through :meth:`add`, then :meth:`finish` (see the module docstring).

    Parameters
    ----------
    input_names
        (Nu,) design input names (the currents r is added to).
    fs_hz
        sample rate [Hz].
    n_transient_periods
        Pt if known, else None (estimated from y).
    band_hz
        band of interest for the detection lines, or None.
    rel_tol
        equality and zero tolerance, relative to r's peak.
    transient_factor
        a period is settled when it differs from the
        next by at most this times the noise scatter.
    """

    def __init__(self, input_names, fs_hz: float, n_transient_periods: int | None = None,
                 band_hz: tuple[float, float] | None = None, rel_tol: float = 1e-6,
                 transient_factor: float = 3.0) -> None:
        self.names, self.fs, self.pt_given, self.band = tuple(input_names), float(fs_hz), n_transient_periods, band_hz
        self.rel_tol, self.factor = rel_tol, transient_factor
        self.start: int | None = None
        self.n: int | None = None
        self.buf_r: list[np.ndarray] = []
        self.buf_y: list[np.ndarray] = []
        self.buf_rows = 0
        self.next_try = 4096
        self.peak = 0.0
        self.row = 0                      # rows seen
        self.pending_r = self.pending_y = None   # rows of the current, incomplete period
        self.prev_r = self.prev_y = None
        self.runs: list[list] = []        # per segment: [first row, periods, spectrum, [d_p...]]
        self.ended_at: int | None = None

    # ------------------------------------------------------------ feeding
    def add(self, r: np.ndarray, y: np.ndarray) -> None:
        """Next rows of the record: r (n, Nu) [A], y (n, Ny) [m]."""
        r, y = np.asarray(r, float), np.asarray(y, float)
        first = self.row
        self.row += len(r)
        if self.ended_at is not None:
            self._check_silent(r, first)
            return
        if self.start is None:
            on = np.flatnonzero(np.any(r != 0, axis=1))
            if not on.size:
                return
            self.start = first + int(on[0])
            r, y = r[on[0]:], y[on[0]:]
        if self.n is None:
            self.buf_r.append(r)
            self.buf_y.append(y)
            self.buf_rows += len(r)
            if self.buf_rows >= self.next_try:
                self._find_period(final=False)
            return
        self._periods(r, y)

    def _check_silent(self, r: np.ndarray, first: int) -> None:
        on = np.flatnonzero(np.any(np.abs(r) > self.rel_tol * self.peak, axis=1))
        if on.size:
            raise DesignNotFound(f"the excitation starts again at row {first + int(on[0]) + 1} after it stopped "
                                 f"at row {self.ended_at + 1}; import one experiment at a time (cut the record) "
                                 "or give its design: in MAP.yaml")

    def _find_period(self, final: bool) -> None:
        r = np.concatenate(self.buf_r)
        y = np.concatenate(self.buf_y)
        self.buf_r, self.buf_y = [r], [y]
        self.peak = float(np.max(np.abs(r)))
        tol = self.rel_tol * self.peak
        half = len(r) // 2
        cand = np.arange(1, half + 1)
        for i in range(min(16, half)):
            cand = cand[np.max(np.abs(r[cand + i] - r[i]), axis=1) <= tol]
        for n in cand:
            if np.max(np.abs(r[n:2 * n] - r[:n])) <= tol:
                self.n = int(n)
                break
        if self.n is None:
            if final or len(r) >= 2 * MAX_PERIOD:
                lim = len(r) if final else 2 * MAX_PERIOD
                raise DesignNotFound(
                    f"the excitation from row {self.start + 1} does not repeat itself within {lim // 2} rows: it is "
                    f"not periodic or shorter than two periods; give its design: in MAP.yaml, or record at least "
                    "two periods of a periodic multisine")
            self.next_try *= 2
            return
        self.buf_r, self.buf_y, self.buf_rows = [], [], 0
        self._periods(r, y)

    def _periods(self, r: np.ndarray, y: np.ndarray) -> None:
        if self.pending_r is not None:
            r, y = np.concatenate([self.pending_r, r]), np.concatenate([self.pending_y, y])
        n = self.n
        tol = self.rel_tol * self.peak
        k = 0
        while k + n <= len(r) and self.ended_at is None:
            pr, py = r[k:k + n], y[k:k + n]
            row = self.row - len(r) + k
            if self.prev_r is not None and np.max(np.abs(pr - self.prev_r)) <= tol:
                seg = self.runs[-1]
                seg[1] += 1
                seg[3].append(float(np.sum((py - self.prev_y) ** 2)))
            elif np.max(np.abs(pr)) <= tol:
                self.ended_at = row
                self._check_silent(r[k:], row)
                break
            else:
                lead = np.flatnonzero(np.any(np.abs(pr) > tol, axis=1))
                if self.prev_r is not None and lead[-1] < n - 1 and \
                        np.max(np.abs(pr[:lead[-1] + 1] - self.prev_r[:lead[-1] + 1])) <= tol:
                    raise DesignNotFound(
                        f"the excitation stops at row {row + lead[-1] + 2}, {lead[-1] + 1} rows into a period of "
                        f"{n}; cut the record at row {row} (the end of the last whole period) or give its design: "
                        "in MAP.yaml")
                spec = np.fft.rfft(pr, axis=0) * (2.0 / n)
                self.runs.append([row, 1, spec, []])
                self.peak = max(self.peak, float(np.max(np.abs(pr))))
            self.prev_r, self.prev_y = pr.copy(), py.copy()
            k += n
        self.pending_r, self.pending_y = (r[k:].copy(), y[k:].copy()) if self.ended_at is None else (None, None)

    # ------------------------------------------------------------ result
    def finish(self) -> FoundDesign:
        """The design, its start and end rows (:class:`DesignNotFound` if there is none)."""
        if self.start is None:
            raise DesignNotFound("the excitation columns are zero in every row: no experiment in the record; "
                                 "check the excitation: columns in MAP.yaml")
        if self.n is None:
            self._find_period(final=True)
        notes = []
        tail = self.pending_r if self.ended_at is None and self.pending_r is not None else np.zeros((0, 1))
        if np.any(np.abs(tail) > self.rel_tol * self.peak):
            notes.append(f"the record ends {len(self.pending_r)} rows into a period; those rows are left out")
        runs = self.runs
        lengths = [s[1] for s in runs]
        if lengths[-1] < max(lengths) and len(set(lengths[:-1])) <= 1:
            notes.append(f"the last segment has {lengths[-1]} of {max(lengths)} periods (the record or the "
                         "experiment stopped early); it is left out")
            runs = runs[:-1]
            lengths = lengths[:-1]
        if not runs:
            raise DesignNotFound(f"no whole segment of the excitation from row {self.start + 1}; record the "
                                 "experiment to its end or give its design: in MAP.yaml")
        if len(set(lengths)) > 1:
            bad = next(s for s in runs if s[1] != lengths[0])
            raise DesignNotFound(f"the excitation segment from row {bad[0] + 1} repeats its period {bad[1]} times, "
                                 f"the first one {lengths[0]} times: not one multisine design; give its design: "
                                 "in MAP.yaml")
        n, nu = self.n, len(self.names)
        if nu != runs[0][2].shape[1]:
            raise DesignNotFound(f"{runs[0][2].shape[1]} excitation columns for {nu} inputs; give one excitation "
                                 "column per current")
        spec = np.stack([s[2] for s in runs])          # (S, N/2+1, Nu)
        mag = np.abs(spec)
        lines = np.flatnonzero(mag.max(axis=(0, 2)) > self.rel_tol * mag.max())
        lines = lines[(lines > 0) & (2 * lines < n)]
        if not lines.size:
            raise DesignNotFound(f"the excitation from row {self.start + 1} has no line between DC and Nyquist; "
                                 "give a multisine excitation")
        x = spec[:, lines, :].transpose(0, 2, 1)       # (S, Nu, L)
        n_seg = len(runs)
        mimo, ne = self._mimo(x, mag[:, lines, :].transpose(0, 2, 1))
        m = n_seg // ne
        amps = np.abs(x).max(axis=0)                     # (Nu, L)
        with np.errstate(invalid="ignore", divide="ignore"):
            ph = np.where(amps > 0, x / np.where(amps > 0, amps, 1), 0)
        phasors = ph.reshape(m, ne, nu, lines.size)
        seg_periods = lengths[0]
        pt, how = self._transient(runs, seg_periods)
        if self.band is not None:
            k_lo, k_hi = band_bins(self.band, self.fs, n)
            band = (float(self.band[0]), float(self.band[1]))
        else:
            k_lo, k_hi = int(lines[0]), int(lines[-1])
            band = (k_lo * self.fs / n, k_hi * self.fs / n)
        odd, even = detection_lines(lines, k_lo, k_hi)
        unit = ExcitationDesign(
            kind="multisine", fs_hz=self.fs, n_per_period=n, n_periods=seg_periods - pt, n_transient_periods=pt,
            n_realisations=m, n_experiments=ne, input_names=self.names, excited_lines=lines,
            detection_lines_odd=odd, detection_lines_even=even, amplitudes_a=amps, phasors=phasors,
            peak_a=np.zeros(nu), rms_a=np.zeros(nu), crest_factor=np.zeros(nu), band_hz=band, seed=None,
            options={"mimo": mimo, "reconstructed": True})
        design = _finish(unit)
        end = self.start + design.total_samples
        notes[:0] = [f"excitation from row {self.start + 1} to {end}: period N = {n} samples "
                     f"({self.fs / n:g} Hz resolution), {lines.size} excited lines "
                     f"{lines[0] * self.fs / n:g}-{lines[-1] * self.fs / n:g} Hz, {odd.size} odd and {even.size} even "
                     "detection lines",
                     f"{n_seg} segments of {seg_periods} periods: {mimo} design, Ne = {ne} experiment(s) x "
                     f"M = {m} realisation(s); Pt = {pt} transient + P = {seg_periods - pt} periods "
                     f"(transient periods {how})"]
        return FoundDesign(design, self.start, end, "given" if self.pt_given is not None else "response", notes)

    def _mimo(self, x: np.ndarray, mag: np.ndarray) -> tuple[str, int]:
        """('orthogonal' | 'one_at_a_time' | 'simultaneous', Ne) from the segments' phasors x (S, Nu, L)."""
        s, nu, _ = x.shape
        if nu == 1 or s % nu:
            return ("simultaneous" if nu > 1 else "orthogonal"), 1
        tol = 1e-6
        groups = x.reshape(s // nu, nu, nu, -1)           # (M, e, i, L)
        amp = np.abs(groups).max(axis=1, keepdims=True)
        ok = bool(np.all(amp > tol * amp.max()))
        if ok:
            # orthogonal: at every line the (input x experiment) phase matrix T has T T^H = Nu I
            t = (groups / amp).transpose(0, 3, 2, 1)      # (M, L, i, e)
            gram = t @ t.conj().transpose(0, 1, 3, 2)
            ok = bool(np.max(np.abs(gram - nu * np.eye(nu))) <= 1e-6 * nu)
        if ok:
            return "orthogonal", nu
        m = mag.reshape(s // nu, nu, nu, -1)
        top = mag.max()
        if all(np.all(m[:, e, i] <= tol * top) == (i != e) for e in range(nu) for i in range(nu)):
            return "one_at_a_time", nu
        return "simultaneous", 1

    def _transient(self, runs: list, periods: int) -> tuple[int, str]:
        if self.pt_given is not None:
            if not 0 <= self.pt_given < periods:
                raise DesignNotFound(f"transient_periods {self.pt_given} leaves no steady period of the {periods} "
                                     f"in each segment; give transient_periods below {periods}")
            return int(self.pt_given), "given"
        if periods < 3:
            return 0 if periods == 1 else 1, "from the layout (too few periods to see the transient)"
        d = np.array([s[3] for s in runs])                # (S, periods-1): change from period p to p+1
        floor = np.median(d[:, -1])
        pt = 1
        for seg in d:
            settled = seg <= self.factor * floor
            # first p such that every change after period p is at noise level
            last_bad = np.flatnonzero(~settled)
            pt = max(pt, int(last_bad[-1]) + 1 if last_bad.size else 0)
        pt = min(pt, periods - 1)
        return pt, f"estimated from the response: periods still changing by more than {self.factor:g}x the noise"
