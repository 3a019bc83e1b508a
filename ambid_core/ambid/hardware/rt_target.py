"""A simulated real-time target: the AMB rig and its position controller served over UDP.

Stands in for the dSPACE / FPGA / microcontroller that runs the fast loop
of a real rig. It speaks :mod:`ambid.hardware.bridge_protocol` to one hardware
bridge and, per sample k (the order of the lock-step ``plant_sim`` graph,
so a lossless session records the same numbers for the same seed)::

    y[k]  = sim.output()
    ic[k] = controller.step(y[k])
    r[k]  = excitation tagged with index k (0 if none)
    u[k]  = ic[k] + r[k];  sim.step(u[k])

and sends the rows (y, u, ic, r) in MEASUREMENT datagrams of ``block``
samples, a HEARTBEAT every ``heartbeat`` seconds and on every state
change, and an ACK per COMMAND.

Timing (``pace``): 1.0 runs in real time (sample k is due at
t_start + k dt; Python cannot sleep 100 us accurately, so samples are
computed in bursts of about 1 ms and never skipped: a target that falls
more than 10 ms behind counts an overrun and catches up); 0 runs as fast
as it can (free-running).

Excitation: blocks are buffered by their first sample index and applied at
exactly that index, however early they arrive. At a sample of an announced
experiment (COMMAND EXPERIMENT) whose excitation has not arrived, a real
target cannot wait: it applies r = 0 and flags the sample
FLAG_EXCITATION_LATE, and its heartbeat asks for the missing index
(``excitation_next``). Only in free-running mode, ``hold_for_excitation``
makes the clock wait for it instead (deterministic, like ``plant_sim``).

Safe state (SAFE_STATE command, or no datagram from the bridge for
``bridge_timeout`` s while running): zero current reference (ic = r = 0,
controller no longer applied), rows flagged FLAG_SAFE_STATE; after
``safe_seconds`` of simulated landing the clock stops. Datagrams from any
address but the configured bridge are dropped and counted.

Authentication: protocol version 3 seals every datagram with the rig's key
(``key_file``) and accepts only those of the session its handshake agreed
(:mod:`ambid.hardware.link_session`); a refused datagram is counted by
reason (``rx_rejected_by_reason``: auth, session, replay, duplicate, ...),
and the heartbeat tells the bridge. Version 2 (asked for by both ends) is
unauthenticated, which ``main`` says on every start.

Fault injection for tests (outgoing datagrams, reproducible by
``fault_seed``, one random stream per kind): ``drop``, ``corrupt`` (one bit
flipped), ``duplicate``, ``reorder`` (held back behind the next 1 ..
``reorder_depth`` datagrams of its kind) probabilities, and ``mute_at`` /
``mute_seconds``: send nothing for a while from sample ``mute_at`` on.

Run: ``python -m ambid.hardware.rt_target --bind 127.0.0.1:PORT --bridge 127.0.0.1:PORT2 [options]``; it
prints ``RT_TARGET_SUMMARY {json}`` when it exits (``--linger`` s after its clock stopped, on
SIGINT/SIGTERM).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import dataclasses
import json
import math
import select
import signal
import socket
import sys
import threading
import time
import types
from dataclasses import dataclass

import numpy as np

from ambid.hardware import bridge_protocol as bp
from ambid.hardware.link_key import read_key_file
from ambid.hardware.link_session import LinkEnd, link_words

SUMMARY_PREFIX = "RT_TARGET_SUMMARY "
MAX_BURST = 100          # samples between two looks at the socket
BURST_S = 0.001          # paced: wake up when this much simulated time is due (Python sleeps ~0.1-1 ms late)
LAG_OVERRUN_S = 0.01     # behind schedule by more than this: an overrun


def parse_address(text: str) -> tuple[str, int]:
    """``host:port`` -> (IPv4 address, port)."""
    host, sep, port = str(text).rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"address {text!r} must be host:port with a port in 0..65535, e.g. 127.0.0.1:50001")
    try:
        return socket.gethostbyname(host or "0.0.0.0"), int(port)
    except OSError as exc:
        raise ValueError(f"address {text!r}: cannot resolve host {host!r} ({exc})") from None


@dataclass(frozen=True)
class TargetConfig:
    """Everything a target session depends on (times in s, probabilities in [0, 1])."""

    bind: str = "127.0.0.1:50001"
    bridge: str = "127.0.0.1:50002"
    seed: int = 0
    rig_file: str = ""
    nonlinear_magnets: bool = False
    pace: float = 1.0
    samples: int = 0                 # stop after this many samples; 0 = until STOP
    block: int = 10                  # samples per MEASUREMENT datagram
    float32: bool = False
    heartbeat: float = 0.05
    bridge_timeout: float = 0.5
    safe_seconds: float = 0.2
    hold_for_excitation: bool = False
    linger: float = 1.0              # seconds to keep heart-beating once the clock stopped; 0 = until STOP
    protocol_version: int = bp.PROTOCOL_VERSION
    key_file: str = ""               # the rig's key (protocol version 3)
    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_depth: int = 3
    fault_seed: int = 0
    mute_at: int = -1                # sample index at which the target goes silent; -1 = never
    mute_seconds: float = 0.0

    def __post_init__(self) -> None:
        parse_address(self.bind)
        parse_address(self.bridge)
        value_bytes = 4 if self.float32 else 8
        limits = {
            "pace": (self.pace, 0.0, 1e3), "heartbeat": (self.heartbeat, 1e-3, 10.0),
            "bridge_timeout": (self.bridge_timeout, 1e-3, 3600.0), "safe_seconds": (self.safe_seconds, 0.0, 60.0),
            "linger": (self.linger, 0.0, 3600.0), "mute_seconds": (self.mute_seconds, 0.0, 3600.0),
            "drop": (self.drop, 0.0, 1.0), "corrupt": (self.corrupt, 0.0, 1.0),
            "duplicate": (self.duplicate, 0.0, 1.0), "reorder": (self.reorder, 0.0, 1.0),
            # the rig's axes set the true limit (Target checks it); one axis allows the most
            "block": (self.block, 1, bp.max_block_samples(bp.Kind.MEASUREMENT, value_bytes, 1)),
            "samples": (self.samples, 0, 2**62), "seed": (self.seed, 0, 2**63 - 1),
            "fault_seed": (self.fault_seed, 0, 2**63 - 1), "reorder_depth": (self.reorder_depth, 1, 100),
            "protocol_version": (self.protocol_version, 1, max(bp.SUPPORTED_VERSIONS)),
            "mute_at": (self.mute_at, -1, 2**62),
        }
        for name, (v, lo, hi) in limits.items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"rt_target: {name} = {v!r} is outside [{lo}, {hi}]")
        if self.drop + self.corrupt + self.duplicate + self.reorder > 1.0:
            raise ValueError("rt_target: drop + corrupt + duplicate + reorder must not exceed 1")
        if self.hold_for_excitation and self.pace != 0:
            raise ValueError("rt_target: hold_for_excitation needs pace 0 (a real-time target cannot wait)")
        if self.protocol_version >= bp.AUTHENTICATED_VERSION and not self.key_file:
            raise ValueError(f"rt_target: protocol version {self.protocol_version} authenticates every datagram: give "
                             "--key-file KEY (the rig's key; 'ambid keygen --out FILE' writes one), or run "
                             "--protocol-version 2 on both ends for an unauthenticated link")
        if self.protocol_version < bp.AUTHENTICATED_VERSION and self.key_file:
            raise ValueError(f"rt_target: --key-file with protocol version {self.protocol_version}: that version is "
                             "unauthenticated; speak version 3 with the key, or leave --key-file out")


class FaultInjector:
    """Decides the fate of each outgoing datagram of one kind: send, drop, corrupt, duplicate or reorder.

    ``submit(datagram, n_samples)`` returns the datagrams to put on the wire now, in order.
    Counts (datagrams, and samples for MEASUREMENT) are attributes.
    """

    def __init__(self, cfg: TargetConfig, kind: bp.Kind) -> None:
        self._rng = np.random.default_rng([cfg.fault_seed, int(kind)])
        p = (cfg.drop, cfg.corrupt, cfg.duplicate, cfg.reorder)
        self._edges = np.cumsum(p)
        self._active = sum(p) > 0
        self._depth = cfg.reorder_depth
        self._held: tuple[bytes, int] | None = None  # (datagram, datagrams still to pass it)
        self.sent = self.dropped = self.corrupted = self.duplicated = self.reordered = 0
        self.samples_dropped = 0  # samples in dropped or corrupted datagrams

    def submit(self, datagram: bytes, n_samples: int = 0) -> list[bytes]:
        self.sent += 1
        out = [datagram]
        if self._active:
            fate = int(np.searchsorted(self._edges, self._rng.random(), side="right"))
            if fate == 0:
                self.dropped += 1
                self.samples_dropped += n_samples
                out = []
            elif fate == 1:
                self.corrupted += 1
                self.samples_dropped += n_samples
                bit = int(self._rng.integers(len(datagram) * 8))
                bad = bytearray(datagram)
                bad[bit // 8] ^= 1 << (bit % 8)
                out = [bytes(bad)]
            elif fate == 2:
                self.duplicated += 1
                out = [datagram, datagram]
            elif fate == 3 and self._held is None:
                self.reordered += 1
                self._held = (datagram, 1 + int(self._rng.integers(self._depth)))
                return []
        if self._held is not None and out:
            held, left = self._held
            if left <= 1:
                out.append(held)
                self._held = None
            else:
                self._held = (held, left - 1)
        return out

    def flush(self) -> list[bytes]:
        """The held datagram, if any (before the target halts: nothing would release it)."""
        held, self._held = self._held, None
        return [held[0]] if held else []

    def counts(self) -> dict:
        return {"sent": self.sent, "dropped": self.dropped, "corrupted": self.corrupted,
                "duplicated": self.duplicated, "reordered": self.reordered}


class ExcitationBuffer:
    """Excitation blocks r (n, na) [A] by first sample index, looked up sample by sample."""

    def __init__(self) -> None:
        self._starts: list[int] = []
        self._blocks: dict[int, np.ndarray] = {}
        self._cur_first = self._cur_end = 0
        self._cur: np.ndarray | None = None
        self.late_datagrams = 0

    def __len__(self) -> int:
        return len(self._starts)

    def add(self, first: int, data: np.ndarray, now_index: int) -> None:
        """Buffer a block; the part before ``now_index`` (already applied) is cut off."""
        if first + len(data) <= now_index:
            self.late_datagrams += 1
            return
        if first < now_index:
            self.late_datagrams += 1
            data, first = data[now_index - first:], now_index
        if first not in self._blocks:
            bisect.insort(self._starts, first)
        self._blocks[first] = data
        if first == self._cur_first:
            self._cur = None  # replaced: look it up again

    def _find(self, k: int) -> tuple[int, np.ndarray] | None:
        i = bisect.bisect_right(self._starts, k) - 1
        if i >= 0:
            first = self._starts[i]
            data = self._blocks[first]
            if k < first + len(data):
                return first, data
        return None

    def at(self, k: int) -> list[float] | None:
        """r[k] (na floats) or None if no block covers k. Blocks ending before k are forgotten."""
        if self._cur is None or not self._cur_first <= k < self._cur_end:
            # forget what lies behind the clock
            while self._starts and self._starts[0] + len(self._blocks[self._starts[0]]) <= k:
                del self._blocks[self._starts.pop(0)]
            found = self._find(k)
            if found is None:
                self._cur = None
                return None
            self._cur_first, self._cur = found
            self._cur_end = self._cur_first + len(self._cur)
        return self._cur[k - self._cur_first].tolist()

    def first_missing(self, k: int, ranges) -> int | None:
        """First index >= k inside ``ranges`` [(start, end), ...] that no block covers, or None."""
        best = None
        for start, end in ranges:
            i = max(start, k)
            while i < end:
                found = self._find(i)
                if found is None:
                    best = i if best is None else min(best, i)
                    break
                i = found[0] + len(found[1])
        return best


class Target:
    """One target session over a bound UDP socket. ``run()`` serves until the session ends.

    Attributes read by tests and tools: ``address`` (bound host, port), ``state``, ``k`` (samples
    done), ``rx_foreign``, ``rx_malformed``, ``refused`` (by reason), ``link``, ``late_excitation``,
    ``overruns``, ``muted_at``, ``quiet_from``.
    """

    def __init__(self, cfg: TargetConfig, stop: threading.Event | None = None) -> None:
        # imported here: the bridge node imports parse_address from this module without the simulator
        from ambid.control.pid import PidParameters, pid_controller
        from ambid.control.stepper import ControllerStepper
        from ambid.plant.rig import rig_or_default
        from ambid.plant.simulator import PlantSimulator

        self.cfg = cfg
        self.stop = stop or threading.Event()
        self.rig = rig_or_default(cfg.rig_file)
        self.dt = self.rig.dt
        self.sim = PlantSimulator(self.rig, seed=cfg.seed, nonlinear_magnets=cfg.nonlinear_magnets)
        self.n_axes = len(self.rig.layout)
        if cfg.protocol_version == 1 and self.n_axes != bp.V1_AXES:
            raise ValueError(f"rt_target: protocol version 1 carries {bp.V1_AXES} axes, the rig has {self.n_axes}; "
                             "speak version 2 (--protocol-version 2)")
        most = bp.max_block_samples(bp.Kind.MEASUREMENT, 4 if cfg.float32 else 8, self.n_axes, cfg.protocol_version)
        if cfg.block > most:
            raise ValueError(f"rt_target: block = {cfg.block} samples of {self.n_axes} axes exceed a datagram; "
                             f"give at most {most}")
        key = read_key_file(cfg.key_file) if cfg.key_file else None
        self.value_bytes = 4 if cfg.float32 else 8
        self.link = LinkEnd(bp.Sender.TARGET, cfg.protocol_version, key, self.n_axes, self.value_bytes)
        pid = PidParameters()
        self.ctl = ControllerStepper(pid_controller(pid, self.dt, self.rig.layout), pid.current_limit_a)
        self.bridge_addr = parse_address(cfg.bridge)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(parse_address(cfg.bind))
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self.faults = {k: FaultInjector(cfg, k) for k in bp.Kind}
        self.state = bp.TargetState.IDLE
        self.safe_reason = bp.SafeReason.NONE
        self.clock_running = False
        self.k = 0
        self.sent_end = 0
        self.excitation = ExcitationBuffer()
        self.ranges: dict[int, tuple[int, int]] = {}
        self.acks: dict[int, int] = {}  # command_id -> result, so a repeated command is answered alike
        self.rx = self.rx_foreign = 0
        self.refused: collections.Counter = collections.Counter()  # datagrams from the bridge refused, by reason
        self.late_excitation = self.overruns = 0
        self.safe_left = 0
        self.last_rx: float | None = None
        self.halted_at: float | None = None
        self.stop_requested = False
        self.t_start = 0.0
        self.k_start = 0
        self.behind = False
        self.muted_at: float | None = None  # when the mute began (monotonic) [s]
        self.quiet_from: float | None = None  # when the last datagram before the mute left (monotonic) [s]
        self.sent_at: float | None = None  # when the last datagram left (monotonic) [s]
        self.muted_until: float | None = None
        self.started_wall: float | None = None
        self.rows: list[tuple] = []  # (y, u, ic, r) of the samples not yet sent; plain floats: cheap per sample
        self.row_flags: list[int] = []
        self.next_hb = 0.0

    @property
    def rx_malformed(self) -> int:
        """Datagrams from the bridge's address refused (every reason)."""
        return sum(self.refused.values())

    # --- sending ----------------------------------------------------------
    def _send(self, kind: bp.Kind, msg_fields: dict, n_samples: int = 0) -> None:
        cls = {bp.Kind.MEASUREMENT: bp.Measurement, bp.Kind.HEARTBEAT: bp.Heartbeat, bp.Kind.ACK: bp.Ack}[kind]
        data = self.link.pack(cls(sequence=0, **msg_fields))
        if self.muted_until is not None:
            if time.monotonic() < self.muted_until:
                return  # muted: nothing leaves, as in a network outage (the sequence still counts)
            self.muted_until = None
        self._put(self.faults[kind].submit(data, n_samples))

    def _put(self, datagrams: list[bytes]) -> None:
        for d in datagrams:
            try:
                self.sock.sendto(d, self.bridge_addr)
                self.sent_at = time.monotonic()
            except OSError:
                pass  # nobody listening yet: UDP is fire and forget

    def heartbeat(self) -> None:
        self.next_hb = time.monotonic() + self.cfg.heartbeat
        if not self.link.established:
            return  # version 3 before the session: nothing to seal a heartbeat in
        nxt = self.excitation.first_missing(self.k, self.ranges.values()) if self.ranges else None
        r = self.refused
        self._send(bp.Kind.HEARTBEAT, dict(
            state=self.state, safe_reason=self.safe_reason, clock_running=self.clock_running,
            sample_rate_hz=int(round(self.rig.sample_rate_hz)), sample_index=self.k, sent_end=self.sent_end,
            excitation_next=bp.NO_INDEX if nxt is None else nxt,
            next_measurement_sequence=self.link.seq[bp.Kind.MEASUREMENT], rx_datagrams=self.rx,
            rx_rejected=self.rx_foreign + self.rx_malformed, late_excitation_samples=self.late_excitation,
            overruns=self.overruns, axes=self.n_axes, refused_auth=r["auth"], refused_session=r["session"],
            refused_replay=r["replay"], duplicates=r["duplicate"]))

    def send_block(self) -> None:
        n = len(self.rows)
        if n == 0:
            return
        self._send(bp.Kind.MEASUREMENT, dict(first_index=self.k - n, data=np.array(self.rows),
                                             sample_flags=np.array(self.row_flags, dtype=np.uint8)), n)
        self.sent_end = self.k
        self.rows, self.row_flags = [], []

    # --- receiving --------------------------------------------------------
    def receive(self) -> None:
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return  # e.g. ICMP port unreachable reported on this socket
            if addr != self.bridge_addr:
                self.rx_foreign += 1
                continue
            agreed = self.link.established
            try:
                msg = self.link.receive(data)
            except bp.ProtocolError as exc:
                self.refused[exc.reason] += 1
                continue
            self.rx += 1
            if isinstance(msg, bp.Hello):  # answered; not a sign of the bridge in the session
                reply = self.link.welcome(msg)
                if reply is not None:
                    self._put([reply])
                continue
            self.last_rx = time.monotonic()
            if isinstance(msg, bp.Excitation):
                self.excitation.add(msg.first_index, msg.data, self.k)
            elif isinstance(msg, bp.Command):
                self.command(msg)
            elif not isinstance(msg, bp.Heartbeat):
                self.refused["kind"] += 1  # MEASUREMENT or ACK never go to the target (version 2)
            if not agreed and self.link.established:
                self.heartbeat()  # the session is agreed: the bridge hears the target at once

    def command(self, c: bp.Command) -> None:
        result = self.acks.get(c.command_id)
        if result is None:
            result = self.execute(c)
            self.acks[c.command_id] = result
        self._send(bp.Kind.ACK, dict(command_id=c.command_id, code=c.code, result=result, state=self.state,
                                     sample_index=self.k))
        self.heartbeat()

    def execute(self, c: bp.Command) -> int:
        S = bp.TargetState
        if c.code == bp.CommandCode.START:
            if self.state == S.RUNNING:
                return bp.AckResult.OK
            if self.state != S.IDLE:
                return bp.AckResult.REFUSED
            self.state, self.clock_running = S.RUNNING, True
            self.t_start, self.k_start = time.monotonic(), self.k
            self.started_wall = time.perf_counter()
            return bp.AckResult.OK
        if c.code == bp.CommandCode.SAFE_STATE:
            if self.state in (S.RUNNING, S.IDLE):
                self.enter_safe(bp.SafeReason.COMMANDED)
            return bp.AckResult.OK
        if c.code == bp.CommandCode.STOP:
            if self.state != S.DONE:
                self.halt(S.DONE)
            self.stop_requested = True  # leave once the ACK is out
            return bp.AckResult.OK
        if c.code == bp.CommandCode.EXPERIMENT:
            if c.arg1 == 0:
                self.ranges.pop(c.arg2, None)
            elif c.arg0 + c.arg1 >= bp.NO_INDEX:
                return bp.AckResult.BAD_ARGUMENT
            else:
                self.ranges[c.arg2] = (c.arg0, c.arg0 + c.arg1)
            return bp.AckResult.OK
        return bp.AckResult.BAD_ARGUMENT

    # --- state ------------------------------------------------------------
    def enter_safe(self, reason: bp.SafeReason) -> None:
        was_running = self.state == bp.TargetState.RUNNING
        self.state, self.safe_reason = bp.TargetState.SAFE, reason
        self.safe_left = int(round(self.cfg.safe_seconds / self.dt)) if was_running else 0
        if self.safe_left == 0:
            self.halt(bp.TargetState.SAFE)

    def halt(self, state: bp.TargetState) -> None:
        self.send_block()
        self.state, self.clock_running = state, False
        self.halted_at = time.monotonic()
        for inj in self.faults.values():
            self._put(inj.flush())
        self.heartbeat()

    # --- the loop ---------------------------------------------------------
    def needs_excitation(self, k: int) -> bool:
        return any(a <= k < b for a, b in self.ranges.values())

    def run_samples(self, n: int) -> int:
        """Run up to n samples; returns how many ran (fewer when holding for excitation or halting)."""
        sim, ctl, exc = self.sim, self.ctl, self.excitation
        block = self.cfg.block
        zero = [0.0] * self.n_axes
        for i in range(n):
            k = self.k
            flag = 0
            if self.state == bp.TargetState.SAFE:
                y = sim.output()
                ic = r = zero
                flag = bp.FLAG_SAFE_STATE
                self.safe_left -= 1
            else:
                r = exc.at(k) if exc else None
                if r is None:
                    if self.ranges and self.needs_excitation(k):
                        if self.cfg.hold_for_excitation:
                            return i
                        flag = bp.FLAG_EXCITATION_LATE
                        self.late_excitation += 1
                    r = zero
                y = sim.output()
                ic = ctl.step(y)
            u = [a + b for a, b in zip(ic, r)]
            clipped, contact = sim.step(u)
            self.rows.append((*y.tolist(), *u, *ic, *r))
            self.row_flags.append(flag | (bp.FLAG_CLIPPED if clipped else 0) | (bp.FLAG_LANDED if contact else 0))
            self.k = k + 1
            if self.cfg.mute_at == k:
                self.muted_at = time.monotonic()
                self.muted_until = self.muted_at + self.cfg.mute_seconds
                self.quiet_from = self.sent_at
            if len(self.rows) == block:
                self.send_block()
            if self.cfg.samples and self.k >= self.cfg.samples:
                self.halt(bp.TargetState.DONE)
                return i + 1
            if self.state == bp.TargetState.SAFE and self.safe_left <= 0:
                self.halt(bp.TargetState.SAFE)
                return i + 1
        return n

    def due_samples(self, now: float) -> int:
        if self.cfg.pace == 0:
            return MAX_BURST
        due = self.k_start + int((now - self.t_start) / (self.dt * self.cfg.pace)) + 1
        lag = due - self.k
        late = lag * self.dt * self.cfg.pace > LAG_OVERRUN_S
        if late and not self.behind:
            self.overruns += 1
        self.behind = late
        return max(0, min(lag, MAX_BURST))

    def run(self) -> dict:
        """Serve until STOP/linger/stop event; returns the summary."""
        cfg = self.cfg
        self.heartbeat()
        try:
            while not self.stop.is_set():
                self.receive()
                if self.stop_requested:
                    break
                now = time.monotonic()
                if (self.state == bp.TargetState.RUNNING and self.last_rx is not None
                        and now - self.last_rx > cfg.bridge_timeout):
                    self.enter_safe(bp.SafeReason.BRIDGE_SILENT)
                wait = max(0.0, self.next_hb - now)
                if self.clock_running:
                    n = self.due_samples(now)
                    ran = self.run_samples(n) if n else 0
                    if self.clock_running and (ran < n or cfg.pace > 0):
                        if ran < n:  # holding for excitation
                            wait = min(wait, 0.001)
                        else:  # sleep until a burst of ~1 ms of samples is due
                            period = self.dt * cfg.pace
                            burst = max(1, int(BURST_S / period))
                            next_due = self.t_start + (self.k + burst - 1 - self.k_start) * period
                            wait = min(wait, max(0.0, next_due - time.monotonic()))
                    elif self.clock_running:
                        wait = 0.0
                elif self.halted_at is not None and cfg.linger > 0 and now - self.halted_at > cfg.linger:
                    break
                if time.monotonic() >= self.next_hb:
                    self.heartbeat()
                    wait = 0.0
                if wait > 0:
                    select.select([self.sock], [], [], min(wait, 0.05))
        finally:
            self.sock.close()
        return self.summary()

    def summary(self) -> dict:
        wall = time.perf_counter() - self.started_wall if self.started_wall else 0.0
        m = self.faults[bp.Kind.MEASUREMENT]
        return {
            "state": bp.TargetState(self.state).name.lower(),
            "safe_reason": bp.SafeReason(self.safe_reason).name.lower(),
            "samples": self.k, "sent_end": self.sent_end, "wall_s": wall,
            "samples_per_wall_s": self.k / wall if wall > 0 else 0.0,
            "measurement_samples_dropped": m.samples_dropped,
            "faults": {k.name.lower(): inj.counts() for k, inj in self.faults.items()},
            "rx_datagrams": self.rx, "rx_foreign": self.rx_foreign, "rx_malformed": self.rx_malformed,
            "rx_rejected_by_reason": dict(self.refused),
            "protocol_version": self.cfg.protocol_version, "authenticated": self.link.authenticated,
            "key_fingerprint": self.link.fingerprint(), "session": self.link.session.hex() if self.link.session else "",
            "late_excitation_samples": self.late_excitation,
            "late_excitation_datagrams": self.excitation.late_datagrams,
            "overruns": self.overruns, "seed": self.cfg.seed,
        }


