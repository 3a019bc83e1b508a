"""The hardware layout: the composed session with the bridge to a real-time target in place of plant_sim
and the position controller (the target runs the fast loop; docs/bridge_protocol.md).

The bridge is started first: the target must answer before anything is written, so a wrong address
leaves no recording behind. The target starts its clock (START) once it has acknowledged the
experiment, and is told to STOP once the session's samples are in.

The loop alone (``ambid graph --hardware``): the bridge starts an idle target as soon as it hears it, a
listener (:class:`ambid_nodes.watch.SessionWatch`) judges the levitation from the session's blocks as
plant_sim does (over the second half of the run), and the target is told to STOP once the run's samples
arrived (or it finished): the bridge's figures with the levitation's.
"""

from __future__ import annotations

from ambid.hardware.bridge_protocol import CommandCode

from ambid_nodes.running.composed import ComposedLayout
from ambid_nodes.running.plan import SessionConfig, hardware_summary


def bridge_parameters(cfg: SessionConfig) -> dict:
    """The bridge's parameters for ``cfg.hardware`` (HOST:PORT): where the target is, how to talk to it,
    and that it waits for the experiment (every layout's bridge)."""
    from ambid.hardware.rt_target import parse_address

    host, port = parse_address(cfg.hardware)
    return {"target_host": host, "target_port": port, "local_port": cfg.local_port, "autostart": False,
            "key_file": cfg.key_file, "protocol_version": cfg.protocol_version}


class HardwareLayout(ComposedLayout):
    """A real-time target's session (:class:`~ambid_nodes.running.layout.Layout`): recorder, generator,
    consumer and the bridge in this process."""

    kind = "hardware"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.stop_sent = False

    def start_graph(self) -> None:
        self.plant = self.add(self.make_plant())
        if self.loop_only:   # the levitation judged from the session's blocks, as plant_sim judges it
            from ambid_nodes.watch import SessionWatch

            self.watch = self.add(SessionWatch(self.session["session"], self.plan.rig.backup_clearance_m,
                                               self.total // 2, int(round(0.5 * self.fs)), **self.ns))
            return
        # the target must answer before anything is written: a wrong address leaves no recording behind
        self.spin_until(lambda: self.plant.connected, 15,
                        f"the real-time target at {self.cfg.hardware} (is it running and sending to this bridge's "
                        "port?); nothing was recorded")
        super().start_graph()

    def make_plant(self):
        from ambid_nodes.hardware_bridge import HardwareBridge

        return HardwareBridge(**self.ns, rig=self.plan.rig, parameter_overrides=self.params({
            **bridge_parameters(self.cfg), "autostart": self.loop_only, **self.rig_param, **self.session}))

    def start_loop(self, answer) -> None:
        """The target starts its clock once it has acknowledged the experiment (the bridge starts it at once
        where the loop runs alone)."""
        if answer is None:
            return
        plant = self.plant
        self.spin_until(lambda: answer.experiment_id in plant.slots and plant.connected
                        and not plant.commands.pending, 30,
                        f"the real-time target at {self.cfg.hardware} to acknowledge the experiment (is it running, "
                        "idle, and sending to this bridge's port?)")
        plant.queue_command(CommandCode.START)

    def run_loop(self, answer) -> dict:
        if answer is not None:
            return super().run_loop(answer)
        bridge, executor = self.plant, self.executor
        while not bridge.finished.done() and bridge.figures()["samples_published"] < self.total:
            if not self.context.ok():
                raise KeyboardInterrupt
            executor.spin_until_future_complete(bridge.finished, timeout_sec=0.25)
        if not bridge.finished.done() and bridge.connected:
            bridge.queue_command(CommandCode.STOP)  # the session is over: the target stops its clock
            executor.spin_until_future_complete(bridge.finished, timeout_sec=2.0)
        figures = bridge.figures()
        return {**figures, **self.watch.monitor.figures(),
                "samples_per_wall_s": figures["samples_published"] / max(figures["wall_s"], 1e-9)}

    def progress(self) -> int:
        k = self.plant.figures()["samples_published"]
        if k >= self.total and not self.stop_sent:  # enough recorded: the target's clock may stop
            self.plant.queue_command(CommandCode.STOP)
            self.stop_sent = True
        return k

    def plant_summary(self, summary: dict) -> dict:
        import time

        return hardware_summary(summary, self.total, self.fs, time.perf_counter() - self.wall0)

    def blocks_published(self, plant_summary: dict) -> int:
        return self.plant.figures()["blocks"]

    def words(self) -> str:
        return f"hardware bridge to {self.cfg.hardware}"
