"""Running the plant and controller graph: composed in one process or as separate processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field

import numpy as np
from ambid.control.kinds import ControllerDesign
from ambid.plant.rig import Rig

from ambid_nodes.node_main import SUMMARY_PREFIX, spin_until_done

DEFAULT_NAMESPACE = "/amb"


@dataclass
class GraphConfig:
    """What to run: parameters per node (name -> value), namespace, layout.

    ``rig`` and ``controller_design``: the rig parsed and the controller designed once by the caller,
    handed to the nodes of a composed run (None: the plant parses its ``rig_file`` and hands that rig to
    the controller, which designs from its parameters). Separate processes each read their own
    parameters, so each parses the rig file (and the controller designs its controller) once, in its
    own process.
    """

    sim_seconds: float = 2.0
    namespace: str = DEFAULT_NAMESPACE
    plant: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)
    rig: Rig | None = None
    controller_design: ControllerDesign | None = None


def session_domain_id() -> int:
    """ROS_DOMAIN_ID if set, else one derived from this process, so sessions don't cross-talk."""
    env = os.environ.get("ROS_DOMAIN_ID")
    if env:
        return int(env)
    return 100 + os.getpid() % 100


def run_composed(cfg: GraphConfig) -> dict:
    """Plant and controller as two nodes of one process, one EventsExecutor. Returns the plant's summary."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter

    from ambid_nodes.plant_sim import PlantSim
    from ambid_nodes.position_controller import PositionController

    def overrides(d: dict) -> list:
        return [Parameter(k, value=v) for k, v in d.items()]

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=session_domain_id())
    executor = EventsExecutor(context=context)
    nodes = []
    try:
        plant = PlantSim(namespace=cfg.namespace, context=context, rig=cfg.rig,
                         parameter_overrides=overrides({"sim_seconds": float(cfg.sim_seconds), **cfg.plant}))
        nodes.append(plant)
        nodes.append(PositionController(namespace=cfg.namespace, context=context, rig=plant.rig,
                                        design=cfg.controller_design, parameter_overrides=overrides(cfg.controller)))
        for n in nodes:
            executor.add_node(n)
        spin_until_done(executor, plant.finished, context)
        return {**plant.finished.result(), "layout": "composed"}
    finally:
        executor.shutdown()
        for n in nodes:
            n.destroy_node()
        rclpy.shutdown(context=context)


def ros_args(namespace: str, params: dict) -> list[str]:
    args = ["--ros-args", "-r", f"__ns:={namespace}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={json.dumps(v) if isinstance(v, str) else str(v).lower() if isinstance(v, bool) else v}"]
    return args


def stop_processes(procs: list[subprocess.Popen], grace_s: float = 5.0) -> None:
    """SIGTERM every process, SIGKILL what is left after grace_s.

    A running node shuts down cleanly on SIGTERM (rclpy handles it as SIGINT); a
    process still importing ends quietly, where SIGINT would print a
    KeyboardInterrupt traceback from the middle of an import.
    """
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def run_processes(cfg: GraphConfig) -> dict:
    """Plant and controller as separate processes on one DDS domain. Returns the plant's summary."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(session_domain_id()))
    py = sys.executable
    procs = []
    try:
        ctrl = subprocess.Popen([py, "-m", "ambid_nodes.position_controller", *ros_args(cfg.namespace, cfg.controller)],
                                env=env, start_new_session=True)
        procs.append(ctrl)
        plant = subprocess.Popen([py, "-m", "ambid_nodes.plant_sim",
                                  *ros_args(cfg.namespace, {"sim_seconds": float(cfg.sim_seconds), **cfg.plant})],
                                 env=env, stdout=subprocess.PIPE, text=True, start_new_session=True)
        procs.append(plant)
        summary = None
        for line in plant.stdout:
            if line.startswith(SUMMARY_PREFIX):
                summary = json.loads(line[len(SUMMARY_PREFIX):])
            else:
                sys.stdout.write(line)
        code = plant.wait()
        if ctrl.poll() is not None and summary is None:
            raise RuntimeError(f"position_controller exited with code {ctrl.returncode} before the run ended")
        if summary is None:
            raise RuntimeError(f"plant_sim exited with code {code} without a summary")
        return {**summary, "layout": "processes"}
    finally:
        stop_processes(procs)


def run_hardware(cfg: GraphConfig, target: str, local_port: int = 0) -> dict:
    """The graph against a real-time target over the UDP bridge (docs/bridge_protocol.md).

    The target runs the fast loop (plant and position controller); this
    process runs ``hardware_bridge``, which publishes the measured blocks,
    and a listener that judges the levitation from them as plant_sim does
    (over the second half of the run). Once ``cfg.sim_seconds`` of samples
    arrived (or the target finished) the target is told to STOP, and the
    bridge's figures are returned with the levitation's.
    """
    import rclpy
    from ambid.hardware.bridge_protocol import CommandCode
    from ambid.hardware.rt_target import parse_address
    from ambid.plant.levitation import LevitationMonitor
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter

    from ambid_msgs.msg import SampleBlock
    from ambid_nodes import qos
    from ambid_nodes.conversions import block_data
    from ambid_nodes.hardware_bridge import HardwareBridge

    host, port = parse_address(target)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=session_domain_id())
    executor = EventsExecutor(context=context)
    params = {"target_host": host, "target_port": port, "local_port": local_port, **cfg.plant}
    bridge = HardwareBridge(namespace=cfg.namespace, context=context, rig=cfg.rig,
                            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    wanted = int(round(cfg.sim_seconds / bridge.dt))
    monitor = LevitationMonitor(bridge.rig.backup_clearance_m, wanted // 2)
    listener = rclpy.create_node("graph_levitation", namespace=cfg.namespace, context=context)

    def on_block(msg) -> None:
        data = block_data(msg, bridge.measurement_names)
        monitor.add_block(msg.first_index, data[:, :bridge.na],
                          (np.asarray(msg.sample_flags) & SampleBlock.FLAG_LANDED) != 0)

    listener.create_subscription(SampleBlock, "measurement", on_block, qos.BLOCKS)
    executor.add_node(bridge)
    executor.add_node(listener)
    try:
        while not bridge.finished.done() and bridge.figures()["samples_published"] < wanted:
            executor.spin_until_future_complete(bridge.finished, timeout_sec=0.25)
        if not bridge.finished.done() and bridge.connected:
            bridge.queue_command(CommandCode.STOP)  # the session is over: the target stops its clock
            executor.spin_until_future_complete(bridge.finished, timeout_sec=2.0)
        figures = bridge.figures()
        return {**figures, **monitor.figures(), "layout": f"hardware bridge to {target}",
                "samples_per_wall_s": figures["samples_published"] / max(figures["wall_s"], 1e-9)}
    finally:
        executor.shutdown()
        listener.destroy_node()
        bridge.destroy_node()
        rclpy.shutdown(context=context)
