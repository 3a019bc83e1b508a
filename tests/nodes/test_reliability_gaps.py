"""Issue 9, point 4, end to end: a measurement block lost between the plant and its consumers is
detected by the FRF consumer (event, status figures, the period dropped: no FRF across the gap)
and by the recording (``ambid inspect`` names the missing samples)."""

from __future__ import annotations

import argparse
import json

from ambid_cli.commands import inspect as inspect_cmd
from ambid_nodes.excitation_generator import ExcitationGenerator
from ambid_nodes.frf_consumer import FrfConsumer
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from ambid_nodes.recorder import Recorder
from rclpy.node import Node
from rclpy.parameter import Parameter

from ambid_msgs.msg import FrfEstimate, SampleBlock, SessionEvent
from ambid_msgs.srv import StartExperiment
from ambid_nodes import qos

NS = "/gap"
BLOCK = 500
START = 1500          # start_margin: the generator places the experiment here (plant at 0)
N, P, TRANSIENT = 1000, 4, 1
DROPPED = START + (TRANSIENT + 1) * N  # the first block of steady-state period 1


class LossyLink(Node):
    """Forwards the plant's measurement blocks to ``measurement``, losing one."""

    def __init__(self, context):
        super().__init__("lossy_link", namespace=NS, context=context)
        self.pub = self.create_publisher(SampleBlock, "measurement", qos.BLOCKS)
        self.create_subscription(SampleBlock, "measurement_raw", self.forward, qos.BLOCKS)
        self.events: list[SessionEvent] = []
        self.frf: list[FrfEstimate] = []
        self.create_subscription(SessionEvent, "events", self.events.append, qos.EVENTS)
        self.create_subscription(FrfEstimate, "frf", self.frf.append, qos.LATCHED)
        self.start = self.create_client(StartExperiment, "start_experiment")

    def forward(self, msg: SampleBlock) -> None:
        if msg.first_index != DROPPED:
            self.pub.publish(msg)


def test_a_lost_block_is_reported_by_consumer_and_recording_and_no_frf_spans_it(ros, tmp_path, capsys):
    path = tmp_path / "gap.mcap"
    link = ros.add(LossyLink(ros.context))
    rec = ros.add(Recorder(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("output", value=str(path)), Parameter("topics", value=["measurement", "excitation/design"]),
        Parameter("discovery_period_s", value=0.05)]))
    gen = ros.add(ExcitationGenerator(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in dict(
            input_names=["u_a_x"], band_hz=[50.0, 1000.0], resolution_hz=10.0, n_periods=P,
            n_transient_periods=TRANSIENT, peak_current_a=0.3, n_realisations=1, phases="random", block_size=BLOCK, lookahead=3000,
            start_margin=START, seed=3).items()]))
    consumer = ros.add(FrfConsumer(namespace=NS, context=ros.context))
    plant = ros.add(PlantSim(namespace=NS, context=ros.context, cli_args=[
        "--ros-args", "-r", "measurement:=measurement_raw"], parameter_overrides=[
        Parameter("sim_seconds", value=(START + (TRANSIENT + P) * N + BLOCK) * 1e-4),
        Parameter("block_size", value=BLOCK)]))
    assert ros.spin_until(lambda: gen.plant_known and link.start.service_is_ready()
                          and f"{NS}/measurement" in rec.subs and f"{NS}/excitation/design" in rec.subs, 60)
    ros.matched(link, to=plant)  # every listener hears the loop from its first block
    for node in (rec, consumer):
        ros.matched(node, to=link)
    future = link.start.call_async(StartExperiment.Request())
    assert ros.spin_until(future.done, 10) and future.result().accepted, future.result()
    assert future.result().start_index == START
    ros.add(PositionController(namespace=NS, context=ros.context))  # the loop starts now
    assert ros.spin_until(plant.finished.done, 120)
    exp = future.result().experiment_id
    assert ros.spin_until(lambda: exp in consumer.results, 20), consumer.figures()
    assert plant.finished.result()["state"] == "done"

    # the consumer: one gap, its 500 samples, the period it touched dropped from the estimate
    f = consumer.figures(final=True)
    assert (f["gaps"], f["missing_samples"]) == (1, BLOCK)
    assert f["periods_used"] == P - 1
    assert ros.spin_until(lambda: any(e.code == "sample_gap" for e in link.events)
                          and link.frf and link.frf[-1].periods_used == P - 1, 5)
    gap = next(e for e in link.events if e.code == "sample_gap")
    assert f"[{DROPPED}, {DROPPED + BLOCK})" in gap.text and gap.severity == SessionEvent.WARN

    # the recording: inspect names the same gap
    rec.close()
    code = inspect_cmd.run(argparse.Namespace(file=str(path), json=True, recover=False))
    report = json.loads(capsys.readouterr().out)
    assert code == 0
    meas = report["sample_index"][f"{NS}/measurement"]
    assert (meas["gap_count"], meas["missing_samples"]) == (1, BLOCK)
    assert meas["gaps"][0]["expected_index"] == DROPPED and meas["gaps"][0]["got_index"] == DROPPED + BLOCK
