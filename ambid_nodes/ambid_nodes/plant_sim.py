"""plant_sim: the simulated AMB rig, owner of the sample clock.

Lock-step on the sample index: publishes y[k] on ``displacement``, waits for
the controller's ic[k] on ``control_current``, applies u = ic + r over the
next sample period and steps. Publishes measurement blocks (y, u, ic, r),
``/clock``, a latched ``plant/description``, ``status`` and ``events``.

A control message with the wrong index, channel count or a NaN is rejected
(counted, logged, reported as an event) and the previous valid current is held
for that sample. A controller silent for ``controller_timeout`` seconds of wall
time makes the plant go to its safe state: in simulation the rotor is dropped
onto the backup bearings (zero control current) and the session is marked failed.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import rclpy
from ambid_msgs.msg import ExcitationDesign, PlantDescription, Sample, SampleBlock, SessionEvent, SessionStatus
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from ambid.rig import AXES, CURRENT_NAMES, DISPLACEMENT_NAMES, analytical_model, load_rig, make_rig
from ambid.simulator import PlantSimulator
from ambid_nodes import qos
from ambid_nodes.conversions import BadMessage, block_data, block_msg, statespace_to_msg, time_msg
from ambid_nodes.parameters import declare, refuse_unknown
from ambid_nodes.sample_codec import decode_sample, encode_sample
from ambid.levitation import LevitationMonitor

MEASUREMENT_NAMES = (DISPLACEMENT_NAMES + CURRENT_NAMES + tuple(f"ic_{a}" for a in AXES)
                     + tuple(f"r_{a}" for a in AXES))
MEASUREMENT_UNITS = ("m",) * 4 + ("A",) * 12
EXCITATION_NAMES = tuple(f"r_{a}" for a in AXES)


class PlantSim(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("plant_sim", **kwargs)
        rig_file = declare(self, "rig_file", "", "YAML rig parameter file; empty = the default rig")
        self.seed = declare(self, "seed", 0, "seed of the sensor noise", 0, 2**31 - 1)
        nonlinear = declare(self, "nonlinear_magnets", False, "use the nonlinear magnet force, eq. 2.14")
        self.sim_seconds = declare(self, "sim_seconds", 0.0, "simulated time to run; 0 = until stopped",
                                   0.0, 1e6, "s")
        self.block_size = declare(self, "block_size", 1000, "samples per measurement block", 1, 100_000)
        self.clock_every = declare(self, "clock_every", 100, "samples between /clock messages", 1, 100_000)
        self.timeout = declare(self, "controller_timeout", 2.0,
                               "wall time without an answer before the controller is declared lost",
                               0.01, 3600.0, "s")
        refuse_unknown(self)
        self.rig = load_rig(rig_file) if rig_file else make_rig()
        self.sim = PlantSimulator(self.rig, seed=self.seed, nonlinear_magnets=nonlinear)
        self.dt = self.rig.dt
        self.n_total = int(round(self.sim_seconds / self.dt)) if self.sim_seconds > 0 else None

        self.pub_y = self.create_publisher(Sample, "displacement", qos.LOOP)
        self.pub_block = self.create_publisher(SampleBlock, "measurement", qos.BLOCKS)
        self.pub_desc = self.create_publisher(PlantDescription, "plant/description", qos.LATCHED)
        self.pub_status = self.create_publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.create_publisher(SessionEvent, "events", qos.EVENTS)
        self.pub_clock = self.create_publisher(Clock, "/clock", qos.CLOCK)
        self.sub_ic = self.create_subscription(Sample, "control_current", self.on_control, qos.LOOP, raw=True)
        self.create_subscription(SampleBlock, "excitation", self.on_excitation, qos.BLOCKS)
        self.create_subscription(ExcitationDesign, "excitation/design", self.on_design, qos.LATCHED)

        self.k = 0
        self.ic_last = [0.0] * 4
        self.excitation: dict[int, np.ndarray] = {}  # first_index -> (n, 4) block, consumed in order
        # sample ranges [start, end) a design says are excited: the plant waits for their blocks,
        # so where the excitation lands never depends on message timing
        self.excited_ranges: dict[str, tuple[int, int]] = {}
        self.pending_ic: list[float] | None = None
        self.buf = np.zeros((self.block_size, len(MEASUREMENT_NAMES)))
        self.buf_flags = np.zeros(self.block_size, dtype=np.uint8)
        self.buf_start = 0
        self.received = 0
        self.rejected = 0
        self.monitor = LevitationMonitor(self.rig.backup_clearance_m,
                                         self.n_total // 2 if self.n_total else int(0.5 / self.dt))
        self.state = SessionStatus.STATE_IDLE
        self.started_wall = None
        self.finished_wall = None
        self.last_answer_wall = None
        self.summary: dict | None = None
        self.finished = Future()  # completes with the summary when the run ends
        self.publish_description()
        self.start_timer = self.create_timer(0.05, self.try_start)
        self.watchdog = self.create_timer(min(0.1, self.timeout / 2), self.check_controller)

    # --- set-up -----------------------------------------------------------
    def publish_description(self) -> None:
        r = self.rig
        self.pub_desc.publish(PlantDescription(
            stamp=time_msg(0.0), name=self.get_fully_qualified_name(), source="sim", rig_name=r.name,
            sample_period=self.dt, displacement_names=list(DISPLACEMENT_NAMES), current_names=list(CURRENT_NAMES),
            bias_current=[r.bias_current_a] * 4, current_limit=[r.current_limit_a] * 4,
            backup_clearance=[r.backup_clearance_m] * 2, analytical_model=statespace_to_msg(analytical_model(r)),
            seed=self.seed, controller_timeout_samples=0, rig_json=json.dumps(r.to_dict())))

    def try_start(self) -> None:
        # start once both directions are matched: neither y[0] nor the answer ic[0] may be lost
        if self.pub_y.get_subscription_count() < 1 or self.sub_ic.get_publisher_count() < 1:
            return
        self.start_timer.cancel()
        self.state = SessionStatus.STATE_RUNNING
        self.started_wall = self.last_answer_wall = time.perf_counter()
        self.event(SessionEvent.INFO, "started", f"lock-step loop started, {self.describe_run()}")
        self.publish_y()

    def describe_run(self) -> str:
        t = f"{self.sim_seconds:g} s" if self.n_total else "until stopped"
        return f"rig {self.rig.name}, {1 / self.dt:g} Hz, {t}, seed {self.seed}"

    # --- the loop ---------------------------------------------------------
    def publish_y(self) -> None:
        self.y = self.sim.output()
        self.pub_y.publish(encode_sample(self.k, self.y.tolist()))

    def on_control(self, data: bytes) -> None:
        self.received += 1
        if self.state != SessionStatus.STATE_RUNNING:
            return
        try:
            index, ic = decode_sample(data, 4, "control_current")
        except BadMessage as exc:
            if exc.index != self.k:
                self.reject(f"{exc} (sample {exc.index}, now {self.k})")
                return
            self.reject(f"{exc}; holding the previous current for sample {self.k}")
            index, ic = self.k, self.ic_last
        if index != self.k:
            self.reject(f"control_current index {index}, expected {self.k} (stale or duplicated)")
            return
        self.last_answer_wall = time.perf_counter()
        self.ic_last = ic
        if self.excited_ranges and not self.has_excitation(self.k):
            self.pending_ic = ic  # resumed by on_excitation
            return
        self.advance(ic)

    def needs_excitation(self, k: int) -> bool:
        return any(a <= k < b for a, b in self.excited_ranges.values())

    def has_excitation(self, k: int) -> bool:
        if not self.needs_excitation(k):
            return True
        return any(first <= k < first + len(b) for first, b in self.excitation.items())

    def excitation_at(self, k: int) -> list[float]:
        for first, block in self.excitation.items():
            if first <= k < first + len(block):
                if k == first + len(block) - 1:
                    del self.excitation[first]
                return block[k - first].tolist()
        return [0.0, 0.0, 0.0, 0.0]

    def advance(self, ic: list[float]) -> None:
        k = self.k
        r = self.excitation_at(k) if self.excitation else [0.0, 0.0, 0.0, 0.0]
        u = [ic[0] + r[0], ic[1] + r[1], ic[2] + r[2], ic[3] + r[3]]
        clipped, contact = self.sim.step(u)
        row = k - self.buf_start
        self.buf[row] = (*self.y.tolist(), *u, *ic, *r)
        self.buf_flags[row] = (SampleBlock.FLAG_CLIPPED if clipped else 0) | (SampleBlock.FLAG_LANDED if contact else 0)
        self.k = k + 1
        if self.k % self.clock_every == 0:
            self.pub_clock.publish(Clock(clock=time_msg(self.k * self.dt)))
        done = self.n_total is not None and self.k >= self.n_total
        if row + 1 == self.block_size or done:
            self.flush_block(final=done)
        if done:
            self.finish(SessionStatus.STATE_DONE)
        else:
            self.publish_y()

    def flush_block(self, final: bool = False) -> None:
        n = self.k - self.buf_start
        if n <= 0:
            return
        self.monitor.add_block(self.buf_start, self.buf[:n, :4], self.buf_flags[:n] & SampleBlock.FLAG_LANDED)
        self.pub_block.publish(block_msg(self.buf_start, self.dt, MEASUREMENT_NAMES, MEASUREMENT_UNITS, self.buf[:n],
                                         self.buf_flags[:n], SampleBlock.FLAG_FINAL if final else 0))
        self.buf_start = self.k
        self.publish_status()

    def on_excitation(self, msg: SampleBlock) -> None:
        self.received += 1
        try:
            data = block_data(msg, EXCITATION_NAMES)
        except BadMessage as exc:
            self.reject(f"excitation: {exc}")
            return
        first = msg.first_index
        if first < self.k:
            late = min(self.k - first, len(data))
            self.event(SessionEvent.ERROR, "excitation_late",
                       f"excitation samples {first}..{first + late - 1} arrived after they were due (now {self.k}) "
                       "and were not applied; publish excitation further ahead")
            if late == len(data):
                self.rejected += 1
                return
            first, data = first + late, data[late:]
        self.excitation[first] = data
        self.resume()

    def on_design(self, msg: ExcitationDesign) -> None:
        self.received += 1
        end = msg.start_index + msg.total_samples
        if msg.total_samples == 0 or end <= self.k:
            self.excited_ranges.pop(msg.experiment_id, None)
        else:
            self.excited_ranges[msg.experiment_id] = (msg.start_index, end)
        self.resume()

    def resume(self) -> None:
        if self.pending_ic is not None and self.has_excitation(self.k):
            ic, self.pending_ic = self.pending_ic, None
            self.advance(ic)

    # --- supervision ------------------------------------------------------
    def check_controller(self) -> None:
        if self.state != SessionStatus.STATE_RUNNING or self.last_answer_wall is None:
            return
        if self.pending_ic is not None:
            return  # waiting for the excitation generator, not for the controller
        if time.perf_counter() - self.last_answer_wall > self.timeout:
            self.event(SessionEvent.FATAL, "controller_lost",
                       f"no control current for sample {self.k} within {self.timeout:g} s: "
                       "safe state, control current zero, the rotor lands on the backup bearings")
            self.land()
            self.flush_block(final=True)
            self.finish(SessionStatus.STATE_FAILED)

    def land(self) -> None:
        # simulate the drop on the retainer: zero control current for 0.2 s
        for _ in range(int(0.2 / self.dt)):
            self.sim.step([0.0, 0.0, 0.0, 0.0])

    def reject(self, why: str) -> None:
        self.rejected += 1
        self.get_logger().warn(f"rejected message ({self.rejected} so far): {why}",
                               throttle_duration_sec=1.0)
        self.event(SessionEvent.WARN, "rejected_message", why)

    def event(self, severity: int, code: str, text: str) -> None:
        self.pub_event.publish(SessionEvent(stamp=time_msg(self.k * self.dt), sample_index=self.k, severity=severity,
                                            node=self.get_fully_qualified_name(), code=code, text=text))

    def figures(self) -> dict:
        wall = (self.finished_wall or time.perf_counter()) - (self.started_wall or time.perf_counter())
        return {**self.monitor.figures(), "samples": self.k, "simulated_s": self.k * self.dt, "wall_s": wall,
                "samples_per_wall_s": self.k / wall if wall > 0 else 0.0,
                "messages_received": self.received, "messages_rejected": self.rejected}

    def publish_status(self) -> None:
        f = self.figures()
        progress = self.k / self.n_total if self.n_total else -1.0
        text = (f"t={f['simulated_s']:.3f} s, {f['samples_per_wall_s']:.0f} samples/s, "
                f"rms {f['displacement_rms_m'] * 1e6:.2f} um, rejected {self.rejected}")
        self.pub_status.publish(SessionStatus(
            stamp=time_msg(self.k * self.dt), node=self.get_fully_qualified_name(), state=self.state,
            sample_index=self.k, progress=progress, messages_received=self.received,
            messages_rejected=self.rejected, text=text,
            keys=list(f), values=[json.dumps(v) for v in f.values()]))

    def finish(self, state: int) -> None:
        self.finished_wall = time.perf_counter()
        if state == SessionStatus.STATE_DONE and not self.monitor.levitated():
            state = SessionStatus.STATE_FAILED
            self.event(SessionEvent.ERROR, "not_levitated", "the rotor did not stay levitated")
        self.state = state
        self.summary = {**self.figures(), "state": "done" if state == SessionStatus.STATE_DONE else "failed"}
        self.publish_status()
        self.event(SessionEvent.INFO, "finished", json.dumps(self.summary))
        self.start_timer.cancel()
        self.watchdog.cancel()
        self.finished.set_result(self.summary)


def main(args=None) -> int:
    from ambid_nodes.node_main import run_single
    return run_single(PlantSim, args)


if __name__ == "__main__":
    sys.exit(main())
