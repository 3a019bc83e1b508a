"""Write an ambid session as an MCAP file laid out like rosbag2's MCAP storage.

The file is what ``ros2 bag record -s mcap`` (Jazzy) writes, so ``ros2 bag
info``, Foxglove and the ``mcap`` tools open it:

- header profile ``ros2``;
- one schema per type: encoding ``ros2msg``, data = full .msg text with its
  dependencies appended (:mod:`ambid.recording.ros2_schema`);
- one channel per topic: message encoding ``cdr``, metadata
  ``offered_qos_profiles`` (YAML, rosbag2 metadata version 9 layout) and
  ``topic_type_hash`` (``RIHS01_...``);
- messages carry the serialized CDR bytes as received, log time = receive
  time in ns;
- on :meth:`SessionWriter.close`, a metadata record ``rosbag2`` with key
  ``serialized_metadata`` (the bag's ``metadata.yaml`` content), then the
  summary: schemas, channels, statistics, chunk indexes, metadata indexes,
  summary offsets, footer.

Crash safety: messages are grouped in compressed chunks; a chunk is closed
when it reaches ``chunk_size_bytes`` or spans ``chunk_max_duration_ns`` of log
time (or on :meth:`SessionWriter.flush`), and each closed chunk and its
message indexes are written and flushed to the operating system at once
(``os.fsync`` too with ``fsync=True``). A writer killed with SIGKILL therefore
loses at most its open chunk; :func:`ambid.recording.reader.scan_session`
and ``recover=True`` read the rest.

Pure Python (mcap, PyYAML); nothing here imports rclpy.
"""

from __future__ import annotations

import errno
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterable, Mapping

import yaml
from mcap.writer import LIBRARY_IDENTIFIER as MCAP_LIBRARY_IDENTIFIER
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from ambid.version import __version__ as AMBID_VERSION
from .ros2_schema import MessageSchema, load_message_schema, normalize_type_name

__all__ = [
    "DURATION_INFINITE_NS",
    "SESSION_METADATA_NAME",
    "ROSBAG2_METADATA_NAME",
    "QosProfile",
    "qos_profile_from",
    "serialize_qos_profiles",
    "parse_qos_profiles",
    "available_compressions",
    "SessionWriteError",
    "SessionWriter",
]

#: rmw's RMW_DURATION_INFINITE in ns ({sec: 9223372036, nsec: 854775807}).
DURATION_INFINITE_NS = 2**63 - 1
#: Name of the MCAP metadata record holding the session facts.
SESSION_METADATA_NAME = "ambid.session"
#: Name of the MCAP metadata record rosbag2 reads its bag metadata from.
ROSBAG2_METADATA_NAME = "rosbag2"
#: rosbag2_storage BagMetadata version written by Jazzy.
ROSBAG2_METADATA_VERSION = 9
# libyaml when PyYAML has it: the metadata holds the session facts, ~150 kB, 0.27 s in pure Python
_SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)

_POLICY_VALUES = {
    "history": ("keep_last", "keep_all", "system_default", "unknown"),
    "reliability": ("reliable", "best_effort", "system_default", "best_available", "unknown"),
    "durability": ("volatile", "transient_local", "system_default", "best_available", "unknown"),
    "liveliness": ("automatic", "manual_by_topic", "system_default", "best_available", "unknown"),
}
# Size of a Message record without its payload: opcode, length, channel id,
# sequence, log time, publish time.
_MESSAGE_RECORD_OVERHEAD = 1 + 8 + 2 + 4 + 8 + 8
_UINT64_MAX = 2**64 - 1


