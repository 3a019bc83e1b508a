"""Issue 9, point 8: random and malformed messages to every subscribed topic of every node, and
random datagrams to the bridge: no crash, every one accounted for, the node still works after.

Per node at least 10,000 messages (the per-topic split is in ``PLAN``); for each topic one third
typed messages with malformed contents (wrong sizes, NaN/Inf, random and out-of-range indices,
wrong channel names, empty, a few of several MB), one third random bytes, one third mutated
CDR of a valid message (bytes flipped, truncated, extended, spliced). All are sent as raw CDR
on a raw-capable publisher, paced to the node's queue depth (a latched topic holds one message),
so nothing is dropped by the middleware and the count is exact: for every topic the node's
``received`` equals what an independent raw listener heard (equal to what was sent where only the
fuzzer publishes), and ``received == accepted + rejected`` with no handler error. The bridge also
gets 10,000 datagrams on its UDP port, 7,000 from its configured target's address and 3,000 from a
foreign one, each counted by reason.
"""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
import zlib

import numpy as np
from ambid.control.pid import PidParameters, pid_controller
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.rt_target import Target, TargetConfig
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import make_rig
from ambid.recording import scan_session
from ambid_nodes.conversions import block_msg, float_array, statespace_to_msg
from ambid_nodes.excitation_generator import ExcitationGenerator
from ambid_nodes.frf_consumer import FrfConsumer
from ambid_nodes.hardware_bridge import HardwareBridge
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from ambid_nodes.recorder import Recorder
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile
from rclpy.serialization import deserialize_message, serialize_message

from ambid_msgs.msg import (ControllerDescription, ExcitationDesign, FrfEstimate, PlantDescription, Sample,
                            SampleBlock, SessionEvent, SessionStatus)
from ambid_msgs.srv import StartExperiment
from ambid_nodes import qos
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels
MEASUREMENT_UNITS = ("m",) * 4 + ("A",) * 12

DT = 1e-4
R_NAMES = ("r_a_x", "r_b_x", "r_a_y", "r_b_y")
FAR = 2**39  # index of the templates: far from any sample a session reaches
TYPES = {"excitation": SampleBlock, "measurement": SampleBlock, "excitation/design": ExcitationDesign,
         "plant/description": PlantDescription, "controller/description": ControllerDescription,
         "control_current": Sample, "displacement": Sample, "status": SessionStatus, "events": SessionEvent,
         "frf": FrfEstimate}
QOS = {"excitation": qos.BLOCKS, "measurement": qos.BLOCKS, "excitation/design": qos.LATCHED,
       "plant/description": qos.LATCHED, "controller/description": qos.LATCHED, "control_current": qos.LOOP,
       "displacement": qos.LOOP, "status": qos.STATUS, "events": qos.EVENTS, "frf": qos.LATCHED}
# messages in flight at once: within every subscriber's queue (latched: 1, loop: 100, blocks: 200)
BATCH = {"excitation": 50, "measurement": 50, "control_current": 30, "displacement": 30, "status": 1,
         "events": 1, "frf": 1, "excitation/design": 1, "plant/description": 1, "controller/description": 1}
# messages per node and topic: at least 10,000 per node
PLAN = {
    "plant_sim": {"control_current": 5000, "excitation": 3000, "excitation/design": 2000},
    "position_controller": {"displacement": 7000, "status": 3000},
    "excitation_generator": {"measurement": 7000, "plant/description": 3000},
    "frf_consumer": {"measurement": 5000, "excitation/design": 2500, "controller/description": 2500},
    "hardware_bridge": {"excitation": 6000, "excitation/design": 4000},
    "recorder": {t: 1250 for t in ("measurement", "excitation", "excitation/design", "plant/description",
                                   "controller/description", "frf", "status", "events")},
}
DATAGRAMS_FROM_TARGET, DATAGRAMS_FOREIGN = 7000, 3000


# --- valid templates and malformed messages ------------------------------------------------------------

_TEMPLATES: dict[str, bytes] = {}


