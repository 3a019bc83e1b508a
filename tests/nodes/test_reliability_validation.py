"""Issue 9, point 1: every subscriber of every node rejects bad messages with their reason, counts
them per topic in its status, and keeps working (a good message after them is accepted)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ambid.control.pid import PidParameters, pid_controller
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig
from ambid_nodes.conversions import block_msg, statespace_to_msg
from ambid_nodes.excitation_generator import ExcitationGenerator
from ambid_nodes.frf_consumer import FrfConsumer
from ambid_nodes.hardware_bridge import HardwareBridge
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ambid_msgs.msg import (ControllerDescription, ExcitationDesign, PlantDescription, Sample, SampleBlock,
                            SessionEvent, SessionStatus)
from ambid_nodes import qos
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels
MEASUREMENT_UNITS = ("m",) * 4 + ("A",) * 12

DT = 1e-4
R_NAMES = ("r_a_x", "r_b_x", "r_a_y", "r_b_y")
KEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
QOS = {"excitation": qos.BLOCKS, "measurement": qos.BLOCKS, "excitation/design": qos.LATCHED,
       "plant/description": qos.LATCHED, "controller/description": qos.LATCHED, "control_current": qos.LOOP,
       "displacement": qos.LOOP, "status": qos.STATUS}
TYPES = {"excitation": SampleBlock, "measurement": SampleBlock, "excitation/design": ExcitationDesign,
         "plant/description": PlantDescription, "controller/description": ControllerDescription,
         "control_current": Sample, "displacement": Sample, "status": SessionStatus}


def exc_block(first, n=100, value=0.01, names=R_NAMES, dt=DT):
    return block_msg(first, dt, names, ("A",) * len(names), np.full((n, len(names)), value))


def meas_block(first, n=100, value=1e-6):
    return block_msg(first, DT, MEASUREMENT_NAMES, MEASUREMENT_UNITS, np.full((n, 16), value))


def design(exp_id="e1", start=1000, total=1000, rate=1.0 / DT, **kw):
    fields = dict(experiment_id=exp_id, kind="multisine", start_index=start, total_samples=total, sample_rate=rate,
                  samples_per_period=1000, n_periods=1, input_names=["u_a_x"], excited_lines=[10, 20],
                  rms=[0.1], peak=[0.3], crest_factor=[3.0], measurement_time=total * DT, design_json="{}")
    fields.update(kw)
    return ExcitationDesign(**fields)


def plant_description(**kw):
    rig = make_rig()
    fields = dict(name="/x/plant_sim", source="sim", rig_name=rig.name, sample_period=DT,
                  displacement_names=["y_a_x", "y_b_x", "y_a_y", "y_b_y"],
                  current_names=["u_a_x", "u_b_x", "u_a_y", "u_b_y"], bias_current=[rig.bias_current_a] * 4,
                  current_limit=[rig.current_limit_a] * 4, backup_clearance=[rig.backup_clearance_m] * 2,
                  analytical_model=statespace_to_msg(analytical_model(rig)))
    fields.update(kw)
    return PlantDescription(**fields)


def controller_description(**kw):
    model = statespace_to_msg(pid_controller(PidParameters(), DT))
    for k, v in kw.items():
        setattr(model, k, v)
    return ControllerDescription(name="/x/position_controller", kind="pid", model=model, current_limit=[3.0] * 4)


def bad_a():
    m = statespace_to_msg(analytical_model(make_rig()))
    m.a = m.a[:-1]
    return m


# node -> (class, parameters, [(topic, message or raw bytes, accepted?, fragment of the rejection)])
CASES = {
    "plant_sim": (PlantSim, {}, [
        ("excitation", exc_block(100, names=("r_a_x", "r_b_x", "r_a_y", "r_x")), False, "expected ['r_a_x'"),
        ("excitation", exc_block(100, value=float("nan")), False, "NaN or Inf"),
        ("excitation", SampleBlock(first_index=100, sample_period=DT, n_samples=3, channel_names=list(R_NAMES),
                                   data=[0.0] * 11), False, "11 values, expected n_samples x channels"),
        ("excitation", SampleBlock(first_index=100, sample_period=DT, n_samples=0, channel_names=list(R_NAMES)),
         False, "no samples"),
        ("excitation", exc_block(100, dt=2 * DT), False, "sample period"),
        ("excitation", exc_block(2**50), False, "out of range"),
        ("excitation", exc_block(5_000_000), False, "horizon"),
        ("excitation", b"\x00\x01\x00\x00\xff\xff\xff\xff\x07", False, "do not decode as SampleBlock"),
        ("excitation", exc_block(100), True, ""),
        ("excitation", exc_block(150), False, "repeat or overlap the block [100, 200)"),
        ("excitation/design", design(rate=5000.0), False, "designed at 5000 Hz, the plant runs at 10000 Hz"),
        ("excitation/design", design(rms=[0.1, 0.2]), False, "2 rms values for 1 inputs"),
        ("excitation/design", design(exp_id=""), False, "empty experiment_id"),
        ("excitation/design", design(start=2**41), False, "out of range"),
        ("excitation/design", design(), True, ""),
        ("excitation/design", design("e2", start=1500), False, "overlap experiment 'e1' [1000, 2000)"),
        ("control_current", b"\x00\x01", False, "too short for a Sample"),
        ("control_current", Sample(index=0, values=[0.0] * 4), False, "the plant has not started"),
    ]),
    "position_controller": (PositionController, {}, [
        ("displacement", Sample(index=5, values=[0.0] * 4), False, "no session runs"),
        ("displacement", b"\x00\x01\x00\x00\x01", False, "too short for a Sample"),
        ("displacement", Sample(index=0, values=[float("nan")] * 4), False, "non-finite"),
        ("displacement", Sample(index=7, values=[0.0] * 4), False, "ahead of the loop or out of range"),
        # y[0] again before the loop moved on: the plant did not hear the answer, it gets it again
        ("displacement", Sample(index=0, values=[0.0] * 4), True, ""),
        ("displacement", Sample(index=1, values=[0.0] * 3), False, "3 values, expected 4"),
        ("displacement", Sample(index=2**63, values=[0.0] * 4), False, "out of range"),
        ("displacement", Sample(index=2, values=[1e-6] * 4), True, ""),
        # one of the last two again: the plant asks again (issue 21), the answer already given goes again
        ("displacement", Sample(index=1, values=[1e-6] * 4), True, ""),
        ("displacement", Sample(index=0, values=[1e-6] * 4), False, "repeated or out of order (expected 3)"),
        ("status", b"\x00\x01\x00\x00" + b"\xff" * 8, False, "do not decode as SessionStatus"),
    ]),
    "excitation_generator": (ExcitationGenerator, {}, [
        ("plant/description", plant_description(current_limit=[3.0] * 3), False, "3 current_limit values for 4"),
        ("plant/description", plant_description(analytical_model=bad_a()), False, "analytical_model"),
        ("plant/description", plant_description(sample_period=float("inf")), False, "sample_period inf"),
        ("plant/description", plant_description(current_names=["u_a_x"] * 4), False, "repeated channel names"),
        ("plant/description", plant_description(), True, ""),
        ("measurement", meas_block(0, value=float("inf")), False, "NaN or Inf"),
        ("measurement", b"garbage", False, "do not decode as SampleBlock"),
        ("measurement", meas_block(0), True, ""),
        ("measurement", meas_block(0), False, "repeated or out of order"),
        ("measurement", meas_block(2**41), False, "out of range"),
    ]),
    "frf_consumer": (FrfConsumer, {}, [
        ("controller/description", controller_description(a=[1.0]), False, "a has 1 entries"),
        ("controller/description", controller_description(sample_period=0.0), False, "must be discrete"),
        ("controller/description", controller_description(output_names=["x"]), False, "1 output_names for 4"),
        ("controller/description", controller_description(), True, ""),
        ("excitation/design", design(peak=[0.1, 0.2, 0.3]), False, "3 peak values for 1 inputs"),
        ("excitation/design", design(excited_lines=[10, 501]), False, "beyond samples_per_period / 2 = 500"),
        ("excitation/design", design(sample_rate=float("nan")), False, "sample_rate nan"),
        ("excitation/design", design(design_json="{oops"), False, "JSONDecodeError"),
        ("measurement", SampleBlock(first_index=0, sample_period=DT, n_samples=2, channel_names=["y_a_x"],
                                    data=[0.0]), False, "1 values, expected n_samples x channels = 2 x 1"),
        ("measurement", meas_block(2**45), False, "out of range"),
        ("measurement", meas_block(0), True, ""),
    ]),
    "hardware_bridge": (HardwareBridge, {"local_port": 0, "excitation_horizon": 10_000, "protocol_version": 2}, [
        ("excitation", exc_block(20_000), False, "horizon of 10000 samples"),
        ("excitation", exc_block(100, n=80), True, ""),
        ("excitation", exc_block(100, n=80), False, "repeat or overlap"),
        ("excitation", exc_block(179, n=10), False, "repeat or overlap"),
        ("excitation", exc_block(180, n=10), True, ""),
        ("excitation/design", design(rate=20_000.0), False, "designed at 20000 Hz"),
        ("excitation/design", b"\x00\x01\x00\x00", False, "do not decode as ExcitationDesign"),
        ("excitation/design", design(), True, ""),
    ]),
}


class Probe(Node):
    """Publishes the cases to one node's topics and collects its events and status."""

    def __init__(self, context, ns: str, node_name: str):
        super().__init__("probe", namespace=ns, context=context)
        self.fqn = f"{ns}/{node_name}"
        self.events: list[SessionEvent] = []
        self.status: list[SessionStatus] = []
        self.pubs = {}
        self.create_subscription(SessionEvent, "events", self.on_event, KEEP)
        self.create_subscription(SessionStatus, "status", self.on_status, KEEP)

    def on_event(self, e):
        if e.node == self.fqn:
            self.events.append(e)

    def on_status(self, s):
        if s.node == self.fqn:
            self.status.append(s)

    def pub(self, topic):
        if topic not in self.pubs:
            self.pubs[topic] = self.create_publisher(TYPES[topic], topic, QOS[topic])
        return self.pubs[topic]


