"""excitation_generator with the real plant_sim and position_controller composed on the test's context."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rclpy
from ambid.excitation import ExcitationDesign, check_headroom, design_multisine
from ambid_nodes.conversions import block_data
from ambid_nodes.excitation_generator import ExcitationGenerator
from ambid_nodes.parameters import ParameterError
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.parameter import Parameter

from ambid_msgs.msg import ExcitationDesign as DesignMsg
from ambid_msgs.msg import SampleBlock, SessionStatus
from ambid_msgs.srv import StartExperiment, StopExperiment
from ambid_nodes import qos
from ambid.channels import RADIAL

MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels
EXCITATION_NAMES = RADIAL.excitations

NS = "/amb"
FS = 10_000.0
INPUTS = ["u_a_x", "u_b_y"]  # excited through r_a_x (column 0) and r_b_y (column 3)
COLS = [EXCITATION_NAMES.index("r_a_x"), EXCITATION_NAMES.index("r_b_y")]
# 2 periods of an N = 1000 orthogonal multisine on 2 inputs: 2 experiments x 2 periods x 1000 = 4000 samples
GEN = {"band_hz": [50.0, 2000.0], "resolution_hz": 10.0, "input_names": INPUTS, "peak_current_a": 0.3,
       "n_periods": 2, "n_transient_periods": 0, "n_realisations": 1, "phases": "random", "seed": 7, "block_size": 500,
       "lookahead": 3000, "start_margin": 1500, "working_current_a": 1.0}
R_COLS = [MEASUREMENT_NAMES.index(n) for n in EXCITATION_NAMES]


def params(d: dict) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in d.items()]


class Rig:
    """plant_sim + position_controller + excitation_generator and a test node recording what they publish."""

    def __init__(self, ros, gen: dict) -> None:
        self.ros = ros
        self.plant = ros.add(PlantSim(namespace=NS, context=ros.context))
        self.gen = ros.add(ExcitationGenerator(namespace=NS, context=ros.context, parameter_overrides=params(gen)))
        self.node = ros.add(rclpy.create_node("probe", namespace=NS, context=ros.context))
        self.blocks: list[tuple[SampleBlock, int]] = []  # excitation block, plant sample index on arrival
        self.meas: dict[int, np.ndarray] = {}
        self.node.create_subscription(SampleBlock, "excitation", self.on_block, qos.BLOCKS)
        self.node.create_subscription(SampleBlock, "measurement", self.on_meas, qos.BLOCKS)
        self.start = self.node.create_client(StartExperiment, "start_experiment")
        self.stop = self.node.create_client(StopExperiment, "stop_experiment")
        # the probe hears the plant and the generator before the controller joins and the loop starts
        ros.matched(self.node, to=self.plant)
        ros.matched(self.node, to=self.gen)
        ros.add(PositionController(namespace=NS, context=ros.context))
        assert ros.spin_until(lambda: self.gen.plant_known and self.start.service_is_ready()
                              and self.stop.service_is_ready(), 60)

    def on_block(self, msg: SampleBlock) -> None:
        self.blocks.append((msg, self.plant.k))

    def on_meas(self, msg: SampleBlock) -> None:
        self.meas[msg.first_index] = block_data(msg, MEASUREMENT_NAMES)

    def call(self, client, request):
        future = client.call_async(request)
        assert self.ros.spin_until(future.done, 10)
        return future.result()

    def measured_until(self, index: int) -> bool:
        return any(first + len(d) >= index for first, d in self.meas.items())

    def r(self, lo: int, hi: int) -> np.ndarray:
        """(hi - lo, 4) excitation r the plant applied at samples [lo, hi)."""
        firsts = sorted(self.meas)
        assert all(a + len(self.meas[a]) == b for a, b in zip(firsts, firsts[1:])), "measurement gap"
        first = firsts[0]
        assert first <= lo and hi <= firsts[-1] + len(self.meas[firsts[-1]])
        data = np.concatenate([self.meas[k] for k in firsts])
        return data[lo - first:hi - first][:, R_COLS]

    def latched_design(self, name: str) -> list[DesignMsg]:
        got: list[DesignMsg] = []
        late = self.ros.add(rclpy.create_node(name, namespace=NS, context=self.ros.context))
        late.create_subscription(DesignMsg, "excitation/design", got.append, qos.LATCHED)
        assert self.ros.spin_until(lambda: got, 10)
        return got


def test_experiment_streams_blocks_the_plant_applies_at_their_index(ros):
    rig = Rig(ros, GEN)
    expected = design_multisine((50.0, 2000.0), 10.0, FS, INPUTS, 0.3, n_periods=2, n_transient_periods=0, seed=7)
    assert expected.total_samples == 4000

    # too much excitation for 3 A with 1 A working current: refused with check_headroom's words
    big = design_multisine((50.0, 2000.0), 10.0, FS, INPUTS, 2.5, n_periods=2, n_transient_periods=0)
    with pytest.raises(ValueError) as refusal:
        check_headroom(big, 3.0, 1.0)
    resp = rig.call(rig.start, StartExperiment.Request(design_json=json.dumps(big.to_dict())))
    assert not resp.accepted and resp.message == str(refusal.value)
    # a design at another sample rate is refused too
    slow = design_multisine((50.0, 2000.0), 10.0, 5000.0, INPUTS, 0.3, n_periods=2, n_transient_periods=0)
    resp = rig.call(rig.start, StartExperiment.Request(design_json=json.dumps(slow.to_dict())))
    assert not resp.accepted and "5000 Hz differs from the plant's 10000 Hz" in resp.message

    resp = rig.call(rig.start, StartExperiment.Request())  # the design of the parameters, next safe start
    assert resp.accepted, resp.message
    start, total = resp.start_index, resp.total_samples
    assert total == 4000 and start >= GEN["start_margin"]
    second = rig.call(rig.start, StartExperiment.Request())
    assert not second.accepted and resp.experiment_id in second.message and "running" in second.message

    assert ros.spin_until(lambda: rig.measured_until(start + total + 200), 30)

    # a subscriber created after the design was published still gets it, complete
    (msg,) = rig.latched_design("late")
    assert (msg.experiment_id, msg.start_index, msg.total_samples) == (resp.experiment_id, start, total)
    assert ExcitationDesign.from_dict(json.loads(msg.design_json)) == expected
    assert list(msg.excited_lines) == expected.excited_lines.tolist() and msg.multi_input == "orthogonal"
    assert msg.measurement_time == pytest.approx(0.4) and list(msg.peak) == pytest.approx([0.3, 0.3])

    # blocks: contiguous from start to start + total, no gap or overlap, the last one final
    firsts = [b.first_index for b, _ in rig.blocks]
    sizes = [b.n_samples for b, _ in rig.blocks]
    assert firsts[0] == start and firsts[-1] + sizes[-1] == start + total
    assert np.array_equal(np.diff(firsts), sizes[:-1])
    assert [b.flags & SampleBlock.FLAG_FINAL for b, _ in rig.blocks] == [0] * (len(firsts) - 1) + [4]
    data = np.concatenate([block_data(b, EXCITATION_NAMES) for b, _ in rig.blocks])
    assert np.array_equal(data[:, COLS], expected.samples(0, total))
    assert not np.any(data[:, [1, 2]])
    # never more than lookahead samples ahead of the plant (4000 samples > 3000: the bound bites)
    ahead = [b.first_index + b.n_samples - k for b, k in rig.blocks]
    assert max(ahead) <= GEN["lookahead"]

    # the plant applied sample offset j at sample index start + j, and nothing outside
    r = rig.r(start - 100, start + total + 100)
    assert np.array_equal(r[100:-100][:, COLS], expected.samples(0, total))
    assert not np.any(r[:100]) and not np.any(r[-100:]) and not np.any(r[:, [1, 2]])

    assert ros.spin_until(lambda: rig.gen.state == SessionStatus.STATE_DONE, 5)
    assert rig.gen.samples_published == total
    assert rig.gen.intake.total_rejected == 0 and rig.plant.intake.total_rejected == 0


def test_stop_cuts_the_design_at_a_block_boundary(ros):
    # 80,000 samples, far longer than the test runs; lookahead 2000 >= block 500 + measurement block 1000
    # a start 20,000 samples ahead: the free-running plant does ~10^5 samples/s, so a margin of 1000 (10 ms)
    # was sometimes passed before the design arrived (seen in CI and in stop 14's review)
    rig = Rig(ros, {**GEN, "n_periods": 40, "lookahead": 2000, "start_margin": 20_000})
    assert rig.call(rig.stop, StopExperiment.Request()).accepted is False  # nothing runs yet
    resp = rig.call(rig.start, StartExperiment.Request())
    assert resp.accepted and resp.total_samples == 80_000
    start = resp.start_index
    assert ros.spin_until(lambda: rig.measured_until(start + 500), 30)
    stop = rig.call(rig.stop, StopExperiment.Request(experiment_id=resp.experiment_id))
    assert stop.accepted, stop.message
    assert ros.spin_until(lambda: rig.measured_until(stop.stop_index + 500), 30)  # the plant goes on
    published = sum(b.n_samples for b, _ in rig.blocks)

    # the stop is the end of the last published block, on a block boundary, before the planned end
    assert stop.stop_index == start + published == rig.blocks[-1][0].first_index + rig.blocks[-1][0].n_samples
    assert (stop.stop_index - start) % GEN["block_size"] == 0 and stop.stop_index < start + 80_000
    (msg,) = rig.latched_design("late")
    assert msg.total_samples == stop.stop_index - start and msg.experiment_id == resp.experiment_id
    design = ExcitationDesign.from_dict(json.loads(msg.design_json))
    r = rig.r(start, stop.stop_index + 500)
    assert np.array_equal(r[:-500][:, COLS], design.samples(0, stop.stop_index - start))
    assert not np.any(r[-500:])  # no excitation after the stop

    assert not rig.call(rig.stop, StopExperiment.Request()).accepted
    again = rig.call(rig.start, StartExperiment.Request())  # a new experiment may follow, not overlapping
    assert again.accepted and again.start_index >= stop.stop_index and again.experiment_id != resp.experiment_id


@pytest.mark.parametrize("override, words", [
    ({"band_hz": [50.0, 6000.0]}, "Nyquist"),
    ({"band_hz": [50.0]}, "band_hz' takes 2 values"),
    ({"resolution_hz": 3.0}, "resolution"),
    ({"kind": "noise", "grid": "odd"}, "grid 'odd' does not apply to a noise design"),
    ({"input_names": ["u_a_x", "u_c_x"]}, "u_c_x"),
    ({"block_size": 2000, "lookahead": 3000}, "lookahead"),
    ({"peak": 1.0}, "unknown parameter"),
])
def test_bad_parameters_are_refused_at_start_up(ros, override, words):
    with pytest.raises(ParameterError, match=words):
        ExcitationGenerator(namespace=NS, context=ros.context, parameter_overrides=params({**GEN, **override}))