def valid(topic: str):
    """A valid message of the topic's type (a fresh copy of a cached template)."""
    if topic not in _TEMPLATES:
        _TEMPLATES[topic] = serialize_message(_valid(topic))
    return deserialize_message(_TEMPLATES[topic], TYPES[topic])


def _valid(topic: str):
    if topic in ("control_current", "displacement"):
        return Sample(index=FAR, values=[1e-6, -2e-6, 0.5, -0.25])
    if topic in ("excitation", "measurement"):
        names = R_NAMES if topic == "excitation" else MEASUREMENT_NAMES
        units = ("A",) * 4 if topic == "excitation" else MEASUREMENT_UNITS
        return block_msg(FAR, DT, names, units, np.full((20, len(names)), 0.01), experiment_id="fuzz")
    if topic == "excitation/design":
        return ExcitationDesign(experiment_id="fuzz", kind="multisine", start_index=FAR, total_samples=1000,
                                sample_rate=1 / DT, samples_per_period=1000, n_periods=1, input_names=["u_a_x"],
                                excited_lines=[10, 20], rms=[0.1], peak=[0.3], crest_factor=[3.0],
                                measurement_time=0.1, design_json='{"format": "x"}')
    if topic == "plant/description":
        rig = make_rig()
        return PlantDescription(name="/fuzz/plant", sample_period=DT, displacement_names=["y_a_x", "y_b_x"],
                                current_names=["u_a_x", "u_b_x"], bias_current=[2.5] * 2, current_limit=[3.0] * 2,
                                backup_clearance=[2.5e-4], analytical_model=statespace_to_msg(analytical_model(rig)))
    if topic == "controller/description":
        return ControllerDescription(name="/fuzz/ctrl", kind="pid",
                                     model=statespace_to_msg(pid_controller(PidParameters(), DT)),
                                     current_limit=[3.0] * 4)
    if topic == "status":
        return SessionStatus(node="/fuzz/node", state=1, sample_index=FAR, keys=["a"], values=["1"])
    if topic == "events":
        return SessionEvent(node="/fuzz/node", code="fuzz", text="fuzz")
    return FrfEstimate(experiment_id="fuzz", output_names=["y"], input_names=["u"], frequency=[1.0], real=[1.0],
                       imag=[0.0])


