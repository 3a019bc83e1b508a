"""frf_consumer: live FRF from the measurement stream, its events, and the same result offline."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rclpy
from ambid.excitation import design_multisine
from ambid.frf.offline import frf_from_session
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.recording import SessionWriter
from ambid_nodes.conversions import block_msg
from ambid_nodes.excitation_generator import ExcitationGenerator
from ambid_nodes.frf_consumer import FrfConsumer
from ambid_nodes.parameters import ParameterError
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ambid_msgs.msg import ExcitationDesign as DesignMsg
from ambid_msgs.msg import FrfEstimate, SampleBlock, SessionEvent, SessionStatus
from ambid_msgs.srv import StartExperiment
from ambid_nodes import qos
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels
MEASUREMENT_UNITS = ("m",) * 4 + ("A",) * 12

NS = "/amb"
FS = 10_000.0
# the listener keeps every message (the nodes' latched profiles keep only the last)
KEEP_ALL = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Listener:
    """A test node collecting the consumer's outputs (and, raw, what a recorder would)."""

    def __init__(self, ros, raw_topics=()):
        self.node = ros.add(rclpy.create_node("listener", namespace=NS, context=ros.context))
        self.frf: list[FrfEstimate] = []
        self.status: list[SessionStatus] = []
        self.events: list[SessionEvent] = []
        self.raw: list[tuple[str, bytes]] = []
        self.node.create_subscription(FrfEstimate, "frf", self.frf.append, KEEP_ALL)
        self.node.create_subscription(SessionStatus, "status", self.on_status, KEEP_ALL)
        self.node.create_subscription(SessionEvent, "events", self.on_event, KEEP_ALL)
        for topic, msg_type, profile in raw_topics:
            self.node.create_subscription(msg_type, topic, lambda b, t=topic: self.raw.append((t, b)), profile,
                                          raw=True)

    def on_status(self, msg):
        if msg.node.endswith("frf_consumer"):
            self.status.append(msg)

    def on_event(self, msg):
        if msg.node.endswith("frf_consumer"):
            self.events.append(msg)

    def codes(self):
        return [e.code for e in self.events]


def _consumer(ros, **params):
    return ros.add(FrfConsumer(namespace=NS, context=ros.context,
                               parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]))


def _design_msg(design, exp_id, start):
    return DesignMsg(experiment_id=exp_id, kind=design.kind, start_index=start, total_samples=design.total_samples,
                     sample_rate=design.fs_hz, samples_per_period=design.n_per_period, n_periods=design.n_periods,
                     n_transient_periods=design.n_transient_periods, n_realisations=design.n_realisations,
                     n_experiments=design.n_experiments, input_names=list(design.input_names),
                     design_json=json.dumps(design.to_dict()))


def test_consumer_fed_by_hand_gaps_and_bad_messages(ros):
    """y = A u exactly: the indirect estimate is A; a lost block and bad messages are reported."""
    d = design_multisine((100.0, 1000.0), 100.0, FS, ("u_a_x", "u_b_x"), 0.5, n_periods=2, n_realisations=2,
                         n_transient_periods=1, seed=4)
    start, n = 500, 2000
    rng = np.random.default_rng(0)
    a = rng.standard_normal((4, 2)) * 1e-5                    # m/A
    r = np.zeros((n, 4))
    r[start:start + d.total_samples, :2] = d.samples(0, d.total_samples)
    u = r + 1e-3 * rng.standard_normal((n, 4))               # fed-back noise on every current
    y = u[:, :2] @ a.T
    x = np.hstack([y, u, u - r, r])
    consumer = _consumer(ros)
    out = Listener(ros)
    pub_design = out.node.create_publisher(DesignMsg, "excitation/design", qos.LATCHED)
    pub_block = out.node.create_publisher(SampleBlock, "measurement", qos.BLOCKS)
    ros.matched(pub_block, pub_design)
    ros.matched(out.node, to=consumer)  # the listener hears every status and estimate from the first
    pub_design.publish(_design_msg(d, "hand-1", start))
    # no plant description here: the design waits for the first block to say the displacement channels
    assert ros.spin_until(lambda: consumer.stream is not None or consumer.pending_design is not None, 10)
    pub_design.publish(DesignMsg(experiment_id="broken", design_json="{not json"))
    bad = block_msg(0, 1 / FS, MEASUREMENT_NAMES, MEASUREMENT_UNITS, x[:100])
    bad.n_samples = 99                                        # data no longer matches
    pub_block.publish(bad)
    for k in range(0, n, 100):
        if k != 900:                                          # lost: steady-state period 0 of (m=0, e=1)
            pub_block.publish(block_msg(k, 1 / FS, MEASUREMENT_NAMES, MEASUREMENT_UNITS, x[k:k + 100]))
    assert ros.spin_until(lambda: "hand-1" in consumer.results and out.status
                          and out.status[-1].state == SessionStatus.STATE_DONE, 20)
    assert ros.spin_until(lambda: len(out.frf) >= 2, 5)      # realisation 0, then the end
    final = out.frf[-1]
    nl = d.excited_lines.size
    np.testing.assert_array_equal(final.frequency, d.freq_hz)
    assert (final.output_names, final.input_names) == (["y_a_x", "y_b_x", "y_a_y", "y_b_y"], ["u_a_x", "u_b_x"])
    g = (np.asarray(final.real) + 1j * np.asarray(final.imag)).reshape(nl, 4, 2)
    np.testing.assert_allclose(g, np.broadcast_to(a, g.shape), rtol=1e-9)
    assert len(final.variance_noise) == len(final.variance_total) == nl * 8 and len(final.coherence) == nl * 4
    assert (final.periods_used, final.realisations_used, final.experiments_used) == (3, 2, 2)
    assert (out.frf[0].periods_used, out.frf[0].realisations_used) == (1, 1)
    assert out.codes().count("sample_gap") == 1 and out.codes().count("rejected_message") == 2
    gap = next(e for e in out.events if e.code == "sample_gap")
    assert "[900, 1000)" in gap.text and "(0, 1, 0)" in gap.text
    last = out.status[-1]
    figures = dict(zip(last.keys, (json.loads(v) for v in last.values)))
    assert last.messages_rejected == 2 and figures["gaps"] == 1 and figures["iso_zone"] == "A"
    assert figures["missing_samples"] == 100 and "zone A" in last.text
    running = [s.text for s in out.status if s.state == SessionStatus.STATE_RUNNING]
    assert any("realisation 2/2, periods" in t and "time left" in t for t in running)


