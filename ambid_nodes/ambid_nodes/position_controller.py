"""position_controller: discrete position controller of the AMB, answering y[k] with ic[k].

Subscribes ``displacement`` (ambid_msgs/Sample), publishes ``control_current``
for the same sample index, a latched ``controller/description`` (its discrete
state-space, so C(e^jwT) is known to every node) and ``status``.

Before it answers anything it checks the closed loop with the rig's
analytical model and refuses to run an unstable combination.

A displacement message with the wrong channel count or a NaN is rejected
(counted, logged); the controller then answers with its previous current and
leaves its state untouched, so one bad sample cannot destabilise the loop.
"""

from __future__ import annotations

import json
import sys

import rclpy
from ambid_msgs.msg import ControllerDescription, Sample, SessionEvent, SessionStatus
from rclpy.node import Node

from ambid.closed_loop import check_stability
from ambid.controller import ControllerStepper, PidParameters, pid_controller, pid_parameters_dict
from ambid.rig import analytical_model, load_rig, make_rig
from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, statespace_to_msg, time_msg
from ambid_nodes.parameters import ParameterError, declare, refuse_unknown
from ambid_nodes.sample_codec import decode_sample, encode_sample

STATUS_EVERY = 10_000  # samples between status messages


class PositionController(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("position_controller", **kwargs)
        rig_file = declare(self, "rig_file", "", "YAML rig parameter file used for the stability check")
        self.kind = declare(self, "controller", "pid", "controller kind: pid")
        d = PidParameters()
        pid = PidParameters(
            kp_a_per_m=declare(self, "kp", d.kp_a_per_m, "proportional gain", 1.0, 1e9, "A/m"),
            ti_s=declare(self, "ti", d.ti_s, "integral time", 1e-5, 1e4, "s"),
            td_s=declare(self, "td", d.td_s, "derivative time", 0.0, 1.0, "s"),
            derivative_filter_n=declare(self, "derivative_filter_n", d.derivative_filter_n,
                                        "derivative filter ratio N (lead up to N)", 1.0, 1000.0),
            lowpass_hz=declare(self, "lowpass", d.lowpass_hz, "first-order low-pass corner", 1.0, 1e6, "Hz"),
            delay_samples=declare(self, "delay_samples", d.delay_samples, "computational delay", 0, 100),
            current_limit_a=declare(self, "current_limit", d.current_limit_a, "saturation of ic", 1e-3, 1e3, "A"),
        )
        refuse_unknown(self)
        if self.kind != "pid":
            raise ParameterError(f"position_controller: controller '{self.kind}' is not available; use 'pid'")
        self.rig = load_rig(rig_file) if rig_file else make_rig()
        self.model = pid_controller(pid, self.rig.dt)
        try:
            check_stability(analytical_model(self.rig), self.model, "analytical model with this controller")
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.params = pid
        self.stepper = ControllerStepper(self.model, pid.current_limit_a)
        self.pub_ic = self.create_publisher(Sample, "control_current", qos.LOOP)
        self.pub_desc = self.create_publisher(ControllerDescription, "controller/description", qos.LATCHED)
        self.pub_status = self.create_publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.create_publisher(SessionEvent, "events", qos.EVENTS)
        self.create_subscription(Sample, "displacement", self.on_displacement, qos.LOOP, raw=True)
        self.expected: int | None = None
        self.ic_last = [0.0] * 4
        self.received = 0
        self.rejected = 0
        self.pub_desc.publish(ControllerDescription(
            stamp=time_msg(0.0), name=self.get_fully_qualified_name(), kind=self.kind,
            delay_samples=pid.delay_samples, model=statespace_to_msg(self.model),
            current_limit=[pid.current_limit_a] * 4, parameters_json=json.dumps(pid_parameters_dict(pid))))

    def on_displacement(self, data: bytes) -> None:
        self.received += 1
        try:
            k, y = decode_sample(data, 4, "displacement")
        except BadMessage as exc:
            if exc.index is None:
                self.reject(-1, str(exc))
                return
            k, y = exc.index, None
            bad = str(exc)
        if self.expected is not None and k != self.expected:
            if k < self.expected:
                self.reject(k, f"displacement index {k} repeated or out of order (expected {self.expected})")
                return
            self.reject(k, f"displacement jumped from {self.expected} to {k}: {k - self.expected} samples missing")
        if y is None:
            self.reject(k, f"{bad}; answering with the previous current")
            ic = self.ic_last
        else:
            ic = self.stepper.step(y)
        self.expected = k + 1
        self.ic_last = ic
        self.pub_ic.publish(encode_sample(k, ic))
        if k % STATUS_EVERY == 0:
            self.publish_status(k)

    def reject(self, k: int, why: str) -> None:
        self.rejected += 1
        self.get_logger().warn(f"rejected message ({self.rejected} so far): {why}", throttle_duration_sec=1.0)
        self.pub_event.publish(SessionEvent(sample_index=k, severity=SessionEvent.WARN,
                                            node=self.get_fully_qualified_name(), code="rejected_message", text=why))

    def publish_status(self, k: int) -> None:
        self.pub_status.publish(SessionStatus(
            node=self.get_fully_qualified_name(), state=SessionStatus.STATE_RUNNING, sample_index=k,
            progress=-1.0, messages_received=self.received, messages_rejected=self.rejected,
            text=f"sample {k}, {self.kind}, rejected {self.rejected}"))


def main(args=None) -> int:
    from ambid_nodes.node_main import run_single
    return run_single(PositionController, args)


if __name__ == "__main__":
    sys.exit(main())