def serve(cfg: TargetConfig, stop: threading.Event | None = None) -> dict:
    """Run one target session (blocking); returns its summary dict."""
    return Target(cfg, stop).run()


def parse_args(argv: list[str] | None = None) -> TargetConfig:
    # the defaults, read off the fields: a TargetConfig() itself would refuse version 3 without a key file
    d = types.SimpleNamespace(**{f.name: f.default for f in dataclasses.fields(TargetConfig)})
    p = argparse.ArgumentParser(prog="python -m ambid.hardware.rt_target", description=__doc__.split("\n\n")[0])
    p.add_argument("--bind", default=d.bind, help="local host:port to listen on")
    p.add_argument("--bridge", default=d.bridge, help="host:port of the only bridge accepted")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of the simulated sensor noise")
    p.add_argument("--rig-file", default=d.rig_file, help="YAML rig file; empty = the default rig")
    p.add_argument("--nonlinear-magnets", action="store_true", help="full magnet force law (eq. 2.14)")
    p.add_argument("--pace", type=float, default=d.pace, help="1 = real time, 0 = as fast as possible")
    p.add_argument("--samples", type=int, default=d.samples, help="stop after this many samples; 0 = until STOP")
    p.add_argument("--block", type=int, default=d.block, help="samples per MEASUREMENT datagram")
    p.add_argument("--float32", action="store_true", help="send measurement values as float32")
    p.add_argument("--heartbeat", type=float, default=d.heartbeat, help="heartbeat period [s]")
    p.add_argument("--bridge-timeout", type=float, default=d.bridge_timeout,
                   help="silence of the bridge [s] after which a running target goes to its safe state")
    p.add_argument("--safe-seconds", type=float, default=d.safe_seconds,
                   help="simulated landing time in the safe state before the clock stops [s]")
    p.add_argument("--hold-for-excitation", action="store_true",
                   help="free-running only: wait at an announced sample for its excitation instead of r = 0")
    p.add_argument("--linger", type=float, default=d.linger,
                   help="keep heart-beating this long after the clock stopped, then exit [s]; 0 = until STOP")
    p.add_argument("--protocol-version", type=int, default=d.protocol_version,
                   help="protocol version spoken: 3 authenticated (needs --key-file), 2 unauthenticated")
    p.add_argument("--key-file", default=d.key_file, help="the rig's key file (protocol version 3; 'ambid keygen')")
    for name in ("drop", "corrupt", "duplicate", "reorder"):
        p.add_argument(f"--{name}", type=float, default=0.0, help=f"probability to {name} an outgoing datagram")
    p.add_argument("--reorder-depth", type=int, default=d.reorder_depth,
                   help="a reordered datagram is sent after 1..this many later ones")
    p.add_argument("--fault-seed", type=int, default=d.fault_seed, help="seed of the fault injection")
    p.add_argument("--mute-at", type=int, default=d.mute_at, help="go silent at this sample index; -1 = never")
    p.add_argument("--mute-seconds", type=float, default=d.mute_seconds, help="how long to stay silent [s]")
    a = p.parse_args(argv)
    return TargetConfig(**{k.replace("-", "_"): v for k, v in vars(a).items()})


def main(argv: list[str] | None = None) -> int:
    try:
        cfg = parse_args(argv)
        target = Target(cfg)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: target.stop.set())
    print(link_words(target.link, "rt_target"), file=sys.stderr, flush=True)
    print(f"RT_TARGET_LISTENING {target.address[0]}:{target.address[1]}", flush=True)
    summary = target.run()
    print(SUMMARY_PREFIX + json.dumps(summary), flush=True)
    return 0 if summary["state"] == "done" else 1


if __name__ == "__main__":
    sys.exit(main())
