"""position_controller: discrete position controller of the AMB, answering y[k] with ic[k].

Subscribes ``displacement`` (ambid_msgs/Sample), publishes ``control_current``,
a latched ``controller/description`` (its discrete state-space, so C(e^jwT)
is known to every node) and ``status``.

Pipelining. A controller with a computational delay (no feedthrough, D = 0:
ic[k] depends on y[k-1] and older) answers y[k] with ic[k + 1], computed as
soon as y[k] is in, and y[0] with ic[0] and ic[1]: the plant then finds its
next current already there when it has stepped, and the two nodes' work
overlaps when they run as separate processes. The currents are the very
numbers of answering y[k] with ic[k]. A controller with feedthrough answers
y[k] with ic[k].

Before it answers anything it checks the closed loop with the rig's
analytical model and refuses to run an unstable combination.

Session (parameter ``session``, docs/sessions.md): it answers the displacements of its session's plant
only (its GID, from the roster on ``session``), takes the status of its session only, and stamps the
id on all it publishes; another source's messages are foreign: counted, named, never answered.

A displacement message with the wrong channel count or a NaN is rejected
(counted, logged); the controller then answers with its previous current and
leaves its state untouched, so one bad sample cannot destabilise the loop. A
displacement for any index but the awaited one (stale, repeated, ahead, out of
range) is rejected and changes nothing; a session starts at index 0 (a plant
that re-sends y[0] before the loop moved on gets the same answer again). A plant
that asks again for one of the last two displacements (its ``resend_after_s`` wait
passed: an answer or a displacement was lost) gets the answer already given,
byte for byte, without a second step (``answers_repeated`` in ``status``). Every
received message is counted per topic in ``status`` (``ambid_nodes.intake``).

Plant supervision. Once the loop runs, a plant silent for ``plant_timeout_s``
seconds of wall time is declared lost -- unless its last ``status`` said
its run ended (done or failed). In lock-step the plant's next sample is the
one that did not come, so the detection latency is 0 samples and
``plant_timeout_s`` (+ up to two watchdog periods, each at most 0.1 s: no
clock is read per sample, the watchdog dates progress to its ticks) of wall time. Then
the controller reports a FAILED status and an ERROR ``plant_lost`` event,
resets its state to zero current and idles safely: it answers nothing until
a plant starts a new session at sample 0 (a stalled plant that resumes is
not answered, so it goes to its own safe state).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from ambid.control.kinds import ControllerDesign, checked_design, describe_kinds
from ambid.control.pid import PidParameters
from ambid.control.stepper import ControllerStepper
from ambid.plant.rig import Rig
from rclpy.qos import HistoryPolicy, QoSProfile

from ambid_msgs.msg import ControllerDescription, Sample, SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, statespace_to_msg, status_msg, time_msg
from ambid_nodes.session_node import SessionNode
from ambid_nodes.loop_call import BoundKernel, ContextWord
from ambid_nodes.loop_kernels import (CK_LEAD, CK_LIMIT, CK_MAT, CK_N, CK_P, CK_Q, CK_SLOTS, CK_STATUS_EVERY, CK_WORK,
                                      CONTROLLER_STATUS,
                                      LOOP_COUNT, LOOP_GATE, LOOP_K, LOOP_LIMIT, LOOP_NO_LIMIT, LOOP_OUT, N_CK,
                                      controller_kernel, sample_buffer)
from ambid_nodes.identity import LoopPartner
from ambid_nodes.loop_pump import NOT_RUN, GatingState, LoopEntry
from ambid_nodes.parameters import ParameterError, declare, declare_fields, node_rig
from ambid_nodes.raw_publish import raw_publisher
from ambid_nodes.sample_codec import decode_sample, encode_sample

STATUS_EVERY = 10_000  # samples between status messages
RUNNING = SessionStatus.STATE_RUNNING  # read once: rosidl constants are class properties


class PositionController(SessionNode):
    # the next displacement index awaited (None: no session), in the compiled path's context
    expected = ContextWord("fast", LOOP_K, none=-1)
    state = GatingState()  # each assignment sets the loop pump's gate (regate)

    def __init__(self, *, rig: Rig | None = None, design: ControllerDesign | None = None, **kwargs) -> None:
        """``rig`` and ``design``: the rig and the controller a composed run parsed and designed (and
        checked) once; else the node's parameters' (``rig_file``, ``controller``, the PID gains)."""
        super().__init__("position_controller", **kwargs)
        rig_file = declare(self, "rig_file", "", "YAML rig parameter file used for the stability check")
        self.kind = declare(self, "controller", "",
                            f"controller: {describe_kinds()}, or a controller file (.npz, .mat, .yaml: a discrete "
                            "state space or per-axis transfer functions); empty: the rig file's controller, else pid")
        pid = PidParameters(**declare_fields(self, PidParameters))   # the gains: PidParameters' names and defaults
        pipeline = declare(self, "pipeline", True,
                           "answer y[k] with ic[k+1] when the controller has a computational delay (no "
                           "feedthrough), so the next current travels while the plant steps; false: with ic[k]")
        self.timeout = declare(self, "plant_timeout_s", 2.0,
                               "wall time without a displacement before the running plant is declared lost",
                               0.01, 3600.0, "s")
        self.join_session()
        self.rig = node_rig(self, rig_file, rig)
        if design is None:
            try:
                # refuses a loop that is unstable on the analytical or on the true linearised rig
                design = checked_design(self.kind, self.rig, pid)
            except ValueError as exc:
                raise ParameterError(f"position_controller: {exc}") from None
        self.model = design.model
        delay_samples, params_json = design.delay_samples, design.parameters
        self.design = design
        self.stepper = ControllerStepper(self.model, design.current_limit_a)
        self.pub_ic = self.create_publisher(Sample, "control_current", qos.LOOP)
        self.publish_ic = raw_publisher(self.pub_ic)
        self.pipelined = bool(pipeline) and self.stepper.strictly_proper
        self.lead = int(self.pipelined)  # y[k] is answered with ic[k + lead]
        self.first_answers: list[bytes] = []  # the answers to y[0], sent again if the plant repeats y[0]
        # the compiled path: loop_kernels.controller_kernel on the stepper's work vector (bound again
        # with each session's stepper), run on each displacement by the loop pump while a session runs
        self.fast = BoundKernel(controller_kernel, N_CK)
        # the answers to the last two displacements, y[k]'s in slot k % 2, published as they are; both
        # paths write them, so a plant asking again for y[k] gets the very bytes it missed
        self.n_in, self.n_out = self.stepper.n_inputs, self.stepper.n_outputs  # the rig's axes, y in and ic out
        self.slots = (sample_buffer(self.n_out), sample_buffer(self.n_out))
        self.fast.bind(CK_SLOTS, self.slots[0], np.uint8)
        self.fast.bind(CK_SLOTS + 2, self.slots[1], np.uint8)
        self.fast.bind(LOOP_OUT, self.slots[0], np.uint8)  # the kernel names the slot of each answer
        self.answers_repeated = 0  # displacements the plant sent again, answered again without a step
        self.fast.set(LOOP_LIMIT, LOOP_NO_LIMIT)
        self.fast.set(CK_LEAD, self.lead)
        self.fast.set(CK_P, self.n_in)
        self.fast.set(CK_Q, self.n_out)
        self.fast.set(CK_STATUS_EVERY, STATUS_EVERY)
        self.bind_stepper()
        publisher = self.identity.publisher  # its messages carry the session's id
        self.pub_desc = publisher(ControllerDescription, "controller/description", qos.LATCHED)
        self.pub_status = publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = publisher(SessionEvent, "events", qos.EVENTS)
        self.make_intake()
        self.y_tally = self.intake.tally("displacement")
        self.y_tally.count_also(self.fast.context[LOOP_COUNT:LOOP_COUNT + 1])
        # displacement: the loop pump runs controller_kernel, publishes the answer and counts in compiled code
        self.loop = LoopEntry(self, Sample, "displacement", qos.LOOP, self.pub_ic, self.fast,
                              self.finish_displacement)
        # the session's plant by GID (the roster): another publisher's displacements are dropped in C
        self.plant = LoopPartner(self.identity, self.loop.entry, self.loop.subscription.get_topic_name(),
                                 self.finish_displacement,
                                 lambda gid: self.intake.foreign("displacement", gid=gid, count=False), NOT_RUN)
        self.y_tally.count_foreign_also(self.plant)
        # the plant's status says whether its silence is the end of its run; a deep queue so no
        # other node's status can push the plant's last one out before it is read
        self.intake.subscribe(SessionStatus, "status", self.on_status, QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=100, reliability=qos.STATUS.reliability,
            durability=qos.STATUS.durability))
        self.expected: int | None = None  # next displacement index awaited; None: no session
        self.state = SessionStatus.STATE_IDLE
        self.last_y_wall: float | None = None  # when the watchdog last saw the loop move on
        self.watch_expected: int | None = None
        self.plant_nodes: set[str] = set()  # who publishes displacement
        self.plant_ended: dict[str, bool] = {}  # node -> its last status was done/failed
        self.lost_at: int | None = None
        self.watchdog = self.create_timer(min(0.1, self.timeout / 2), self.check_plant)
        self.status_received = -1
        self.create_timer(1.0, self.status_when_idle)
        self.pub_desc.publish(ControllerDescription(
            stamp=time_msg(0.0), name=self.get_fully_qualified_name(), kind=design.kind,
            delay_samples=delay_samples, model=statespace_to_msg(self.model),
            current_limit=[design.current_limit_a] * self.n_out, parameters_json=json.dumps(params_json)))
        self.identity.announce([self.pub_ic, self.pub_desc, self.pub_status, self.pub_event])

    def regate(self) -> None:
        """The loop pump runs the kernel while a session runs."""
        self.fast.set(LOOP_GATE, int(self._state == RUNNING))

    def destroy_node(self) -> None:
        self.loop.close()
        super().destroy_node()

    def finish_displacement(self, data: bytes, code: int) -> None:
        """A displacement the loop pump's kernel did not finish: ``code`` is what controller_kernel
        returned for the awaited index (CONTROLLER_ANSWERED the pump published itself), or NOT_RUN
        while no session runs."""
        if code == CONTROLLER_STATUS:  # answered, and a status is due
            self.y_tally.accepted += 1
            k = self.expected
            self.expected = k + 1
            self.publish_ic(self.slots[k & 1])
            self.publish_status()
            return
        self.on_displacement_checked(data)

    def on_displacement_checked(self, data: bytes) -> None:
        """Every message the compiled path does not take: decided, reasons given, answered if due."""
        try:
            k, y = decode_sample(data, self.n_in, "displacement")
        except BadMessage as exc:
            if exc.index is None:
                self.intake.reject("displacement", str(exc))
                return
            k, y, bad = exc.index, None, str(exc)
        if k != self.expected or self.state != RUNNING:
            if not self.start_or_refuse(k, self.state == RUNNING, y):
                return
        if y is None:
            self.intake.reject("displacement", f"{bad}; answering with the previous current")
            ic = self.ic_last  # and the state stays as it is
        else:
            self.y_tally.accepted += 1
            ic = self.step(y)
        self.expected = k + 1
        answer = encode_sample(k + self.lead, ic)
        self.slots[k & 1][:] = answer
        self.publish_ic(answer)
        if k == 0:
            self.first_answers.append(answer)
        if k % STATUS_EVERY == 0:
            self.publish_status()

    @property
    def ic_last(self) -> tuple[float, ...]:
        """The last current answered [A] (one per axis): what a bad displacement is answered with."""
        return self.stepper.last_output()

    def start_or_refuse(self, k: int, running: bool, y) -> bool:
        """Off the per-sample path: start a session at y[0], answer a repeated y[0] again, or reject."""
        intake = self.intake
        if k == 0 and running and self.expected == 1 and y is not None:
            intake.accept("displacement")  # the plant did not hear our answer yet: the same again
            self.answers_repeated += 1
            for answer in self.first_answers:
                self.publish_ic(answer)
            return False
        if running and y is not None and self.expected - 2 <= k < self.expected:
            # the plant asks again (its answer, or a displacement, was lost): the answer already given,
            # from its slot, without stepping twice
            slot = self.slots[k & 1]
            if int.from_bytes(slot[4:12], "little") == k + self.lead:
                intake.accept("displacement")
                self.answers_repeated += 1
                self.publish_ic(slot)
                return False
        if k == 0 and not running:
            self.start_session()
            return True
        if not running:
            why = (f"the plant was declared lost at sample {self.lost_at}" if self.lost_at is not None
                   else "no session runs")
            intake.reject("displacement", f"displacement index {k} while {why}: waiting for a session to "
                                          "start at sample 0")
            return False
        kind = "repeated or out of order" if k < self.expected else "ahead of the loop or out of range"
        intake.reject("displacement", f"displacement index {k} {kind} (expected {self.expected})")
        return False

    def reset_stepper(self) -> None:
        """A controller at zero state and zero current, stepped by both paths."""
        self.stepper = ControllerStepper(self.model, self.design.current_limit_a)
        self.bind_stepper()

    def bind_stepper(self) -> None:
        """Point the Python path and the compiled path (work vector, matrix, limit) at the present stepper."""
        self.step = self.stepper.step_ahead if self.pipelined else self.stepper.step
        w, n, mat, limit = self.stepper.kernel_args(ahead=self.pipelined)
        self.fast.bind(CK_WORK, w, np.float64)
        self.fast.set(CK_N, n)
        self.fast.set(CK_MAT, mat)
        self.fast.set_float(CK_LIMIT, limit)

    def start_session(self) -> None:
        """Sample 0 of a plant: a new session from the controller's zero state."""
        self.reset_stepper()
        self.expected, self.watch_expected = 0, None
        self.state, self.lost_at = RUNNING, None
        self.plant_ended.clear()
        self.update_plant_nodes()
        self.first_answers = []
        if self.pipelined:  # ic[0] does not depend on y[0]: it goes first
            ic0 = encode_sample(0, self.stepper.current_output())
            self.first_answers.append(ic0)
            self.publish_ic(ic0)

    def update_plant_nodes(self) -> None:
        topic = self.resolve_topic_name("displacement")
        self.plant_nodes = {f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                            for i in self.get_publishers_info_by_topic(topic)}

    def on_status(self, msg: SessionStatus) -> None:
        if msg.node in self.plant_nodes or not self.plant_nodes:
            self.plant_ended[msg.node] = msg.state in (SessionStatus.STATE_DONE, SessionStatus.STATE_FAILED)

    def check_plant(self) -> None:
        if self.state != RUNNING:
            return
        if not self.plant_nodes:
            self.update_plant_nodes()  # discovery may have been late at sample 0
        now = time.perf_counter()
        if self.expected != self.watch_expected:  # the loop moved on since the last tick
            self.watch_expected, self.last_y_wall = self.expected, now
            return
        quiet = now - self.last_y_wall
        if quiet <= self.timeout:
            return
        k = self.expected
        if any(self.plant_ended.get(n, False) for n in self.plant_nodes):
            self.state = SessionStatus.STATE_DONE
            self.event(SessionEvent.INFO, "plant_finished", f"the plant ended its run after sample {k - 1}; idle",
                       k)
        else:
            self.state, self.lost_at = SessionStatus.STATE_FAILED, k
            self.event(SessionEvent.ERROR, "plant_lost",
                       f"no displacement for sample {k} within {self.timeout:g} s ({quiet:.3f} s quiet) and the "
                       "plant did not report the end of its run: plant lost; control current reset to zero, "
                       "idle until a plant starts a new session at sample 0", k)
        self.reset_stepper()  # zero state, zero current
        self.publish_status()

    @property
    def dt(self) -> float:
        return self.rig.dt

    def event_index(self) -> int:
        return self.expected or 0

    def log_event(self, severity: int, code: str, text: str) -> None:
        if severity >= SessionEvent.ERROR:
            self.get_logger().error(text)

    def status_when_idle(self) -> None:
        # while the loop runs, status goes out every STATUS_EVERY samples; otherwise when the counters moved
        if self.state != SessionStatus.STATE_RUNNING and self.status_signature() != self.status_received:
            self.publish_status()

    def status_signature(self) -> tuple[int, int]:
        # not every received message: the controller hears its own status too
        return self.intake.received["displacement"], self.intake.total_rejected

    def publish_status(self) -> None:
        self.status_received = self.status_signature()
        k = max((self.expected or 1) - 1, 0)
        f = {"plant_timeout_s": self.timeout, "lost_at": self.lost_at, "answers_repeated": self.answers_repeated,
             **self.intake.figures()}
        states = {SessionStatus.STATE_IDLE: "idle", SessionStatus.STATE_RUNNING: "running",
                  SessionStatus.STATE_DONE: "done", SessionStatus.STATE_FAILED: "failed: plant lost"}
        self.pub_status.publish(status_msg(
            time_msg(k * self.rig.dt), self.get_fully_qualified_name(), self.state, k, -1.0,
            self.intake.total_received, self.intake.total_rejected,
            f"{states[self.state]}, sample {k}, {self.design.kind}, rejected {self.intake.total_rejected}", f))


main = PositionController.main  # the console script: SessionNode.main


if __name__ == "__main__":
    sys.exit(main())