class Fuzzer:
    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def floats(self, n: int) -> np.ndarray:
        x = self.rng.standard_normal(n) * 10.0 ** self.rng.integers(-9, 3)
        if n and self.rng.random() < 0.5:
            x[self.rng.integers(0, n)] = self.rng.choice([np.nan, np.inf, -np.inf, 1e308])
        return x

    def index(self, near: int) -> int:
        r = self.rng.random()
        if r < 0.4:
            return int(self.rng.integers(0, 2**63, dtype=np.uint64)) * 2 + int(self.rng.integers(0, 2))
        if r < 0.6:
            return int(self.rng.integers(2**40, 2**41))
        return int(self.rng.integers(0, max(near, 1)))  # in the past of the running loop

    def names(self, good) -> list[str]:
        r = self.rng.random()
        if r < 0.3:
            return []
        if r < 0.6:
            return [f"ch{self.rng.integers(0, 99)}" for _ in range(int(self.rng.integers(1, 20)))]
        out = list(good)
        out[int(self.rng.integers(0, len(out)))] = "x"
        return out

    def typed(self, topic: str, near: int, huge: bool):
        rng = self.rng
        if topic in ("control_current", "displacement"):
            n = 200_000 if huge else int(rng.choice([0, 1, 3, 4, 4, 4, 5, 64]))
            values = self.floats(n)
            if n == 4 and np.isfinite(values).all():
                values[0] = np.nan  # a 4-channel sample must be broken somewhere
            return Sample(index=self.index(near), values=values.tolist())
        if topic in ("excitation", "measurement"):
            good = R_NAMES if topic == "excitation" else MEASUREMENT_NAMES
            n = 60_000 if huge else int(rng.integers(0, 300))
            names = list(good) if rng.random() < 0.5 else self.names(good)
            m = SampleBlock(first_index=self.index(near), n_samples=n + int(rng.choice([0, 0, 1, -1])) % 2**32,
                            sample_period=float(rng.choice([DT, 0.0, -DT, np.nan, 2 * DT, 1e300])),
                            channel_names=names, channel_units=["A"] * int(rng.integers(0, 20)))
            m.data = float_array(self.floats(max(n * len(names) + int(rng.choice([0, 0, 1, -1])), 0)))
            m.sample_flags = rng.integers(0, 256, int(rng.choice([0, n, n + 3])), dtype=np.uint8)
            return m
        if topic == "excitation/design":
            n_u = int(rng.integers(0, 4))
            return ExcitationDesign(
                experiment_id=str(rng.choice(["", "fuzz", "e" * 1000, "exp-0001"])), kind="multisine",
                start_index=self.index(near), total_samples=int(rng.integers(0, 2**63, dtype=np.uint64)),
                sample_rate=float(rng.choice([1 / DT, 0.0, np.nan, -1.0, 1e9, 5000.0])),
                samples_per_period=int(rng.integers(0, 10**6)), n_periods=int(rng.integers(0, 2**32)),
                input_names=[str(rng.choice(["u_a_x", "", "u_a_x", "zz"])) for _ in range(n_u)],
                excited_lines=rng.integers(0, 2**32, 200_000 if huge else 5).tolist(),
                rms=self.floats(int(rng.integers(0, 4))).tolist(), peak=self.floats(n_u + 1).tolist(),
                measurement_time=float(rng.choice([0.1, np.nan, np.inf])),
                design_json=str(rng.choice(["", "{", '{"format": 1}', "[]", "null", '{"phasors": 3}'])))
        if topic == "plant/description":
            k = int(rng.integers(0, 6))
            m = valid(topic)
            m.sample_period = float(rng.choice([DT, 0.0, np.nan, -1.0, np.inf]))
            m.current_names = [f"u{i}" for i in range(k)]
            m.current_limit = self.floats(int(rng.integers(0, 6))).tolist()
            m.analytical_model.a = self.floats(200_000 if huge else int(rng.integers(0, 40))).tolist()
            return m
        if topic == "controller/description":
            m = valid(topic)
            m.model.n_states = int(rng.integers(0, 2**32))
            m.model.sample_period = float(rng.choice([DT, 0.0, np.nan]))
            m.model.b = self.floats(200_000 if huge else int(rng.integers(0, 40))).tolist()
            return m
        if topic == "status":
            return SessionStatus(node=f"fuzz{rng.integers(0, 9)}", state=int(rng.integers(0, 256)),
                                 sample_index=self.index(near), progress=float(self.floats(1)[0]),
                                 keys=["k"] * int(rng.integers(0, 5)), values=["v" * (10**6 if huge else 3)])
        if topic == "events":
            return SessionEvent(severity=int(rng.integers(0, 256)), node="fuzz", code="x" * int(rng.integers(0, 50)),
                                text="t" * (10**6 if huge else 5))
        return FrfEstimate(experiment_id="fuzz", output_names=self.names(["y"]), frequency=self.floats(5).tolist(),
                           real=self.floats(200_000 if huge else 7).tolist())

    def random_bytes(self) -> bytes:
        n = int(self.rng.integers(0, 400)) if self.rng.random() < 0.98 else int(self.rng.integers(400, 70_000))
        b = self.rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        if n >= 4 and self.rng.random() < 0.5:
            b = b"\x00\x01\x00\x00" + b[4:]  # a valid encapsulation header: the parser goes further
        return b

    def mutate(self, template: bytes) -> bytes:
        b = bytearray(template)
        r = self.rng.random()
        if r < 0.4:
            for _ in range(int(self.rng.integers(1, 9))):
                b[int(self.rng.integers(4, len(b)))] = int(self.rng.integers(0, 256))
        elif r < 0.6:
            b = b[:int(self.rng.integers(0, len(b)))]
        elif r < 0.8:
            b += self.rng.integers(0, 256, int(self.rng.integers(1, 64)), dtype=np.uint8).tobytes()
        else:
            i, j = sorted(self.rng.integers(4, len(b), 2))
            b = b[:i] + b[j:] + b[i:j]
            # a sequence length field rewritten to something huge
            if len(b) > 12:
                k = int(self.rng.integers(4, len(b) - 4))
                b[k:k + 4] = struct.pack("<I", int(self.rng.integers(2**20, 2**32)))
        return bytes(b)

    def payloads(self, topic: str, n: int, near: int) -> list[bytes]:
        template = serialize_message(valid(topic))
        kinds = self.rng.permutation(np.arange(n) % 3)
        huge = set(self.rng.choice(np.flatnonzero(kinds == 0), 3, replace=False).tolist())
        out = []
        for i, kind in enumerate(kinds):
            if kind == 0:
                out.append(serialize_message(self.typed(topic, near, i in huge)))
            elif kind == 1:
                out.append(self.random_bytes())
            else:
                out.append(self.mutate(template))
        return out


