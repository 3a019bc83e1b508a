"""ambid node NAME [--ros-args ...]: start one node of the graph as its own process."""

from __future__ import annotations

import argparse
import os
import sys

HELP = "start a single node (plant_sim, position_controller, excitation_generator, frf_consumer, recorder, " \
       "hardware_bridge) with ROS arguments"


def node_names() -> list[str]:
    """The nodes this package installs as console entry points."""
    from importlib.metadata import entry_points

    names = sorted(ep.name for ep in entry_points(group="console_scripts") if ep.value.startswith("ambid_nodes."))
    return names or ["plant_sim", "position_controller", "excitation_generator", "frf_consumer", "recorder",
                     "hardware_bridge"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", help="node to start: " + ", ".join(node_names()))
    p.add_argument("ros_args", nargs=argparse.REMAINDER,
                   help="passed to the node, e.g. --ros-args -r __ns:=/amb -p seed:=3 "
                        "(default namespace /amb, parameter file config/<name>.yaml of the package)")


def run(args: argparse.Namespace) -> int:
    if args.name not in node_names():
        print(f"ambid node: unknown node '{args.name}'; choose one of {', '.join(node_names())}", file=sys.stderr)
        return 2
    ros_args = list(args.ros_args)
    if "--ros-args" not in ros_args:
        ros_args = ["--ros-args", "-r", "__ns:=/amb"]
    # replace this process: signals go straight to the node
    os.execv(sys.executable, [sys.executable, "-m", f"ambid_nodes.{args.name}", *ros_args])
    return 0  # not reached
