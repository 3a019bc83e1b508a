"""An identification session on the ROS graph: every node, one experiment, recorded.

Composed layout (the default): recorder, plant_sim, excitation_generator,
frf_consumer and position_controller as nodes of one process on one
EventsExecutor. The experiment is designed here, handed to the generator
through its ``start_experiment`` service before the loop starts, and placed
at a fixed sample index after lift-off, so a session is reproducible for a
seed. The loop starts when the controller joins, after the recorder and the
consumer are subscribed, so nothing of the experiment is missed.

Processes layout (``processes``): every node its own process, supervised
(``ambid_nodes.session_processes``): a node's death ends the run with one line
naming the node and the sample (:class:`NodeDied`).

Either way every node belongs to the session ``session`` (docs/sessions.md):
it acts only on that session's messages, and the recording holds only them.
"""

from __future__ import annotations

import json
import multiprocessing
import sys
import time
from dataclasses import dataclass, fields, replace
from typing import Callable

from ambid.excitation import ExcitationDesign
from ambid.frf.offline import data_channels
from ambid.hardware.bridge_protocol import CommandCode
from ambid.identification.result import Identification
from ambid.jsonable import JsonRecord, json_field
from ambid.session_id import format_session, new_session_id

from rclpy.node import Node

from ambid_msgs.msg import ControllerDescription, PlantDescription
from ambid_msgs.msg import ExcitationDesign as DesignMessage
from ambid_nodes import qos
from ambid_nodes.graph import preflight
from ambid_nodes.node_main import gc_frozen
from ambid_nodes.running.domain import session_domain_id
# the plan and its parts live in ambid_nodes.running.plan; the command line takes them from here, beside the
# entry points (run_identify, run_session_composed)
from ambid_nodes.running.plan import (LIFT_OFF_S, NodeDied, ProgressBar, SessionConfig, SessionPlan,  # noqa: F401
                                      config_json, hardware_summary, plan_session, run_facts, session_samples)

SETTLE_S = 0.2  # wall time for the status and events the nodes publish as the run ends, once the data is in


def start_live(cfg: SessionConfig):
    """The live view of ``cfg`` (``live_port``) as a process of its own, started; None without one."""
    if cfg.live_port is None:
        return None
    from ambid_nodes.live_view import LiveProcess

    return LiveProcess(cfg.live_port, cfg.live_host, cfg.namespace, cfg.estimator, session_domain_id(),
                       cfg.session or 0)


def local_readers(nodes, topic: str) -> int:
    """How many subscriptions of ``nodes`` (this process's) read ``topic`` (a resolved name)."""
    return sum(1 for n in nodes for sub in n.subscriptions if sub.topic_name == topic)


def run_session_composed(cfg: SessionConfig, plan: SessionPlan | None = None,
                         report_foreign: Callable[[dict], None] | None = None, live=None, early=None) -> dict:
    """Run the whole graph in this process; returns the run's facts (no offline analysis).

    ``plan`` (default :func:`plan_session`) is what the nodes run: one rig, one controller, one design.
    ``report_foreign`` is told the foreign publishers found on the rig's topics before anything starts.
    ``live`` (a started :class:`ambid_nodes.live_view.LiveProcess`): the experiment starts once it listens
    and hears the measurement, so it shows the whole experiment. ``early``
    (:class:`ambid.identification.early.EarlyAnalysis`): handed the session's inputs as they become known,
    and the final FRF the moment the consumer has it, so the analysis runs while the graph closes.
    """
    run = _Composed(cfg, plan_session(cfg) if plan is None else plan)
    try:
        foreign = preflight(run.executor, cfg.namespace, run.context, report_foreign)
        plant, recorder, generator, consumer, inputs = run.add_nodes(early is not None)
        run.wait_readers(plant, recorder, generator, live)
        answer = run.start_experiment(plant, recorder, generator)

        def analyse_early() -> None:
            if inputs is not None and not early.analysing and answer.experiment_id in consumer.results:
                early.analyse(inputs.session_inputs(run.mcap_path, consumer.results[answer.experiment_id],
                                                    cfg.nonlinear_magnets))

        plant_summary = run.until_finished(plant, consumer, analyse_early)
        rec = run.close_recording(plant, recorder, consumer, plant_summary, answer, analyse_early)
        return run_facts(answer, plant_summary, rec, _live_figures(consumer.results[answer.experiment_id]),
                         time.perf_counter() - run.wall0, f"hardware bridge to {cfg.hardware}" if cfg.hardware
                         else "composed", run.plan.design, run.mcap_path, foreign,
                         consumer.finished_at.get(answer.experiment_id))
    finally:
        run.shutdown()