@pytest.mark.parametrize("name", list(CASES))
def test_every_subscriber_rejects_bad_messages_with_reason_and_counts_them(ros, name):
    cls, params, cases = CASES[name]
    ns = f"/val_{name}"
    node = ros.add(cls(namespace=ns, context=ros.context,
                       parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]))
    probe = ros.add(Probe(ros.context, ns, name))
    topics = sorted({t for t, *_ in cases})
    for t in topics:
        pub = probe.pub(t)
        ros.matched(pub)
    expected_rejects: dict[str, int] = {}
    for topic, msg, accepted, fragment in cases:
        before = dict(received=node.intake.received[topic], accepted=node.intake.accepted[topic],
                      rejected=node.intake.rejected[topic], events=len(probe.events))
        probe.pub(topic).publish(msg)
        # one at a time: a latched topic's queue holds one message
        assert ros.spin_until(lambda: node.intake.received[topic] > before["received"], 10), (topic, fragment)
        assert node.intake.received[topic] == before["received"] + 1
        assert node.intake.accepted[topic] == before["accepted"] + accepted, (topic, fragment, probe.events[-3:])
        assert node.intake.rejected[topic] == before["rejected"] + (not accepted), (topic, fragment)
        if not accepted:
            expected_rejects[topic] = expected_rejects.get(topic, 0) + 1
            assert ros.spin_until(lambda: any(fragment in e.text for e in probe.events[before["events"]:]
                                              if e.code == "rejected_message"), 5), (fragment, [
                e.text for e in probe.events[before["events"]:]])
    assert node.intake.errors == 0
    # the status reports the counters per topic (and the totals)
    def reported():
        for s in reversed(probe.status):
            f = dict(zip(s.keys, s.values))
            if all(json.loads(f.get(f"rejected:{t}", "-1")) == n for t, n in expected_rejects.items()):
                return s
        return None
    assert ros.spin_until(lambda: reported() is not None, 5), [dict(zip(s.keys, s.values)) for s in probe.status[-2:]]
    s = reported()
    assert s.messages_rejected >= sum(expected_rejects.values())
    f = {k: json.loads(v) for k, v in zip(s.keys, s.values)}
    for t in expected_rejects:
        assert f[f"received:{t}"] == f[f"accepted:{t}"] + f[f"rejected:{t}"]
