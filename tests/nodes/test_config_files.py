"""Each node's installed parameter file (ambid_nodes/config/<node>.yaml) says the node's real defaults:
a file that drifts from the declared defaults would run a different rig than the node alone."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from rclpy.parameter import Parameter
from ambid_nodes.excitation_generator import ExcitationGenerator
from ambid_nodes.frf_consumer import FrfConsumer
from ambid_nodes.hardware_bridge import HardwareBridge
from ambid_nodes.plant_sim import PlantSim
from ambid_nodes.position_controller import PositionController
from ambid_nodes.recorder import Recorder

CONFIG = Path(__file__).resolve().parents[2] / "ambid_nodes" / "config"
NODES = {"plant_sim": PlantSim, "position_controller": PositionController, "excitation_generator": ExcitationGenerator,
         "frf_consumer": FrfConsumer, "recorder": Recorder, "hardware_bridge": HardwareBridge}


@pytest.mark.parametrize("name", list(NODES))
def test_parameter_file_holds_the_declared_defaults(ros, name, tmp_path):
    params = yaml.safe_load((CONFIG / f"{name}.yaml").read_text())["/**"]["ros__parameters"]
    kwargs = {"output": str(tmp_path / "r.mcap")} if name == "recorder" else {}
    if name == "hardware_bridge":  # its default port may be taken on a shared machine: any free one; a key file
        from ambid.hardware.link_key import write_key_file

        write_key_file(tmp_path / "rig.key")
        kwargs = {"local_port": 0, "key_file": str(tmp_path / "rig.key")}

    node = NODES[name](namespace="/cfg", context=ros.context,
                       parameter_overrides=[Parameter(k, value=v) for k, v in kwargs.items()])
    try:
        declared = {k: node.get_parameter(k).value for k in params if k not in kwargs}
        names = set(node.get_parameters_by_prefix(""))
        missing = sorted(set(params) - names)
        assert not missing, f"{name}.yaml names parameters the node does not declare: {missing}"
        undocumented = sorted(names - set(params) - {"use_sim_time", "start_type_description_service"})
        assert not undocumented, f"{name}.yaml leaves out declared parameters: {undocumented}"
        drift = {k: (v, declared[k]) for k, v in params.items() if k not in kwargs and v != declared[k]
                 and not (isinstance(v, (int, float)) and isinstance(declared[k], (int, float))
                          and float(v) == float(declared[k]))}
        assert not drift, f"{name}.yaml (file, declared): {drift}"
    finally:
        node.destroy_node()