@dataclass(frozen=True)
class QosProfile:
    """QoS profile offered by one publisher, as rosbag2 records it.

    Policies are rmw's lower-case names (``"keep_last"``, ``"reliable"``,
    ``"volatile"``, ``"automatic"``, ...); durations are in ns, with
    :data:`DURATION_INFINITE_NS` for "infinite" and 0 for "unspecified".
    The defaults are what a default rclpy/rclcpp publisher reports.
    """

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline_ns: int = DURATION_INFINITE_NS
    lifespan_ns: int = DURATION_INFINITE_NS
    liveliness: str = "automatic"
    liveliness_lease_duration_ns: int = DURATION_INFINITE_NS
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        for key, allowed in _POLICY_VALUES.items():
            value = getattr(self, key)
            if value not in allowed:
                raise ValueError(f"QoS {key} {value!r} is not one of {allowed}")
        if not isinstance(self.depth, int) or self.depth < 0:
            raise ValueError(f"QoS depth must be an integer >= 0, got {self.depth!r}")
        for key in ("deadline_ns", "lifespan_ns", "liveliness_lease_duration_ns"):
            value = getattr(self, key)
            if not isinstance(value, int) or not 0 <= value <= DURATION_INFINITE_NS:
                raise ValueError(f"QoS {key} must be an integer in [0, 2**63-1] ns, got {value!r}")

    def to_rosbag2(self) -> dict[str, Any]:
        """The profile as a dict in rosbag2's (version 9) key order and layout."""

        def dur(ns: int) -> dict[str, int]:
            return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}

        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": dur(self.deadline_ns),
            "lifespan": dur(self.lifespan_ns),
            "liveliness": self.liveliness,
            "liveliness_lease_duration": dur(self.liveliness_lease_duration_ns),
            "avoid_ros_namespace_conventions": bool(self.avoid_ros_namespace_conventions),
        }


def _policy_name(value: Any) -> str:
    # rclpy policies are enums (HistoryPolicy.KEEP_LAST); rmw's strings are their lower-case names.
    name = getattr(value, "name", value)
    return str(name).lower()


def _duration_ns(value: Any, key: str) -> int:
    if isinstance(value, Mapping):
        ns = int(value["sec"]) * 1_000_000_000 + int(value["nsec"])
    elif hasattr(value, "nanoseconds"):  # rclpy.duration.Duration
        ns = int(value.nanoseconds)
    elif isinstance(value, int):
        ns = value
    else:
        raise ValueError(f"QoS {key} {value!r} is neither {{sec, nsec}}, a Duration nor ns")
    return min(ns, DURATION_INFINITE_NS)


def qos_profile_from(profile: Any) -> QosProfile:
    """Convert a publisher's offered QoS to a :class:`QosProfile`.

    Parameters
    ----------
    profile
        a :class:`QosProfile`; an rclpy ``QoSProfile`` (duck-typed:
        policy enums, ``Duration`` attributes; e.g. from
        ``node.get_publishers_info_by_topic(t)[i].qos_profile``); or a
        dict in rosbag2's layout (as :meth:`QosProfile.to_rosbag2` gives).

    Raises
    ------
    ValueError
        on unknown policy names or bad durations.
    """
    if isinstance(profile, QosProfile):
        return profile
    if isinstance(profile, Mapping):
        get = profile.__getitem__
    else:
        def get(key: str) -> Any:
            return getattr(profile, key)
    try:
        return QosProfile(
            history=_policy_name(get("history")),
            depth=int(get("depth")),
            reliability=_policy_name(get("reliability")),
            durability=_policy_name(get("durability")),
            deadline_ns=_duration_ns(get("deadline"), "deadline"),
            lifespan_ns=_duration_ns(get("lifespan"), "lifespan"),
            liveliness=_policy_name(get("liveliness")),
            liveliness_lease_duration_ns=_duration_ns(
                get("liveliness_lease_duration"), "liveliness_lease_duration"
            ),
            avoid_ros_namespace_conventions=bool(get("avoid_ros_namespace_conventions")),
        )
    except (KeyError, AttributeError) as exc:
        raise ValueError(f"QoS profile {profile!r} lacks field {exc}; pass an rclpy QoSProfile or a rosbag2 dict") from exc


def serialize_qos_profiles(profiles: Iterable[Any]) -> str:
    """rosbag2's ``offered_qos_profiles`` channel metadata string.

    Block-style YAML list of dicts (history, depth, reliability, durability,
    deadline {sec, nsec}, lifespan, liveliness, liveliness_lease_duration,
    avoid_ros_namespace_conventions), without trailing newline, as yaml-cpp's
    ``YAML::Dump`` writes it; ``"[]"`` when no publisher was seen.
    """
    items = [qos_profile_from(p).to_rosbag2() for p in profiles]
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False).rstrip("\n")


