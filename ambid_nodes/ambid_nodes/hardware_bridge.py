"""hardware_bridge: the rig's real-time target seen from ROS, over the UDP protocol of docs/bridge_protocol.md.

Takes the place of ``plant_sim`` in the graph when the fast loop (position
control at the sample rate) runs on a real-time target. Publishes
``measurement`` (SampleBlock y, u, ic, r, blocks of ``block_size`` samples,
split where samples were lost: a block never spans a gap), a latched
``plant/description`` (source "hardware"), ``/clock`` from the target's
sample index, ``status`` and ``events``; forwards ``excitation`` blocks and
``excitation/design`` (as an EXPERIMENT command) to the target, holding
them until the target is heard and re-sending blocks its heartbeat says are
missing.

Session (parameter ``session``, docs/sessions.md): the bridge obeys only its session's designs and
excitation blocks (anyone else's are foreign: counted, named, never forwarded to the target) and stamps
the id on all it publishes.

Protocol version 3 (``key_file``: the rig's key) authenticates every datagram and binds it to the session
its handshake agreed (``ambid.hardware.link_session``): forged, replayed and old datagrams are refused and
counted by reason, with an event each, and the target's own refusals (from its heartbeat) are reported as
``target_refused``. The key itself is never logged or published, only its fingerprint. Version 2 (asked for
on both ends) is unauthenticated, which every start says.

Datagrams from any address but ``target_host:target_port`` are dropped and
counted; malformed ones (magic, version, CRC, length, and ``content``: enum
fields out of range, indices beyond 2**40, a zero sample rate) are refused and
counted by reason; so are datagrams of kinds only the bridge sends
(``direction``). Received ROS messages are accepted or rejected with their
reason and counted per topic (``ambid_nodes.intake``): an excitation block
that is malformed, at another sample period, passed, repeated or overlapping
a held one, or beyond ``excitation_horizon`` samples ahead of the target; a
design that is inconsistent or at another sample rate; lost (sequence gaps), duplicated, reordered and late
datagrams are counted and lost sample ranges reported as ``sample_gap``
events. A target silent for ``target_timeout_s`` s is reported
(``target_silent``); when it is heard again it is commanded to its safe
state. ``finished`` completes once the target's clock stopped and every
sample up to its end was published or declared lost: state done if the
target finished its run (DONE), failed if it went to its safe state.
"""

from __future__ import annotations

import collections
import json
import socket
import sys
import threading
import time

import numpy as np
from ambid.hardware import bridge_protocol as bp
from ambid.hardware.bridge_link import (CommandQueue, ExcitationChunks, FlagRuns, content_error, refusals_text,
                                        target_refusals)
from ambid.hardware.link_key import read_key_file
from ambid.hardware.link_session import LinkEnd, link_words, refusal_event
from ambid.hardware.rt_target import parse_address
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import Rig
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from ambid_msgs.msg import ExcitationDesign, PlantDescription, SampleBlock, SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid_nodes.conversions import (block_msg, check_design, check_excitation_block, statespace_to_msg, status_msg,
                                     time_msg)
from ambid_nodes.session_node import SessionNode
from ambid_nodes.parameters import ParameterError, declare, node_rig

TICK_S = 0.005  # period of the timer that processes received datagrams and supervises the target
EVENT_THROTTLE_S = 1.0