class _Composed:
    """One composed run's executor and nodes, and its stages in the order :func:`run_session_composed` runs them."""

    def __init__(self, cfg: SessionConfig, plan: SessionPlan) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor

        self.cfg, self.plan = cfg, plan
        self.fs = plan.rig.sample_rate_hz
        self.start_index, self.total = session_samples(plan.design, self.fs)
        self.mcap_path = cfg.out_dir / "session.mcap"
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=session_domain_id())
        self.executor = EventsExecutor(context=self.context)
        self.nodes: list = []
        self.wall0 = time.perf_counter()
        self.session = {"session": cfg.session or new_session_id()}  # every session has an id, given or fresh
        # said, not parsed again: the nodes get plan.rig
        self.rig_param = {"rig_file": cfg.rig_file} if cfg.rig_file else {}
        self.ns = dict(namespace=cfg.namespace, context=self.context)

    @staticmethod
    def params(d: dict) -> list:
        from rclpy.parameter import Parameter

        return [Parameter(k, value=v) for k, v in d.items()]

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin_until(self, pred, timeout_s: float, what: str) -> None:
        end = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > end:
                raise RuntimeError(f"identify: timed out after {timeout_s:g} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.05)

    def add_nodes(self, with_inputs: bool) -> tuple:
        """Plant (or the bridge to the target), recorder, generator, consumer, and the inputs' listener."""
        from ambid_nodes.excitation_generator import ExcitationGenerator
        from ambid_nodes.frf_consumer import FrfConsumer
        from ambid_nodes.plant_sim import PlantSim
        from ambid_nodes.recorder import Recorder

        cfg, plan, ns, params, session, rig_param = (self.cfg, self.plan, self.ns, self.params, self.session,
                                                     self.rig_param)
        if cfg.hardware:
            plant = self.add_bridge()
        cfg.out_dir.mkdir(parents=True, exist_ok=True)
        recorder = self.add(Recorder(**ns, parameter_overrides=params({
            "output": str(self.mcap_path), "overwrite": True,
            "session_facts": json.dumps({"session": "identify", "config": config_json(cfg)}), **session})))
        if not cfg.hardware:
            plant = self.add(PlantSim(**ns, rig=plan.rig, parameter_overrides=params({
                "sim_seconds": self.total / self.fs, "seed": cfg.seed, "nonlinear_magnets": cfg.nonlinear_magnets,
                **rig_param, **session})))
        generator = self.add(ExcitationGenerator(**ns, rig=plan.rig, parameter_overrides=params({
            "start_margin": self.start_index, **rig_param, **session})))
        consumer = self.add(FrfConsumer(**ns, parameter_overrides=params({"estimator": cfg.estimator, **session})))
        inputs = self.add(SessionMessages(session["session"], **ns)) if with_inputs else None
        return plant, recorder, generator, consumer, inputs

    def add_bridge(self):
        """The bridge to the target, which runs plant and controller; it starts once it knows the experiment."""
        from ambid.hardware.rt_target import parse_address
        from ambid_nodes.hardware_bridge import HardwareBridge

        cfg = self.cfg
        host, port = parse_address(cfg.hardware)
        plant = self.add(HardwareBridge(**self.ns, rig=self.plan.rig, parameter_overrides=self.params({
            "target_host": host, "target_port": port, "local_port": cfg.local_port, "autostart": False,
            "key_file": cfg.key_file, "protocol_version": cfg.protocol_version, **self.rig_param, **self.session})))
        # the target must answer before anything is written: a wrong address leaves no recording behind
        self.spin_until(lambda: plant.connected, 15, f"the real-time target at {cfg.hardware} (is it running and "
                                                     "sending to this bridge's port?); nothing was recorded")
        return plant

    def wait_readers(self, plant, recorder, generator, live) -> None:
        """Every reader of the measurement and of the (latched) design matched before the plant runs.

        This process's own (the recorder's once it has found the topic), and a live view's, whose process
        discovers ours late on a loaded machine (a design it got after the experiment's blocks had passed
        would leave it no FRF to show).
        """
        remote = 0
        if live is not None:
            print(f"ambid: live view on {live.wait_ready()} (docs/live.md)", file=sys.stderr, flush=True)
            remote = 1
        for pub, who in ((plant.pub_block, "the measurement"), (generator.pub_design, "the excitation design")):
            topic = pub.topic_name
            self.spin_until(lambda pub=pub, topic=topic: topic in recorder.subs and
                            pub.get_subscription_count() >= local_readers(self.nodes, topic) + remote, 30,
                            f"every reader of {who}" + (" (the live view among them)" if remote else ""))
        self.spin_until(lambda: generator.plant_known, 30, "the plant description at the generator")

    def start_experiment(self, plant, recorder, generator):
        """Hand the design to the generator, then start the target or add the controller; the service's answer."""
        from ambid_msgs.srv import StartExperiment
        from ambid_nodes.position_controller import PositionController

        cfg, spin_until = self.cfg, self.spin_until
        client = recorder.create_client(StartExperiment, "start_experiment")
        spin_until(client.service_is_ready, 30, "the start_experiment service")
        future = client.call_async(StartExperiment.Request(start_index=self.start_index,
                                                           design_json=json.dumps(self.plan.design.to_dict())))
        spin_until(future.done, 30, "the start_experiment answer")
        answer = future.result()
        if not answer.accepted:
            raise ValueError(f"identify: the excitation generator refused the experiment: {answer.message}")
        if cfg.hardware:
            spin_until(lambda: answer.experiment_id in plant.slots and plant.connected
                       and not plant.commands.pending, 30,
                       f"the real-time target at {cfg.hardware} to acknowledge the experiment (is it running, "
                       "idle, and sending to this bridge's port?)")
            plant.queue_command(CommandCode.START)
        else:
            self.add(PositionController(**self.ns, rig=self.plan.rig, design=self.plan.controller,
                                        parameter_overrides=self.params({
                                            **self.rig_param, "controller": cfg.controller, **self.session})))
        return answer

    def until_finished(self, plant, consumer, analyse_early: Callable[[], None]) -> dict:
        """Spin until the plant's run ends, showing progress; the plant's summary."""
        cfg, total, fs = self.cfg, self.total, self.fs
        bar = ProgressBar(cfg.progress)
        stop_sent = False

        def tick() -> None:
            nonlocal stop_sent
            analyse_early()
            if cfg.hardware:
                k = plant.figures()["samples_published"]
                if k >= total and not stop_sent:  # enough recorded: the target's clock may stop
                    plant.queue_command(CommandCode.STOP)
                    stop_sent = True
            else:
                k = plant.k
            st = _consumer_text(consumer)
            rate = k / max(time.perf_counter() - self.wall0, 1e-9)
            bar.show(k / total, f"sim {k / fs:6.2f}/{total / fs:.2f} s  {rate / 1000:5.1f}k samples/s  {st}")

        # a timer among the loop's events: the composed loop keeps the executor busy, so that
        # spin_until_future_complete returns only when the run is over; the bar moves by the timer
        timer = self.nodes[0].create_timer(0.25, tick)
        with gc_frozen():
            while not plant.finished.done():
                self.executor.spin_until_future_complete(plant.finished, timeout_sec=0.25)
                tick()
        self.nodes[0].destroy_timer(timer)
        bar.show(1.0, "simulation done, closing the recording", force=True)
        bar.close()
        plant_summary = plant.finished.result()
        if cfg.hardware:
            plant_summary = hardware_summary(plant_summary, total, fs, time.perf_counter() - self.wall0)
        return plant_summary

    def close_recording(self, plant, recorder, consumer, plant_summary: dict, answer,
                        analyse_early: Callable[[], None]) -> dict:
        """Let the recorder and the consumer take the last blocks, then what the nodes said at the end."""
        meas = plant.pub_block.topic_name
        n_blocks = (plant.figures()["blocks"] if self.cfg.hardware
                    else -(-plant_summary["samples"] // plant.block_size))
        self.spin_until(lambda: recorder.counts.get(meas, 0) >= n_blocks, 30,
                        "the last measurement block at the recorder")
        failure = plant_summary.get("failure")
        if failure:  # the run stopped short, no estimate will come: keep the recording, say why
            recorder.close()
            raise RuntimeError(f"the plant ended the session failed ({failure['code']}): {failure['text']}; "
                               f"the recording so far is in {self.mcap_path}")
        self.spin_until(lambda: answer.experiment_id in consumer.results, 30, "the final FRF estimate")
        analyse_early()
        end = time.monotonic() + SETTLE_S
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
        return recorder.close()

    def shutdown(self) -> None:
        import rclpy

        self.executor.shutdown()
        for n in self.nodes:
            n.destroy_node()
        rclpy.shutdown(context=self.context)


class SessionMessages(Node):
    """A listener of the session's latched descriptions (its own session's only), the plant's, the controller's and the experiment's,
    kept as they come: the inputs of an early analysis, read as the recording's are
    (:func:`ambid.identification.inputs.inputs_from_messages`)."""

    def __init__(self, session: int, **kwargs) -> None:
        super().__init__("identify_inputs", **kwargs)
        self.last: dict = {}
        latched = qos.subscription(qos.LATCHED)

        def keep(name: str, msg) -> None:  # another session's descriptions are never the inputs
            if msg.session_id == session:
                self.last[name] = msg

        for name, kind, topic in (("plant", PlantDescription, "plant/description"),
                                  ("controller", ControllerDescription, "controller/description"),
                                  ("design", DesignMessage, "excitation/design")):
            self.create_subscription(kind, topic, lambda msg, name=name: keep(name, msg), latched)
        self.design_topic = self.resolve_topic_name("excitation/design")

    def described(self, controller: bool = True) -> bool:
        """The plant and the experiment (and the controller, where this graph runs one) are known."""
        return {"plant", "design"} | ({"controller"} if controller else set()) <= set(self.last)

    def session_inputs(self, path, frf, nonlinear_magnets: bool):
        """:class:`ambid.identification.inputs.SessionInputs` of what was heard, with ``frf`` (or None)."""
        from ambid.identification.inputs import inputs_from_messages

        return inputs_from_messages(path, self.design_topic, self.last["design"], self.last.get("plant"),
                                    self.last.get("controller"), frf, nonlinear_magnets)


def _consumer_text(consumer) -> str:
    f = consumer.figures()
    if not f:
        return "waiting for the experiment"
    noise = f.get("relative_noise_std")
    noise_txt = f"  FRF noise {100 * noise:.2g} %" if noise is not None else ""
    return f"periods {f['periods_done']}/{f['periods']}{noise_txt}"


def _live_figures(result) -> dict:
    return {"relative_noise_std": float(result.relative_noise_std), "periods": int(result.n_periods),
            "realisations": int(result.n_realisations), "iso_zone": result.iso_zone,
            "sensitivity_peak": [float(v) for v in result.sensitivity_peak]}


def run_identify(cfg: SessionConfig, plan: SessionPlan | None = None,
                 report_foreign: Callable[[dict], None] | None = None,
                 on_headline: Callable[[IdentifyResult], None] | None = None,
                 on_phase: Callable[[str], None] | None = None) -> IdentifyResult:
    """The whole job: the recorded session on the graph, then the offline identification of it.

    The analysis runs in a process of its own (:class:`ambid.identification.early.EarlyAnalysis`), started
    with the session: what the measurement does not change is computed while it runs, the fit and the update
    start the moment the last period is in, while the graph and the recording close. ``on_headline`` is called
    with the summary as soon as the results are there, before the report is written (the numbers are those of
    the recording's analysis; should that process fail, the recording is analysed here, as before).
    ``on_phase`` is told each phase after the session as it starts (the analysis, the report).

    Writes ``out_dir/session.mcap``, ``out_dir/summary.json`` and ``out_dir/report/``.
    """
    from ambid.identification.early import EarlyAnalysis, EarlyAnalysisFailed
    from ambid.identification.pipeline import identify_session

    true_model = None
    if cfg.true_model:
        from ambid.hardware.target_model import read_target_model

        true_model = read_target_model(cfg.true_model).plant
    options = dict(estimator=cfg.estimator, true_model=true_model, report=cfg.report)
    live = start_live(cfg)
    # with a real-time target the bridge must never fall silent: the analysis yields it the CPU. A session
    # run by a daemonic worker (a study's on Dask) may not start processes: it analyses the recording itself
    early = (None if multiprocessing.current_process().daemon
             else EarlyAnalysis(cfg.out_dir, nice=5 if cfg.hardware else 0, **options))
    plan = plan_session(cfg) if plan is None else plan
    if early is not None:
        # what the analysis compares with and the measurement does not change, computed while the session runs
        # (from the plan: used if it is what the session then describes, see SessionMessages); the FRF's
        # channels as the recording will name them: the rig's displacements by the design's inputs
        outputs, inputs, _ = data_channels(plan.design.input_names, plan.rig.layout.measurement_names)
        early.prepare(_planned_inputs(cfg, plan), plan.design.freq_hz, outputs, inputs)
    try:
        if cfg.processes:   # no early analysis there: the recording is analysed once the session is over
            from ambid_nodes.session_processes import run_session_processes

            run = run_session_processes(cfg, plan, report_foreign, live=live)
        else:
            run = run_session_composed(cfg, plan, report_foreign, live=live, early=early)
        design: ExcitationDesign = run.pop("design")
        shown: dict = {}
        phase = on_phase or (lambda text: None)

        def show(offline: Identification) -> None:   # the headline, as soon as the results are there
            shown["at"] = time.perf_counter()
            if on_headline is not None:
                on_headline(_identify_summary(cfg, run, design, offline, _timing(run, shown)))
            phase("writing the report" if cfg.report is True else "handing the report to a process of its own")

        phase("analysing the recording: FRF, fit, model update")

        offline = notes = None
        if early is not None and early.analysing:
            try:
                early.recording_closed()
                first, how = early.summary()
                shown.update(how, early=True)
                if run.get("final_estimate_at") is not None:
                    shown["analysis_started_after_last_period_s"] = early.times["analyse"] - run["final_estimate_at"]
                show(first)
                offline, notes = early.result()
            except EarlyAnalysisFailed as exc:
                print(f"ambid identify: the analysis process failed ({str(exc).splitlines()[0]}); analysing the "
                      "recording here", file=sys.stderr)
        if offline is None:
            offline = identify_session(run["mcap_path"], cfg.out_dir, on_summary=None if shown else show, **options)
        shown["done"] = time.perf_counter()
        if notes:   # the early inputs differed from the recording's: the results shown were replaced
            print("ambid identify: " + "; ".join(notes), file=sys.stderr)
            offline = replace(offline, notes=list(offline.notes) + notes)
            show(offline)
        summary = _identify_summary(cfg, run, design, offline, _timing(run, shown))
    finally:
        if early is not None:
            early.close()
        live_figures = live.stop() if live is not None else None
    if live_figures is not None:
        summary = replace(summary, live=live_figures)
    (cfg.out_dir / "summary.json").write_text(json.dumps(summary.to_json(), indent=2))
    return summary


def _planned_inputs(cfg: SessionConfig, plan: SessionPlan):
    """The session's inputs as the plan foresees them (the rig's JSON as plant_sim publishes it, the
    controller's model, the design), without the FRF: what reference models can be computed from early."""
    from ambid.identification.inputs import SessionInputs

    ctrl = None if plan.controller is None else (plan.controller.model, {})
    experiment = {"topic": "", "experiment_id": "", "start_index": 0, "total_samples": plan.design.total_samples,
                  "design": plan.design}
    return SessionInputs(str(cfg.out_dir / "session.mcap"), experiment, None, json.loads(json.dumps(plan.rig.to_dict())),
                         "hardware" if cfg.hardware else "sim", ctrl, cfg.nonlinear_magnets)


def _timing(run: dict, shown: dict) -> dict:
    """Wall seconds from the last period's estimate (the consumer's final FRF) to the headline and the report."""
    t0 = run.get("final_estimate_at")
    if t0 is None:
        return {}
    out = {k: shown[k] for k in ("early", "references_s", "references_used", "waited_for_references_s",
                                 "analysis_s", "analysis_cpu_s", "analysis_started_after_last_period_s") if k in shown}
    if "at" in shown:
        out["headline_after_last_period_s"] = shown["at"] - t0
    if "done" in shown:
        out["report_after_last_period_s"] = shown["done"] - t0
    return out


def _identify_summary(cfg: SessionConfig, run: dict, design: ExcitationDesign, offline: Identification,
                      timing: dict) -> IdentifyResult:
    rec, plant = run["recorder"], run["plant"]
    return IdentifyResult(
        sample_rate_hz=float(design.fs_hz), simulated_time_s=run["simulated_s"], wall_time_s=run["wall_s"],
        simulated_samples_per_wall_s=run["samples_per_wall_s"], real_time_factor=run["simulated_s"] / run["wall_s"],
        layout=run["layout"], state=plant["state"], levitated=plant["levitated"],
        # lost loop messages the plant asked for again, and the answers that then came twice
        loop_recovery=LoopRecovery(resends=plant.get("resends", 0),
                                   duplicate_answers=plant.get("duplicate_answers", 0)),
        live_frf=run["live_frf"], identification=offline, analysis_timing=timing,
        recording=RecordingFacts(path=run["mcap_path"], messages=rec.get("messages", rec.get("message_count")),
                                 complete=rec.get("complete", True)),
        # what the recorder heard of other sources during the session and kept out, per topic
        session=SessionFacts(id=format_session(cfg.session), foreign_publishers=run["foreign_publishers"],
                             foreign_messages=rec.get("foreign", {})))


@dataclass(frozen=True, eq=False)
class LoopRecovery(JsonRecord):
    """Lost loop messages the plant asked for again, and the answers that then came twice."""

    resends: int
    duplicate_answers: int


@dataclass(frozen=True, eq=False)
class RecordingFacts(JsonRecord):
    """The session's recording: its file, how many messages, whether it was closed completely."""

    path: str
    messages: int | None
    complete: bool


@dataclass(frozen=True, eq=False)
class SessionFacts(JsonRecord):
    """The session's id, the foreign publishers found before it started and what the recorder kept out."""

    id: str
    foreign_publishers: dict
    foreign_messages: dict


@dataclass(frozen=True, eq=False)
class IdentifyResult(JsonRecord):
    """What ``ambid identify`` made: the run on the graph and the identification of its recording
    (``summary.json``; its keys are the run's, then the identification's, as the file has always had them).

    Attributes:
        sample_rate_hz: the plant's sample rate [Hz].
        simulated_time_s, wall_time_s: the session's simulated and wall time [s].
        simulated_samples_per_wall_s, real_time_factor: how fast it ran.
        layout: how it ran (``composed``, ``processes``, ``hardware bridge to HOST:PORT``).
        state, levitated: how the plant ended.
        loop_recovery: lost loop messages asked for again.
        live_frf: the FRF consumer's last figures (relative_noise_std, periods, realisations, iso_zone,
            sensitivity_peak).
        identification: the identification of the recording
            (:class:`ambid.identification.result.Identification`).
        analysis_timing: wall seconds from the last period to the headline and the report.
        recording: the recording's facts.
        session: the session's id and the foreign publishers.
        live: the live view's figures, when it ran.
    """

    sample_rate_hz: float
    simulated_time_s: float
    wall_time_s: float
    simulated_samples_per_wall_s: float
    real_time_factor: float
    layout: str
    state: str
    levitated: bool | None
    loop_recovery: LoopRecovery
    live_frf: dict
    identification: Identification
    analysis_timing: dict
    recording: RecordingFacts
    session: SessionFacts
    live: dict | None = json_field(omit_none=True)

    def json_items(self) -> dict:
        ident = self.identification.json_items()
        out = {"excitation": ident["excitation"], "sample_rate_hz": self.sample_rate_hz, "band_hz": ident["band_hz"],
               "inputs": ident["inputs"]}
        out.update((f.name, getattr(self, f.name)) for f in fields(self)
                   if f.name in ("simulated_time_s", "wall_time_s", "simulated_samples_per_wall_s",
                                 "real_time_factor", "layout", "state", "levitated", "loop_recovery", "live_frf"))
        for k, v in ident.items():
            out.setdefault(k, v)
        out.update(analysis_timing=self.analysis_timing, recording=self.recording, session=self.session)
        if self.live is not None:
            out["live"] = self.live
        return out