# --- publishing and counting -----------------------------------------------------------------------------

class FuzzNode(Node):
    """Publishes raw bytes on a namespace's topics and counts, raw, everything that crosses them."""

    def __init__(self, context, ns: str, topics):
        super().__init__("fuzzer", namespace=ns, context=context)
        self.pubs, self.heard = {}, {t: 0 for t in topics}
        for t in topics:
            self.pubs[t] = self.create_publisher(TYPES[t], t, QOS[t])
            listen = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=20_000, reliability=QOS[t].reliability,
                                durability=DurabilityPolicy.VOLATILE)
            self.create_subscription(TYPES[t], t, lambda _b, t=t: self.heard.__setitem__(t, self.heard[t] + 1),
                                     listen, raw=True)


def wait(ros, predicate, timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, what
        ros.executor.spin_once(timeout_sec=0.01)


def fuzz_topics(ros, node, fuzzer: FuzzNode, plan: dict, near=lambda: 0, counted=None, seed=1,
                batch: int | None = None) -> dict:
    """Send the plan's messages, paced to the node's queues; returns {topic: sent}."""
    counted = counted or (lambda t: node.intake.received[t])
    f = Fuzzer(seed)
    sent = {}
    for topic, n in plan.items():
        pub = fuzzer.pubs[topic]
        wait(ros, lambda: pub.get_subscription_count() >= 2, 60, f"{topic}: subscribers")
        t0 = time.perf_counter()
        payloads = f.payloads(topic, n, near())
        t1 = time.perf_counter()
        base = counted(topic)
        step = batch or BATCH[topic]
        for i in range(0, n, step):
            for p in payloads[i:i + step]:
                pub.publish(p)
            target = base + min(i + step, n)
            wait(ros, lambda: counted(topic) >= target, 60, f"{topic}: {counted(topic) - base} of {target - base}")
        sent[topic] = n
        print(f"fuzz {topic}: {n} messages made in {t1 - t0:.2f} s, delivered in {time.perf_counter() - t1:.2f} s")
    return sent


def check_accounting(ros, node, fuzzer, sent, legit_free=True) -> None:
    intake = node.intake
    for topic, n in sent.items():
        wait(ros, lambda: fuzzer.heard[topic] >= n, 20, f"listener of {topic}")
        # the node takes them at its pace (on a busy machine after the listener): waited for, not a pause
        wait(ros, lambda: intake.received[topic] == fuzzer.heard[topic], 20,
             f"{topic}: {intake.received[topic]} taken by the node, {fuzzer.heard[topic]} heard by the listener")
        if legit_free:
            assert intake.received[topic] == n, topic
        assert intake.received[topic] == intake.accepted[topic] + intake.rejected[topic], topic
    assert intake.errors == 0
    print(f"{node.get_name()}: " + ", ".join(f"{t} {n} sent, {intake.rejected[t]} rejected, {intake.accepted[t]} "
                                              "accepted" for t, n in sent.items()))


# --- the nodes --------------------------------------------------------------------------------------------

def test_fuzz_plant_and_controller_while_the_loop_runs(ros):
    ns = "/fz_loop"
    topics = list(PLAN["plant_sim"]) + list(PLAN["position_controller"])
    fuzzer = ros.add(FuzzNode(ros.context, ns, topics))
    plant = ros.add(PlantSim(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter("controller_timeout_s", value=30.0)]))
    ctrl = ros.add(PositionController(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter("plant_timeout_s", value=30.0)]))
    wait(ros, lambda: plant.k >= 6000, 60, "the loop levitates")  # lifted off and settled
    near = lambda: max(plant.k - 200, 1)  # noqa: E731 - indices of samples already passed
    # on the loop topics the fuzz rides along the lock-step traffic: all of it is refused, nothing else is
    loop_rejected = lambda t: (plant if t == "control_current" else ctrl).intake.rejected[t]  # noqa: E731
    sent = fuzz_topics(ros, plant, fuzzer, {"control_current": PLAN["plant_sim"]["control_current"]}, near,
                       loop_rejected, seed=1)
    sent_c = fuzz_topics(ros, ctrl, fuzzer, {"displacement": PLAN["position_controller"]["displacement"]}, near,
                         loop_rejected, seed=2)
    # excitation at passed samples only (index 0 + up to 300 samples): none may reach the running loop
    sent |= fuzz_topics(ros, plant, fuzzer, {t: PLAN["plant_sim"][t] for t in ("excitation", "excitation/design")},
                        lambda: 1, seed=3)
    sent_c |= fuzz_topics(ros, ctrl, fuzzer, {"status": PLAN["position_controller"]["status"]}, near, seed=4)
    k_after = plant.k
    wait(ros, lambda: plant.k >= k_after + 3000, 60, "the loop goes on after the fuzz")
    f = plant.figures()
    assert plant.state == SessionStatus.STATE_RUNNING and ctrl.state == SessionStatus.STATE_RUNNING
    assert f["levitated"] and f["contact_samples_after_settling"] == 0, f
    # the loop topics: every fuzz message refused, every lock-step message accepted
    assert plant.intake.rejected["control_current"] == sent["control_current"]
    assert ctrl.intake.rejected["displacement"] == sent_c["displacement"]
    # (a loaded machine makes the plant ask again now and then: the answers that then come twice are accepted)
    assert abs(plant.intake.accepted["control_current"] - plant.duplicate_answers - plant.k) <= 1
    assert abs(ctrl.intake.accepted["displacement"] - ctrl.answers_repeated - plant.k) <= 1
    check_accounting(ros, plant, fuzzer, {t: sent[t] for t in ("excitation", "excitation/design")})
    check_accounting(ros, ctrl, fuzzer, {"status": sent_c["status"]}, legit_free=False)
    for node, topic in ((plant, "control_current"), (ctrl, "displacement")):
        i = node.intake
        assert i.received[topic] == i.accepted[topic] + i.rejected[topic]
    assert plant.intake.errors == 0 and ctrl.intake.errors == 0
    print(f"loop: control_current {sent['control_current']} and displacement {sent_c['displacement']} fuzzed, "
          f"all refused; the loop ran to sample {plant.k}, levitated")