class HardwareBridge(SessionNode):
    def __init__(self, *, rig: Rig | None = None, **kwargs) -> None:
        """``rig``: the rig a composed run parsed once (else the ``rig_file`` parameter's)."""
        super().__init__("hardware_bridge", **kwargs)
        (target_host, target_port, local_host, local_port, key_file, rig_file, window, reorder_timeout,
         rcvbuf) = self._declare_parameters()
        if self.version not in bp.SUPPORTED_VERSIONS:
            raise ParameterError(f"hardware_bridge: protocol_version {self.version} is not implemented; "
                                 f"this build speaks {list(bp.SUPPORTED_VERSIONS)}")
        try:
            self.target_addr = parse_address(f"{target_host}:{target_port}")
            local = parse_address(f"{local_host}:{local_port}")
        except ValueError as exc:
            raise ParameterError(f"hardware_bridge: {exc}") from None
        self.rig = node_rig(self, rig_file, rig)
        self.dt = self.rig.dt
        # the rig's axes: the channels of every datagram and block (y, u, ic, r of each; r going out)
        self.layout = self.rig.layout
        self.na = len(self.layout)
        self._open_link(key_file)
        self.measurement_names = bp.block_channels(bp.Kind.MEASUREMENT, self.layout)
        self.measurement_units = tuple(u for sig in ("y", "u", "ic", "r") for u in self.layout.units(sig))
        self.excitation_names = bp.block_channels(bp.Kind.EXCITATION, self.layout)
        self.chunk = min(self.chunk, bp.max_block_samples(bp.Kind.EXCITATION, 8, self.na, self.version))

        self.pub_block = self.identity.publisher(SampleBlock, "measurement", qos.BLOCKS)
        self.pub_desc = self.identity.publisher(PlantDescription, "plant/description", qos.LATCHED)
        self.pub_status = self.identity.publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.identity.publisher(SessionEvent, "events", qos.EVENTS)
        self.pub_clock = self.create_publisher(Clock, "/clock", qos.CLOCK)
        self.make_intake()
        self.identity.announce([self.pub_block, self.pub_desc, self.pub_status, self.pub_event, self.pub_clock])
        self.intake.subscribe(SampleBlock, "excitation", self.on_excitation, qos.BLOCKS)
        self.intake.subscribe(ExcitationDesign, "excitation/design", self.on_design, qos.LATCHED)

        self._init_run_state(window, reorder_timeout)
        self._open_socket(local, rcvbuf)
        self.publish_description()
        self.timer = self.create_timer(TICK_S, self.tick)
        self.get_logger().info(f"bridge {self.local_address[0]}:{self.local_address[1]} <-> target "
                               f"{self.target_addr[0]}:{self.target_addr[1]}, protocol v{self.version}")
        words = link_words(self.link, "hardware_bridge")
        if self.link.authenticated:
            self.get_logger().info(words)
        else:  # every start says so
            self.get_logger().warn(words)
            self.event(SessionEvent.WARN, "unauthenticated_link", words)

    # --- set-up and tear-down ---------------------------------------------




    def _open_socket(self, local: tuple, rcvbuf: int) -> None:
        """Bind the UDP socket and start the thread that empties it."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        try:
            self.sock.bind(local)
        except OSError as exc:
            self.sock.close()
            raise ParameterError(f"hardware_bridge: cannot bind {local[0]}:{local[1]}: {exc}") from None
        self.local_address = self.sock.getsockname()
        self.sock.settimeout(0.1)
        # a thread only moves datagrams from the kernel into a queue (with their arrival time), so a busy
        # executor never lets the socket buffer overflow; all protocol logic runs in the timer
        self.inbox: collections.deque = collections.deque()
        self.closing = threading.Event()
        self.reader = threading.Thread(target=self.read_socket, name="hardware_bridge_rx", daemon=True)
        self.reader.start()

    def _init_run_state(self, window: int, reorder_timeout: float) -> None:
        """Counters, the target's last word, the excitation and commands held."""
        self.assembler = bp.MeasurementAssembler(self.block_size, window, reorder_timeout)
        self.c = collections.Counter()  # counters for status and summary
        self.malformed = collections.Counter()  # by ProtocolError.reason
        self.hb: bp.Heartbeat | None = None  # newest heartbeat of the target
        self.hb_seq: int | None = None
        self.connected = self.silent = False
        self.last_rx: float | None = None
        self.silence_latency: list[float] = []
        self.chunks = ExcitationChunks(self.chunk)  # excitation held until the target applied it
        self.slots: dict[str, int] = {}
        self.commands = CommandQueue(self.retry_s, self.retries)
        self.runs = FlagRuns()  # runs of flagged samples, each reported when it ends
        self.last_clock = 0
        self.state = SessionStatus.STATE_IDLE
        self.throttle: dict[str, list] = {}
        self.target_refused: dict[str, int] = {}  # the target's refusals by reason, as its heartbeat last said
        self.started_wall = time.perf_counter()
        self.next_hb = self.next_status = 0.0
        self.summary: dict | None = None
        self.finished = Future()
        self.start_state = "waiting"  # start_with_experiment: waiting -> experiment (queued) -> sent
        self.stop_sent = False

    def _open_link(self, key_file: str) -> None:
        """The link's protocol version and key, checked against the rig's axes."""
        if self.version == 1 and self.na != bp.V1_AXES:
            raise ParameterError(f"hardware_bridge: protocol_version 1 carries {bp.V1_AXES} axes, the rig has "
                                 f"{self.na} ({' '.join(self.layout.axes)}); use protocol_version 2")
        if (self.version >= bp.AUTHENTICATED_VERSION) != bool(key_file):
            raise ParameterError(
                f"hardware_bridge: protocol_version {self.version} authenticates every datagram and needs key_file "
                "(the rig's key: 'ambid keygen --out FILE', the same file for the target), or set protocol_version 2 "
                "on bridge and target for an unauthenticated link" if key_file == "" else
                f"hardware_bridge: key_file with protocol_version {self.version}: that version is unauthenticated; "
                "speak version 3 with the key, or leave key_file out")
        try:
            self.link = LinkEnd(bp.Sender.BRIDGE, self.version, read_key_file(key_file) if key_file else None, self.na)
        except ValueError as exc:
            raise ParameterError(f"hardware_bridge: {exc}") from None

    def _declare_parameters(self) -> tuple:
        """The node's typed parameters, then the session joined; those only the set-up reads are returned."""
        target_host = declare(self, "target_host", "127.0.0.1", "address of the real-time target")
        target_port = declare(self, "target_port", 50001, "UDP port of the real-time target", 1, 65535)
        local_host = declare(self, "local_host", "127.0.0.1", "local address to bind; 0.0.0.0 = all interfaces")
        local_port = declare(self, "local_port", 50002, "local UDP port; 0 = any free port", 0, 65535)
        self.version = declare(self, "protocol_version", bp.PROTOCOL_VERSION,
                               "bridge protocol version; datagrams of any other are refused (3: authenticated, "
                               "2: unauthenticated)", 1, 255)
        key_file = declare(self, "key_file", "", "the rig's key file, mode 0600 (protocol version 3; 'ambid keygen "
                           "--out FILE'); only its fingerprint is ever shown")
        rig_file = declare(self, "rig_file", "", "YAML rig parameter file describing the rig; empty = the default")
        self.timeout = declare(self, "target_timeout_s", 0.5, "silence after which the target is declared lost",
                               0.005, 3600.0, "s")
        self.hb_period = declare(self, "heartbeat_period_s", 0.05, "period of the bridge's heartbeats", 0.001, 10.0,
                                 "s")
        window = declare(self, "reorder_window", 16, "later datagrams after which a missing one is lost", 1, 4096)
        reorder_timeout = declare(self, "reorder_timeout_s", 0.2, "longest wait for a missing datagram",
                                  0.0, 60.0, "s")
        self.block_size = declare(self, "block_size", 1000, "samples per measurement block", 1, 100_000)
        self.chunk = declare(self, "excitation_chunk", 40, "samples per EXCITATION datagram (at most what one "
                             "datagram of the rig's axes carries)", 1, bp.max_block_samples(bp.Kind.EXCITATION, 8, 1))
        self.clock_every = declare(self, "clock_every", 100, "samples between /clock messages", 1, 100_000)
        self.retry_s = declare(self, "command_retry_s", 0.1, "wait for an ACK before a command is sent again",
                               0.001, 60.0, "s")
        self.retries = declare(self, "command_retries", 20, "sends of a command before it is given up", 1, 1000)
        self.autostart = declare(self, "autostart", True, "send START when an idle target is first heard")
        self.start_with_experiment = declare(
            self, "start_with_experiment", False,
            "send START once the target acknowledged the first experiment (a session in the processes layout: "
            "the experiment is placed before the target's clock runs)")
        self.stop_after = declare(self, "stop_after_samples", 0,
                                  "send STOP once this many samples are published (the session's length); 0: never",
                                  0, 2**40)
        self.horizon = declare(self, "excitation_horizon", 1_000_000,
                               "most samples an excitation block may lie ahead of the target (memory bound)",
                               1, 1_000_000_000)
        rcvbuf = declare(self, "receive_buffer", 4 * 1024 * 1024, "UDP receive buffer (capped by "
                         "net.core.rmem_max)", 65536, 1 << 30, "bytes")
        self.join_session()
        return target_host, target_port, local_host, local_port, key_file, rig_file, window, reorder_timeout, rcvbuf

    def publish_description(self) -> None:
        r, lay = self.rig, self.layout
        self.pub_desc.publish(PlantDescription(
            stamp=time_msg(0.0), name=self.get_fully_qualified_name(), source="hardware", rig_name=r.name,
            sample_period=self.dt, displacement_names=list(lay.outputs),
            current_names=list(lay.inputs), bias_current=[m.bias_current_a for m in r.axis_magnets()],
            current_limit=[r.current_limit_a] * self.na, backup_clearance=[c for _, c in r.backup_bearings()],
            analytical_model=statespace_to_msg(analytical_model(r)), seed=0, controller_timeout_samples=0,
            rig_json=json.dumps(r.to_dict())))

    def destroy_node(self) -> None:
        self.closing.set()
        self.reader.join(timeout=1.0)
        self.sock.close()
        super().destroy_node()

    def read_socket(self) -> None:
        while not self.closing.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)  # larger than the protocol allows: oversize is seen
            except TimeoutError:
                continue
            except OSError:
                if self.closing.is_set():
                    return
                time.sleep(0.01)  # e.g. an ICMP error reported on the socket
                continue
            self.inbox.append((data, addr, time.monotonic()))

    def send(self, msg) -> None:
        """Send a message (its sequence number is the link's next of its kind)."""
        self.send_datagram(self.link.pack(msg))

    def send_datagram(self, datagram: bytes) -> None:
        try:
            self.sock.sendto(datagram, self.target_addr)
        except OSError as exc:
            self.c["send_errors"] += 1
            self.event_throttled(SessionEvent.WARN, "send_failed", f"sending to the target failed: {exc}")

    def send_heartbeat(self) -> None:
        self.send(bp.Heartbeat(0, bp.TargetState.RUNNING if self.connected else bp.TargetState.IDLE,
                               sample_index=self.assembler.next_index or 0, rx_datagrams=self.c["datagrams"],
                               rx_rejected=self.c["foreign"] + sum(self.malformed.values()), axes=self.na,
                               refused_auth=self.malformed["auth"], refused_session=self.malformed["session"],
                               refused_replay=self.malformed["replay"], duplicates=self.c["link_duplicates"]))

    # --- the periodic work ------------------------------------------------
    def tick(self) -> None:
        inbox = self.inbox
        while inbox:
            data, addr, t_rx = inbox.popleft()
            try:
                self.on_datagram(data, addr, t_rx)
            except Exception as exc:  # noqa: BLE001 - a bug must not stop the bridge; counted and reported
                self.malformed["handler_error"] += 1
                self.get_logger().error(f"handling a datagram failed: {type(exc).__name__}: {exc}",
                                        throttle_duration_sec=1.0)
                self.event_throttled(SessionEvent.ERROR, "handler_error",
                                     f"handling a datagram failed ({type(exc).__name__}: {exc}); it was dropped")
        now = time.monotonic()
        hb = self.hb
        self.publish_items(self.assembler.poll(now, hb.sent_end if hb else None,
                                               hb.next_measurement_sequence if hb else None))
        self.publish_clock()
        self.check_halted()
        self.check_silence(now)
        self.send_commands(now)
        if self.start_state == "experiment" and self.connected and not self.commands.pending:
            self.start_state = "sent"
            self.queue_command(bp.CommandCode.START)
        if self.stop_after and not self.stop_sent and self.c["samples_published"] >= self.stop_after:
            self.stop_sent = True  # the session's samples are in: the target's clock may stop
            self.queue_command(bp.CommandCode.STOP)
        if now >= self.next_hb:
            self.next_hb = now + self.hb_period
            if not self.link.established:  # version 3: the session is proposed until the target is heard in it
                self.send_datagram(self.link.hello())
            if self.link.sending_session is not None:
                self.send_heartbeat()
        if now >= self.next_status:
            self.next_status = now + 0.5
            self.publish_status()

    def on_datagram(self, data: bytes, addr, t_rx: float) -> None:
        if addr != self.target_addr:
            self.c["foreign"] += 1
            self.event_throttled(SessionEvent.WARN, "foreign_datagram",
                                 f"dropped a datagram from {addr[0]}:{addr[1]}; only the target at "
                                 f"{self.target_addr[0]}:{self.target_addr[1]} is accepted")
            return
        try:
            msg = self.link.receive(data)
        except bp.ProtocolError as exc:
            self.on_refused(exc)
            return
        if isinstance(msg, bp.Welcome):  # version 3: confirm the session the target proposed
            self.send_heartbeat()
            return
        if not isinstance(msg, (bp.Measurement, bp.Heartbeat, bp.Ack)):
            self.malformed["direction"] += 1  # refused, not counted received: nor a sign of a live target
            self.event_throttled(SessionEvent.WARN, "malformed_datagram",
                                 f"refused a {type(msg).__name__.upper()} datagram: only the bridge sends those")
            return
        why = content_error(msg)
        if why:
            self.malformed["content"] += 1
            self.event_throttled(SessionEvent.WARN, "malformed_datagram", f"refused a datagram from the target "
                                                                          f"(content): {why}")
            return
        self.c["datagrams"] += 1
        self.last_rx = t_rx
        if self.silent:
            self.silent = False
            self.event(SessionEvent.ERROR, "target_back",
                       "the target answers again after its silence; its data meanwhile is lost, so it is "
                       "commanded to its safe state")
            self.queue_command(bp.CommandCode.SAFE_STATE)
        if isinstance(msg, bp.Measurement):
            self.c["measurement_datagrams"] += 1
            verdict = self.assembler.push(msg)
            if verdict == "duplicate":
                self.event_throttled(SessionEvent.WARN, "duplicate_datagram",
                                     f"duplicated MEASUREMENT datagram (sequence {msg.sequence}) dropped")
            elif verdict == "late":
                self.event_throttled(SessionEvent.WARN, "late_datagram",
                                     f"MEASUREMENT samples [{msg.first_index}, {msg.end_index}) arrived after "
                                     "they were declared lost; dropped")
        elif isinstance(msg, bp.Heartbeat):
            self.on_heartbeat(msg, t_rx)
        else:
            self.on_ack(msg)

    def on_refused(self, exc: bp.ProtocolError) -> None:
        """A datagram from the target's address refused: counted by its reason, an event named for it."""
        if exc.reason == "duplicate":
            self.c["link_duplicates"] += 1
        else:
            self.malformed[exc.reason] += 1
        severity = SessionEvent.ERROR if exc.reason in ("version", "auth", "session", "replay") else SessionEvent.WARN
        self.event_throttled(severity, refusal_event(exc.reason),
                             f"refused a datagram from the target's address ({exc.reason}): {exc}")

    def on_heartbeat(self, hb: bp.Heartbeat, t_rx: float) -> None:
        if self.hb_seq is not None:
            d = bp.seq_diff(hb.sequence, self.hb_seq)
            if d <= 0:
                self.c["heartbeats_stale"] += 1
                return  # duplicated or overtaken by a newer one
            self.c["heartbeats_lost"] += d - 1
        self.hb_seq = hb.sequence
        old = self.hb
        self.hb = hb
        now_refused = target_refusals(hb)
        grown = {r: n - self.target_refused.get(r, 0) for r, n in now_refused.items()}
        if any(n > 0 for n in grown.values()):
            self.target_refused = now_refused
            self.event(SessionEvent.ERROR if any(grown[r] for r in ("auth", "session", "replay")) else SessionEvent.WARN,
                       "target_refused", f"the target refused datagrams sent to it as the bridge's since its last "
                                         f"report: {refusals_text(grown)} (forged or replayed traffic on the rig "
                                         "network, or duplicates on the way)")
        if not self.connected:
            self.connected = True
            self.state = SessionStatus.STATE_RUNNING
            if not self.assembler.started:
                self.assembler.start(hb.sent_end, hb.next_measurement_sequence)
            self.event(SessionEvent.INFO, "target_connected",
                       f"target at {self.target_addr[0]}:{self.target_addr[1]} is "
                       f"{bp.TargetState(hb.state).name} at sample {hb.sample_index}, {hb.sample_rate_hz} Hz")
            if abs(hb.sample_rate_hz * self.dt - 1.0) > 1e-6:
                self.event(SessionEvent.ERROR, "sample_rate_mismatch",
                           f"the target runs at {hb.sample_rate_hz} Hz, the rig description says {self.rig.sample_rate_hz:g} Hz; "
                           "set rig_file to the rig the target runs")
            if hb.axes and hb.axes != self.na:   # version 2 says the target's axes
                self.event(SessionEvent.ERROR, "axes_mismatch",
                           f"the target runs {hb.axes} axes, the rig description has {self.na} "
                           f"({' '.join(self.layout.axes)}); set rig_file to the rig the target runs")
            for first in list(self.chunks.firsts):
                self.send_chunk(first, t_rx)
            if self.autostart and hb.state == bp.TargetState.IDLE:
                self.queue_command(bp.CommandCode.START)
        if old is not None and old.state != hb.state:
            sev = SessionEvent.ERROR if hb.state == bp.TargetState.SAFE else SessionEvent.INFO
            reason = f" ({bp.SafeReason(hb.safe_reason).name.lower()})" if hb.state == bp.TargetState.SAFE else ""
            self.event(sev, "target_state", f"target is {bp.TargetState(hb.state).name}{reason} at sample "
                                            f"{hb.sample_index}")
        self.chunks.applied(hb.sample_index)
        if hb.excitation_next != bp.NO_INDEX:  # the target lacks excitation there: what we hold, again
            for first in self.chunks.to_resend(hb.excitation_next, t_rx, max(2 * self.hb_period, self.retry_s)):
                self.send_chunk(first, t_rx)

    def on_ack(self, ack: bp.Ack) -> None:
        cmd = self.commands.acknowledged(ack.command_id)
        if cmd is None:
            self.c["acks_unexpected"] += 1
            return
        if ack.result != bp.AckResult.OK:
            self.event(SessionEvent.ERROR, "command_refused",
                       f"the target refused {bp.CommandCode(cmd.code).name} ({bp.AckResult(ack.result).name}) "
                       f"in state {bp.TargetState(ack.state).name}")

    # --- measurement out --------------------------------------------------
    def publish_items(self, items: list) -> None:
        for item in items:
            if isinstance(item, bp.Gap):
                self.on_gap(item)
            else:
                self.publish_block(item)

    def publish_block(self, b: bp.Block) -> None:
        raw = b.sample_flags
        flags = ((raw & (bp.FLAG_CLIPPED | bp.FLAG_LANDED))
                 | np.where(raw & bp.FLAG_SAFE_STATE, SampleBlock.FLAG_CONTROLLER_LOST, 0)).astype(np.uint8)
        self.pub_block.publish(block_msg(b.first_index, self.dt, self.measurement_names, self.measurement_units, b.data,
                                         flags,
                                         SampleBlock.FLAG_FINAL if b.final else 0))
        self.c["blocks"] += 1
        self.c["samples_published"] += len(b.data)
        for bit, code, what in ((bp.FLAG_EXCITATION_LATE, "excitation_late",
                                 "the target had no excitation for these announced samples and applied r = 0; "
                                 "publish the excitation further ahead"),
                                (bp.FLAG_SAFE_STATE, "safe_state", "the target was in its safe state (zero current "
                                                                   "reference, rotor landing)")):
            self.report_runs(b.first_index, raw & bit != 0, bit, code, what)

    def report_runs(self, first: int, mask: np.ndarray, bit: int, code: str, what: str) -> None:
        """One event per run of flagged samples, when the run ends (a gap or the session end may end it too)."""
        for start, end in self.runs.feed(first, mask, bit):
            self.report_run(bit, start, end, code, what)

    def report_run(self, bit: int, start: int, end: int, code: str, what: str) -> None:
        sev = SessionEvent.ERROR if bit == bp.FLAG_SAFE_STATE else SessionEvent.WARN
        self.event(sev, code, f"samples [{start}, {end}) ({end - start} samples): {what}")

    def close_runs(self, end: int) -> None:
        for bit, code in ((bp.FLAG_EXCITATION_LATE, "excitation_late"), (bp.FLAG_SAFE_STATE, "safe_state")):
            run = self.runs.close(bit, end)
            if run is not None:
                self.report_run(bit, *run, code, "flagged by the target")

    def on_gap(self, g: bp.Gap) -> None:
        self.close_runs(g.start)
        lost = f"{g.datagrams} datagram(s)" if g.datagrams >= 0 else "an unknown number of datagrams"
        self.event(SessionEvent.WARN, "sample_gap",
                   f"samples [{g.start}, {g.end}) lost ({g.end - g.start} samples, {lost}); the measurement is "
                   "split there, no block spans the gap", index=g.start)

    def publish_clock(self) -> None:
        k = self.assembler.next_index or 0
        tick = k // self.clock_every * self.clock_every
        if tick > self.last_clock:
            self.last_clock = tick
            self.pub_clock.publish(Clock(clock=time_msg(tick * self.dt)))

    def check_halted(self) -> None:
        hb = self.hb
        if (self.finished.done() or hb is None or hb.clock_running
                or hb.state not in (bp.TargetState.DONE, bp.TargetState.SAFE)
                or self.assembler.next_index is None or self.assembler.next_index < hb.sent_end
                or self.assembler.pending):
            return
        self.publish_items(self.assembler.finish())
        self.close_runs(self.assembler.next_index)
        ok = hb.state == bp.TargetState.DONE and self.c["silent_episodes"] == 0
        self.finish(SessionStatus.STATE_DONE if ok else SessionStatus.STATE_FAILED)

    # --- supervision ------------------------------------------------------
    def check_silence(self, now: float) -> None:
        if not self.connected or self.silent or self.last_rx is None or self.finished.done():
            return
        hb = self.hb
        if not hb.clock_running and hb.state in (bp.TargetState.DONE, bp.TargetState.SAFE):
            return  # a target whose session ended may go away
        quiet = now - self.last_rx
        if quiet > self.timeout:
            self.silent = True
            self.c["silent_episodes"] += 1
            self.silence_latency.append(quiet)
            self.state = SessionStatus.STATE_FAILED
            self.event(SessionEvent.ERROR, "target_silent",
                       f"no datagram from the target for {quiet:.3f} s (timeout {self.timeout:g} s) after sample "
                       f"{self.assembler.next_index}; it will be commanded to its safe state when it answers")
            self.publish_status()

    # --- excitation and commands in ---------------------------------------
    def on_excitation(self, msg: SampleBlock) -> None:
        done = self.hb.sample_index if self.hb else 0
        data = check_excitation_block(msg, self.excitation_names, self.dt, done, self.horizon, self.chunks.firsts,
                                      self.chunks.length, "target", passed=done)
        now = time.monotonic()
        for first in self.chunks.add(msg.first_index, data):
            if self.connected:
                self.send_chunk(first, now)

    def send_chunk(self, first: int, now: float) -> None:
        data, again = self.chunks.sent(first, now)
        self.c["excitation_resent"] += again
        self.c["excitation_datagrams"] += 1
        self.send(bp.Excitation(0, first, data))

    def on_design(self, msg: ExcitationDesign) -> None:
        check_design(msg, self.dt)
        slot = self.slots.setdefault(msg.experiment_id, len(self.slots) + 1)
        self.queue_command(bp.CommandCode.EXPERIMENT, msg.start_index, msg.total_samples, slot)
        if self.start_with_experiment and self.start_state == "waiting":
            self.start_state = "experiment"  # START once the target acknowledged it (tick)

    def queue_command(self, code: int, arg0: int = 0, arg1: int = 0, arg2: int = 0) -> None:
        self.commands.queue(code, arg0, arg1, arg2)
        self.send_commands(time.monotonic())

    def send_commands(self, now: float) -> None:
        if not self.connected:
            return
        send, failed = self.commands.due(now)
        for cmd in failed:
            self.event(SessionEvent.ERROR, "command_failed",
                       f"{bp.CommandCode(cmd.code).name} not acknowledged after {self.commands.retries} sends")
        for cid, cmd in send:
            self.c["commands_sent"] += 1
            self.send(bp.Command(0, cid, cmd.code, *cmd.args))

    # --- reporting --------------------------------------------------------
    def event_index(self) -> int:
        return self.assembler.next_index or 0

    def event_throttled(self, severity: int, code: str, text: str) -> None:
        """At most one event per code and second; the next one says how many were folded into it."""
        now = time.monotonic()
        last, folded = self.throttle.get(code, (-1e9, 0))
        if now - last < EVENT_THROTTLE_S:
            self.throttle[code] = (last, folded + 1)
            return
        self.throttle[code] = (now, 0)
        more = f" ({folded} more like it in the last {EVENT_THROTTLE_S:g} s)" if folded else ""
        self.get_logger().warn(text + more)
        self.event(severity, code, text + more)

    def figures(self) -> dict:
        a = self.assembler.counts
        hb = self.hb
        wall = time.perf_counter() - self.started_wall
        return {
            "target_state": bp.TargetState(hb.state).name.lower() if hb else "unknown",
            "target_sample_index": hb.sample_index if hb else 0, "connected": self.connected, "silent": self.silent,
            "samples": self.assembler.next_index or 0, "samples_published": self.c["samples_published"],
            "blocks": self.c["blocks"], "wall_s": wall,
            "datagrams_received": self.c["datagrams"], "datagrams_foreign": self.c["foreign"],
            "datagrams_malformed": sum(self.malformed.values()), "malformed_by_reason": dict(self.malformed),
            "measurement_datagrams": self.c["measurement_datagrams"],
            "duplicates": a.duplicates + self.c["link_duplicates"],
            "reordered": a.reordered, "late": a.late, "gaps": a.gaps, "missing_samples": a.missing_samples,
            "lost_measurement_datagrams": a.lost_datagrams, "heartbeats_lost": self.c["heartbeats_lost"],
            "silent_episodes": self.c["silent_episodes"], "silence_detected_after_s": self.silence_latency,
            "excitation_datagrams": self.c["excitation_datagrams"], "excitation_resent": self.c["excitation_resent"],
            "commands_sent": self.c["commands_sent"], "messages_received": self.intake.total_received,
            "messages_rejected": self.intake.total_rejected, **self.intake.figures(),
            "target_late_excitation_samples": hb.late_excitation_samples if hb else 0,
            "target_rx_rejected": hb.rx_rejected if hb else 0, "target_overruns": hb.overruns if hb else 0,
            "protocol_version": self.version, "authenticated": self.link.authenticated,
            "key_fingerprint": self.link.fingerprint(), "session": (self.link.session or b"").hex(),
            "target_refused_by_reason": dict(self.target_refused),
        }

    def publish_status(self) -> None:
        f = self.figures()
        text = (f"target {f['target_state']}{' SILENT' if self.silent else ''} at sample {f['target_sample_index']}, "
                f"published {f['samples_published']}, lost {f['missing_samples']} samples in {f['gaps']} gaps, "
                f"malformed {f['datagrams_malformed']}, foreign {f['datagrams_foreign']}"
                + ("" if self.link.authenticated else ", UNAUTHENTICATED link"))
        self.pub_status.publish(status_msg(
            time_msg(f["samples"] * self.dt), self.get_fully_qualified_name(), self.state, f["samples"], -1.0,
            self.intake.total_received + self.c["datagrams"] + f["datagrams_malformed"] + f["datagrams_foreign"],
            self.intake.total_rejected + f["datagrams_malformed"] + f["datagrams_foreign"], text, f))

    def finish(self, state: int) -> None:
        self.state = state
        self.summary = {**self.figures(), "state": "done" if state == SessionStatus.STATE_DONE else "failed"}
        self.publish_status()
        self.event(SessionEvent.INFO, "finished", json.dumps(self.summary))
        self.finished.set_result(self.summary)


main = HardwareBridge.main  # the console script: SessionNode.main


if __name__ == "__main__":
    sys.exit(main())
