"""Running the plant and controller graph: composed in one process or as separate processes."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

from ambid.control.kinds import ControllerDesign
from ambid.plant.rig import Rig

from ambid_nodes.node_main import spin_until_done
from ambid_nodes.running.domain import DEFAULT_NAMESPACE, session_domain_id
from ambid_nodes.running.layout import preflight


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
    session: int = 0  # the session's id (docs/sessions.md); 0: open nodes
    report_foreign: Callable[[dict], None] | None = None  # told the foreign publishers found before the start


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
        foreign = preflight(executor, cfg.namespace, context, cfg.report_foreign)
        session = {"session": cfg.session}
        plant = PlantSim(namespace=cfg.namespace, context=context, rig=cfg.rig, parameter_overrides=overrides(
            {"sim_seconds": float(cfg.sim_seconds), **cfg.plant, **session}))
        nodes.append(plant)
        nodes.append(PositionController(namespace=cfg.namespace, context=context, rig=plant.rig,
                                        design=cfg.controller_design,
                                        parameter_overrides=overrides({**cfg.controller, **session})))
        for n in nodes:
            executor.add_node(n)
        spin_until_done(executor, plant.finished, context)
        return {**plant.finished.result(), "layout": "composed", "foreign_publishers": foreign}
    finally:
        executor.shutdown()
        for n in nodes:
            n.destroy_node()
        rclpy.shutdown(context=context)


def run_processes(cfg: GraphConfig) -> dict:
    """Plant and controller as separate processes on one DDS domain, supervised (ambid_nodes.supervisor).

    Returns the plant's summary; where a node died before the run was over, the figures up to there (from
    the plant's summary if it ended its run, else from the measurement blocks this process heard) and
    ``death``: {node, how, sample_index, consequence}.
    """
    from ambid.plant.rig import rig_or_default

    from ambid_nodes.running.processes import died_summary
    from ambid_nodes.supervisor import NodeGone, supervise, supervised, wait_for

    rig = cfg.rig or rig_or_default(cfg.plant.get("rig_file"))
    n_total = int(round(cfg.sim_seconds / rig.dt))
    with supervised(cfg.namespace, cfg.session, rig.backup_clearance_m, n_total // 2,
                    int(round(0.5 / rig.dt))) as (executor, sup, watch):
        foreign = preflight(executor, cfg.namespace, watch.context, cfg.report_foreign)
        session = {"session": cfg.session}
        plant = sup.start("plant_sim", {"sim_seconds": float(cfg.sim_seconds), **cfg.plant, **session},
                          finishes=True)
        wall0 = time.perf_counter()
        try:  # the watch hears every block from the first before the controller joins and the loop starts
            wait_for(executor, sup, watch, watch.hears_the_plant, 120, "plant_sim's measurement")
            sup.start("position_controller", {**cfg.controller, **session})
            death = supervise(executor, sup, watch, lambda: sup.exited("plant_sim"))
        except NodeGone as gone:
            death = gone.death
        summary = plant.summary
        if death is None and summary is None:
            raise RuntimeError(f"plant_sim exited with code {plant.proc.returncode} without a summary")
        if death is not None:
            summary = died_summary(death, summary, watch, rig.dt, time.perf_counter() - wall0)
        return {**summary, "layout": "processes", "foreign_publishers": foreign}


def run_hardware(cfg: GraphConfig, target: str, local_port: int = 0) -> dict:
    """The graph against a real-time target over the UDP bridge (docs/bridge_protocol.md).

    The target runs the fast loop (plant and position controller); this
    process runs ``hardware_bridge``, which publishes the measured blocks,
    and a listener (``SessionWatch``) that judges the levitation from the
    session's blocks as plant_sim does (over the second half of the run). Once ``cfg.sim_seconds`` of samples
    arrived (or the target finished) the target is told to STOP, and the
    bridge's figures are returned with the levitation's.
    """
    import rclpy
    from ambid.hardware.bridge_protocol import CommandCode
    from ambid.hardware.rt_target import parse_address
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter

    from ambid_nodes.hardware_bridge import HardwareBridge
    from ambid_nodes.watch import SessionWatch

    host, port = parse_address(target)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=session_domain_id())
    executor = EventsExecutor(context=context)
    foreign = preflight(executor, cfg.namespace, context, cfg.report_foreign)
    params = {"target_host": host, "target_port": port, "local_port": local_port, **cfg.plant, "session": cfg.session}
    bridge = HardwareBridge(namespace=cfg.namespace, context=context, rig=cfg.rig,
                            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    wanted = int(round(cfg.sim_seconds / bridge.dt))
    # the levitation judged from the session's blocks, as plant_sim judges it
    watch = SessionWatch(cfg.session, bridge.rig.backup_clearance_m, wanted // 2, int(round(0.5 / bridge.dt)),
                         namespace=cfg.namespace, context=context)
    executor.add_node(bridge)
    executor.add_node(watch)
    try:
        while not bridge.finished.done() and bridge.figures()["samples_published"] < wanted:
            executor.spin_until_future_complete(bridge.finished, timeout_sec=0.25)
        if not bridge.finished.done() and bridge.connected:
            bridge.queue_command(CommandCode.STOP)  # the session is over: the target stops its clock
            executor.spin_until_future_complete(bridge.finished, timeout_sec=2.0)
        figures = bridge.figures()
        return {**figures, **watch.monitor.figures(), "layout": f"hardware bridge to {target}",
                "samples_per_wall_s": figures["samples_published"] / max(figures["wall_s"], 1e-9),
                "foreign_publishers": foreign}
    finally:
        executor.shutdown()
        watch.destroy_node()
        bridge.destroy_node()
        rclpy.shutdown(context=context)
