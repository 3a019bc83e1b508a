"""excitation_generator: designs an excitation experiment and streams it ahead of the plant.

Services (namespace-relative):
  ``start_experiment`` (ambid_msgs/StartExperiment): design_json empty = the design of the
    parameters, else ``ExcitationDesign.from_dict(json)``; start_index 0 = the next safe one
    (the plant's progress + ``start_margin``, not before the previous experiment's end).
    Refused, with the reason in ``message``: while another experiment runs, before the
    ``plant/description`` arrived, when the design's sample rate differs from the plant's,
    names an input the plant has not, or lacks headroom (peak + ``working_current_a`` above
    the amplifier limit; the message is ``check_headroom``'s).
  ``stop_experiment`` (ambid_msgs/StopExperiment): no more blocks; the design is republished
    with total_samples cut at the next block boundary not yet published.

Topics: publishes the latched ``excitation/design`` (ExcitationDesign, design_json =
``to_dict()``), ``excitation`` (SampleBlock, channels r_a_x, r_b_x, r_a_y, r_b_y [A], first_index
= start_index + offset, contiguous, the last one flagged FLAG_FINAL), ``status`` and ``events``;
subscribes the latched ``plant/description`` (sample period, current names and limits) and
``measurement``.

Flow control: the plant's progress is the end (first_index + n_samples) of its latest
``measurement`` block, which is reliable and namespaced (``/clock`` is best effort, so a lost
last message could stall the plant forever, and global, so two rigs would mix). A block is
published only when its end is at most ``lookahead`` samples past that progress, so memory
stays flat however long the experiment; each block is computed on demand by
``design.samples``. Every received message is accepted or rejected with its reason (a
plant/description with inconsistent array sizes; a measurement block that is malformed, out of
range or not after the previous one), counted per topic in ``status`` (``ambid_nodes.intake``).
Since the plant waits at an excited sample until its block arrives and
publishes measurement every ``m`` samples, ``lookahead`` must exceed ``block_size + m``
(checked at run time; an event warns otherwise).
"""

from __future__ import annotations

import json
import sys

import numpy as np
from ambid.excitation import ExcitationDesign
from ambid.excitation.experiment import Experiment, Streaming, place_experiment
from ambid.excitation.spec import DesignSpec
from ambid.plant.rig import Rig
from ambid.recording.facts import design_fields

from ambid_msgs.msg import ExcitationDesign as DesignMsg
from ambid_msgs.msg import PlantDescription, SampleBlock, SessionEvent, SessionStatus
from ambid_msgs.srv import StartExperiment, StopExperiment
from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, block_data, block_msg, check_plant_description, status_msg, time_msg
from ambid_nodes.session_node import SessionNode
from ambid_nodes.parameters import ParameterError, declare, declare_fields, node_rig

STATUS_PERIOD_S = 0.5