def test_fuzz_excitation_generator(ros):
    ns = "/fz_gen"
    fuzzer = ros.add(FuzzNode(ros.context, ns, PLAN["excitation_generator"]))
    gen = ros.add(ExcitationGenerator(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in dict(input_names=["u_a_x"], band_hz=[50.0, 1000.0], resolution_hz=10.0,
                                               n_periods=1, n_transient_periods=0, n_realisations=1, phases="random",
                                               block_size=500, lookahead=2000, start_margin=1000).items()]))
    sent = fuzz_topics(ros, gen, fuzzer, PLAN["excitation_generator"], seed=5)
    check_accounting(ros, gen, fuzzer, sent)
    # still works: a real plant description and progress, then an experiment streams from where it says
    desc = serialize_message(_plant_description())
    n = gen.intake.accepted["plant/description"]
    fuzzer.pubs["plant/description"].publish(desc)
    wait(ros, lambda: gen.intake.accepted["plant/description"] == n + 1 and gen.plant_known, 10, "description")
    progress = gen.progress
    fuzzer.pubs["measurement"].publish(serialize_message(block_msg(progress, DT, MEASUREMENT_NAMES, MEASUREMENT_UNITS,
                                                                   np.zeros((100, 16)))))
    wait(ros, lambda: gen.progress == progress + 100, 10, "progress")
    client = fuzzer.create_client(StartExperiment, "start_experiment")
    wait(ros, client.service_is_ready, 10, "service")
    future = client.call_async(StartExperiment.Request())
    wait(ros, future.done, 10, "start")
    assert future.result().accepted and future.result().start_index == progress + 100 + 1000, future.result()
    assert gen.blocks_published >= 1


