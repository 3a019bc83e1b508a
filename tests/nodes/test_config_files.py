"""Each node's installed parameter file (ambid_nodes/config/<node>.yaml) says the node's real defaults:
a file that drifts from the declared defaults would run a different rig than the node alone."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from ambid.control.pid import PidParameters
from ambid.excitation.experiment import Streaming
from ambid.excitation.spec import DesignSpec
from ambid.quantity import quantities
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


# the nodes whose parameters are a core dataclass's fields (ambid_nodes.parameters.declare_fields)
FIELDS = [("excitation_generator", DesignSpec), ("excitation_generator", Streaming),
          ("position_controller", PidParameters)]


@pytest.mark.parametrize("name, cls", FIELDS)
def test_parameter_file_says_the_dataclass_names_defaults_and_descriptions(name, cls):
    """Each field of the dataclass is a line ``name: default  # description [unit]`` of the node's file: the
    quantity's one name, default and description live in the core, and the file is held against them."""
    text = (CONFIG / f"{name}.yaml").read_text()
    params = yaml.safe_load(text)["/**"]["ros__parameters"]
    lines = {ln.split(":", 1)[0].strip(): ln for ln in text.splitlines() if ":" in ln and not ln.lstrip().startswith("#")}
    for field, default, q in quantities(cls):
        assert field in params, f"{name}.yaml lacks {field} ({cls.__name__}.{field})"
        want = (list(default) or [q.empty]) if isinstance(default, tuple) else default
        assert params[field] == want, f"{name}.yaml {field}: {params[field]!r}, the dataclass says {want!r}"
        comment = lines[field].split("#", 1)[1].strip() if "#" in lines[field] else ""
        assert comment == q.description(), f"{name}.yaml {field}: comment {comment!r}, the dataclass says " \
                                           f"{q.description()!r}"


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
        # each line's comment is the parameter's description (the declaration's, a dataclass field's for those
        # of FIELDS), so a user reading the file reads what `ros2 param describe` says
        comments = {ln.split(":", 1)[0].strip(): ln.split("  # ", 1)[1] if "  # " in ln else ""
                    for ln in (CONFIG / f"{name}.yaml").read_text().splitlines() if ln.startswith("    ")
                    and not ln.lstrip().startswith("#") and ln.split(":", 1)[0].strip() in params}
        wrong = {k: (c, node.describe_parameter(k).description) for k, c in comments.items()
                 if c != node.describe_parameter(k).description}
        assert not wrong, f"{name}.yaml (comment, description): {wrong}"
    finally:
        node.destroy_node()
