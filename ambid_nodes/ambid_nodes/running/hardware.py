"""The hardware layout: the composed session with the bridge to a real-time target in place of plant_sim
and the position controller (the target runs the fast loop; docs/bridge_protocol.md).

The bridge is started first: the target must answer before anything is written, so a wrong address
leaves no recording behind. The target starts its clock (START) once it has acknowledged the
experiment, and is told to STOP once the session's samples are in.
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
        # the target must answer before anything is written: a wrong address leaves no recording behind
        self.spin_until(lambda: self.plant.connected, 15,
                        f"the real-time target at {self.cfg.hardware} (is it running and sending to this bridge's "
                        "port?); nothing was recorded")
        super().start_graph()

    def make_plant(self):
        from ambid_nodes.hardware_bridge import HardwareBridge

        return HardwareBridge(**self.ns, rig=self.plan.rig, parameter_overrides=self.params({
            **bridge_parameters(self.cfg), **self.rig_param, **self.session}))

    def start_loop(self, answer) -> None:
        """The target starts its clock once it has acknowledged the experiment."""
        plant = self.plant
        self.spin_until(lambda: answer.experiment_id in plant.slots and plant.connected
                        and not plant.commands.pending, 30,
                        f"the real-time target at {self.cfg.hardware} to acknowledge the experiment (is it running, "
                        "idle, and sending to this bridge's port?)")
        plant.queue_command(CommandCode.START)

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
