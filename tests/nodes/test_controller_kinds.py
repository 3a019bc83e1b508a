"""docs/architecture.md's 'Adding a controller kind' kept true: a kind registered in
ambid.control.kinds alone reaches the node, the CLI and the stability check, and levitates the rotor."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ambid.control import kinds
from ambid.control.kinds import ControllerDesign, ControllerKind
from ambid.control.pid import PidParameters, pid_controller
from ambid.plant.rig import Rig
from ambid_cli.commands import graph as graph_command
from ambid_nodes.parameters import ParameterError
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from rclpy.parameter import Parameter

from ambid_msgs.msg import ControllerDescription
from ambid_nodes import qos

NS = "/amb"


def _stiff_pid(rig: Rig, pid: PidParameters) -> ControllerDesign:
    """A kind written here: the PID with 20 % more gain and a lower current limit."""
    p = PidParameters(kp_a_per_m=1.2 * pid.kp_a_per_m, current_limit_a=2.5)
    return ControllerDesign("stiff_pid", pid_controller(p, rig.dt), p.current_limit_a, p.delay_samples,
                            {"kp_a_per_m": p.kp_a_per_m})


@pytest.fixture
def stiff_kind(monkeypatch):
    monkeypatch.setitem(kinds.CONTROLLER_KINDS, "stiff_pid", ControllerKind("PID, 20 % stiffer", _stiff_pid))


def test_a_registered_kind_is_offered_by_the_cli(stiff_kind):
    import argparse

    parser = argparse.ArgumentParser()
    graph_command.add_arguments(parser)
    assert parser.parse_args(["--controller", "stiff_pid"]).controller == "stiff_pid"
    assert "stiff_pid (PID, 20 % stiffer)" in kinds.describe_kinds()


def test_a_registered_kind_runs_in_the_node_and_levitates(ros, stiff_kind):
    got: list[ControllerDescription] = []
    probe = ros.add(__import__("rclpy").create_node("probe", namespace=NS, context=ros.context))
    probe.create_subscription(ControllerDescription, "controller/description", got.append, qos.LATCHED)
    plant = ros.add(PlantSim(namespace=NS, context=ros.context, parameter_overrides=[
        Parameter("sim_seconds", value=0.6), Parameter("seed", value=3)]))
    ros.add(PositionController(namespace=NS, context=ros.context,
                               parameter_overrides=[Parameter("controller", value="stiff_pid")]))
    assert ros.spin_until(lambda: plant.finished.done() and got, timeout_s=60)
    assert plant.summary["state"] == "done", plant.summary
    desc = got[0]
    design = _stiff_pid(plant.rig, PidParameters())
    assert desc.kind == "stiff_pid"
    assert json.loads(desc.parameters_json) == design.parameters
    assert list(desc.current_limit) == [2.5] * 4
    assert np.allclose(np.asarray(desc.model.a).reshape(design.model.a.shape), design.model.a)


def test_an_unknown_kind_is_refused_naming_the_known_ones(ros):
    with pytest.raises(ParameterError, match="controller 'nope' is unknown; use one of 'pid', 'lqg'"):
        PositionController(namespace=NS, context=ros.context, parameter_overrides=[Parameter("controller", value="nope")])
