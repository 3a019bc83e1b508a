"""recorder: records the session's topics into one MCAP file laid out as rosbag2 writes it.

Each wanted topic's type is discovered from the graph (polled every
``discovery_period_s`` seconds, so late topics are picked up) and the topic is
subscribed with ``raw=True``: the CDR bytes go to the file unchanged, nothing
is deserialised except the few latched description messages. The
subscription QoS follows the publishers' offers as rosbag2's does: reliable
if every publisher is, transient-local if every publisher is (so
``plant/description``, ``controller/description``, ``excitation/design``,
``status`` and ``events`` published before the recorder joined still arrive).
An ambid topic the graph knows only from its subscribers so far (the plant
listens to ``excitation`` before the generator exists) is subscribed at once
with the QoS the ambid nodes publish with, so its first messages are not lost
to the discovery delay; other topics wait for a publisher. The publishers'
offered QoS and type hash go into the channel metadata (taken at the first
message if no publisher was known at subscription).

Every subscription is KEEP_ALL, as every ambid node's (``qos.subscription``): a
flood cannot push a genuine message out of the queue; it slows the recorder down.

Session (parameter ``session``, docs/sessions.md): only the session's own messages are
recorded. An ambid message carries its ``session_id`` (read from the bytes: a
SampleBlock's by a walk past its data, the others decoded); ``/clock`` and the loop
topics carry none and are taken by GID from the session's publishers only (the
roster on ``session``; taps of the loop pump, ``ambid_nodes.identity.LoopPartner``).
Anything else on a recorded topic is foreign: never written, counted per topic
(``foreign:<topic>``, ``foreign_from:<topic>`` naming its publishers in ``status``)
and reported as ``foreign_message`` events (the first of each topic, then at most one
a second). A topic of a type without ``session_id`` other than those (a user's own
topic) is recorded as it comes.

Messages published on a volatile topic before the recorder's subscription
matched (about ``discovery_period_s`` plus DDS discovery) are not recorded:
start the recorder first and let it subscribe (``topic_recorded`` events,
the subscription count) before the loop starts.

Log time. Each message is stamped with its receive time on the node's ROS
clock: system time by default (as ``ros2 bag record``), simulated time with
``use_sim_time:=true``. Log times are kept non-decreasing: a clock stepping
back holds the last time (reported once as an event), so readers iterating in
log-time order see the receive order. Publish time equals log time (rclpy's
EventsExecutor cannot deliver message info to a raw callback).

Session facts (rig, plant and controller descriptions, excitation designs,
the recorder's parameters, ambid version, log-time convention) are written as
MCAP metadata ``ambid.session`` when they become known, readable without
decoding any message.

Crash safety: a wall-clock timer closes the open chunk every
``flush_period_s`` seconds, so a SIGKILL loses at most that much; ``ambid
inspect --recover`` reads the rest. SIGINT and SIGTERM close the file
completely (summary and footer). A write failure (disk full) is logged,
reported as an ``events`` ERROR and a failed ``status``, recording stops and
the node finishes with exit code 1; what was written stays readable with
``--recover``.

Capacity: one Python callback and one writer call per message, about 3,000
messages/s on a loaded 2-core box. The measurement blocks (10 per second at
10 kHz) cost nothing; ``include_loop_topics`` (one message per sample on each
of two topics) keeps up only while the lock-step loop runs slower than about
1,500 samples/s, beyond that the loop publishers' KEEP_LAST queues drop
samples for the recorder (the loop itself never waits for it).

Publishes ``status`` (messages per topic, bytes, last flush) and ``events``.
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import sys
import time

import ambid
from ambid.recording import SessionWriteError
from ambid.recording.blocks import SAMPLE_BLOCK_TYPE, sample_block_session
from ambid.session_id import format_session
from ambid.recording.facts import FACT_TYPES, controller_facts, design_facts, plant_facts
from ambid.recording.in_progress import Recording
from ambid.recording.writer import available_compressions
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.task import Future

from ambid_msgs.msg import SessionEvent, SessionStatus
from ambid_nodes import qos
from ambid_nodes.conversions import (BadMessage, check_controller_description, check_design, check_plant_description,
                                     decode_message, status_msg)
from ambid_nodes.identity import GONE, UNNAMED, LoopPartner
from ambid_nodes.loop_pump import NOT_RUN, LoopEntry
from ambid_nodes.parameters import ParameterError, declare
from ambid_nodes.session_node import SessionNode

#: every topic of the ambid graph, relative to the rig's namespace (plus /clock)
DEFAULT_TOPICS = ["displacement", "control_current", "measurement", "excitation", "excitation/design",
                  "plant/description", "controller/description", "frf", "status", "events", "session", "/clock"]
#: the per-sample lock-step topics (10,000 msgs/s each), recorded only with include_loop_topics
LOOP_TOPICS = ("displacement", "control_current")
#: the QoS the ambid nodes publish with, used to subscribe to a topic before its publisher exists
CONVENTIONAL_QOS = {"displacement": qos.LOOP, "control_current": qos.LOOP, "measurement": qos.BLOCKS,
                    "excitation": qos.BLOCKS, "excitation/design": qos.LATCHED, "plant/description": qos.LATCHED,
                    "controller/description": qos.LATCHED, "status": qos.STATUS, "events": qos.EVENTS,
                    "session": qos.MEMBERS, "/clock": qos.CLOCK}
#: the topics without a session id of their own whose session publishers the roster names: taken by GID
BY_GID = ("displacement", "control_current", "/clock")
FOREIGN_EVENT_S = 1.0  # foreign_message events per topic: the first, then at most one this often
MAX_NAMES = 8  # foreign publishers named per topic
LOG_TIME_CONVENTION = ("receive time on the recorder's ROS clock (system time, or /clock with use_sim_time), "
                       "held non-decreasing; publish time = log time")


def subscription_qos(offered: list) -> QoSProfile:
    """A QoS that matches every offered profile: reliable / transient-local only if all publishers are; KEEP_ALL
    (a flood cannot push a genuine message out)."""
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return qos.subscription(QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE))


def _decoded_session(cls, data: bytes) -> int:
    """The session id of an ambid message; BadMessage where the bytes do not decode."""
    return decode_message(data, cls, "recorded message").session_id


def message_class(type_name: str):
    """The Python class of ``pkg/msg/Type``; ImportError/AttributeError if not installed."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class Recorder(SessionNode):
    stop_on_signal = True   # never interrupted in the middle of a chunk write: SIGINT/SIGTERM close the file

    def __init__(self, **kwargs) -> None:
        super().__init__("recorder", **kwargs)
        output = declare(self, "output", "session.mcap", "MCAP file to write (relative: to the working directory)")
        overwrite = declare(self, "overwrite", False, "replace an existing output file")
        topics = declare(self, "topics", list(DEFAULT_TOPICS),
                         "topics to record; relative names resolve in the node's namespace")
        self.include_loop = declare(self, "include_loop_topics", False,
                                    "also record the lock-step topics displacement and control_current "
                                    "(2 x 10,000 msgs/s; the measurement blocks carry the same samples)")
        chunk_size = declare(self, "chunk_size", 1 << 20, "uncompressed size at which a chunk is closed",
                             1024, 1 << 30, "bytes")
        compression = declare(self, "compression", "zstd", "chunk compression: zstd, lz4 or none")
        fsync = declare(self, "fsync", False, "fsync the file after every chunk (survives a power loss)")
        flush_period = declare(self, "flush_period_s", 1.0,
                               "wall time between chunk flushes: at most this much is lost to a SIGKILL",
                               0.02, 60.0, "s")
        discovery_period = declare(self, "discovery_period_s", 0.25, "wall time between graph polls for new topics",
                                   0.02, 60.0, "s")
        status_period = declare(self, "status_period_s", 1.0, "wall time between status messages", 0.02, 3600.0, "s")
        facts_text = declare(self, "session_facts", "{}",
                             "extra session facts as a JSON object, e.g. {\"operator\": \"...\", \"notes\": \"...\"}")
        self.join_session()
        if compression not in available_compressions():
            raise ParameterError(f"recorder: compression '{compression}' is not usable here; "
                                 f"choose one of {list(available_compressions())}")
        try:
            extra_facts = json.loads(facts_text)
        except json.JSONDecodeError as exc:
            raise ParameterError(f"recorder: session_facts is not valid JSON ({exc}); "
                                 "pass a JSON object such as '{\"operator\": \"me\"}'") from None
        if not isinstance(extra_facts, dict):
            raise ParameterError("recorder: session_facts must be a JSON object ({...}), "
                                 f"got {type(extra_facts).__name__}")
        if not output:
            raise ParameterError("recorder: parameter 'output' is empty; give the MCAP file to write")

        self.wanted, skipped = self.resolve_topics(topics)
        self.path = os.path.abspath(output)
        try:
            # the file, its counts and its facts: the recording logic, in the core
            self.rec = Recording(self.path, chunk_size=chunk_size, flush_period_s=flush_period,
                                 compression=compression, fsync=fsync, overwrite=overwrite)
        except FileExistsError:
            raise ParameterError(f"recorder: {self.path} exists; pass overwrite:=true or choose another "
                                 "output") from None
        except OSError as exc:
            raise ParameterError(f"recorder: cannot create {self.path}: {exc.strerror or exc}") from None

        self.pub_status = self.identity.publisher(SessionStatus, "status", qos.STATUS)
        self.pub_event = self.identity.publisher(SessionEvent, "events", qos.EVENTS)
        self.identity.announce([self.pub_status, self.pub_event])
        self.subs: dict[str, object] = {}  # topic -> subscription
        self.by_gid = {self.resolve_topic_name(t) for t in BY_GID}
        self.taps: dict[str, tuple[LoopEntry, LoopPartner]] = {}  # topic -> its tap, taken by GID
        self.foreign: dict[str, int] = {}  # topic -> foreign messages, not recorded
        self.foreign_names: dict[str, set[str]] = {}
        self.unnamed: dict[str, dict[bytes, str]] = {}   # topic -> {GID: its name while the graph knew no node}
        self.foreign_reported: dict[str, tuple[float, int]] = {}  # topic -> (last event, count then)
        self.types: dict[str, str] = {}  # topic -> pkg/msg/Type
        self.conventional_qos = {self.resolve_topic_name(t): q for t, q in CONVENTIONAL_QOS.items()}
        self.ignored: set[str] = set()  # topics that cannot be recorded (reported once)
        self.fact_decoders: dict[str, tuple[str, type]] = {}  # topic -> (fact key, message class)
        self.session_of: dict[str, object] = {}  # topic -> its messages' session id from their bytes
        self.clock_back_reported = False
        self.unreadable = 0  # descriptions without readable facts since the last report
        self.unreadable_reported = -1e9
        self.summary: dict | None = None
        self.finished = Future()  # completes only if recording fails; SIGINT/SIGTERM close via destroy_node

        params = {name: p.value for name, p in sorted(self.get_parameters_by_prefix("").items())}
        try:
            self.rec.write_facts({"recorder": {"node": self.get_fully_qualified_name(), "path": self.path,
                                               "topics": self.wanted, "parameters": params},
                                  "session_id": format_session(self.identity.id),
                                  "log_time": LOG_TIME_CONVENTION, "ambid_version": ambid.__version__,
                                  "started_unix_ns": time.time_ns(), **extra_facts})
        except SessionWriteError as exc:
            self.rec.writer.close()
            raise ParameterError(f"recorder: cannot write {self.path}: {exc}") from None
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # keeps flushing while /clock stands still
        self.flush_timer = self.create_timer(flush_period, self.flush, clock=steady)
        self.discovery_timer = self.create_timer(discovery_period, self.discover, clock=steady)
        self.status_timer = self.create_timer(status_period, self.publish_status, clock=steady)
        if skipped:
            self.get_logger().info(f"not recording the loop topics {skipped} (include_loop_topics:=true does)")
        self.event(SessionEvent.INFO, "recording_started",
                   f"recording {len(self.wanted)} topics to {self.path} ({compression}, flush every "
                   f"{flush_period:g} s)")
        self.discover()

    # what the recording counts, as the node's figures
    counts = property(lambda self: self.rec.counts)
    received = property(lambda self: self.rec.received)
    rejected = property(lambda self: self.rec.rejected)

    # --- set-up -----------------------------------------------------------
    def resolve_topics(self, topics: list[str]) -> tuple[list[str], list[str]]:
        loop = {self.resolve_topic_name(t) for t in LOOP_TOPICS}
        wanted, skipped = [], []
        for t in topics:
            try:
                name = self.resolve_topic_name(t)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types for a bad name
                raise ParameterError(f"recorder: topic '{t}' is not a valid topic name: {exc}") from None
            if name in loop and not self.include_loop:
                skipped.append(name)
            elif name not in wanted:
                wanted.append(name)
        if not wanted:
            raise ParameterError("recorder: no topic left to record; check 'topics' and 'include_loop_topics'")
        return wanted, skipped

    def discover(self) -> None:
        """Subscribe to every wanted topic the graph knows and that is not recorded yet.

        A topic with publishers is subscribed with a QoS matching their offers. A
        topic that so far only has subscribers (the plant listens to ``excitation``
        long before the generator publishes) is subscribed at once if it is an ambid
        topic, with the graph's conventional QoS, so its first messages are not lost
        to the discovery delay; other topics wait for a publisher.
        """
        if not self.rec.open:
            return
        graph = None
        for topic in self.wanted:
            if topic in self.subs or topic in self.ignored:
                continue
            if graph is None:
                graph = dict(self.get_topic_names_and_types())
            types = graph.get(topic)
            if not types:
                continue
            if len(types) > 1:
                self.ignore(topic, "topic_type_conflict", f"{topic} has several types {types}; not recorded "
                            "(rosbag2 refuses it too): fix the publishers")
                continue
            offered = self.get_publishers_info_by_topic(topic)
            if offered or topic in self.conventional_qos:
                self.start_topic(topic, types[0], offered)

    def start_topic(self, topic: str, type_name: str, offered: list) -> None:
        try:
            cls = message_class(type_name)
        except (ImportError, AttributeError, ValueError) as exc:
            self.ignore(topic, "topic_skipped", f"{topic}: type {type_name} is not installed here ({exc}); "
                        "not recorded: source the workspace that defines it")
            return
        self.types[topic] = type_name
        if offered and not self.register(topic, offered):
            return
        profiles = [p.qos_profile for p in offered] or [self.conventional_qos[topic]]
        sub_qos = subscription_qos(profiles)
        self.rec.track(topic, sample_blocks=type_name == SAMPLE_BLOCK_TYPE)
        if type_name in FACT_TYPES:
            self.fact_decoders[topic] = (FACT_TYPES[type_name], cls)
        if not self.identity.open and "session_id" in cls.get_fields_and_field_types():
            self.session_of[topic] = (sample_block_session if type_name == SAMPLE_BLOCK_TYPE
                                      else functools.partial(_decoded_session, cls))
        if not self.identity.open and topic in self.by_gid:
            # no session id in the message: taken from the session's publisher only, by GID
            deliver = functools.partial(self.on_tapped, topic)
            entry = LoopEntry(self, cls, topic, sub_qos, None, None, deliver)
            partner = LoopPartner(self.identity, entry.entry, entry.subscription.get_topic_name(), deliver,
                                  functools.partial(self.on_foreign_gid, topic), NOT_RUN)
            self.taps[topic] = (entry, partner)
            self.subs[topic] = entry.subscription
        else:
            self.subs[topic] = self.create_subscription(cls, topic, functools.partial(self.on_message, topic),
                                                        sub_qos, raw=True)
        self.event(SessionEvent.INFO, "topic_recorded",
                   f"{topic} ({type_name}, {len(offered)} publisher(s), {sub_qos.reliability.name.lower()}, "
                   f"{sub_qos.durability.name.lower()})")

    def register(self, topic: str, offered: list) -> bool:
        """Add the topic's channel to the file with the publishers' offered QoS and type hash."""
        hashes = {str(p.topic_type_hash) for p in offered}
        type_hash = hashes.pop() if len(hashes) == 1 and next(iter(hashes)).startswith("RIHS01_") else None
        try:
            self.rec.add_topic(topic, self.types[topic], [p.qos_profile for p in offered], type_hash=type_hash)
        except SessionWriteError as exc:
            self.fail(exc)
            return False
        except (FileNotFoundError, ValueError) as exc:
            self.ignore(topic, "topic_skipped", f"{topic}: cannot store the definition of {self.types[topic]} "
                        f"({exc})")
            return False
        return True

    def ignore(self, topic: str, code: str, why: str) -> None:
        self.ignored.add(topic)
        self.get_logger().warn(why)
        self.event(SessionEvent.WARN, code, why)

    # --- recording --------------------------------------------------------
    def on_tapped(self, topic: str, data: bytes, code: int) -> None:
        """A message of a tapped topic from the session's publisher."""
        self.on_message(topic, data)

    def on_message(self, topic: str, data: bytes) -> None:
        rec = self.rec
        rec.received += 1
        session_of = self.session_of.get(topic)
        if session_of is not None:
            try:
                session = session_of(data)
            except (ValueError, BadMessage):  # bytes that do not decode name no session: not shown to be ours
                rec.rejected += 1
                return
            if session != self.identity.id:
                self.keep_out(topic, session)
                return
        if not rec.open:
            rec.rejected += 1
            return
        now, back = rec.log_time(self.get_clock().now().nanoseconds)
        if back and not self.clock_back_reported:
            self.clock_back_reported = True
            self.event(SessionEvent.WARN, "clock_backwards",
                       f"the ROS clock stepped back by {back * 1e-9:.6f} s; log times are held at the last time "
                       "so they stay non-decreasing")
        if topic not in rec.registered and (
                topic in self.ignored or not self.register(topic, self.get_publishers_info_by_topic(topic))):
            rec.rejected += 1
            return
        try:
            rec.write(topic, data, now)
        except SessionWriteError as exc:
            rec.rejected += 1
            self.fail(exc)
            return
        if topic in self.fact_decoders:
            self.update_facts(topic, data)

    def keep_out(self, topic: str, session: int | None = None, gid: bytes | None = None,
                 count: bool = True) -> None:
        """A message of another session on ``topic`` (or, ``gid``, the first of a foreign publisher of a tapped
        topic, counted by its tap): not recorded; counted, named, reported (throttled)."""
        if count:
            self.foreign[topic] = self.foreign.get(topic, 0) + 1
        who = ([self.identity.name_gid(gid, topic)] if gid is not None else self.identity.foreign_publishers(topic))
        if not who:
            who = [f"a publisher gone from the graph (session {format_session(session or 0)})"]
        if gid is None:  # the topic's foreign publishers as the graph shows them now
            self.foreign_names[topic] = set(who[:MAX_NAMES])
        else:
            names = self.foreign_names.setdefault(topic, set())
            for name in who:
                if len(names) < MAX_NAMES:
                    names.add(name)
            if UNNAMED in who[0]:  # named again once the graph knows its node (at the latest, at close)
                self.unnamed.setdefault(topic, {})[bytes(gid)] = who[0]
        now = time.monotonic()
        last, then = self.foreign_reported.get(topic, (-1e9, 0))
        n = self.foreign_count(topic)
        if now - last < FOREIGN_EVENT_S:
            return
        self.foreign_reported[topic] = (now, n)
        sid = f" of session {format_session(session)}" if session is not None else ""
        more = f" ({n - then - 1} more since the last report)" if n - then > 1 else ""
        self.event(SessionEvent.WARN, "foreign_message",
                   f"{topic}: a message{sid} from {', '.join(who)}, not of this session "
                   f"({self.identity}): counted, not recorded{more}")

    def on_foreign_gid(self, topic: str, gid: bytes) -> None:
        self.keep_out(topic, gid=gid, count=False)

    def foreign_figures(self) -> dict:
        """{topic: {"messages": n, "from": [publishers named]}} of the foreign messages kept out so far; once
        the file is closed, what its facts say (the last status then names what the file names)."""
        if self.rec.closed:
            return (self.summary or {}).get("foreign", {})
        for topic, gids in self.unnamed.items():   # a publisher first named by its GID: by its node, if known now
            names = self.foreign_names.get(topic, set())
            for gid, old in list(gids.items()):
                new = self.identity.name_gid(gid, topic)
                if UNNAMED not in new and GONE not in new:
                    names.discard(old)
                    names.add(new)
                    del gids[gid]
        out = {}
        for topic in sorted(set(self.foreign) | set(self.taps)):
            n = self.foreign_count(topic)
            if n:
                out[topic] = {"messages": n, "from": sorted(self.foreign_names.get(topic, ()))}
        return out

    def foreign_count(self, topic: str) -> int:
        tap = self.taps.get(topic)
        return self.foreign.get(topic, 0) + (tap[1].foreign if tap is not None else 0)

    def update_facts(self, topic: str, data: bytes) -> None:
        """Session facts from a description message; one that is malformed is recorded but adds no fact."""
        key, cls = self.fact_decoders[topic]
        try:
            msg = deserialize_message(data, cls)
            if key == "plant":
                check_plant_description(msg)
                facts = {"plant": plant_facts(msg), "rig": msg.rig_json}
            elif key == "controller":
                check_controller_description(msg)
                facts = {"controller": controller_facts(msg)}
            else:
                check_design(msg)
                facts = self.rec.design_facts(msg.experiment_id, design_facts(msg))
            self.rec.write_facts(facts)  # unless a latched message came again
        except SessionWriteError as exc:
            self.fail(exc)
        except Exception as exc:  # noqa: BLE001 - a malformed description must not stop the recording
            # reported at most once a second (a flood of bad descriptions must not slow recording down:
            # rclpy's logger costs milliseconds per call, throttled or not)
            self.unreadable += 1
            now = time.monotonic()
            if now - self.unreadable_reported >= 1.0:
                more = f" ({self.unreadable - 1} more since the last report)" if self.unreadable > 1 else ""
                why = f"{topic}: recorded, but no session facts could be read from it: {exc}{more}"
                self.get_logger().warn(why)
                self.event(SessionEvent.WARN, "unreadable_description", why)
                self.unreadable, self.unreadable_reported = 0, now

    def flush(self) -> None:
        if not self.rec.open:
            return
        try:
            self.rec.flush()
        except SessionWriteError as exc:
            self.fail(exc)

    def fail(self, exc: Exception) -> None:
        """Stop recording after a write error; keep what is on disk readable."""
        if self.rec.failed:
            return
        text = self.rec.fail(exc)
        self.get_logger().error(text)
        self.event(SessionEvent.ERROR, "write_failed", text)
        self.discovery_timer.cancel()  # the subscriptions stay (destroying one inside its callback is unsafe)
        self.flush_timer.cancel()
        self.summary = {**self.rec.figures(), "foreign": self.foreign_figures()}
        self.publish_status()
        if not self.finished.done():
            self.finished.set_result(self.summary)

    # --- reporting --------------------------------------------------------
    def publish_status(self) -> None:
        rec = self.rec
        f = rec.figures()
        state = f["state"]
        shown = {"path": self.path, "messages": f["messages"], "bytes_received": f["bytes_received"],
                 "file_bytes": f["file_bytes"], "chunks": f["chunks"], "flushed_messages": f["flushed_messages"],
                 "last_flush_age_s": round(time.monotonic() - rec.last_flush_wall, 3)}
        shown.update((f"messages:{topic}", n) for topic, n in sorted(rec.counts.items()))
        shown.update((f"end_index:{topic}", end) for topic, end in sorted(rec.block_end.items()))
        for topic, kept_out in self.foreign_figures().items():
            shown[f"foreign:{topic}"] = kept_out["messages"]
            shown[f"foreign_from:{topic}"] = kept_out["from"]
        measurement = self.resolve_topic_name("measurement")
        text = (f"{state}: {f['messages']} messages ({f['messages_per_wall_s']:.0f}/s), "
                f"{f['file_bytes'] / 1e6:.2f} MB in {self.path}" + (f"; {rec.failed}" if rec.failed else ""))
        states = {"running": SessionStatus.STATE_RUNNING, "done": SessionStatus.STATE_DONE,
                  "failed": SessionStatus.STATE_FAILED}
        try:
            self.pub_status.publish(status_msg(
                self.get_clock().now().to_msg(), self.get_fully_qualified_name(), states[state],
                rec.block_end.get(measurement, 0), -1.0, rec.received, rec.rejected, text, shown))
        except Exception:  # noqa: BLE001 - the context may already be shut down (SIGINT)
            pass

    def event_index(self) -> int:
        """Where the recording stands: the end of the newest block recorded."""
        return max(self.rec.block_end.values(), default=0)

    def event_stamp(self, index: int):
        return self.get_clock().now().to_msg()

    # --- shutdown ---------------------------------------------------------
    def close(self) -> dict:
        """Write the last chunk, summary and footer; stop recording. Idempotent; returns the summary."""
        if self.rec.closed:
            return self.summary
        for timer in (self.flush_timer, self.discovery_timer, self.status_timer):
            timer.cancel()
        # taken once: the file's facts and the summary (identify's line) name the same publishers, also where
        # the graph learns a GID-named one's node while the file closes
        foreign = self.foreign_figures()
        if not self.rec.failed:
            try:
                if foreign:  # what was kept out, in the file's facts (the last status comes after the file)
                    self.rec.write_facts({"foreign": foreign})
                self.rec.close()
            except SessionWriteError as exc:
                self.get_logger().error(f"closing {self.path} failed: {exc}")
                self.event(SessionEvent.ERROR, "write_failed", f"closing {self.path} failed: {exc}")
            self.summary = {**self.rec.figures(), "foreign": foreign}
        self.rec.closed = True
        line = (f"closed {self.path}: {self.summary['messages']} messages, {self.summary['file_bytes']} bytes, "
                f"{self.summary['state']}")
        if self.context.ok():
            self.get_logger().info(line)
        else:  # after SIGINT/SIGTERM the logger's rosout publisher is gone
            print(f"[recorder] {line}", file=sys.stderr, flush=True)
        self.publish_status()
        self.event(SessionEvent.INFO, "recording_closed", json.dumps(self.summary))
        return self.summary

    def destroy_node(self) -> None:
        self.close()
        for entry, _ in self.taps.values():
            entry.close()
        super().destroy_node()


main = Recorder.main  # the console script: SessionNode.main (SIGINT/SIGTERM close the file)


if __name__ == "__main__":
    sys.exit(main())
