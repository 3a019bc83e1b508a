"""A session being recorded: the MCAP writer and the bookkeeping a recorder keeps beside it.

:class:`Recording` takes each message's CDR bytes as received, stamps it with
a log time kept non-decreasing, writes it (:class:`ambid.recording.writer.SessionWriter`),
counts it per topic, follows the end index of every SampleBlock topic, and
keeps the session facts (rig, plant and controller descriptions, excitation
designs) written as MCAP metadata ``ambid.session`` whenever they change. A
write failure stops the recording and leaves what is on disk readable.
The recorder node is this over ROS (discovery, subscriptions, events, status).
"""

from __future__ import annotations

import os
import time

from ambid.recording.blocks import sample_block_span
from ambid.recording.writer import SessionWriteError, SessionWriter

#: experiments whose design is kept in the session facts (each fact update rewrites them all)
MAX_DESIGN_FACTS = 1000


class Recording:
    """One MCAP file being written, with its counts and facts.

    Parameters
    ----------
    path
        the file (absolute).
    chunk_size
        uncompressed size at which a chunk is closed [bytes].
    flush_period_s
        longest a chunk stays open [s] (what a SIGKILL can lose).
    compression
        "zstd", "lz4" or "none".
    fsync
        fsync after every chunk.
    overwrite
        replace an existing file (else FileExistsError).

    Raises
    ------
    FileExistsError, OSError
        the file cannot be created.
    """

    def __init__(self, path: str, *, chunk_size: int, flush_period_s: float, compression: str, fsync: bool,
                 overwrite: bool) -> None:
        self.path = path
        os.makedirs(os.path.dirname(path), exist_ok=True)
        self.writer = SessionWriter(path, chunk_size_bytes=chunk_size, chunk_max_duration_ns=int(flush_period_s * 1e9),
                                    compression=compression, fsync=fsync, overwrite=overwrite)
        self.registered: set[str] = set()  # topics with a channel in the file
        self.counts: dict[str, int] = {}
        self.block_end: dict[str, int] = {}  # SampleBlock topic -> end index of its latest block
        self.facts: dict[str, object] = {}
        self.received = self.rejected = self.bytes = 0
        self.last_log_ns = 0
        self.failed: str | None = None
        self.closed = False
        self.started_wall = self.last_flush_wall = time.monotonic()

    @property
    def open(self) -> bool:
        """Still recording: neither closed nor failed."""
        return not (self.closed or self.failed)

    def track(self, topic: str, sample_blocks: bool = False) -> None:
        """Count the topic from now on (it is subscribed); ``sample_blocks``: follow its end index too."""
        self.counts.setdefault(topic, 0)
        if sample_blocks:
            self.block_end.setdefault(topic, 0)

    def add_topic(self, topic: str, type_name: str, qos_profiles: list, type_hash: str | None = None) -> None:
        """Add the topic's channel with its publishers' offered QoS and type hash. SessionWriteError: the
        file failed; FileNotFoundError/ValueError: the type's definition cannot be stored."""
        self.writer.add_topic(topic, type_name, qos_profiles, type_hash=type_hash)
        self.registered.add(topic)

    def log_time(self, now_ns: int) -> tuple[int, int]:
        """(the log time of a message received at ``now_ns``, how far the clock stepped back, 0 if not):
        log times never decrease, a clock stepping back holds the last one."""
        back = self.last_log_ns - now_ns
        if back > 0:
            return self.last_log_ns, back
        self.last_log_ns = now_ns
        return now_ns, 0

    def write(self, topic: str, data: bytes, log_ns: int) -> None:
        """Record one message of a registered topic. SessionWriteError: recording failed (see :meth:`fail`)."""
        self.writer.write(topic, data, log_ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.bytes += len(data)
        if topic in self.block_end:
            try:
                first, n = sample_block_span(data)
                self.block_end[topic] = max(self.block_end[topic], first + n)
            except ValueError:
                pass  # recorded as received; the consumers judge the content

    def write_facts(self, facts: dict) -> bool:
        """Merge ``facts`` into the session facts and write them if any changed (a latched message comes
        again); True if written."""
        if all(self.facts.get(k) == v for k, v in facts.items()):
            return False
        self.facts.update(facts)
        self.writer.write_session_facts(facts)
        return True

    def design_facts(self, experiment_id: str, facts: dict) -> dict:
        """The ``excitation`` fact with one experiment's design added; ValueError beyond MAX_DESIGN_FACTS."""
        designs = dict(self.facts.get("excitation", {}))
        if experiment_id not in designs and len(designs) >= MAX_DESIGN_FACTS:
            raise ValueError(f"more than {MAX_DESIGN_FACTS} experiments in one session; the facts keep the first ones")
        designs[experiment_id] = facts
        return {"excitation": designs}

    def flush(self) -> None:
        """Close the open chunk, if it holds anything. SessionWriteError: the file failed."""
        if self.writer.message_count > self.writer.flushed_message_count:
            self.writer.flush()
        self.last_flush_wall = time.monotonic()

    def fail(self, exc: Exception) -> str:
        """Stop after a write error, keep what is on disk readable; returns the text that says so."""
        self.failed = str(exc)
        self.writer.close()  # after a failure this only releases the file
        return (f"writing {self.path} failed: {exc}. Recording stopped; the file keeps "
                f"{self.writer.flushed_message_count} messages, read them with 'ambid inspect --recover'")

    def close(self) -> None:
        """Write the last chunk, the summary and the footer. SessionWriteError: closing failed (recorded)."""
        self.closed = True
        if not self.failed:
            try:
                self.writer.close()
            except SessionWriteError as exc:
                self.failed = str(exc)
                raise

    @property
    def state(self) -> str:
        return "failed" if self.failed else ("done" if self.closed else "running")

    def figures(self) -> dict:
        """What the recording holds and how fast it went."""
        wall = time.monotonic() - self.started_wall
        written = self.writer.message_count
        file_bytes = os.path.getsize(self.path) if os.path.exists(self.path) else 0
        return {"state": self.state, "path": self.path, "messages": written, "topics": dict(self.counts),
                "bytes_received": self.bytes, "file_bytes": file_bytes, "chunks": self.writer.chunk_count,
                "flushed_messages": self.writer.flushed_message_count, "messages_received": self.received,
                "messages_rejected": self.rejected, "wall_s": wall,
                "messages_per_wall_s": written / wall if wall > 0 else 0.0, "error": self.failed,
                "block_end": dict(self.block_end)}