def test_bad_parameters_are_refused(ros):
    with pytest.raises(ParameterError, match="estimator 'welch'"):
        _consumer(ros, estimator="welch")
    with pytest.raises(ParameterError, match="pair"):
        _consumer(ros, inputs=["u_a_x", "u_b_x"])


def test_live_estimate_on_the_simulated_rig_matches_the_rig_and_the_offline_result(ros, tmp_path):
    """plant + controller + excitation generator + consumer, composed: a short orthogonal multisine."""
    rig = make_rig()
    d = design_multisine((20.0, 600.0), 20.0, rig.values["sample_rate_hz"], ("u_a_x", "u_b_x"), 1.0, n_periods=2,
                         n_transient_periods=2, seed=1)
    plant = ros.add(PlantSim(namespace=NS, context=ros.context))
    # the rotor lifts off the retainer and settles within ~5000 samples; 20,000 ahead of the plant so that the
    # design reaches it first (the free-running plant does ~10^5 samples/s: 5000 was passed once under load)
    gen = ros.add(ExcitationGenerator(namespace=NS, context=ros.context,
                                      parameter_overrides=[Parameter("start_margin", value=20_000)]))
    consumer = _consumer(ros)
    out = Listener(ros, raw_topics=[("measurement", SampleBlock, qos.BLOCKS),
                                    ("excitation/design", DesignMsg, qos.LATCHED)])
    for node in (plant, gen, consumer):  # the listener hears everything before the controller starts the loop
        ros.matched(out.node, to=node)
    ros.matched(consumer, to=plant)
    ros.add(PositionController(namespace=NS, context=ros.context))
    client = out.node.create_client(StartExperiment, "start_experiment")
    assert ros.spin_until(lambda: client.service_is_ready() and gen.plant_known, 60)
    future = client.call_async(StartExperiment.Request(design_json=json.dumps(d.to_dict())))
    assert ros.spin_until(future.done, 10) and future.result().accepted, future.result().message
    exp_id = future.result().experiment_id
    assert ros.spin_until(lambda: exp_id in consumer.results, 90)
    assert ros.spin_until(lambda: out.frf and out.frf[-1].experiment_id == exp_id and out.status
                          and out.status[-1].state == SessionStatus.STATE_DONE, 5)
    msg = out.frf[-1]
    nl = d.excited_lines.size
    assert len(msg.frequency) == nl and len(msg.real) == len(msg.imag) == len(msg.variance_noise) == nl * 8
    assert len(msg.variance_total) == 0 and len(msg.coherence) == nl * 4        # M = 1
    g = (np.asarray(msg.real) + 1j * np.asarray(msg.imag)).reshape(nl, 4, 2)
    p_true = true_linear_model(rig, discrete=True).freqresp(d.freq_hz)[:, :, :2]
    err = np.linalg.norm(g - p_true, axis=(1, 2)) / np.linalg.norm(p_true, axis=(1, 2))
    assert np.median(err) < 0.1, err
    # the recording gives the same numbers offline
    path = tmp_path / "session.mcap"
    types = {"measurement": "ambid_msgs/msg/SampleBlock", "excitation/design": "ambid_msgs/msg/ExcitationDesign"}
    with SessionWriter(path, compression="none") as w:
        for topic, type_name in types.items():
            w.add_topic(f"{NS}/{topic}", type_name)
        for i, (topic, data) in enumerate(out.raw):
            w.write(f"{NS}/{topic}", data, log_time_ns=i)
    offline = frf_from_session(path)
    live = consumer.results[exp_id]
    for k in ("freq_hz", "frf", "var_noise", "coherence", "sensitivity", "noise_std", "sensitivity_peak"):
        np.testing.assert_array_equal(getattr(offline, k), getattr(live, k), err_msg=k)
    np.testing.assert_array_equal(offline.frf.real.ravel(), msg.real)
    final = dict(zip(out.status[-1].keys, (json.loads(v) for v in out.status[-1].values)))
    assert final["iso_zone"] in "ABCD" and len(final["odd_distortion_db"]) == 4
    assert final["controller_consistency"] < 0.05, final
    print(f"median |G - P_true| / |P_true| {np.median(err):.3g}, max {err.max():.3g}; {out.status[-1].text}; "
          f"controller consistency {final['controller_consistency']:.2g}")