def _plant_description() -> PlantDescription:
    rig = make_rig()
    return PlantDescription(name="/fz/plant_sim", source="sim", rig_name=rig.name, sample_period=rig.dt,
                            displacement_names=["y_a_x", "y_b_x", "y_a_y", "y_b_y"],
                            current_names=["u_a_x", "u_b_x", "u_a_y", "u_b_y"], bias_current=[rig.bias_current_a] * 4,
                            current_limit=[rig.current_limit_a] * 4, backup_clearance=[rig.backup_clearance_m] * 2,
                            analytical_model=statespace_to_msg(analytical_model(rig)))


def _frf_design():
    from ambid.excitation import design_multisine
    return design_multisine((100.0, 1000.0), 100.0, 1 / DT, ("u_a_x",), 0.5, n_periods=2, n_realisations=1,
                            n_transient_periods=0, seed=4)


def test_fuzz_frf_consumer(ros):
    ns = "/fz_frf"
    fuzzer = ros.add(FuzzNode(ros.context, ns, PLAN["frf_consumer"]))
    consumer = ros.add(FrfConsumer(namespace=ns, context=ros.context))
    sent = fuzz_topics(ros, consumer, fuzzer, PLAN["frf_consumer"], seed=6)
    check_accounting(ros, consumer, fuzzer, sent)
    # still works: an experiment by hand, y = A u, gives G = A
    d = _frf_design()
    start = 2**30  # after any index the fuzz may have moved the consumer to
    fuzzer.pubs["excitation/design"].publish(serialize_message(ExcitationDesign(
        experiment_id="after-fuzz", kind=d.kind, start_index=start, total_samples=d.total_samples,
        sample_rate=d.fs_hz, samples_per_period=d.n_per_period, n_periods=d.n_periods, n_realisations=1,
        n_experiments=1, input_names=list(d.input_names), design_json=json.dumps(d.to_dict()))))
    wait(ros, lambda: consumer.experiment_id == "after-fuzz", 10, "design accepted")
    a = np.array([[2e-5], [-1e-5], [3e-6], [1e-6]])
    r = np.zeros((d.total_samples, 4))
    r[:, :1] = d.samples(0, d.total_samples)
    x = np.hstack([r[:, :1] @ a.T, r, np.zeros_like(r), r])
    for k in range(0, d.total_samples, 100):
        fuzzer.pubs["measurement"].publish(serialize_message(block_msg(start + k, DT, MEASUREMENT_NAMES,
                                                                       MEASUREMENT_UNITS, x[k:k + 100])))
    wait(ros, lambda: "after-fuzz" in consumer.results, 20, "estimate")
    g = consumer.results["after-fuzz"].frf
    np.testing.assert_allclose(g, np.broadcast_to(a, g.shape), rtol=1e-9)
    assert consumer.intake.errors == 0


