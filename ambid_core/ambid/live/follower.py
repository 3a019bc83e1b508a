"""Following a running session for the live view: what arrives in, :class:`~ambid.live.frames.Frame` s out.

:class:`SessionFollower` is fed what a session publishes -- its excitation
design, its measurement blocks, its nodes' statuses and events -- in the
order they arrive, and answers each with the frames to show. It runs its own
:class:`ambid.frf.streaming.FrfStream` on the blocks (the same estimator as
the session's ``frf_consumer``, so its final estimate is the session's), and
estimates the FRF again after every period that completes a record (a
period measured in all Ne experiments of an orthogonal design), the running
realisation's records included. Blocks it never got (a live view may lose
some: it keeps only the latest blocks, so that it can never slow the loop) are
counted (``lost_blocks``), and the periods they touch left out of its FRF, as
a gap is everywhere else (``frf_gaps``: also the experiment's samples that
came before the live view did).

Channels are data: the outputs are the block's ``y_*`` channels, the inputs
the ``u_*`` (and ``r_*``) channels of the design's inputs, the orbits the
bearings with an x and a y axis (:attr:`ambid.channels.Layout.radial_pairs`).
Not thread-safe: one thread feeds it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ambid.channels import Layout, bearing_of
from ambid.excitation.design import ExcitationDesign
from ambid.frf.streaming import ESTIMATORS, FrfResult, FrfStream, match_inputs
from ambid.live.frames import (Frame, envelope_frames, event_frame, frf_frames, levels_frames, orbit_frame,
                               progress_frame, status_frame, time_ns)

__all__ = ["SessionFollower"]


class SessionFollower:
    """The live view's model of one session.

    Parameters
    ----------
    estimator
        the session's FRF estimator (:data:`ambid.frf.streaming.ESTIMATORS`).
    signal_rate_hz
        the most envelope pairs of the time plot per second of session time [Hz] (:meth:`display_frames`).
    orbit_points
        the most points of an orbit frame (the latest block's, per bearing).
    estimate_every_s
        the least wall time between two live estimates: a record completed sooner waits for the next one
        (a simulated session completes records many times a second; each estimate costs its noise and
        distortion figures). The final estimate is always made. 0: after every record.
    """

    def __init__(self, estimator: str = "indirect", signal_rate_hz: float = 200.0, orbit_points: int = 200,
                 estimate_every_s: float = 0.0) -> None:
        if estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
        if not signal_rate_hz > 0 or orbit_points < 2:
            raise ValueError(f"need signal_rate_hz > 0 and orbit_points >= 2, got {signal_rate_hz}, {orbit_points}")
        self.estimator = estimator
        self.estimate_every_s = float(estimate_every_s)
        self._estimated_at = -1e300   # time.monotonic() of the last estimate
        self.signal_rate_hz = float(signal_rate_hz)
        self.orbit_points = int(orbit_points)
        self.experiment_id = ""
        self.design: ExcitationDesign | None = None
        self.stream: FrfStream | None = None
        self.result: FrfResult | None = None   # the latest estimate
        self._pending: tuple[ExcitationDesign, int, int] | None = None   # a design whose stream waits for names
        self._names: tuple[str, ...] = ()
        self._columns: np.ndarray | None = None
        self._shown: np.ndarray | None = None          # columns of y_* and u_* for the time plot
        self._shown_names: tuple[str, ...] = ()
        self._orbits: list[tuple[str, int, int, str, str]] = []
        self._records = 0
        self._announce: list[Frame] = []
        self._next: int | None = None
        self._index = 0
        self._fs = 0.0
        self.counts = {"blocks": 0, "lost_blocks": 0, "lost_samples": 0, "rejected_blocks": 0, "estimates": 0,
                       "frames_thinned": 0}
        self.problems: list[str] = []   # one line each, for the status (rejected blocks, failed estimates)
        #: whether the time signals and orbits are shown: without, block() does nothing for them (nobody looks)
        self.display = True
        self._envelope: np.ndarray | None = None   # (2, C) min and max of the shown channels since the last pair
        self._span = (0, 0)                         # first and last sample the envelope covers
        self._latest: tuple[int, np.ndarray] | None = None   # the latest block not yet displayed: first index, data
        self._held = 0                              # blocks taken since the last display

    # ---- what arrives ---------------------------------------------------------------------------
    def design_message(self, experiment_id: str, design: ExcitationDesign, start_index: int,
                       total_samples: int) -> list[Frame]:
        """An experiment's design (``excitation/design``): a new experiment, or the running one cut short."""
        total = min(int(total_samples), design.total_samples)
        if self.stream is not None and experiment_id == self.experiment_id:
            if total < self.stream.end_index - self.stream.start_index and not self.stream.finished:
                try:
                    self.stream.truncate(total)
                except ValueError as exc:
                    self.problems.append(f"design {experiment_id}: {exc}")
            return [self._progress()]
        self.experiment_id, self.design, self.result, self._records = experiment_id, design, None, 0
        self.stream, self._columns = None, None
        self._pending = (design, int(start_index), total)
        if self._names:
            self._start_stream()
        return self._announced() + [self._progress()]

    def block(self, first_index: int, sample_period_s: float, names: Sequence[str],
              data: np.ndarray) -> list[Frame]:
        """A measurement block: (n, C) samples of the channels ``names`` from sample ``first_index``."""
        names = tuple(names)
        data = np.asarray(data, dtype=float)
        self._fs = 1.0 / float(sample_period_s)
        if names != self._names:
            self._channels(names)
        self.counts["blocks"] += 1
        if self._next is not None and first_index > self._next:
            self.counts["lost_blocks"] += 1
            self.counts["lost_samples"] += first_index - self._next
        self._next = max(self._next or 0, first_index + data.shape[0])
        self._index = max(self._index, first_index + data.shape[0])
        if self.display and data.shape[0]:
            self._hold(first_index, data)
        frames = self._feed(first_index, sample_period_s, data)
        return self._announced() + frames

    def _hold(self, first_index: int, data: np.ndarray) -> None:
        """Fold a block into the envelope of the time plot (two vectorised reductions) and keep it for the orbits."""
        if self._shown_names:
            shown = data[:, self._shown]
            lo, hi = shown.min(axis=0), shown.max(axis=0)
            if self._envelope is None:
                self._envelope, self._span = np.stack([lo, hi]), (first_index, first_index)
            else:
                np.minimum(self._envelope[0], lo, out=self._envelope[0])
                np.maximum(self._envelope[1], hi, out=self._envelope[1])
            self._span = (self._span[0], first_index + data.shape[0] - 1)
        self._latest = (first_index, data)
        self._held += 1

    @property
    def display_pending(self) -> bool:
        """Whether blocks came since the last :meth:`display_frames`."""
        return self._latest is not None

    @property
    def display_topics(self) -> list[str]:
        """The topics :meth:`display_frames` sends (the time signals' and each bearing's orbit)."""
        return (["signals"] if self._shown_names else []) + [f"orbit/{o[0]}" for o in self._orbits]

    def display_frames(self, final: bool = False) -> list[Frame]:
        """What a viewer draws of the blocks since the last call: the time signals' envelope (each channel's
        minimum and maximum over every sample since the pair before, as two frames; held on, still growing,
        until it spans 1 / ``signal_rate_hz`` of session time unless ``final``) and each bearing's orbit over
        the latest block. [] when no block came since. A server calls it at its display rate."""
        if self._latest is None and (self._envelope is None or not final):
            return []
        frames: list[Frame] = []
        env = self._envelope
        if env is not None and (final or (self._span[1] + 1 - self._span[0]) * self.signal_rate_hz >= self._fs):
            frames += envelope_frames(*self._span, self._fs, self._shown_names, env)
            self._envelope = None
        if self._latest is not None:
            first, data = self._latest
            for bearing, xi, yi, xn, yn in self._orbits:
                frames.append(orbit_frame(bearing, xn, yn, first, self._fs, data[:, xi], data[:, yi],
                                          self.orbit_points))
            # each bearing's orbit of every block but the latest never went out
            self.counts["frames_thinned"] += (self._held - 1) * len(self._orbits)
            self._latest, self._held = None, 0
        return frames

    def _announced(self) -> list[Frame]:
        out, self._announce = self._announce, []
        return out

    def status_message(self, node: str, state: int, sample_index: int, progress: float, received: int,
                       rejected: int, text: str, figures: Mapping[str, Any], t_ns: int) -> list[Frame]:
        """A node's SessionStatus; ``figures`` as the message's keys and values (JSON text each)."""
        parsed = {}
        for k, v in figures.items():
            try:
                parsed[k] = json.loads(v) if isinstance(v, str) else v
            except ValueError:
                parsed[k] = v
        return [status_frame(node, state, sample_index, progress, received, rejected, text, parsed, t_ns)]

    def event_message(self, node: str, severity: int, code: str, text: str, sample_index: int,
                      t_ns: int) -> list[Frame]:
        """A SessionEvent."""
        return [event_frame(node, severity, code, text, sample_index, t_ns)]

    # ---- inside -------------------------------------------------------------------------------------
    def _channels(self, names: tuple[str, ...]) -> None:
        """A block's channel names, new or changed: the time plot's and the orbits' columns."""
        self._names = names
        y = [i for i, n in enumerate(names) if n.startswith("y_")]
        u = [i for i, n in enumerate(names) if n.startswith("u_")]
        self._shown = np.array(y + u, dtype=np.int64)
        self._shown_names = tuple(names[i] for i in y + u)
        self._orbits = []
        try:
            layout = Layout.from_names([names[i] for i in y])
        except ValueError:
            layout = None
        if layout is not None:
            for xi, yi in layout.radial_pairs:
                xn, yn = layout.outputs[xi], layout.outputs[yi]
                bearing = bearing_of(layout.axes[xi])
                self._orbits.append((bearing, names.index(xn), names.index(yn), xn, yn))
        self._columns = None
        self._envelope, self._latest, self._held = None, None, 0   # other columns: what was held is not theirs
        # advertised now: a client subscribes before anything is shown (nothing is, until one does)
        self._announce += [Frame(t, "ambid.live.Signals" if t == "signals" else "ambid.live.Orbit", None, 0)
                           for t in self.display_topics]
        if self.design is not None:
            self._start_stream() if self.stream is None else self._pick_columns()

    def _start_stream(self) -> None:
        if self._pending is None:
            return
        design, start, total = self._pending
        outputs = [n for n in self._names if n.startswith("y_")]
        inputs = [n for n in self._names if n.startswith("u_")]
        refs = ["r_" + n[2:] for n in inputs]
        try:
            u_names, r_names = match_inputs(design.input_names, inputs, refs)
            self.stream = FrfStream(design, outputs, u_names, r_names, start_index=start, total_samples=total)
            self._pick_columns()
            # the channels of the estimates, advertised now: a client subscribes before the first estimate
            self._announce += ([Frame(f"frf/{o}/{i}", "ambid.live.FrfEntry", None, 0) for o in outputs for i in u_names]
                               + [Frame(f"levels/{o}", "ambid.live.Levels", None, 0) for o in outputs])
        except ValueError as exc:
            self.problems.append(f"experiment {self.experiment_id}: no live FRF: {exc}")
            self.stream = None
        self._pending = None

    def _pick_columns(self) -> None:
        try:
            self._columns = self.stream.columns(self._names)
        except ValueError as exc:
            self.problems.append(f"experiment {self.experiment_id}: {exc}")
            self._columns = None

    def _feed(self, first_index: int, sample_period_s: float, data: np.ndarray) -> list[Frame]:
        stream = self.stream
        if stream is None or self._columns is None or stream.finished:
            return []
        if first_index + data.shape[0] <= stream.start_index or first_index >= stream.end_index:
            return []
        try:
            stream.check_sample_period(sample_period_s)
            report = stream.add(first_index, data[:, self._columns])
        except ValueError as exc:
            self.counts["rejected_blocks"] += 1
            self.problems.append(f"block at sample {first_index}: {exc}")
            return []
        if not (report.periods_completed or report.finished or report.gaps):
            return []
        frames = []
        records = stream.records_done
        due = time.monotonic() - self._estimated_at >= self.estimate_every_s
        if (records != self._records and due) or report.finished:
            self._records = records
            frames += self._estimate(final=report.finished)
        frames.append(self._progress())
        return frames

    def _estimate(self, final: bool) -> list[Frame]:
        try:
            result = self.stream.estimate(self.estimator, partial=not final)
        except ValueError as exc:
            self.problems.append(f"experiment {self.experiment_id}: estimate failed: {exc}")
            return []
        if result is None:
            return []
        self._estimated_at = time.monotonic()
        self.result = result
        self.counts["estimates"] += 1
        d = self.design
        t = time_ns(min(self._index, self.stream.end_index), self._fs)
        scale = d.fs_hz / d.n_per_period
        return (frf_frames(result, self.experiment_id, t)
                + levels_frames(result, d.detection_lines_odd * scale, d.detection_lines_even * scale,
                                self.experiment_id, t))

    def _progress(self) -> Frame:
        return progress_frame(self.figures(), time_ns(self._index, self._fs) if self._fs else 0)

    def figures(self) -> dict:
        """Where the session is, as the live view saw it: progress, records, estimates and losses."""
        f: dict[str, Any] = {"experiment_id": self.experiment_id, **self.counts, "dropped_frames": 0}
        s = self.stream
        if s is not None:
            p = s.progress()
            f.update(fraction=p.samples_done / p.total_samples if p.total_samples else 1.0,
                     periods_done=p.periods_done, periods=p.periods_total, records=s.records_done,
                     realisations_done=p.realisations_done, realisations=p.n_realisations,
                     time_left_s=p.time_left_s, finished=p.finished, frf_gaps=len(s.gaps),
                     frf_gap_samples=sum(g.n_samples for g in s.gaps))
        else:
            f.update(fraction=0.0, periods_done=0, periods=0, records=0, realisations_done=0, realisations=0,
                     time_left_s=0.0, finished=False, frf_gaps=0, frf_gap_samples=0)
        r = self.result
        rel = r.relative_noise_std if r is not None else float("nan")
        f["relative_frf_noise_std"] = rel if np.isfinite(rel) else None
        return f