def parse_qos_profiles(text: str) -> list[QosProfile]:
    """Inverse of :func:`serialize_qos_profiles` (empty text gives ``[]``)."""
    items = yaml.safe_load(text) if text else []
    if not isinstance(items, list):
        raise ValueError(f"offered_qos_profiles must be a YAML list, got {type(items).__name__}")
    return [qos_profile_from(item) for item in items]


def available_compressions() -> tuple[str, ...]:
    """Chunk compressions usable here: subset of ``("zstd", "lz4")`` plus ``"none"``."""
    # a probe: whether each library imports is the answer
    out = []
    try:
        import zstandard  # noqa: F401

        out.append("zstd")
    except ImportError:
        pass
    try:
        import lz4.frame  # noqa: F401

        out.append("lz4")
    except ImportError:
        pass
    return tuple(out) + ("none",)


_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


class SessionWriteError(OSError):
    """Writing the session file failed (disk full, I/O error); ``errno`` is kept.

    What was written before the failure stays readable with
    ``read_messages(path, recover=True)``.
    """


@dataclass(frozen=True)
class _Topic:
    channel_id: int
    schema: MessageSchema
    qos_yaml: str


def _json_or_str(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, sort_keys=True)


class SessionWriter:
    """Streaming writer of one session MCAP file (not thread-safe).

    Usage::

        with SessionWriter("run/session.mcap") as w:
            w.write_session_facts({"rig": "sim", "excitation": design_dict})
            w.add_topic("/amb/y", "ambid_msgs/msg/SampleBlock", qos_profiles)
            w.write("/amb/y", cdr_bytes, log_time_ns=t_ns)

    Parameters
    ----------
    output
        file path, or a binary file object with ``write``, ``tell``
        and ``flush`` (not closed by the writer).
    chunk_size_bytes
        a chunk is closed once its uncompressed messages
        reach this size [bytes].
    chunk_max_duration_ns
        a chunk is closed before a message whose log
        time is this much later than the chunk's first [ns], so a slow
        topic still reaches the file regularly.
    compression
        ``"zstd"``, ``"lz4"`` or ``"none"``.
    fsync
        also ``os.fsync`` the file after each chunk (survives power
        loss, costs a disk sync per chunk).
    overwrite
        allow replacing an existing file at ``output``.
    ros_distro
        stored in the rosbag2 metadata.
    prefixes
        ament install prefixes to look definitions up in;
        ``None`` uses ``AMENT_PREFIX_PATH``.

    Raises
    ------
    ValueError
        on bad sizes, durations or compression names.
    FileExistsError
        if ``output`` exists and ``overwrite`` is False.
    """

    def __init__(
        self,
        output: str | os.PathLike | IO[bytes],
        *,
        chunk_size_bytes: int = 1024 * 1024,
        chunk_max_duration_ns: int = 1_000_000_000,
        compression: str = "zstd",
        fsync: bool = False,
        overwrite: bool = False,
        ros_distro: str = "jazzy",
        prefixes: Iterable[os.PathLike | str] | None = None,
    ) -> None:
        if not isinstance(chunk_size_bytes, int) or chunk_size_bytes <= 0:
            raise ValueError(f"chunk_size_bytes must be a positive integer, got {chunk_size_bytes!r}")
        if not isinstance(chunk_max_duration_ns, int) or chunk_max_duration_ns <= 0:
            raise ValueError(
                f"chunk_max_duration_ns must be a positive integer (ns), got {chunk_max_duration_ns!r}"
            )
        if compression not in _COMPRESSION:
            raise ValueError(f"compression {compression!r} is not one of {tuple(_COMPRESSION)}")
        if compression not in available_compressions():
            raise ValueError(
                f"compression {compression!r} needs a package that is not installed "
                f"({'zstandard' if compression == 'zstd' else 'lz4'}); usable here: {available_compressions()}"
            )
        self._chunk_size = chunk_size_bytes
        self._chunk_max_ns = chunk_max_duration_ns
        self._compression = compression
        self._fsync = bool(fsync)
        self._ros_distro = ros_distro
        self._prefixes = None if prefixes is None else [Path(p) for p in prefixes]

        if isinstance(output, (str, os.PathLike)):
            self._path: str | None = os.fspath(output)
            if not overwrite and os.path.exists(self._path):
                raise FileExistsError(
                    errno.EEXIST, "session file exists; pass overwrite=True or choose a new path", self._path
                )
            self._stream: IO[bytes] = open(self._path, "wb")
            self._owns_stream = True
        else:
            self._path = getattr(output, "name", None) if isinstance(getattr(output, "name", None), str) else None
            self._stream = output
            self._owns_stream = False

        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._topic_counts: dict[str, int] = {}
        self._session_facts: dict[str, str] = {}
        self._message_count = 0
        self._flushed_message_count = 0
        self._chunk_count = 0
        self._chunk_messages = 0
        self._chunk_bytes = 0
        self._chunk_first_ns = 0
        self._start_ns: int | None = None
        self._end_ns = 0
        self._failed: SessionWriteError | None = None
        self._closed = False

        self._mcap = McapWriter(
            self._stream,
            # Chunks are closed here (size and log-time span), never by the library.
            chunk_size=2**62,
            compression=_COMPRESSION[compression],
        )
        self._guarded(self._start, "writing the MCAP header")

    # -- public API ---------------------------------------------------------

    @property
    def path(self) -> str | None:
        """Path of the file written, if known."""
        return self._path

    @property
    def message_count(self) -> int:
        """Messages accepted so far."""
        return self._message_count

    @property
    def flushed_message_count(self) -> int:
        """Messages in chunks already handed to the operating system."""
        return self._flushed_message_count

    @property
    def chunk_count(self) -> int:
        """Chunks closed and written so far."""
        return self._chunk_count

    @property
    def topics(self) -> dict[str, str]:
        """Registered topics: ``{topic: "pkg/msg/Type"}``."""
        return {t: info.schema.type_name for t, info in self._topics.items()}

    def add_topic(
        self,
        topic: str,
        type_name: str,
        qos_profiles: Iterable[Any] = (),
        *,
        definition: str | Mapping[str, str] | None = None,
        type_hash: str | None = None,
    ) -> int:
        """Register a topic (channel) and, once per type, its schema.

        Parameters
        ----------
        topic
            topic name, e.g. ``"/amb/y"``.
        type_name
            ``pkg/msg/Type``, e.g. ``"ambid_msgs/msg/SampleBlock"``.
        qos_profiles
            QoS offered by each publisher (rclpy ``QoSProfile``,
            :class:`QosProfile` or rosbag2 dicts).
        definition
            the type's own .msg text, or a mapping of .msg texts
            by type name (the type and any of its dependencies); other
            definitions are read from the install prefixes.
        type_hash
            ``RIHS01_...``; ``None`` reads it from the installed
            ``<Type>.json`` (empty if absent).

        Returns
        -------
        The MCAP channel id.

        Raises
        ------
        ValueError
            if the topic is already registered with another type,
            or on bad names.
        FileNotFoundError
            if a definition is neither given nor installed.
        """
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"topic must be a non-empty string, got {topic!r}")
        full = normalize_type_name(type_name)
        if topic in self._topics:
            known = self._topics[topic].schema.type_name
            if known != full:
                raise ValueError(f"topic {topic!r} is already recorded with type {known}, not {full}")
            return self._topics[topic].channel_id
        if isinstance(definition, str):
            definition = {full: definition}
        schema = load_message_schema(full, self._prefixes, definition, type_hash)
        qos_yaml = serialize_qos_profiles(qos_profiles)

        def register() -> int:
            if full not in self._schema_ids:
                self._schema_ids[full] = self._mcap.register_schema(
                    name=full, encoding="ros2msg", data=schema.definition.encode("utf-8")
                )
            return self._mcap.register_channel(
                topic=topic,
                message_encoding="cdr",
                schema_id=self._schema_ids[full],
                metadata={"offered_qos_profiles": qos_yaml, "topic_type_hash": schema.type_hash},
            )

        channel_id = self._guarded(register, f"registering topic {topic}")
        self._topics[topic] = _Topic(channel_id, schema, qos_yaml)
        self._topic_counts[topic] = 0
        return channel_id

    def write(
        self,
        topic: str,
        data: bytes | bytearray | memoryview,
        log_time_ns: int,
        *,
        publish_time_ns: int | None = None,
        sequence: int = 0,
    ) -> None:
        """Append one serialized message.

        Parameters
        ----------
        topic
            a topic registered with :meth:`add_topic`.
        data
            CDR bytes as received (``raw=True`` subscription).
        log_time_ns
            receive time [ns], 0 <= t < 2**64.
        publish_time_ns
            send time [ns]; defaults to ``log_time_ns``.
        sequence
            publisher sequence number if known (uint32).

        Raises
        ------
        ValueError
            on an unknown topic, non-bytes data or bad times.
        SessionWriteError
            if the file cannot be written (disk full...).
        """
        self._check_open()
        info = self._topics.get(topic)
        if info is None:
            raise ValueError(f"topic {topic!r} is not registered; call add_topic(topic, type_name, qos) first")
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise ValueError(f"data must be the serialized message bytes, got {type(data).__name__}")
        if publish_time_ns is None:
            publish_time_ns = log_time_ns
        for key, value in (("log_time_ns", log_time_ns), ("publish_time_ns", publish_time_ns)):
            if not isinstance(value, int) or not 0 <= value <= _UINT64_MAX:
                raise ValueError(f"{key} must be an integer in [0, 2**64) ns, got {value!r}")
        if not isinstance(sequence, int) or not 0 <= sequence < 2**32:
            raise ValueError(f"sequence must be an integer in [0, 2**32), got {sequence!r}")
        payload = bytes(data)

        if self._chunk_messages and log_time_ns - self._chunk_first_ns >= self._chunk_max_ns:
            self._guarded(self._close_chunk, "writing a chunk")

        def add() -> None:
            self._mcap.add_message(
                channel_id=info.channel_id,
                log_time=log_time_ns,
                data=payload,
                publish_time=publish_time_ns,
                sequence=sequence,
            )

        self._guarded(add, f"adding a message on {topic}")
        if self._chunk_messages == 0:
            self._chunk_first_ns = log_time_ns
        self._chunk_first_ns = min(self._chunk_first_ns, log_time_ns)
        self._chunk_messages += 1
        self._chunk_bytes += _MESSAGE_RECORD_OVERHEAD + len(payload)
        self._message_count += 1
        self._topic_counts[topic] += 1
        self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
        self._end_ns = max(self._end_ns, log_time_ns)
        if self._chunk_bytes >= self._chunk_size:
            self._guarded(self._close_chunk, "writing a chunk")

    def add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """Write an MCAP metadata record now (and flush it to the OS).

        Parameters
        ----------
        name
            record name, e.g. ``"ambid.session"``.
        data
            key/values; non-string values are stored as JSON text.
        """
        self._check_open()
        if not isinstance(name, str) or not name:
            raise ValueError(f"metadata name must be a non-empty string, got {name!r}")
        if name == ROSBAG2_METADATA_NAME:
            raise ValueError(f"metadata name {name!r} is reserved: the writer writes it on close()")
        record = self._string_map(data)

        def add() -> None:
            self._mcap.add_metadata(name, record)
            self._stream.flush()

        self._guarded(add, f"writing metadata {name!r}")

    def write_session_facts(self, facts: Mapping[str, Any]) -> None:
        """Store the session's own facts as metadata record ``ambid.session``.

        Parameters
        ----------
        facts
            e.g. ``{"rig": ..., "controller": ..., "excitation": {...},
            "parameters": {...}}``; non-string values become JSON text.
            Key ``ambid_version`` is added unless given. The facts are also
            copied into the rosbag2 metadata's ``custom_data``.
        """
        record = self._string_map(facts)
        record.setdefault("ambid_version", AMBID_VERSION)
        self.add_metadata(SESSION_METADATA_NAME, record)
        self._session_facts.update(record)

    def add_attachment(
        self,
        name: str,
        data: bytes,
        media_type: str = "application/octet-stream",
        *,
        log_time_ns: int = 0,
        create_time_ns: int = 0,
    ) -> None:
        """Write an MCAP attachment (a file stored whole, e.g. a config YAML)."""
        self._check_open()
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise ValueError(f"attachment data must be bytes, got {type(data).__name__}")

        def add() -> None:
            self._mcap.add_attachment(create_time_ns, log_time_ns, name, media_type, bytes(data))
            self._stream.flush()

        self._guarded(add, f"writing attachment {name!r}")

    def flush(self) -> None:
        """Close the open chunk (if it has messages) and hand it to the OS now.

        A recorder may call this from a wall-clock timer so that a topic that
        stopped publishing still reaches the disk.
        """
        self._check_open()
        self._guarded(self._close_chunk, "writing a chunk")

    def close(self) -> None:
        """Write the last chunk, the rosbag2 metadata, the summary and the footer.

        Safe to call twice. After a write failure it only releases the file:
        the part written before the failure is readable with ``recover=True``.

        Raises
        ------
        SessionWriteError
            if the summary cannot be written.
        """
        if self._closed:
            return
        self._closed = True
        try:
            if self._failed is None:
                self._guarded(self._finish, "writing the summary")
        finally:
            if self._owns_stream:
                try:
                    self._stream.close()
                except OSError:
                    pass  # the buffered tail of a failed write cannot be saved anyway

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- internals ----------------------------------------------------------

    def _check_open(self) -> None:
        if self._failed is not None:
            raise self._failed
        if self._closed:
            raise ValueError(f"session writer for {self._path or 'stream'} is closed")

    @staticmethod
    def _string_map(data: Mapping[str, Any]) -> dict[str, str]:
        if not isinstance(data, Mapping):
            raise ValueError(f"metadata must be a mapping of str keys, got {type(data).__name__}")
        out = {}
        for key, value in data.items():
            if not isinstance(key, str):
                raise ValueError(f"metadata key {key!r} is not a string")
            out[key] = _json_or_str(value)
        return out

    def _guarded(self, action, what: str):
        try:
            return action()
        except OSError as exc:
            where = self._path or repr(self._stream)
            reason = "disk full" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
            self._failed = SessionWriteError(
                exc.errno,
                f"{what} failed ({reason}); {self._flushed_message_count} messages in "
                f"{self._chunk_count} complete chunks are on disk, read them with recover=True",
                where,
            )
            raise self._failed from exc

    def _start(self) -> None:
        library = f"ambid {AMBID_VERSION}; {MCAP_LIBRARY_IDENTIFIER}"
        self._mcap.start(profile="ros2", library=library)
        self._stream.flush()

    def _sync(self) -> None:
        self._stream.flush()
        if self._fsync:
            fileno = getattr(self._stream, "fileno", None)
            if fileno is not None:
                os.fsync(fileno())

    def _close_chunk(self) -> None:
        had_messages = self._chunk_messages > 0
        self._mcap.flush()  # finishes the chunk and its message indexes, flushes the stream
        self._sync()
        if had_messages:
            self._chunk_count += 1
        self._flushed_message_count = self._message_count
        self._chunk_messages = 0
        self._chunk_bytes = 0

    def rosbag2_metadata_yaml(self) -> str:
        """The ``serialized_metadata`` YAML rosbag2 Jazzy stores (BagMetadata v9)."""
        start = self._start_ns or 0
        duration = self._end_ns - start if self._message_count else 0
        name = os.path.basename(self._path) if self._path else "session.mcap"
        topics = [
            {
                "topic_metadata": {
                    "name": topic,
                    "type": info.schema.type_name,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": yaml.safe_load(info.qos_yaml) or [],
                    "type_description_hash": info.schema.type_hash,
                },
                "message_count": self._topic_counts[topic],
            }
            for topic, info in self._topics.items()
        ]
        meta = {
            "version": ROSBAG2_METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self._message_count,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [name],
            "files": [
                {
                    "path": name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": self._message_count,
                }
            ],
            "custom_data": dict(self._session_facts) or None,
            "ros_distro": self._ros_distro,
        }
        return yaml.dump(meta, Dumper=_SAFE_DUMPER, sort_keys=False, default_flow_style=False)

    def _finish(self) -> None:
        self._close_chunk()
        self._mcap.add_metadata(ROSBAG2_METADATA_NAME, {"serialized_metadata": self.rosbag2_metadata_yaml()})
        self._mcap.finish()
        self._sync()
