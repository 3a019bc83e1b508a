"""The composed layout: recorder, plant_sim, excitation_generator, frf_consumer and position_controller as
nodes of one process on one EventsExecutor (the default of ``ambid identify``).

The experiment is designed once (the plan), handed to the generator through its ``start_experiment``
service before the loop starts, and placed at a fixed sample index after lift-off, so a session is
reproducible for a seed. The loop starts when the controller joins, after the recorder and the consumer
are subscribed, so nothing of the experiment is missed.
"""

from __future__ import annotations

import contextlib
import json
import time

from rclpy.node import Node

from ambid_msgs.msg import ControllerDescription, PlantDescription
from ambid_msgs.msg import ExcitationDesign as DesignMessage
from ambid_nodes import qos
from ambid_nodes.identity import not_subscribed
from ambid_nodes.node_main import gc_frozen
from ambid_nodes.running.domain import session_domain_id
from ambid_nodes.running.layout import Layout, announce_live
from ambid_nodes.running.plan import ProgressBar, config_json

SETTLE_S = 0.2  # wall time for the status and events the nodes publish as the run ends, once the data is in


class ComposedLayout(Layout):
    """Every node of the session in this process (:class:`~ambid_nodes.running.layout.Layout`).

    ``early`` (:class:`ambid.identification.early.EarlyAnalysis`): handed the session's inputs as they
    become known, and the final FRF the moment the consumer has it, so the analysis runs while the graph
    closes.
    """

    kind = "composed"

    def __init__(self, *args, early=None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.early = early
        self.nodes: list = []
        self.plant = self.recorder = self.generator = self.consumer = self.inputs = self.answer = None

    # --- the steps ---------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def opened(self):
        import rclpy
        from rclpy.experimental import EventsExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=session_domain_id())
        self.executor = EventsExecutor(context=self.context)
        self.ns = dict(namespace=self.cfg.namespace, context=self.context)
        try:
            yield
        finally:
            self.executor.shutdown()
            for n in self.nodes:
                n.destroy_node()
            rclpy.shutdown(context=self.context)

    def start_graph(self) -> None:
        """Recorder, plant (unless the bridge came first), generator, consumer, and the inputs' listener."""
        from ambid_nodes.excitation_generator import ExcitationGenerator
        from ambid_nodes.frf_consumer import FrfConsumer
        from ambid_nodes.recorder import Recorder

        cfg, plan, ns, params = self.cfg, self.plan, self.ns, self.params
        if self.loop_only:
            if self.plant is None:
                self.plant = self.add(self.make_plant())
            return
        cfg.out_dir.mkdir(parents=True, exist_ok=True)
        self.recorder = self.add(Recorder(**ns, parameter_overrides=params({
            "output": str(self.mcap_path), "overwrite": True,
            "session_facts": json.dumps({"session": "identify", "config": config_json(cfg)}), **self.session})))
        if self.plant is None:
            self.plant = self.add(self.make_plant())
        self.generator = self.add(ExcitationGenerator(**ns, rig=plan.rig, parameter_overrides=params({
            "start_margin": self.start_index, **self.rig_param, **self.session})))
        self.consumer = self.add(FrfConsumer(**ns, parameter_overrides=params({"estimator": cfg.estimator,
                                                                                **self.session})))
        if self.early is not None:
            self.inputs = self.add(SessionMessages(self.session["session"], **ns))

    def wait_readers(self) -> None:
        """Every reader of the measurement and of the (latched) design matched before the plant runs.

        This process's own (the recorder's once it has found the topic), and a live view's, whose process
        discovers ours late on a loaded machine (a design it got after the experiment's blocks had passed
        would leave it no FRF to show). The loop alone starts at once: its nodes are this process's.
        The writers are this process's, so their matched counts are read here, the hardware bridge's as
        plant_sim's (the processes layout cannot: it hands the count to plant_sim, ``measurement_readers``).
        """
        if self.loop_only:
            return
        remote = announce_live(self.live)
        recorder = self.recorder
        # the live view by name too: another listener of this topic (a monitor) would make up its count
        for node, pub, who in ((self.plant, self.plant.pub_block, "the measurement"),
                               (self.generator, self.generator.pub_design, "the excitation design")):
            topic = pub.topic_name
            self.spin_until(lambda node=node, pub=pub, topic=topic: topic in recorder.subs and
                            pub.get_subscription_count() >= local_readers(self.nodes, topic) + remote and
                            not not_subscribed(node, topic, ["live_view"] * remote), 30,
                            f"every reader of {who}" + (" (the live view among them)" if remote else ""))
        self.spin_until(lambda: self.generator.plant_known, 30, "the plant description at the generator")

    def start_experiment(self):
        """Hand the design to the generator, then start the loop (:meth:`start_loop`); the service's answer."""
        from ambid_msgs.srv import StartExperiment

        if self.loop_only:
            self.start_loop(None)
            return None
        client = self.recorder.create_client(StartExperiment, "start_experiment")
        self.spin_until(client.service_is_ready, 30, "the start_experiment service")
        future = client.call_async(StartExperiment.Request(start_index=self.start_index,
                                                           design_json=json.dumps(self.plan.design.to_dict())))
        self.spin_until(future.done, 30, "the start_experiment answer")
        answer = future.result()
        if not answer.accepted:
            raise ValueError(f"identify: the excitation generator refused the experiment: {answer.message}")
        self.answer = answer
        self.wait_live_design(answer)
        self.start_loop(answer)
        return answer

    def run_loop(self, answer) -> dict:
        """Spin until the plant's run ends, showing progress; the plant's summary."""
        bar = ProgressBar(self.cfg.progress)

        def tick() -> None:
            self.analyse_early()
            self.show_progress(bar, self.progress(), f"  {consumer_text(self.consumer)}")

        # a timer among the loop's events: the composed loop keeps the executor busy, so that
        # spin_until_future_complete returns only when the run is over; the bar moves by the timer
        timer = self.nodes[0].create_timer(0.25, tick)
        plant = self.plant
        with gc_frozen():
            while not plant.finished.done():
                if not self.context.ok():   # ^C or SIGTERM (rclpy shuts the context down): every node stops
                    raise KeyboardInterrupt
                self.executor.spin_until_future_complete(plant.finished, timeout_sec=0.25)
                tick()
        self.nodes[0].destroy_timer(timer)
        bar.show(1.0, "simulation done, closing the recording", force=True)
        bar.close()
        return self.plant_summary(plant.finished.result())

    def stop(self, plant_summary: dict, answer) -> tuple[dict, dict]:
        """Let the recorder and the consumer take the last blocks, then what the nodes said at the end."""
        recorder, consumer = self.recorder, self.consumer
        meas = self.plant.pub_block.topic_name
        n_blocks = self.blocks_published(plant_summary)
        self.spin_until(lambda: recorder.counts.get(meas, 0) >= n_blocks, 30,
                        "the last measurement block at the recorder")
        failure = plant_summary.get("failure")
        if failure:  # the run stopped short, no estimate will come: keep the recording, say why
            recorder.close()
            raise RuntimeError(f"the plant ended the session failed ({failure['code']}): {failure['text']}; "
                               f"the recording so far is in {self.mcap_path}")
        self.spin_until(lambda: answer.experiment_id in consumer.results, 30, "the final FRF estimate")
        self.analyse_early()
        end = time.monotonic() + SETTLE_S
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
        return recorder.close(), consumer.final_figures[answer.experiment_id]

    def words(self) -> str:
        return "composed"

    def final_estimate_at(self, answer) -> float | None:
        return self.consumer.finished_at.get(answer.experiment_id)

    # --- what the hardware layout does its own way ---------------------------------------------------------
    def make_plant(self):
        """The simulated rig, run for the session's samples."""
        from ambid_nodes.plant_sim import PlantSim

        cfg = self.cfg
        return PlantSim(**self.ns, rig=self.plan.rig, parameter_overrides=self.params({
            "sim_seconds": self.sim_seconds, "seed": cfg.seed, "nonlinear_magnets": cfg.nonlinear_magnets,
            **self.rig_param, **self.session}))

    def start_loop(self, answer) -> None:
        """The controller joins: the loop starts."""
        from ambid_nodes.position_controller import PositionController

        self.add(PositionController(**self.ns, rig=self.plan.rig, design=self.plan.controller,
                                    parameter_overrides=self.params({
                                        **self.rig_param, "controller": self.cfg.controller, **self.session})))

    def progress(self) -> int:
        """Samples run so far."""
        return self.plant.k

    def plant_summary(self, summary: dict) -> dict:
        return summary

    def blocks_published(self, plant_summary: dict) -> int:
        return -(-plant_summary["samples"] // self.plant.block_size)

    # --- helpers -----------------------------------------------------------------------------------------
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

    def analyse_early(self) -> None:
        """Hand the early analysis the session's inputs and the final FRF, once the consumer has it."""
        early, answer, consumer = self.early, self.answer, self.consumer
        if (self.inputs is not None and not early.analysing and answer is not None
                and answer.experiment_id in consumer.results):
            early.analyse(self.inputs.session_inputs(self.mcap_path, consumer.results[answer.experiment_id],
                                                     self.cfg.nonlinear_magnets))


def local_readers(nodes, topic: str) -> int:
    """How many subscriptions of ``nodes`` (this process's) read ``topic`` (a resolved name)."""
    return sum(1 for n in nodes for sub in n.subscriptions if sub.topic_name == topic)


def consumer_text(consumer) -> str:
    """The consumer's progress for the progress bar."""
    f = consumer.figures() if consumer is not None else {}
    if not f:
        return "waiting for the experiment"
    noise = f.get("relative_noise_std")
    noise_txt = f"  FRF noise {100 * noise:.2g} %" if noise is not None else ""
    return f"periods {f['periods_done']}/{f['periods']}{noise_txt}"


class SessionMessages(Node):
    """A listener of the session's latched descriptions (its own session's only), the plant's, the
    controller's and the experiment's, kept as they come: the inputs of an early analysis, read as the
    recording's are (:func:`ambid.identification.inputs.inputs_from_messages`)."""

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