def test_fuzz_hardware_bridge_topics_and_datagrams(ros, tmp_path):
    from ambid.hardware.link_key import write_key_file

    ns = "/fz_bridge"
    key = write_key_file(tmp_path / "rig.key")
    fuzzer = ros.add(FuzzNode(ros.context, ns, PLAN["hardware_bridge"]))
    target_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    target_sock.bind(("127.0.0.1", 0))  # the fuzzer speaks from the configured target's own address
    foreign = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    foreign.bind(("127.0.0.1", 0))
    tport = target_sock.getsockname()[1]
    bridge = ros.add(HardwareBridge(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter("target_port", value=tport), Parameter("local_port", value=0),
        Parameter("excitation_horizon", value=100_000), Parameter("key_file", value=str(tmp_path / "rig.key"))]))
    sent = fuzz_topics(ros, bridge, fuzzer, PLAN["hardware_bridge"], seed=7)
    check_accounting(ros, bridge, fuzzer, sent)

    rng = np.random.default_rng(8)
    # sealed with the rig's key (version 3), in a session the bridge never agreed (no target answered its HELLO)
    session = bytes(range(8))
    templates = [bp.pack_datagram(m, seal=bp.Seal(key, sender, session)) for m, sender in (
        (bp.Heartbeat(1, bp.TargetState.RUNNING, sample_rate_hz=10_000, sample_index=5, sent_end=5),
         bp.Sender.TARGET),
        (bp.Ack(2, 1, 1, bp.AckResult.OK, bp.TargetState.RUNNING, 5), bp.Sender.TARGET),
        (bp.Measurement(3, FAR, np.zeros((10, 16)), np.zeros(10, np.uint8)), bp.Sender.TARGET),
        (bp.Excitation(4, FAR, np.zeros((10, 4))), bp.Sender.BRIDGE),
        (bp.Command(5, 1, bp.CommandCode.START), bp.Sender.BRIDGE),
        (bp.Welcome(6, bytes(16), bytes(16)), bp.Sender.TARGET))]

    def recrc(b: bytearray) -> bytes:
        b[-4:] = struct.pack("<I", zlib.crc32(bytes(b[:-4])))
        return bytes(b)

    def reseal(b: bytearray) -> bytes:
        b[-20:-4] = key.tag(bytes(b[:-20]))
        return recrc(b)

    def datagram(i: int) -> bytes:
        kind = i % 7
        if kind == 6:  # forged: a changed field under the old tag, or a guessed tag; CRC right
            b = bytearray(templates[int(rng.integers(0, len(templates)))])
            b[int(rng.integers(4, len(b) - 20))] ^= int(rng.integers(1, 256)) if rng.random() < 0.5 else 0
            b[-20:-4] = rng.bytes(16) if rng.random() < 0.5 else b[-20:-4]
            return recrc(b)
        if kind == 0:
            return rng.integers(0, 256, int(rng.integers(0, 1600)), dtype=np.uint8).tobytes()
        b = bytearray(templates[int(rng.integers(0, len(templates)))])
        if kind == 1:  # corrupted in transit
            for _ in range(int(rng.integers(1, 5))):
                b[int(rng.integers(0, len(b)))] ^= int(rng.integers(1, 256))
            return bytes(b)
        if kind == 2:  # truncated or oversized
            return bytes(b[:int(rng.integers(0, len(b)))]) if rng.random() < 0.5 else bytes(b) + bytes(1500)
        if kind == 3:  # another protocol version, CRC right
            b[4] = int(rng.choice([0, 1, 2, 255]))   # 1, 2: the other versions this build knows, not the one spoken
            return recrc(b)
        if kind == 4:  # a kind only the bridge sends (sealed by the key), or an unknown one, CRC right
            if rng.random() < 0.7:
                return templates[int(rng.choice([3, 4]))]
            b[5] = int(rng.integers(8, 256))
            return reseal(b)
        # sealed, CRC right, impossible content: a heartbeat state or ack result out of range
        hb = bytearray(templates[0] if rng.random() < 0.6 else templates[1])
        offset = bp.HEADER_V3.size + (0 if hb[5] == bp.Kind.HEARTBEAT else 6)
        hb[offset] = int(rng.integers(4, 256))
        return reseal(hb)

    def bridge_count():
        return bridge.c["datagrams"] + sum(bridge.malformed.values()) + bridge.c["link_duplicates"]

    def send_all(sock, n, counter, start):
        for i in range(0, n, 200):
            for j in range(i, min(i + 200, n)):
                sock.sendto(datagram(j), bridge.local_address)
            wait(ros, lambda: counter() >= start + min(i + 200, n), 30, "datagrams processed")

    send_all(target_sock, DATAGRAMS_FROM_TARGET, bridge_count, 0)
    send_all(foreign, DATAGRAMS_FOREIGN, lambda: bridge.c["foreign"], 0)
    target_sock.close()
    foreign.close()
    f = bridge.figures()
    assert bridge_count() == DATAGRAMS_FROM_TARGET, (dict(bridge.c), dict(bridge.malformed))
    assert bridge.c["foreign"] == DATAGRAMS_FOREIGN
    assert "handler_error" not in bridge.malformed and not bridge.connected
    print(f"hardware_bridge datagrams: {DATAGRAMS_FROM_TARGET} from the target's address: accepted "
          f"{bridge.c['datagrams']}, refused {dict(bridge.malformed)}; {DATAGRAMS_FOREIGN} foreign: "
          f"{f['datagrams_foreign']} dropped")
    # still works: a real target on that address runs a session to its end, nothing lost
    assert bridge.malformed["auth"] > 0 and bridge.malformed["session"] > 0 and bridge.malformed["direction"] > 0
    tg = Target(TargetConfig(bind=f"127.0.0.1:{tport}", bridge=f"127.0.0.1:{bridge.local_address[1]}", seed=1,
                             pace=1.0, samples=1500, linger=0.3, key_file=str(tmp_path / "rig.key")))
    result = {}
    th = threading.Thread(target=lambda: result.update(tg.run()), daemon=True)
    th.start()
    try:
        wait(ros, bridge.finished.done, 60, "the session after the fuzz")
    finally:
        tg.stop.set()
        th.join(5)
    s = bridge.finished.result()
    assert s["state"] == "done" and s["missing_samples"] == 0 and s["samples_published"] == 1500, s


