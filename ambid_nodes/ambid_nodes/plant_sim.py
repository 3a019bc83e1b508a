"""plant_sim: the simulated AMB rig, owner of the sample clock.

Lock-step on the sample index: publishes y[k] on ``displacement``, waits for
the controller's ic[k] on ``control_current``, applies u = ic + r over the
next sample period and steps. A controller with a computational delay
answers y[k] with ic[k + 1] (and ic[0] first), so the next current is
already on its way while the plant steps; the plant takes the currents in
index order, the awaited one and at most one ahead, and the samples are the
same either way. Publishes measurement blocks (y, u, ic, r),
``/clock``, a latched ``plant/description``, ``status`` (every 10,000 samples
while the loop runs, at its end, and once a second while idle if its counts moved) and
``events``.

Session (parameter ``session``, docs/sessions.md): everything published carries its id; control
currents are taken from the session's controller only (its GID, from the roster on ``session``; the
loop does not start before the roster names it), excitation blocks and designs of the session only;
any other is foreign: counted and named, never acted on.

Every received message is accepted, rejected with its reason, or foreign (counted per
topic in ``status``, logged, reported as a ``rejected_message`` or ``foreign_message`` event; see
``ambid_nodes.intake``). A control message with a NaN or the wrong channel
count for the awaited sample is rejected and the previous valid current is held
for that sample; one for any other index (stale, repeated, out of range) is
rejected and changes nothing. An excitation block is rejected if it is late,
overlaps a block already held, lies beyond ``excitation_horizon`` samples
ahead, or has the wrong channels, sample period or non-finite values; a design
if it is inconsistent, at another sample rate, starts in the past or overlaps
another experiment.

Recovery. Where the loop stands still for ``resend_after_s`` (20 ms) of wall
time waiting for the controller, the plant sends y[k - 1] and y[k] again;
the controller answers the one it missed and repeats the answers it gave,
so a lost displacement or current costs milliseconds and the samples are
the same as without the loss (``resends`` and ``duplicate_answers`` in
``status`` and the summary). Until the first answer the plant sends y[0]
again every ``START_RETRY_S`` (``start_retries``): another listener's match
can let the loop start before the controller's. The plant cannot tell a lost
message from a starved process (a busy machine holds a node for tens of
milliseconds), so it also asks again where nothing was lost: each displacement
sent again is answered again (y[0] of a pipelined controller with ic[0] and
ic[1]), and every answer that comes twice because the plant asked for it is
taken as a duplicate, never rejected.

Controller supervision. In lock-step the plant cannot advance past a sample
whose answer has not arrived, so a dead or stalled controller is detected at
that very sample: the detection latency is 0 samples of simulated time, and
``controller_timeout_s`` (+ up to two watchdog periods, each at most 0.1 s:
the loop reads no clock per sample, the watchdog dates progress to its
ticks) of wall time.
Then the plant goes to its safe state: zero control current, the rotor drops
onto the backup bearings (``LANDING_S`` simulated, recorded with FLAG_CONTROLLER_LOST
and FLAG_LANDED), a FATAL ``controller_lost`` event, the session failed.

Excitation supervision. Where a design says a sample is excited, the plant
waits for its excitation block (where excitation lands never depends on
message timing), and simulated time stands still meanwhile. If the block
has not come after ``excitation_timeout_s`` of wall time (+ up to two watchdog
periods), the excitation generator is taken as lost: a FATAL
``excitation_lost`` event naming the experiment and sample, the block so far
published as final, the session failed; the samples before stay recorded.

Amplifier limits. A sample whose current reference u = ic + r exceeds the
amplifier limit is applied saturated, as a real amplifier does, but recorded
as commanded (u is never altered in the measurement) and flagged
FLAG_CLIPPED; each block with clipped samples gives one ``clipped`` event.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from ambid.plant.analytical import analytical_model
from ambid.plant.excitation_schedule import ExcitationSchedule
from ambid.plant.levitation import LevitationMonitor
from ambid.plant.rig import Rig
from ambid.plant.simulator import PlantSimulator
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from ambid_msgs.msg import ExcitationDesign, PlantDescription, Sample, SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid_nodes.conversions import (BadMessage, block_msg, check_design, check_excitation_block, statespace_to_msg,
                                     status_msg, time_msg)
from ambid_nodes.identity import LoopPartner, not_subscribed
from ambid_nodes.session_node import SessionNode
from ambid_nodes.loop_call import BoundKernel, ContextWord
from ambid_nodes.loop_kernels import (LOOP_COUNT, LOOP_GATE, LOOP_K, LOOP_LIMIT, LOOP_NO_LIMIT, LOOP_OUT, N_PK,
                                      PK_BLOCK_START, PK_CLOCK_EVERY, PK_FREE_UNTIL, PK_LOOP, PK_R, PK_R_FIRST,
                                      PK_WORK, PLANT_AFTER, PLANT_CLIPPED, PLANT_CONTACT, PLANT_KIND, PLANT_LOOKUP,
                                      PLANT_STEPPED, plant_kernel, plant_loop_vector, sample_buffer)
from ambid_nodes.loop_pump import NOT_RUN, GatingState, LoopEntry
from ambid_nodes.parameters import declare, node_rig
from ambid_nodes.raw_publish import raw_publisher
from ambid_nodes.sample_codec import decode_sample, encode_clock, encode_sample

# the safe state recorded after a lost controller: the drop through the clearance takes ~7 ms at 1 g
LANDING_S = 0.05
STATUS_PERIOD_S = 1.0  # wall time between status messages while the loop does not run
STATUS_EVERY = 10_000  # while it runs: a status at the first block end past each multiple of this sample count

NONE = "none"  # an empty name list's one entry (an empty list parameter would have no type)
START_RETRY_S = 0.25  # wall time between re-sends of y[0] until the controller answers
# message constants, read once: the per-sample path must not pay rosidl's class properties
RUNNING, DONE, FAILED, IDLE = (SessionStatus.STATE_RUNNING, SessionStatus.STATE_DONE, SessionStatus.STATE_FAILED,
                               SessionStatus.STATE_IDLE)
FLAG_CLIPPED, FLAG_LANDED = SampleBlock.FLAG_CLIPPED, SampleBlock.FLAG_LANDED
FLAG_CONTROLLER_LOST = SampleBlock.FLAG_CONTROLLER_LOST
AFTER_LIFT_OFF_S = 0.5  # a run that ends before its second half is judged from this long after lift-off


class KernelSchedule(ExcitationSchedule):
    """The excitation schedule with the block in use (rows r[first + i] = rows[i]) and free_until (before
    it no sample outside that block is excited) kept in the plant kernel's context, where plant_kernel
    reads them."""

    first = ContextWord("fast", PK_R_FIRST)
    free_until = ContextWord("fast", PK_FREE_UNTIL)

    def __init__(self, fast: BoundKernel, n_channels: int) -> None:
        self.fast = fast
        self.n_channels = n_channels
        super().__init__(n_channels)

    @property
    def rows(self) -> np.ndarray:
        return self.fast._bound[PK_R]

    @rows.setter
    def rows(self, value: np.ndarray) -> None:  # (rows, na): plant_kernel reads them
        self.fast.bind(PK_R, value, np.float64, self.n_channels, writes=False)


class PlantSim(SessionNode):
    # what the compiled path reads lives in its context (loop_call): the sample index k the plant
    # steps next, and the excitation schedule's block in use (KernelSchedule)
    k = ContextWord("fast", LOOP_K)
    state = GatingState()  # each assignment sets the loop pump's gate (regate)
    buf_start = ContextWord("fast", PK_BLOCK_START)  # the sample index of the measurement block's row 0

    def __init__(self, *, rig: Rig | None = None, **kwargs) -> None:
        """``rig``: the rig a composed run parsed once (else the ``rig_file`` parameter's)."""
        super().__init__("plant_sim", **kwargs)
        self.fqn = self.get_fully_qualified_name()
        rig_file, nonlinear = self._declare_parameters()
        self.rig = node_rig(self, rig_file, rig)
        self.sim = PlantSimulator(self.rig, seed=self.seed, nonlinear_magnets=nonlinear)
        self.sim_work = self.sim.work
        # the rig's axes: the channels of every message and block (y, u, ic, r of each, in its order)
        self.layout = self.rig.layout
        self.na = na = len(self.layout)
        self.measurement_names = self.layout.measurement_names
        self.measurement_units = tuple(u for sig in ("y", "u", "ic", "r") for u in self.layout.units(sig))
        self.excitation_names = self.layout.excitations
        self.zero = (0.0,) * na
        self.dt = self.rig.dt
        self.n_total = int(round(self.sim_seconds / self.dt)) if self.sim_seconds > 0 else None
        self.last_k = self.n_total - 1 if self.n_total else LOOP_NO_LIMIT  # the final sample's index
        # the compiled path: loop_kernels.plant_kernel, run on each control message by the loop
        # pump (its gate open while the loop runs and nothing waits; k < last_k: the final sample
        # goes the Python way), or called with (message, k)
        self.fast = BoundKernel(plant_kernel, N_PK)
        self.fast_step = self.fast.call
        self.fast.set(LOOP_LIMIT, self.last_k)
        self._create_topics()
        self._create_loop_state()

    def _create_loop_state(self) -> None:
        """The loop's state: the compiled path's buffers, the loop entry, the controller's GID, the timers."""
        na = self.na
        self.k = 0
        # currents received for samples k and k + 1 (a pipelined controller answers one ahead), in order
        self.ic_ready: list[list[float]] = []
        # the held excitation blocks and the ranges designs excite: the plant waits for an excited
        # sample's block, so where the excitation lands never depends on message timing
        self.schedule = KernelSchedule(self.fast, na)
        self.excitation_rows = self.schedule.rows_at
        # the plant loop vector (loop_kernels.plant_loop_vector): y[k] as published with the last
        # current taken, and the block's rows (y, u, ic, r); y[k+1] is packed into out
        self.lp, self.cur, self.rec = plant_loop_vector(self.block_size, na)
        self.out = sample_buffer(na)
        self.fast.bind(PK_WORK, self.sim_work, np.float64)
        self.fast.bind(PK_LOOP, self.lp, np.float64)
        self.fast.bind(LOOP_OUT, self.out, np.uint8)
        self.fast.set(PK_CLOCK_EVERY, self.clock_every)
        self.ic_tally.count_also(self.fast.context[LOOP_COUNT:LOOP_COUNT + 1])
        # control_current: the loop pump runs plant_kernel, publishes y[k + 1] and counts in compiled code
        self.loop = LoopEntry(self, Sample, "control_current", qos.LOOP, self.pub_y, self.fast,
                              self.finish_control)
        self.sub_ic = self.loop.subscription
        # the session's controller by GID (the roster): another publisher's currents are dropped in C
        self.controller = LoopPartner(self.identity, self.loop.entry, self.sub_ic.get_topic_name(),
                                      self.finish_control, self.on_foreign_gid("control_current"), NOT_RUN)
        self.ic_tally.count_foreign_also(self.controller)
        self.row_flags: dict[int, int] = {}  # row -> FLAG_* where not 0
        self.buf_start = 0
        self.clipped_samples = 0
        self.controller_lost_after_s: float | None = None  # wall time without an answer when declared lost
        # judged over the second half of the run, or where it ended before, from 0.5 s after lift-off on
        self.monitor = LevitationMonitor(self.rig.backup_clearance_m,
                                         self.n_total // 2 if self.n_total else int(0.5 / self.dt),
                                         int(round(AFTER_LIFT_OFF_S / self.dt)))
        self.state = IDLE
        self.started_wall = None
        self.finished_wall = None
        self.last_answer_wall = None
        self.watch_k = -1  # the sample index the watchdog saw last
        self.exc_wait_k, self.exc_wait_wall = -1, 0.0  # the sample waiting for its excitation, since when
        self.summary: dict | None = None
        self.failure: dict | None = None  # code, text and sample_index of the FATAL event that ended the run
        self.finished = Future()  # completes with the summary when the run ends
        self.publish_description()
        self.start_timer = self.create_timer(0.05, self.try_start)
        self.start_retry = None  # the re-send of y[0] until the first answer (try_start)
        self.watchdog = self.create_timer(min(0.1, self.timeout / 2), self.check_controller)
        # recovery of a lost loop message: no clock is read per sample; this timer sees the loop stand still
        self.resends = 0  # times the plant asked again
        self.duplicate_answers = 0  # answers that came twice because it asked again
        self.start_retries = 0  # times it sent y[0] again before the first answer
        # [first, last] index of the currents that may come twice because the plant asked again (none yet)
        self.asked_again = (1, 0)
        self.resend_watch_k = -1
        self.resend_timer = self.create_timer(self.resend_after, self.resend_if_stalled)
        self.status_received = -1
        self.create_timer(STATUS_PERIOD_S, self.status_when_idle)
        self.identity.announce([self.pub_y, self.pub_block, self.pub_desc, self.pub_status, self.pub_event,
                                self.pub_clock])

    def _create_topics(self) -> None:
        """Publishers, intake and subscriptions (the loop entry comes with the loop state)."""
        self.pub_y = self.create_publisher(Sample, "displacement", qos.LOOP)
        self.publish_y_raw = raw_publisher(self.pub_y)
        publisher = self.identity.publisher  # its messages carry the session's id
        self.pub_block = publisher(SampleBlock, "measurement", qos.BLOCKS)
        self.pub_desc = publisher(PlantDescription, "plant/description", qos.LATCHED)
        self.pub_status = publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = publisher(SessionEvent, "events", qos.EVENTS)
        self.pub_clock = self.create_publisher(Clock, "/clock", qos.CLOCK)
        self.publish_clock_raw = raw_publisher(self.pub_clock)
        self.make_intake()
        self.ic_tally = self.intake.tally("control_current")
        self.intake.subscribe(SampleBlock, "excitation", self.on_excitation, qos.BLOCKS)
        self.intake.subscribe(ExcitationDesign, "excitation/design", self.on_design, qos.LATCHED)

    def _declare_parameters(self) -> tuple:
        """The node's typed parameters, then the session joined; (rig_file, nonlinear_magnets)."""
        rig_file = declare(self, "rig_file", "", "YAML rig parameter file; empty = the default rig")
        self.seed = declare(self, "seed", 0, "seed of the sensor noise", 0, 2**31 - 1)
        nonlinear = declare(self, "nonlinear_magnets", False, "use the nonlinear magnet force, eq. 2.14")
        self.sim_seconds = declare(self, "sim_seconds", 0.0, "simulated time to run; 0 = until stopped",
                                   0.0, 1e6, "s")
        self.block_size = declare(self, "block_size", 1000, "samples per measurement block", 1, 100_000)
        self.clock_every = declare(self, "clock_every", 100, "samples between /clock messages", 1, 100_000)
        self.timeout = declare(self, "controller_timeout_s", 2.0,
                               "wall time without an answer before the controller is declared lost",
                               0.01, 3600.0, "s")
        self.exc_timeout = declare(self, "excitation_timeout_s", 5.0,
                                   "wall time waiting for an excitation block a design says is due before the "
                                   "session fails", 0.01, 3600.0, "s")
        self.resend_after = declare(self, "resend_after_s", 0.02,
                                    "wall time the loop may stand still before the plant sends y[k - 1] and y[k] "
                                    "again (a lost message is recovered; the controller answers them again)",
                                    0.001, 60.0, "s")
        self.horizon = declare(self, "excitation_horizon", 1_000_000,
                               "most samples an excitation block may lie ahead of the plant (memory bound)",
                               1, 1_000_000_000)
        self.measurement_readers = declare(
            self, "measurement_readers", 0,
            "readers of the measurement the loop waits to be matched with before y[0] (a volatile topic: a reader "
            "matched later misses the first blocks)", 0, 1000)
        # by name too: the count alone is met by any other listener (a monitor, a test's) in place of one of them
        self.measurement_reader_nodes = [n for n in declare(
            self, "measurement_reader_nodes", [NONE],
            "nodes (names in the plant's namespace) the loop waits to see subscribed to the measurement before "
            "y[0], besides the count; [none]: none") if n != NONE]
        self.join_session()
        return rig_file, nonlinear

    def regate(self) -> None:
        """Open the loop pump's gate while it may take the next control message: the loop
        runs and no current waits for its excitation (run_ready and the state keep it current)."""
        self.fast.set(LOOP_GATE, int(self._state == RUNNING and not self.ic_ready))

    def destroy_node(self) -> None:
        self.loop.close()
        super().destroy_node()

    # --- set-up -----------------------------------------------------------
    def publish_description(self) -> None:
        r, lay = self.rig, self.layout
        self.pub_desc.publish(PlantDescription(
            stamp=time_msg(0.0), name=self.get_fully_qualified_name(), source="sim", rig_name=r.name,
            sample_period=self.dt, displacement_names=list(lay.outputs), current_names=list(lay.inputs),
            bias_current=[m.bias_current_a for m in r.axis_magnets()], current_limit=[r.current_limit_a] * self.na,
            backup_clearance=[c for _, c in r.backup_bearings()], analytical_model=statespace_to_msg(analytical_model(r)),
            seed=self.seed, controller_timeout_samples=0, rig_json=json.dumps(r.to_dict())))

    def try_start(self) -> None:
        # start once both directions are matched: neither y[0] nor the answer ic[0] may be lost; with a
        # session, once the roster names the session's controller (whose currents alone are taken)
        if (self.pub_y.get_subscription_count() < 1 or self.sub_ic.get_publisher_count() < 1
                or self.pub_block.get_subscription_count() < self.measurement_readers
                or not_subscribed(self, self.pub_block.topic_name, self.measurement_reader_nodes)
                or not self.controller.known):
            return
        self.start_timer.cancel()
        self.state = RUNNING
        self.started_wall = self.last_answer_wall = time.perf_counter()
        self.event(SessionEvent.INFO, "started", f"lock-step loop started, {self.describe_run()}")
        self.publish_y()
        # matched counts cannot tell the controller's subscription from another listener's (a
        # recorder, a monitor): until the first answer arrives, send the same y[0] again
        self.start_retry = self.create_timer(START_RETRY_S, self.resend_first_sample)

    def resend_first_sample(self) -> None:
        if self.k > 0 or self.state != RUNNING:
            self.start_retry.cancel()
            return
        self.start_retries += 1
        self.asked_again = (0, 1)  # y[0]'s answers: ic[0], and ic[1] from a pipelined controller
        self.publish_y_raw(self.y_bytes)

    def describe_run(self) -> str:
        t = f"{self.sim_seconds:g} s" if self.n_total else "until stopped"
        return f"rig {self.rig.name}, {self.rig.sample_rate_hz:g} Hz, {t}, seed {self.seed}, session {self.identity}"

    # --- the loop ---------------------------------------------------------
    def publish_y(self) -> None:
        """Publish y[0] (from then on step_and_record publishes each next y)."""
        self.cur[0:self.na] = self.sim.output()
        self.y_bytes = encode_sample(self.k, self.cur[0:self.na].tolist())
        self.publish_y_raw(self.y_bytes)

    def finish_control(self, data: bytes, code: int) -> None:
        """A control message the loop pump's kernel did not finish: ``code`` is what plant_kernel
        returned for sample k (not PLANT_STEPPED: the pump published that one), or NOT_RUN
        where it did not run (gate closed, the final sample)."""
        if code > 0 and self.stepped_compiled(self.k, code, data):
            return
        self.on_control_checked(data)

    def stepped_compiled(self, k: int, code: int, data: bytes) -> bool:
        """The rest of a sample the compiled path took (as step_and_record does), after looking up
        r[k] if it asked to; False if it did not step (the Python path decides)."""
        if code == PLANT_LOOKUP:
            if self.excitation_rows(k) is None:
                return False  # the excitation block has not arrived
            code = self.fast_step(data, k)  # the lookup set the block in use or the free range
        kind = code & PLANT_KIND
        if kind != PLANT_STEPPED and kind != PLANT_CONTACT:
            return False
        self.ic_tally.accepted += 1
        flags = FLAG_CLIPPED if code & PLANT_CLIPPED else 0
        self.k = k + 1
        if kind == PLANT_CONTACT:
            self.cur[0:self.na] = y = self.sim.finish_contact_sample()
            flags |= FLAG_LANDED
            self.publish_y_raw(encode_sample(k + 1, y))
        else:
            self.publish_y_raw(self.out)
        if flags:
            self.row_flags[k - self.buf_start] = flags
        if code & PLANT_AFTER:
            self.after_step(k + 1, False)
        return True

    def on_control_checked(self, data: bytes) -> None:
        """Every message the compiled path does not take: decided, reasons given, stepped if due."""
        ready = self.ic_ready
        running = self.state == RUNNING
        nxt = self.k + len(ready)  # the only index the plant can take now
        try:
            index, ic = decode_sample(data, self.na, "control_current")
        except BadMessage as exc:
            if exc.index != nxt or not running or len(ready) > 1:
                self.intake.reject("control_current", f"{exc} (sample {exc.index}, now {self.k})")
                return
            self.intake.reject("control_current", f"{exc}; holding the previous current for sample {nxt}")
            index, ic = nxt, (ready[-1] if ready else self.cur[self.na:2 * self.na].tolist())
        else:
            if index != nxt or not running or len(ready) > 1:
                self.refuse_control(index, nxt, running)
                return
            self.ic_tally.accepted += 1
        ready.append(ic)
        self.run_ready()

    def refuse_control(self, index: int, nxt: int, running: bool) -> None:
        intake = self.intake
        if self.state == DONE and index == self.k and not self.ic_ready:
            intake.accept("control_current")  # a pipelined controller's current for the sample after the run
            return
        first, last = self.asked_again
        if self.state != IDLE and first <= index <= last and index < nxt:
            # the second answer to a displacement sent again (also after the run's end): already applied
            intake.accept("control_current")
            self.duplicate_answers += 1
            return
        if not running:
            why = "the plant has not started" if self.state == IDLE else "the session has ended"
            intake.reject("control_current", f"control_current {index} received while {why} (sample {self.k})")
        elif index < nxt:
            intake.reject("control_current", f"control_current index {index}, expected {nxt} (stale or duplicated)")
        else:
            intake.reject("control_current", f"control_current index {index}, expected {nxt} (ahead of the "
                          "plant: a controller answers y[k] with ic[k] or ic[k + 1], or out of range)")

    def run_ready(self) -> None:
        """Step every sample whose current (and excitation, where a design excites it) is here."""
        ready = self.ic_ready
        excitation_rows = self.excitation_rows
        try:
            while ready and self.state == RUNNING:
                k = self.k
                exc = excitation_rows(k)
                if exc is None:
                    return  # waiting for the excitation generator; on_excitation resumes
                self.step_and_record(ready.pop(0), exc[0][exc[1]], 0, final=k == self.last_k)
                if k == self.last_k:
                    self.finish(DONE)
        finally:
            self.regate()

    def step_and_record(self, ic, r, flags: int, final: bool = False, publish: bool = True) -> None:
        """Apply u = ic + r over sample k (the amplifier saturates it), record y, u, ic, r as commanded;
        publish y[k + 1] unless this is the final sample (or ``publish`` is False: the safe state)."""
        k, na = self.k, self.na
        u = [a + b for a, b in zip(ic, r)]
        *y, clipped, contact = self.sim.step_output(*u)
        cur = self.cur
        self.rec[k - self.buf_start] = (*cur[0:na], *u, *ic, *r)
        if flags or clipped or contact:
            self.row_flags[k - self.buf_start] = (flags | (FLAG_CLIPPED if clipped else 0)
                                                  | (FLAG_LANDED if contact else 0))
        self.k = k = k + 1
        cur[0:2 * na] = (*y, *ic)
        if publish and not final:
            self.publish_y_raw(encode_sample(k, y))
        self.after_step(k, final)

    def after_step(self, k: int, final: bool) -> None:
        """Once the samples before k are done: the excitation block they used up, /clock, and the
        measurement block when full or final."""
        self.schedule.passed(k)
        if k % self.clock_every == 0:
            self.publish_clock_raw(encode_clock(k * self.dt))
        if k - self.buf_start == self.block_size or final:
            self.flush_block(final=final)

    def flush_block(self, final: bool = False) -> None:
        n = self.k - self.buf_start
        if n <= 0:
            return
        buf = self.rec[:n]  # y, u, ic, r: the measurement channels (block_msg copies it)
        flags = np.zeros(n, dtype=np.uint8)
        for row, f in self.row_flags.items():
            flags[row] = f
        self.row_flags = {}
        self.report_clipping(buf, flags)
        # judged: the run under control; the safe state's landing after a lost controller is recorded, not judged
        lost = np.flatnonzero(flags & FLAG_CONTROLLER_LOST)
        judged = int(lost[0]) if lost.size else n
        if judged:
            self.monitor.add_block(self.buf_start, buf[:judged, :self.na], flags[:judged] & FLAG_LANDED)
        self.pub_block.publish(block_msg(self.buf_start, self.dt, self.measurement_names, self.measurement_units, buf,
                                         flags, SampleBlock.FLAG_FINAL if final else 0))
        if self.k // STATUS_EVERY != self.buf_start // STATUS_EVERY:  # (finish() sends the final one)
            self.publish_status()
        self.buf_start = self.k

    def on_excitation(self, msg: SampleBlock) -> None:
        schedule = self.schedule
        data = check_excitation_block(msg, self.excitation_names, self.dt, self.k, self.horizon, schedule.starts,
                                      schedule.length, "plant")
        first, end = msg.first_index, msg.first_index + len(data)
        late = schedule.add_block(first, data, self.k)
        if late:
            self.event(SessionEvent.ERROR, "excitation_late",
                       f"excitation samples {first}..{first + late - 1} arrived after they were due (now {self.k}) "
                       "and were not applied; publish excitation further ahead")
            if late == len(data):
                raise BadMessage(f"excitation: samples [{first}, {end}) arrived after they were due (now {self.k})")
        self.run_ready()

    def on_design(self, msg: ExcitationDesign) -> None:
        check_design(msg, self.dt)
        try:
            self.schedule.add_design(msg.experiment_id, msg.start_index, msg.total_samples, self.k)
        except ValueError as exc:
            raise BadMessage(str(exc)) from None
        self.run_ready()

    # --- supervision ------------------------------------------------------
    def resend_if_stalled(self) -> None:
        """Ask again where the loop stood still for a whole ``resend_after_s`` period waiting for the
        controller: send y[k - 1] and y[k] again, as first sent. Whichever of them, or of the answers,
        was lost, the controller answers the one it has not seen and repeats the answers it gave
        (ic[k] answers y[k] or, pipelined, y[k - 1]), so the loop goes on with the very numbers it
        would have had: a lost message costs one to two ``resend_after_s`` periods, nothing else."""
        k = self.k
        if self.state != RUNNING or self.ic_ready or k == 0:  # not waiting for the controller (k = 0: the start)
            self.resend_watch_k = -1
            return
        if k != self.resend_watch_k:
            self.resend_watch_k = k
            return
        self.resends += 1
        # the answers to y[k - 1] and y[k]: ic[k - 1] .. ic[k + 1] (a pipelined controller answers one ahead);
        # those of an earlier request that may still be on their way stay expected
        first, last = self.asked_again
        self.asked_again = (first if last >= k - 2 else k - 1, k + 1)
        row = k - 1 - self.buf_start
        prev = self.rec[row if row >= 0 else self.block_size - 1]  # y[k - 1]: the previous block's last row
        self.publish_y_raw(encode_sample(k - 1, prev[0:self.na].tolist()))
        self.publish_y_raw(encode_sample(k, self.cur[0:self.na].tolist()))

    def check_controller(self) -> None:
        if self.state != RUNNING or self.last_answer_wall is None:
            return
        now = time.perf_counter()
        if self.ic_ready or self.k != self.watch_k:
            # progress, or waiting for the excitation generator, not for the controller: the loop
            # reads no clock per sample, so the last answer is dated to the watchdog tick that saw it
            self.watch_k, self.last_answer_wall = self.k, now
            if self.ic_ready:
                self.check_excitation(now)
            return
        quiet = now - self.last_answer_wall
        if quiet > self.timeout:
            self.controller_lost_after_s = quiet
            self.fatal("controller_lost",
                       f"no control current for sample {self.k} within {self.timeout:g} s ({quiet:.3f} s quiet): "
                       "safe state, control current zero, the rotor lands on the backup bearings")
            self.land()
            self.finish(FAILED)

    def check_excitation(self, now: float) -> None:
        """The plant waits for sample k's excitation block: fail the session once it waited too long."""
        k = self.k
        if k != self.exc_wait_k:
            self.exc_wait_k, self.exc_wait_wall = k, now  # dated to this tick, as the answers are
            return
        waited = now - self.exc_wait_wall
        if waited <= self.exc_timeout:
            return
        exp = self.schedule.experiment_at(k)
        self.fatal("excitation_lost",
                   f"no excitation block for sample {k} of experiment {exp!r} within {self.exc_timeout:g} s "
                   f"({waited:.3f} s waiting): the excitation generator is lost or stalled; the session ends "
                   f"failed at sample {k}, every sample before it recorded (simulated time stood still while "
                   "the plant waited)")
        self.ic_ready.clear()
        self.flush_block(final=True)
        self.finish(FAILED)

    def land(self) -> None:
        """The safe state: zero control current for LANDING_S simulated, the rotor drops onto the retainer; recorded."""
        n = max(1, int(round(LANDING_S / self.dt)))
        for i in range(n):
            self.step_and_record(self.zero, self.zero, SampleBlock.FLAG_CONTROLLER_LOST, final=i == n - 1,
                                 publish=False)

    def report_clipping(self, buf: np.ndarray, flags: np.ndarray) -> None:
        """One event per block with clipped samples: where, how many, the largest commanded |u|."""
        n = len(buf)
        clipped = np.flatnonzero(flags & FLAG_CLIPPED)
        if clipped.size == 0:
            return
        self.clipped_samples += int(clipped.size)
        peak = float(np.abs(buf[clipped, self.na:2 * self.na]).max())
        first = self.buf_start + int(clipped[0])
        self.event(SessionEvent.WARN, "clipped",
                   f"{clipped.size} of {n} samples in [{self.buf_start}, {self.buf_start + n}) exceeded the amplifier "
                   f"limit {self.rig.current_limit_a:g} A (first at sample {first}, commanded |u| up to {peak:.3g} A): "
                   "applied saturated, recorded as commanded and flagged FLAG_CLIPPED; reduce the excitation",
                   index=first)

    def on_foreign_gid(self, topic: str):
        """The report of a loop topic's foreign publisher (its messages are counted in C)."""
        return lambda gid: self.intake.foreign(topic, gid=gid, count=False)

    def fatal(self, code: str, text: str) -> None:
        """The event that ends the run, kept for the summary."""
        self.failure = {"code": code, "text": text, "sample_index": self.k}
        self.event(SessionEvent.FATAL, code, text)


    def event_index(self) -> int:
        return self.k

    def figures(self) -> dict:
        wall = (self.finished_wall or time.perf_counter()) - (self.started_wall or time.perf_counter())
        return {**self.monitor.figures(), "samples": self.k, "simulated_s": self.k * self.dt, "wall_s": wall,
                "samples_per_wall_s": self.k / wall if wall > 0 else 0.0,
                "messages_received": self.intake.total_received, "messages_rejected": self.intake.total_rejected,
                "clipped_samples": self.clipped_samples, "controller_lost_after_s": self.controller_lost_after_s,
                "resends": self.resends, "start_retries": self.start_retries,
                "duplicate_answers": self.duplicate_answers,
                **self.intake.figures()}

    def status_when_idle(self) -> None:
        if self.state != RUNNING and self.intake.total_received != self.status_received:
            self.publish_status()

    def publish_status(self) -> None:
        self.status_received = self.intake.total_received
        f = self.figures()
        progress = self.k / self.n_total if self.n_total else -1.0
        text = (f"t={f['simulated_s']:.3f} s, {f['samples_per_wall_s']:.0f} samples/s, "
                f"rms {f['displacement_rms_m'] * 1e6:.2f} um, rejected {self.intake.total_rejected}")
        self.pub_status.publish(status_msg(
            time_msg(self.k * self.dt), self.fqn, self.state, self.k, progress, self.intake.total_received,
            self.intake.total_rejected, text, f))

    def finish(self, state: int) -> None:
        self.finished_wall = time.perf_counter()
        if state == DONE and not self.monitor.levitated():
            state = FAILED
            self.event(SessionEvent.ERROR, "not_levitated", "the rotor did not stay levitated")
        self.state = state
        self.summary = {**self.figures(), "state": "done" if state == DONE else "failed", "failure": self.failure}
        self.publish_status()
        self.event(SessionEvent.INFO, "finished", json.dumps(self.summary))
        self.start_timer.cancel()
        self.watchdog.cancel()
        self.resend_timer.cancel()
        if self.start_retry is not None:  # a run that ended before its first answer, or a timer still armed
            self.start_retry.cancel()
        self.finished.set_result(self.summary)


main = PlantSim.main  # the console script: SessionNode.main


if __name__ == "__main__":
    sys.exit(main())
