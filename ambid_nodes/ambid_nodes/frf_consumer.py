"""frf_consumer: the FRF of the running excitation experiment, estimated while it runs.

Subscribes ``measurement`` (SampleBlock: y_* [m], u_*, ic_*, r_* [A]), the
latched ``excitation/design`` (ExcitationDesign; the design from its
``design_json``, placed at ``start_index``, cut at ``total_samples``) and the
latched ``controller/description`` (C(z), to check the loop). The numerical
work is :class:`ambid.frf.streaming.FrfStream`: blocks are aligned to the
design's periods by sample index, transient periods dropped, each period
reduced to its line spectra.

Publishes ``frf`` (FrfEstimate) each time a realisation -- all Ne
experiments of it -- is complete (the first one as soon as the MIMO estimate
is defined) and at the end of the experiment; ``status`` after every block
that completed a period (a line a person can follow, and figures in
keys/values; at the end the noise and distortion levels and the input
sensitivity peak with its ISO 14839-3 zone); ``events`` for sample gaps and
rejected messages. Every received message is accepted or rejected with its reason
(malformed, non-finite, out of range, out of order or repeated blocks; designs
and controller descriptions with inconsistent array sizes), counted per topic in
``status`` (``ambid_nodes.intake``); no FRF is computed across a sample gap: the
periods it touches are dropped. :func:`ambid.frf.offline.frf_from_session` gives the same
result from a recording.

When a design excites only some inputs, G is the response to those inputs
with the other loops closed (they are not excited, so not separable).

Channels are data: with the parameters' default ``[auto]`` the outputs are
the plant's displacement channels (its latched ``plant/description``, else
the y channels of the measurement blocks), the inputs and references the u
and r channels of the design's inputs (:func:`ambid.frf.offline.data_channels`),
whatever the rig's axes.
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np
from ambid.excitation import ExcitationDesign as Design
from ambid.frf.offline import data_channels
from ambid.frf.streaming import ESTIMATORS, FrfResult, FrfStream, loop_consistency, match_inputs
from ambid.statespace import StateSpace

from ambid_msgs.msg import (ControllerDescription, ExcitationDesign, FrfEstimate, PlantDescription, SampleBlock,
                            SessionEvent, SessionStatus)
from ambid_nodes import qos
from ambid_nodes.conversions import (BadMessage, block_data, check_controller_description, check_design,
                                     check_plant_description, float_array, statespace_from_msg, status_msg, time_msg)
from ambid_nodes.session_node import SessionNode
from ambid_nodes.parameters import ParameterError, declare


AUTO = "auto"  # a channel parameter taken from the data


class FrfConsumer(SessionNode):
    def __init__(self, **kwargs) -> None:
        super().__init__("frf_consumer", **kwargs)
        self.estimator = declare(self, "estimator", "indirect", "FRF estimator: " + " | ".join(ESTIMATORS))
        self.outputs = list(declare(self, "outputs", [AUTO], "output channels y of G; [auto]: the plant's "
                                                             "displacement channels [m]"))
        self.inputs = list(declare(self, "inputs", [AUTO],
                                   "applied-current channels u; those of the design's inputs are used; [auto]: the "
                                   "design's u_<axis> [A]"))
        self.references = list(declare(self, "references", [AUTO],
                                       "excitation channels r, one per entry of inputs, same order; [auto]: the "
                                       "design's r_<axis> [A]"))
        self.join_session()
        if self.estimator not in ESTIMATORS:
            raise ParameterError(f"frf_consumer: estimator '{self.estimator}' is not one of {list(ESTIMATORS)}")
        for name, names in (("outputs", self.outputs), ("inputs", self.inputs), ("references", self.references)):
            if not names or len(set(names)) != len(names) or not all(names) or (AUTO in names and len(names) > 1):
                raise ParameterError(f"frf_consumer: {name} must be distinct, non-empty channel names (or [auto]), "
                                     f"got {names}")
        if (self.inputs == [AUTO]) != (self.references == [AUTO]) or len(self.inputs) != len(self.references):
            raise ParameterError(f"frf_consumer: inputs {self.inputs} and references {self.references} must pair "
                                 "up one to one (u_i is the current r_i is added to), or both be [auto]")
        self.plant_outputs: list[str] | None = None  # the plant's displacement channels, once it says them
        self.pending_design: tuple | None = None  # (message, design) of a design that came before them

        self.pub_frf = self.identity.publisher(FrfEstimate, "frf", qos.LATCHED)
        self.pub_status = self.identity.publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.identity.publisher(SessionEvent, "events", qos.EVENTS)
        self.make_intake()
        self.identity.announce([self.pub_frf, self.pub_status, self.pub_event])
        self.intake.subscribe(SampleBlock, "measurement", self.on_measurement, qos.BLOCKS)
        self.intake.subscribe(ExcitationDesign, "excitation/design", self.on_design, qos.LATCHED)
        self.intake.subscribe(ControllerDescription, "controller/description", self.on_controller, qos.LATCHED)
        self.intake.subscribe(PlantDescription, "plant/description", self.on_plant, qos.LATCHED)

        self.stream: FrfStream | None = None
        self.experiment_id = ""
        self.controller: StateSpace | None = None
        self.columns: dict[tuple[str, ...], np.ndarray] = {}
        self.result: FrfResult | None = None           # latest estimate of the current experiment
        self.results: dict[str, FrfResult] = {}        # final estimate per experiment
        self.finished_at: dict[str, float] = {}        # when it was made (time.perf_counter), for timing figures
        self.final_figures: dict[str, dict] = {}       # its figures as the frf_done event says them
        self.dt = 0.0
        self.index = 0
        self.state = SessionStatus.STATE_IDLE
        self.status_received = -1
        self.publish_status()
        self.create_timer(1.0, self.status_if_changed)  # rejections between the per-period statuses

    # --- inputs ---------------------------------------------------------------
    def on_plant(self, msg: PlantDescription) -> None:
        check_plant_description(msg)
        self.plant_outputs = list(msg.displacement_names)
        self.start_pending()

    def start_pending(self) -> None:
        """The stream of the design that came before the plant's channels were known, now that they are."""
        pending, self.pending_design = self.pending_design, None
        if pending is None or self.plant_outputs is None:
            self.pending_design = pending
            return
        msg, design = pending
        try:
            stream, u_names = self.new_stream(msg, design)
        except ValueError as exc:
            self.event(SessionEvent.ERROR, "bad_design", f"excitation/design {msg.experiment_id!r} on the plant's "
                                                         f"channels {self.plant_outputs}: {exc}")
            return
        self.start_stream(msg, design, stream, u_names)

    def channels(self, design: Design) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        """(outputs, inputs, references) of the design's FRF: the parameters', [auto] ones from the data."""
        def given(names: list[str]):
            return None if names == [AUTO] else tuple(names)

        return data_channels(design.input_names, self.plant_outputs, given(self.outputs), given(self.inputs),
                             given(self.references))

    def on_controller(self, msg: ControllerDescription) -> None:
        check_controller_description(msg)
        self.controller = statespace_from_msg(msg.model)

    def on_design(self, msg: ExcitationDesign) -> None:
        check_design(msg)
        if self.stream is not None and msg.experiment_id == self.experiment_id:
            self.on_design_update(msg)
            return
        try:
            design = Design.from_dict(json.loads(msg.design_json))
            if abs(msg.sample_rate - design.fs_hz) > 1e-9 * design.fs_hz:
                raise ValueError(f"sample_rate {msg.sample_rate} differs from the design's {design.fs_hz}")
            if not design.is_periodic and self.estimator not in ("indirect", "h1"):
                raise ValueError(f"a {design.kind} excitation is not periodic: the {self.estimator} estimator "
                                 "does not apply; use indirect or h1")
            if self.outputs == [AUTO] and self.plant_outputs is None:
                # the outputs are the plant's displacement channels: the stream starts once its description or
                # a measurement block says them (the latest design waits; an earlier one it replaces is dropped)
                self.pending_design = (msg, design)
                return
            stream, u_names = self.new_stream(msg, design)
        except (ValueError, KeyError, TypeError, AttributeError, IndexError, OverflowError, RecursionError) as exc:
            # JSONDecodeError is a ValueError
            raise BadMessage(f"excitation/design {msg.experiment_id!r}: {type(exc).__name__}: {exc}") from None
        self.start_stream(msg, design, stream, u_names)

    def new_stream(self, msg: ExcitationDesign, design: Design) -> tuple[FrfStream, tuple[str, ...]]:
        """The stream of a design on its channels; ValueError when they cannot make one."""
        outputs, inputs, references = self.channels(design)
        u_names, r_names = match_inputs(design.input_names, inputs, references)
        stream = FrfStream(design, outputs, u_names, r_names, start_index=msg.start_index,
                           total_samples=min(msg.total_samples, design.total_samples))
        if self.estimator == "h2" and len(outputs) != len(u_names):
            raise ValueError(f"the h2 estimator needs as many outputs as inputs ({len(outputs)} outputs, "
                             f"{len(u_names)} inputs excited); use indirect")
        return stream, u_names

    def start_stream(self, msg: ExcitationDesign, design: Design, stream: FrfStream, u_names) -> None:
        if self.stream is not None and not self.stream.finished:
            self.event(SessionEvent.WARN, "experiment_superseded",
                       f"{self.experiment_id} replaced by {msg.experiment_id} before its end; its estimate so far "
                       "is final")
            self.finish()
        self.stream, self.experiment_id, self.result = stream, msg.experiment_id, None
        self.columns = {}  # column picks depend on the design's inputs
        self.dt = design.dt_s
        self.state = SessionStatus.STATE_RUNNING
        self.event(SessionEvent.INFO, "experiment", f"{msg.experiment_id}: {design.kind}, samples "
                   f"[{stream.start_index}, {stream.end_index}), inputs {list(u_names)}, estimator {self.estimator}")
        if stream.finished:  # a zero-length experiment
            self.finish()
        else:
            self.publish_status()

    def on_design_update(self, msg: ExcitationDesign) -> None:
        """The running experiment's design again: a stop cuts total_samples."""
        stream = self.stream
        total = min(msg.total_samples, stream.design.total_samples)
        if stream.end_index - stream.start_index == total:
            return
        if stream.finished:
            raise BadMessage(f"excitation/design {msg.experiment_id!r}: cut to {total} samples after its end")
        try:
            stream.truncate(total)
        except ValueError as exc:
            raise BadMessage(f"excitation/design {msg.experiment_id!r}: {exc}") from None
        self.event(SessionEvent.INFO, "experiment_stopped", f"{self.experiment_id} stops at sample {stream.end_index}")
        if stream.finished:
            self.finish()

    def on_measurement(self, msg: SampleBlock) -> None:
        try:
            data = block_data(msg)
        except BadMessage as exc:
            raise BadMessage(f"measurement: {exc}") from None
        self.index = max(self.index, msg.first_index + msg.n_samples)
        if self.plant_outputs is None:  # no plant description (yet): the record's own displacement channels
            self.plant_outputs = [n for n in msg.channel_names if n.startswith("y_")] or None
        self.start_pending()
        stream = self.stream
        if stream is None or stream.finished:
            return
        if msg.first_index + msg.n_samples <= stream.start_index or msg.first_index >= stream.end_index:
            return  # outside the experiment
        key = tuple(msg.channel_names)
        try:
            stream.check_sample_period(msg.sample_period)
            if key not in self.columns:
                self.columns[key] = stream.columns(key)
            report = stream.add(msg.first_index, data[:, self.columns[key]])
        except ValueError as exc:
            raise BadMessage(f"measurement at sample {msg.first_index}: {exc}") from None
        for gap in report.gaps:
            self.event(SessionEvent.WARN, "sample_gap",
                       f"{self.experiment_id}: samples [{gap.start_index}, {gap.start_index + gap.n_samples}) missing; "
                       f"{len(gap.periods)} steady-state period(s) dropped {list(gap.periods)[:8]}")
        if report.finished:
            self.finish()
        elif report.realisations_completed:
            self.publish_estimate()
            self.publish_status()
        elif report.periods_completed:
            self.publish_status()

    # --- outputs --------------------------------------------------------------
    def publish_estimate(self) -> FrfResult | None:
        try:
            result = self.stream.estimate(self.estimator)
        except ValueError as exc:
            self.event(SessionEvent.ERROR, "estimate_failed", f"{self.experiment_id}: {exc}")
            return None
        if result is None:
            return None
        self.result = result
        g = result.frf

        def variance(v: np.ndarray):
            return float_array([]) if np.all(np.isnan(v)) else float_array(v.ravel())

        msg = FrfEstimate(stamp=time_msg(self.index * self.dt), experiment_id=self.experiment_id,
                          estimator=result.estimator, output_names=list(result.output_names),
                          input_names=list(result.input_names), periods_used=result.n_periods,
                          realisations_used=result.n_realisations, experiments_used=result.n_experiments)
        msg.frequency = float_array(result.freq_hz)
        msg.real = float_array(g.real.ravel())
        msg.imag = float_array(g.imag.ravel())
        msg.variance_noise = variance(result.var_noise)
        msg.variance_total = variance(result.var_total)
        msg.coherence = float_array(np.ravel(result.coherence))
        self.pub_frf.publish(msg)
        return result

    def finish(self) -> None:
        """The experiment ended (or was replaced): final estimate, final status, event."""
        result = self.publish_estimate()
        if result is not None:
            self.results[self.experiment_id] = result
            self.finished_at[self.experiment_id] = time.perf_counter()
        self.state = SessionStatus.STATE_DONE if result is not None else SessionStatus.STATE_FAILED
        figures = self.figures(final=True)
        self.publish_status(figures)
        if result is None:
            self.event(SessionEvent.ERROR, "no_estimate", f"{self.experiment_id} ended without a complete "
                       "realisation: no FRF")
        else:
            self.final_figures[self.experiment_id] = figures
            self.event(SessionEvent.INFO, "frf_done", json.dumps(figures))

    def consistency(self, result: FrfResult) -> float:
        """Largest deviation of the measured S from (I + C G)^-1 with the described controller, or NaN."""
        c = self.controller
        if c is None or not set(c.input_names) <= set(result.output_names):
            return math.nan  # G must cover every measurement the controller uses
        ic_names = ["ic_" + (n[2:] if n.startswith("u_") else n) for n in result.input_names]
        if not set(ic_names) <= set(c.output_names):
            return math.nan
        model = c.freqresp(result.freq_hz)            # (L, n_ic, n_y): ic = model y
        rows = [c.output_names.index(n) for n in ic_names]
        c_jw = np.zeros((result.freq_hz.size, len(rows), len(result.output_names)), complex)
        for j, name in enumerate(result.output_names):
            if name in c.input_names:
                c_jw[:, :, j] = -model[:, rows, c.input_names.index(name)]  # u = r - C y
        return float(loop_consistency(result.frf, result.sensitivity, c_jw).max())

    def figures(self, final: bool = False) -> dict:
        if self.stream is None:
            return {}
        p = self.stream.progress()
        gaps = self.stream.gaps
        f = {"experiment_id": self.experiment_id, "estimator": self.estimator,
             "realisations_done": p.realisations_done, "realisations": p.n_realisations,
             "periods_done": p.periods_done, "periods": p.periods_total, "samples_done": p.samples_done,
             "samples": p.total_samples, "time_left_s": p.time_left_s, "gaps": len(gaps),
             "missing_samples": sum(g.n_samples for g in gaps)}
        r = self.result
        if r is not None:
            f["relative_noise_std"] = _json_float(r.relative_noise_std)
        if final and r is not None:
            d = r.distortion
            f.update({
                "lines": int(r.freq_hz.size), "band_hz": [float(r.freq_hz[0]), float(r.freq_hz[-1])],
                "periods_used": r.n_periods, "realisations_used": r.n_realisations,
                "total_over_noise_variance": _json_float(r.nonlinear_ratio),
                "noise_std_m": [_json_float(v) for v in r.noise_std],
                "odd_distortion_db": [_json_float(v) for v in d.odd_db] if d is not None else [],
                "even_distortion_db": [_json_float(v) for v in d.even_db] if d is not None else [],
                "sensitivity_peak": [float(v) for v in r.sensitivity_peak],
                "sensitivity_peak_hz": [float(v) for v in r.sensitivity_peak_hz],
                "iso_zone": r.iso_zone,
                "controller_consistency": _json_float(self.consistency(r))})
        return f

    def status_if_changed(self) -> None:
        if self.intake.total_received != self.status_received:
            # after an experiment's end its final figures stay in the (latched) status
            self.publish_status(self.figures(final=self.state != SessionStatus.STATE_RUNNING))

    def publish_status(self, figures: dict | None = None) -> None:
        self.status_received = self.intake.total_received
        f = self.figures() if figures is None else figures
        counts = self.intake.figures()
        if self.stream is None:
            text, progress = "idle: waiting for an excitation design", -1.0
        else:
            p = self.stream.progress()
            progress = p.samples_done / p.total_samples if p.total_samples else 1.0
            rel = f.get("relative_noise_std")
            noise = f"{100 * rel:.2g} %" if rel is not None else "n/a"
            if self.state == SessionStatus.STATE_RUNNING:
                text = (f"{self.experiment_id}: realisation {min(p.realisations_done + 1, p.n_realisations)}/"
                        f"{p.n_realisations}, periods {p.periods_done}/{p.periods_total}, median rel. noise std "
                        f"of G {noise}, time left {p.time_left_s:.3g} s simulated")
            elif "iso_zone" in f:
                lv = f["odd_distortion_db"]
                odd = f"{max(lv):.1f} dB" if lv and all(v is not None for v in lv) else "n/a"
                text = (f"{self.experiment_id} done: {f['lines']} lines, {f['realisations_used']} realisation(s), "
                        f"{f['periods_used']} periods, median rel. noise std of G {noise}, odd distortion "
                        f"{odd} above noise, input sensitivity peak {max(f['sensitivity_peak']):.2f} "
                        f"(ISO 14839-3 zone {f['iso_zone']}), gaps {f['gaps']}")
            else:
                text = f"{self.experiment_id} ended without an estimate"
        self.pub_status.publish(status_msg(
            time_msg(self.index * self.dt), self.get_fully_qualified_name(), self.state, self.index, progress,
            self.intake.total_received, self.intake.total_rejected, text, {**f, **counts}))

    def event_index(self) -> int:
        return self.index

def _json_float(x: float) -> float | None:
    """A float for JSON, None for NaN/inf (JSON has no NaN)."""
    x = float(x)
    return x if math.isfinite(x) else None


main = FrfConsumer.main  # the console script: SessionNode.main


if __name__ == "__main__":
    sys.exit(main())