def test_fuzz_recorder(ros, tmp_path):
    ns = "/fz_rec"
    path = tmp_path / "fuzz.mcap"
    fuzzer = ros.add(FuzzNode(ros.context, ns, PLAN["recorder"]))
    rec = ros.add(Recorder(namespace=ns, context=ros.context, parameter_overrides=[
        Parameter("output", value=str(path)), Parameter("discovery_period_s", value=0.05),
        Parameter("status_period_s", value=3600.0)]))
    wait(ros, lambda: all(f"{ns}/{t}" in rec.subs for t in PLAN["recorder"]), 20, "recorder subscribed")
    counted = lambda t: rec.counts.get(f"{ns}/{t}", 0)  # noqa: E731 - messages written per topic
    # the recorder's queues hold queue_depth (1000) messages on every topic, latched ones too
    sent = fuzz_topics(ros, None, fuzzer, PLAN["recorder"], counted=counted, seed=9, batch=200)
    for t, n in sent.items():
        wait(ros, lambda: fuzzer.heard[t] >= n, 20, t)
    # everything heard on a topic is in the file: what the fuzzer sent, and on status/events the
    # recorder's own messages (it reports unreadable descriptions there); written at the recorder's pace
    for t, n in sent.items():
        wait(ros, lambda: counted(t) == fuzzer.heard[t], 20, f"{t}: {counted(t)} written, {fuzzer.heard[t]} heard")
        if t not in ("status", "events"):
            assert counted(t) == n, t
    assert rec.received == sum(rec.counts.values()) + rec.rejected and rec.rejected == 0
    summary = rec.close()
    assert summary["state"] == "done"
    scan = scan_session(path)
    assert scan.complete
    for t in sent:
        assert scan.topic_message_counts[f"{ns}/{t}"] == counted(t), t
    print(f"recorder: {sum(sent.values())} fuzzed over {len(sent)} topics, all {summary['messages']} messages "
          "in a complete file")
