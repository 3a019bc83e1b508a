"""Issue 9, point 3: excitation beyond the amplifier limit, published straight to the plant (past the
generator's design-time check), is applied saturated as a real amplifier does, but every such
sample is recorded as commanded and flagged, and reported as a ``clipped`` event."""

from __future__ import annotations

import re

import numpy as np
from ambid_nodes.conversions import block_data, block_msg
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.node import Node
from rclpy.parameter import Parameter

from ambid_msgs.msg import ExcitationDesign, SampleBlock, SessionEvent
from ambid_nodes import qos
from ambid.channels import RADIAL

EXCITATION_NAMES = RADIAL.excitations
MEASUREMENT_NAMES = RADIAL.measurement_names  # the default rig's channels

NS = "/clip"
START, N = 2000, 1000  # excited samples [2000, 3000)


class Rogue(Node):
    """An excitation source without the generator's headroom check."""

    def __init__(self, context):
        super().__init__("rogue", namespace=NS, context=context)
        self.blocks, self.events = [], []
        self.pub_design = self.create_publisher(ExcitationDesign, "excitation/design", qos.LATCHED)
        self.pub_exc = self.create_publisher(SampleBlock, "excitation", qos.BLOCKS)
        self.create_subscription(SampleBlock, "measurement", self.blocks.append, qos.BLOCKS)
        self.create_subscription(SessionEvent, "events", self.events.append, qos.EVENTS)


def test_clipped_samples_are_flagged_recorded_as_commanded_and_reported(ros):
    rogue = ros.add(Rogue(ros.context))
    plant = ros.add(PlantSim(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("sim_seconds", value=0.4)]))
    ros.matched(rogue, to=plant)
    limit = plant.rig.current_limit_a
    dt = plant.dt
    # a 50 Hz sine on r_a_x reaching 1.5 x the amplifier limit on its own
    t = np.arange(N) * dt
    r = np.zeros((N, 4))
    r[:, 0] = 1.5 * limit * np.sin(2 * np.pi * 50.0 * t)
    rogue.pub_design.publish(ExcitationDesign(
        experiment_id="rogue", kind="multisine", start_index=START, total_samples=N, sample_rate=1 / dt,
        samples_per_period=N, n_periods=1, input_names=["u_a_x"], excited_lines=[5], peak=[1.5 * limit],
        rms=[1.5 * limit / 2**0.5], crest_factor=[2**0.5], measurement_time=N * dt, design_json="{}"))
    assert ros.spin_until(lambda: "rogue" in plant.schedule.ranges, 10)
    for first in range(0, N, 250):
        rogue.pub_exc.publish(block_msg(START + first, dt, EXCITATION_NAMES, ("A",) * 4, r[first:first + 250]))
    assert ros.spin_until(lambda: len(plant.schedule.blocks) == 4, 10)
    ros.add(PositionController(namespace=NS, context=ros.context))
    assert ros.spin_until(plant.finished.done, 120)
    assert ros.spin_until(lambda: sum(b.n_samples for b in rogue.blocks) == plant.k, 10)
    data = np.concatenate([block_data(b, MEASUREMENT_NAMES) for b in rogue.blocks])
    flags = np.concatenate([np.asarray(b.sample_flags) for b in rogue.blocks])
    u, ic, rr = data[:, 4:8], data[:, 8:12], data[:, 12:16]
    # the excitation landed at its index, and u is what was commanded: ic + r, never cut to the limit
    np.testing.assert_array_equal(rr[START:START + N], r)
    np.testing.assert_array_equal(u, ic + rr)
    over = (np.abs(u) > limit).any(axis=1)
    assert over.sum() > 20 and np.abs(u).max() > 1.2 * limit
    # flagged exactly where the amplifier saturated
    clipped = flags & SampleBlock.FLAG_CLIPPED != 0
    np.testing.assert_array_equal(clipped, over)
    for b in rogue.blocks:
        assert bool(b.flags & SampleBlock.FLAG_CLIPPED) == bool(np.any(np.asarray(b.sample_flags) & 1))
    # and reported: one event per block with clipped samples, counting them all
    assert ros.spin_until(lambda: sum(1 for e in rogue.events if e.code == "clipped")
                          == len({i // plant.block_size for i in np.flatnonzero(clipped)}), 5)
    reported = sum(int(re.match(r"(\d+) of", e.text).group(1)) for e in rogue.events if e.code == "clipped")
    assert reported == clipped.sum() == plant.finished.result()["clipped_samples"]
    first = next(e for e in rogue.events if e.code == "clipped")
    assert first.severity == SessionEvent.WARN and first.sample_index == np.flatnonzero(clipped)[0]
    assert "recorded as commanded" in first.text