class ExcitationGenerator(SessionNode):
    def __init__(self, *, rig: Rig | None = None, **kwargs) -> None:
        """``rig``: the rig a composed run parsed once (else the ``rig_file`` parameter's)."""
        super().__init__("excitation_generator", **kwargs)
        rig_file = declare(self, "rig_file", "", "YAML rig parameter file for the defaults until plant/description "
                                                 "arrives; empty = the default rig")
        rig = node_rig(self, rig_file, rig)   # its currents are the default inputs
        terms = declare_fields(self, DesignSpec)  # the experiment's terms: DesignSpec's names and defaults
        # the streaming and the headroom check: Streaming's names and defaults
        streaming = Streaming(**declare_fields(self, Streaming))
        self.block_size, self.lookahead, self.start_margin = (streaming.block_size, streaming.lookahead,
                                                              streaming.start_margin)
        self.current_limit, self.working_current = streaming.current_limit_a, streaming.working_current_a
        self.join_session()
        if self.lookahead < 2 * self.block_size:
            raise ParameterError(f"excitation_generator: lookahead {self.lookahead} must be at least twice "
                                 f"block_size {self.block_size} (the plant waits for each block)")
        unknown = sorted(set(terms["input_names"]) - set(rig.layout.inputs))   # (): the plant's currents
        if unknown:
            raise ParameterError(f"excitation_generator: input_names {unknown} are not plant currents; use some of "
                                 f"{list(rig.layout.inputs)}")
        self.spec = DesignSpec(**terms)
        # defaults until the plant describes itself; the terms are checked now, so a bad band fails at
        # start-up, and designed only when an experiment asks for them (a caller may bring its own design)
        self.set_sample_period(rig.dt)
        self.set_currents(list(rig.layout.inputs), np.full(len(rig.layout), float(rig.current_limit_a)))
        self.plant_known = False
        self.default_error = self.check_spec()
        if self.default_error:
            raise ParameterError(f"excitation_generator: {self.default_error}")
        self.default_design: ExcitationDesign | None = None  # the parameters' design, once asked for

        self.pub_design = self.identity.publisher(DesignMsg, "excitation/design", qos.LATCHED)
        self.pub_block = self.identity.publisher(SampleBlock, "excitation", qos.BLOCKS)
        self.pub_status = self.identity.publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.identity.publisher(SessionEvent, "events", qos.EVENTS)
        self.make_intake()
        self.identity.announce([self.pub_design, self.pub_block, self.pub_status, self.pub_event])
        self.intake.subscribe(PlantDescription, "plant/description", self.on_plant, qos.LATCHED)
        self.intake.subscribe(SampleBlock, "measurement", self.on_measurement, qos.BLOCKS)
        self.create_service(StartExperiment, "start_experiment", self.on_start)
        self.create_service(StopExperiment, "stop_experiment", self.on_stop)

        self.progress = 0          # next sample the plant will apply (known from measurement)
        self.measurement_block = 0  # largest measurement block seen [samples]
        self.last_end = 0          # end of the previous experiment: the next may not overlap it
        self.exp: Experiment | None = None
        self.exp_msg: DesignMsg | None = None  # the running experiment's excitation/design
        self.last: Experiment | None = None
        self.count = 0
        self.state = SessionStatus.STATE_IDLE
        self.blocks_published = self.samples_published = 0
        self.publish_status()
        self.create_timer(STATUS_PERIOD_S, self.publish_status)

    # --- inputs from the plant ---------------------------------------------
    def on_plant(self, msg: PlantDescription) -> None:
        check_plant_description(msg)
        changed = abs(msg.sample_period - self.dt) > 1e-12 * self.dt
        if list(msg.current_names) != self.current_names:
            self.default_design = None   # [auto] inputs: the plant's currents
        self.set_sample_period(float(msg.sample_period))
        self.set_currents(list(msg.current_names), np.asarray(msg.current_limit, dtype=float))
        self.plant_known = True
        if changed:
            self.default_design, self.default_error = None, self.check_spec("the plant's ")
            if self.default_error:
                self.event(SessionEvent.ERROR, "bad_design", self.default_error)

    def set_sample_period(self, dt: float) -> None:
        """The plant's sample period [s] (its messages' stamps) and, from it once, the rate [Hz] designs take."""
        self.dt, self.fs_hz = dt, 1.0 / dt

    def set_currents(self, names: list[str], limits: np.ndarray) -> None:
        """The plant's current channels (u_<axis>) and their limits [A]; the excitation goes out on r_<axis>
        of each, in the same order."""
        self.current_names, self.plant_limit = names, limits
        self.excitation_names = tuple("r_" + (n[2:] if n.startswith("u_") else n) for n in names)
        self.excitation_units = ("A",) * len(names)

    def check_spec(self, whose: str = "") -> str:
        """Why the parameters' design cannot be made at the present sample rate, or ""."""
        try:
            self.spec.check(self.fs_hz)
        except ValueError as exc:
            return f"the design parameters are invalid at {whose}{self.fs_hz:g} Hz: {exc}"
        return ""

    def on_measurement(self, msg: SampleBlock) -> None:
        try:
            block_data(msg)
        except BadMessage as exc:
            raise BadMessage(f"measurement: {exc}") from None
        if msg.first_index < self.progress:
            raise BadMessage(f"measurement: block [{msg.first_index}, {msg.first_index + msg.n_samples}) repeated "
                             f"or out of order: the plant was already at sample {self.progress}")
        if msg.n_samples > self.measurement_block:
            self.measurement_block = msg.n_samples
            if self.lookahead < self.block_size + msg.n_samples:
                self.event(SessionEvent.WARN, "lookahead_too_short",
                           f"lookahead {self.lookahead} < block_size {self.block_size} + measurement block "
                           f"{msg.n_samples}: the plant may wait for excitation forever; raise lookahead")
        self.progress = max(self.progress, msg.first_index + msg.n_samples)
        self.pump()

    # --- services ----------------------------------------------------------
    def on_start(self, req: StartExperiment.Request, resp: StartExperiment.Response) -> StartExperiment.Response:
        try:
            exp = self.prepare(req)
        except ValueError as exc:
            resp.accepted, resp.message = False, str(exc)
            self.event(SessionEvent.WARN, "start_refused", str(exc))
            return resp
        self.exp, self.state = exp, SessionStatus.STATE_RUNNING
        self.exp_msg = self.design_msg(exp)
        self.pub_design.publish(self.exp_msg)
        self.event(SessionEvent.INFO, "started",
                   f"{exp.experiment_id}: {exp.design.kind}, samples [{exp.start}, {exp.end}), "
                   f"{exp.design.measurement_time_s:.6g} s")
        self.pump()
        self.publish_status()
        resp.accepted, resp.experiment_id = True, exp.experiment_id
        resp.start_index, resp.total_samples = exp.start, exp.total
        resp.message = f"{exp.experiment_id} starts at sample {exp.start}, {exp.total} samples"
        return resp

    def prepare(self, req: StartExperiment.Request) -> Experiment:
        """The experiment a request asks for, or ValueError saying why it is refused."""
        if self.exp is not None:
            raise ValueError(f"experiment {self.exp.experiment_id} is running (samples [{self.exp.start}, "
                             f"{self.exp.end})); stop it with stop_experiment or wait for its end")
        if not self.plant_known:
            raise ValueError("no plant/description received yet: start the plant (plant_sim or the hardware "
                             "bridge) in this namespace first")
        if req.design_json:
            try:
                design = ExcitationDesign.from_dict(json.loads(req.design_json))
            except (ValueError, KeyError, TypeError, AttributeError) as exc:  # JSONDecodeError is a ValueError
                raise ValueError(f"design_json is not a valid ExcitationDesign: {exc!r}") from None
        elif self.default_error:
            raise ValueError(self.default_error)
        else:
            if self.default_design is None:
                self.default_design = self.spec.build(self.fs_hz, inputs=self.current_names)
            design = self.default_design
        limit = self.plant_limit if self.current_limit == 0 else self.current_limit
        exp = place_experiment(f"exp-{self.count + 1:04d}", design, fs_hz=self.fs_hz,
                               current_names=self.current_names, current_limit_a=limit,
                               working_current_a=self.working_current, excitation_names=self.excitation_names,
                               progress=self.progress, start_margin=self.start_margin, after=self.last_end,
                               start_index=req.start_index)
        self.count += 1
        return exp

    def design_msg(self, exp: Experiment) -> DesignMsg:
        return DesignMsg(stamp=time_msg(exp.start * self.dt),
                         **design_fields(exp.design, exp.experiment_id, exp.start, exp.total))

    def on_stop(self, req: StopExperiment.Request, resp: StopExperiment.Response) -> StopExperiment.Response:
        exp = self.exp
        if exp is None or (req.experiment_id and req.experiment_id != exp.experiment_id):
            resp.accepted = False
            resp.message = (f"experiment {req.experiment_id!r} is not running" if req.experiment_id
                            else "no experiment is running")
            running = f"; running: {exp.experiment_id}" if exp is not None else ""
            resp.message += running
            return resp
        exp.stop()
        self.exp_msg.total_samples = exp.total
        self.exp_msg.measurement_time = exp.total / exp.design.fs_hz
        self.pub_design.publish(self.exp_msg)
        self.event(SessionEvent.INFO, "stopped", f"{exp.experiment_id} stopped at sample {exp.end} "
                                                 f"({exp.total} of {exp.design.total_samples} samples)")
        self.finish(exp)
        resp.accepted, resp.stop_index = True, exp.end
        resp.message = f"{exp.experiment_id} stops at sample {exp.end}"
        return resp

    # --- streaming -----------------------------------------------------------
    def pump(self) -> None:
        """Publish the blocks whose end lies within lookahead of the plant's progress."""
        exp = self.exp
        if exp is None:
            return
        for first, data, final in exp.due_blocks(self.progress, self.lookahead, self.block_size,
                                                 len(self.excitation_names)):
            self.pub_block.publish(block_msg(first, self.dt, self.excitation_names, self.excitation_units, data,
                                             flags=SampleBlock.FLAG_FINAL if final else 0,
                                             experiment_id=exp.experiment_id))
            self.blocks_published += 1
            self.samples_published += len(data)
        if self.progress >= exp.end:
            self.event(SessionEvent.INFO, "finished", f"{exp.experiment_id} done: samples [{exp.start}, {exp.end}) "
                                                      "applied by the plant")
            self.finish(exp)

    def finish(self, exp: Experiment) -> None:
        self.last_end = max(self.last_end, exp.end)
        self.exp, self.last, self.state = None, exp, SessionStatus.STATE_DONE
        self.publish_status()

    # --- reporting -------------------------------------------------------------
    def event_index(self) -> int:
        return self.progress

    def log_event(self, severity: int, code: str, text: str) -> None:
        if severity >= SessionEvent.WARN and code != "rejected_message":
            self.get_logger().warn(text)

    def publish_status(self) -> None:
        exp = self.exp or self.last
        if exp is None:
            progress, text = -1.0, "idle: call start_experiment"
        else:
            done = min(max(self.progress - exp.start, 0), exp.total)
            progress = done / exp.total if exp.total else 1.0
            verb = "running" if self.exp is not None else "done"
            text = (f"{exp.experiment_id} {verb}: {progress:.0%} of {exp.total} samples applied, "
                    f"{exp.next_offset} published")
        figures = {"experiment_id": exp.experiment_id if exp else "",
                   "start_index": exp.start if exp else 0, "total_samples": exp.total if exp else 0,
                   "experiment_samples_published": exp.next_offset if exp else 0,
                   "samples_published": self.samples_published, "blocks_published": self.blocks_published,
                   "plant_index": self.progress, "lookahead": self.lookahead, **self.intake.figures()}
        self.pub_status.publish(status_msg(
            time_msg(self.progress * self.dt), self.get_fully_qualified_name(), self.state, self.progress, progress,
            self.intake.total_received, self.intake.total_rejected, text, figures))


main = ExcitationGenerator.main  # the console script: SessionNode.main


if __name__ == "__main__":
    sys.exit(main())
