"""SampleBlock messages of a recorded session as numpy arrays, read fast and memory-flat.

``ambid_msgs/msg/SampleBlock`` carries n_samples x n_channels float64 values
(row-major). Decoding it with a generic CDR decoder builds a Python list of
every value (about 36 ms for a 1000 x 16 block); here the CDR is parsed by
hand and the values are a zero-copy ``numpy.frombuffer`` view of the message
bytes, so decoding costs a few microseconds and reading a session is bound by
MCAP decompression.

Memory-flat: :func:`iter_sample_blocks` holds one block at a time,
:func:`read_samples` allocates only the requested sample range.

Layout parsed (ROS 2 CDR, XCDR1 little endian as rmw_fastrtps and
rmw_cyclonedds write it on every current host; alignment counted from the end
of the 4-byte encapsulation header)::

    builtin_interfaces/Time stamp   int32 sec, uint32 nanosec
    string experiment_id            uint32 length (with NUL), bytes
    uint64 first_index              aligned to 8
    float64 sample_period
    uint32 n_samples
    string[] channel_names          uint32 count, strings
    string[] channel_units
    float64[] data                  uint32 count, values aligned to 8
    uint8[] sample_flags            uint32 count, bytes
    uint32 flags
    uint64 session_id               aligned to 8: the session that published it (absent in recordings
                                    made before sessions had ids: read as 0)

Pure Python (numpy, mcap); nothing here imports rclpy.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

# one gap/overlap rule for every sample-index report (inspect_session's, fed here from headers)
from ambid.recording.inspect import gap_report
from ambid.recording.reader import SessionMessage, iter_messages, scan_session

__all__ = [
    "SAMPLE_BLOCK_TYPE",
    "SampleBlockData",
    "SampleRange",
    "decode_sample_block",
    "encode_sample_block",
    "SampleBlockReader",
    "sample_block_session",
    "sample_block_span",
    "iter_sample_blocks",
    "sample_block_topics",
    "block_spans",
    "sample_index_report",
    "read_samples",
]

SAMPLE_BLOCK_TYPE = "ambid_msgs/msg/SampleBlock"
#: largest sample index a message may name: 2**40 samples are 3.5 years at 10 kHz, and
#: every time stamp derived from an index still fits builtin_interfaces/Time (int32 seconds)
MAX_SAMPLE_INDEX = 2**40

_CDR_LE = b"\x00\x01"  # encapsulation identifier of little-endian plain CDR (XCDR1)


@dataclass(frozen=True)
class SampleBlockData:
    """One decoded SampleBlock.

    Attributes
    ----------
    stamp_ns
        time of the first sample [ns] (simulated or target clock).
    experiment_id
        experiment the block belongs to, or ``""``.
    first_index
        sample index of the first row.
    sample_period_s
        sample period [s].
    channel_names, channel_units
        per column, e.g. ``y_a_x`` / ``m``.
    data
        (n_samples, n_channels) float64 [channel units], a read-only
        view of the message bytes (copy it to modify).
    sample_flags
        (n_samples,) uint8 ``FLAG_*`` bits, or shape (0,).
    flags
        OR of the rows' flags.
    session_id
        the session that published the block, or 0 (none).
    """

    stamp_ns: int
    experiment_id: str
    first_index: int
    sample_period_s: float
    channel_names: tuple[str, ...]
    channel_units: tuple[str, ...]
    data: np.ndarray
    sample_flags: np.ndarray
    flags: int
    session_id: int = 0

    @property
    def n_samples(self) -> int:
        """Rows of :attr:`data`."""
        return int(self.data.shape[0])


# Precompiled readers: a block is decoded in a few microseconds of Python.
_U32 = struct.Struct("<I").unpack_from
_U64 = struct.Struct("<Q").unpack_from
_TIME = struct.Struct("<iI").unpack_from
_INDEX_PERIOD_N = struct.Struct("<QdI").unpack_from  # uint64, float64, uint32: contiguous once aligned


def _truncated(pos: int, end: int) -> ValueError:
    return ValueError(f"SampleBlock CDR: truncated at byte {pos} ({end} bytes in all)")


def _check_encapsulation(buf: bytes | memoryview) -> None:
    if len(buf) < 4:
        raise ValueError(f"SampleBlock CDR: {len(buf)} bytes, too short for the encapsulation header")
    if bytes(buf[:2]) != _CDR_LE:
        raise ValueError(
            f"SampleBlock CDR: encapsulation {bytes(buf[:2]).hex()} is not little-endian plain CDR "
            "(0001) as rmw_fastrtps/rmw_cyclonedds write it; other encodings are not supported"
        )


def _string(buf: bytes | memoryview, pos: int, end: int) -> tuple[str, int]:
    pos += -pos & 3  # 4-alignment counted from byte 4 equals absolute 4-alignment
    (n,) = _U32(buf, pos)
    pos += 4
    if pos + n > end:
        raise _truncated(pos, end)
    text = bytes(buf[pos : pos + n - 1]).decode("utf-8") if n else ""  # n counts the NUL
    return text, pos + n


def _strings(buf: bytes | memoryview, pos: int, end: int) -> tuple[tuple[str, ...], int]:
    pos += -pos & 3
    (count,) = _U32(buf, pos)
    pos += 4
    if 4 * count > end - pos:
        raise ValueError(f"SampleBlock CDR: a string sequence claims {count} items, more than the bytes left")
    out = []
    for _ in range(count):
        text, pos = _string(buf, pos, end)
        out.append(text)
    return tuple(out), pos


def _header(buf: bytes | memoryview) -> tuple[int, str, int, float, int, int]:
    """``(stamp_ns, experiment_id, first_index, sample_period, n_samples, next position)``."""
    _check_encapsulation(buf)
    end = len(buf)
    sec, nanosec = _TIME(buf, 4)
    experiment_id, pos = _string(buf, 12, end)
    pos += (4 - pos) & 7  # 8-alignment counted from byte 4
    first_index, sample_period, n_samples = _INDEX_PERIOD_N(buf, pos)
    return sec * 1_000_000_000 + nanosec, experiment_id, first_index, sample_period, n_samples, pos + 20


def sample_block_span(cdr: bytes | memoryview) -> tuple[int, int]:
    """``(first_index, n_samples)`` of a serialized SampleBlock, reading only its header.

    Raises
    ------
    ValueError
        on a truncated buffer or an unsupported encapsulation.
    """
    try:
        _, _, first_index, _, n_samples, _ = _header(cdr)
    except struct.error:
        raise _truncated(len(cdr), len(cdr)) from None
    return first_index, n_samples


def decode_sample_block(cdr: bytes | memoryview) -> SampleBlockData:
    """Decode a serialized SampleBlock (CDR bytes as recorded) without copying its data.

    Parameters
    ----------
    cdr
        the message bytes, encapsulation header included.

    Returns
    -------
    :class:`SampleBlockData`; ``data`` has shape (n_samples, n_channels).

    Raises
    ------
    ValueError
        on truncated bytes, an unsupported encapsulation, or a
        data length that is not n_samples x len(channel_names), or a
        sample_flags length other than 0 or n_samples.
    """
    end = len(cdr)
    try:
        stamp_ns, experiment_id, first_index, sample_period, n_samples, pos = _header(cdr)
        names, pos = _strings(cdr, pos, end)
        units, pos = _strings(cdr, pos, end)
        pos += -pos & 3
        (n_values,) = _U32(cdr, pos)
        pos += 4
        if n_values:  # CDR aligns before the first element only: an empty sequence has no padding
            pos += (4 - pos) & 7
        if pos + 8 * n_values > end:
            raise _truncated(pos, end)
        data = np.frombuffer(cdr, dtype="<f8", count=n_values, offset=pos)
        pos += 8 * n_values
        pos += -pos & 3
        (n_flags,) = _U32(cdr, pos)
        pos += 4
        if pos + n_flags > end:
            raise _truncated(pos, end)
        sample_flags = np.frombuffer(cdr, dtype=np.uint8, count=n_flags, offset=pos)
        pos += n_flags
        pos += -pos & 3
        (flags,) = _U32(cdr, pos)
        pos += 4
        pos += (4 - pos) & 7  # 8-alignment counted from byte 4
        session_id = _U64(cdr, pos)[0] if pos + 8 <= end else 0
    except struct.error:
        raise _truncated(end, end) from None
    n_ch = len(names)
    if n_values != n_samples * n_ch:
        raise ValueError(
            f"SampleBlock at index {first_index}: {n_values} values, expected n_samples x channels = "
            f"{n_samples} x {n_ch}"
        )
    if n_flags not in (0, n_samples):
        raise ValueError(f"SampleBlock at index {first_index}: {n_flags} sample flags for {n_samples} samples")
    return SampleBlockData(
        stamp_ns=stamp_ns,
        experiment_id=experiment_id,
        first_index=first_index,
        sample_period_s=sample_period,
        channel_names=names,
        channel_units=units,
        data=data.reshape(n_samples, n_ch),
        sample_flags=sample_flags,
        flags=flags,
        session_id=session_id,
    )


def sample_block_session(cdr: bytes | memoryview) -> int:
    """The ``session_id`` of a serialized SampleBlock (0 if it has none: recorded before sessions had ids),
    walking past its data unread. (A live message's id is its last 8 bytes:
    :func:`ambid.session_id.session_of`; this walk also reads old recordings right.)

    Raises
    ------
    ValueError
        on truncated bytes or an unsupported encapsulation.
    """
    end = len(cdr)
    try:
        *_, pos = _header(cdr)
        for _ in range(2):  # channel_names, channel_units
            pos += -pos & 3
            (count,) = _U32(cdr, pos)
            pos += 4
            for _ in range(count):
                pos += -pos & 3
                (n,) = _U32(cdr, pos)
                pos += 4 + n
        pos += -pos & 3
        (n_values,) = _U32(cdr, pos)
        pos += 4
        if n_values:
            pos += (4 - pos) & 7
        pos += 8 * n_values
        pos += -pos & 3
        (n_flags,) = _U32(cdr, pos)
        pos += 4 + n_flags
        pos += -pos & 3
        pos += 4  # flags
        if pos > end:
            raise _truncated(pos, end)
        pos += (4 - pos) & 7
        return _U64(cdr, pos)[0] if pos + 8 <= end else 0
    except struct.error:
        raise _truncated(end, end) from None


class SampleBlockReader:
    """Reads the CDR SampleBlocks of one topic in turn, reusing the channel layout of the last block.

    ``reader(cdr)`` returns ``(first_index, sample_period, channel_names,
    data (n_samples, n_channels))``, ``data`` a read-only view of ``cdr``;
    the offline FRF reads a session with it (:func:`decode_sample_block`
    decodes one block with every field).

    Consecutive blocks of a topic carry the same sizes, names and units; when
    those bytes are unchanged their parse (32 strings for a plant's block,
    most of the decoding time) is reused. The comparison skips the alignment
    padding (serialisers leave it uninitialised), so reuse is exact: the parse
    depends only on the bytes compared and their offset.
    """

    def __init__(self) -> None:
        self._at = -1                               # offset of n_samples in the CDR body
        self._keep = np.zeros(0, dtype=np.int64)    # offsets (from there) of the non-padding bytes
        self._kept = b""                            # their values
        self._layout: tuple[int, list[str], int, int] = (0, [], 0, 0)  # n_samples, names, n_values, data pos

    def __call__(self, buf: bytes) -> tuple[int, float, list[str], np.ndarray]:
        if bytes(buf[:2]) not in (b"\x00\x01", b"\x00\x03"):
            raise ValueError(f"SampleBlock: only little-endian CDR is read here, got encapsulation "
                             f"{bytes(buf[:4]).hex()}")
        body = memoryview(buf)[4:]
        (id_len,) = struct.unpack_from("<I", body, 8)     # after the stamp (int32 sec, uint32 nanosec)
        pos = 12 + id_len                                # experiment_id (its length counts the NUL)
        pos += -pos % 8
        first_index, sample_period = struct.unpack_from("<Qd", body, pos)
        pos += 16
        data_pos = self._layout[3]
        if not (pos == self._at and data_pos <= len(body)
                and np.frombuffer(body, np.uint8, data_pos - pos, pos)[self._keep].tobytes() == self._kept):
            self._layout, spans = _sample_block_layout(body, pos)
            keep = np.concatenate([np.arange(a, b) for a, b in spans]) - pos
            self._at, self._keep = pos, keep
            self._kept = np.frombuffer(body, np.uint8, self._layout[3] - pos, pos)[keep].tobytes()
        n_samples, names, n_values, data_pos = self._layout
        if data_pos + 8 * n_values > len(body):
            raise ValueError(f"SampleBlock: {n_values} values for {n_samples} samples x {len(names)} "
                             f"channels but the message ends after {max(len(body) - data_pos, 0) // 8}")
        data = np.frombuffer(body, dtype="<f8", count=n_values, offset=data_pos).reshape(n_samples, len(names))
        return int(first_index), float(sample_period), list(names), data


def _sample_block_layout(body: memoryview, pos: int) -> tuple[tuple[int, list[str], int, int],
                                                               list[tuple[int, int]]]:
    """Parse a SampleBlock body from its n_samples field on.

    Returns
    -------
    ((n_samples, channel_names, n_values, data offset), the byte spans
    [start, end) read, i.e. all but the alignment padding).
    """
    spans: list[tuple[int, int]] = []

    def align(n: int) -> None:
        nonlocal pos
        pos += -pos % n

    def u32() -> int:
        nonlocal pos
        align(4)
        (v,) = struct.unpack_from("<I", body, pos)
        spans.append((pos, pos + 4))
        pos += 4
        return v

    def string() -> str:
        nonlocal pos
        n = u32()
        if n < 1 or pos + n > len(body):
            raise ValueError(f"SampleBlock: bad string length {n} at byte {pos}")
        s = bytes(body[pos:pos + n - 1]).decode()
        spans.append((pos, pos + n))
        pos += n
        return s

    n_samples = u32()
    names = [string() for _ in range(u32())]
    for _ in range(u32()):       # channel_units
        string()
    n_values = u32()
    if n_values:
        align(8)
    if n_values != n_samples * len(names):
        raise ValueError(f"SampleBlock: {n_values} values for {n_samples} samples x {len(names)} channels")
    return (n_samples, names, n_values, pos), spans


def sample_block_topics(path: str | os.PathLike) -> list[str]:
    """Topics of a session whose type is ``ambid_msgs/msg/SampleBlock``, sorted."""
    scan = scan_session(path)
    return sorted(t for t, ty in scan.topic_types.items() if ty == SAMPLE_BLOCK_TYPE)


def iter_sample_blocks(
    path: str | os.PathLike, topic: str, *, recover: bool = False
) -> Iterator[tuple[SessionMessage, SampleBlockData]]:
    """Decoded SampleBlocks of one topic in log-time order, one at a time.

    Parameters
    ----------
    path
        session ``.mcap``.
    topic
        full topic name, e.g. ``"/amb/measurement"``.
    recover
        read a file a killed writer left (see
        :func:`ambid.recording.iter_messages`).

    Yields
    ------
    ``(message, block)``; ``block.data`` views ``message.data``.
    """
    for msg in iter_messages(path, topic, recover=recover):
        if msg.type_name and msg.type_name != SAMPLE_BLOCK_TYPE:
            raise ValueError(f"topic {topic} carries {msg.type_name}, not {SAMPLE_BLOCK_TYPE}")
        yield msg, decode_sample_block(msg.data)


def block_spans(
    path: str | os.PathLike, topics: Iterable[str], *, recover: bool = False
) -> dict[str, list[tuple[int, int, int]]]:
    """``{topic: [(log_time_ns, first_index, n_samples), ...]}`` in log-time order (headers only)."""
    topics = list(topics)
    out: dict[str, list[tuple[int, int, int]]] = {t: [] for t in topics}
    if topics:
        for msg in iter_messages(path, topics, recover=recover):
            first, n = sample_block_span(msg.data)
            out[msg.topic].append((msg.log_time_ns, first, n))
    return out


def sample_index_report(
    path: str | os.PathLike, topics: Iterable[str] | None = None, *, recover: bool = True
) -> dict[str, dict[str, Any]]:
    """Sample-index gaps and overlaps of SampleBlock topics, from the block headers only.

    Parameters
    ----------
    path
        session ``.mcap``.
    topics
        topics to check; ``None`` for every SampleBlock topic.
    recover
        read front to back, as far as the file is complete
        (default, so it also works on a killed recorder's file).

    Returns
    -------
    ``{topic: {blocks, samples, first_index, end_index, gap_count,
    missing_samples, overlapping_blocks, overlapping_samples, gaps}}``;
    ``gaps`` lists up to 20 ``{log_time_ns, expected_index, got_index}``.
    A gap is a block starting after the end of every earlier block.
    """
    if topics is None:
        topics = sample_block_topics(path)
    return {t: gap_report(b) for t, b in block_spans(path, topics, recover=recover).items()}


@dataclass(frozen=True)
class SampleRange:
    """Samples [first_index, first_index + n) of some channels, assembled from blocks.

    Attributes
    ----------
    first_index
        sample index of row 0.
    channel_names
        columns of :attr:`data`.
    data
        (n, n_channels) float64; NaN where no block covered a sample.
    present
        (n,) bool, True where a block covered the sample.
    sample_period_s
        sample period of the blocks [s] (NaN without blocks).
    """

    first_index: int
    channel_names: tuple[str, ...]
    data: np.ndarray
    present: np.ndarray
    sample_period_s: float


def read_samples(
    path: str | os.PathLike,
    topic: str,
    start_index: int,
    stop_index: int,
    channels: Sequence[str] | None = None,
    *,
    recover: bool = False,
) -> SampleRange:
    """Samples ``[start_index, stop_index)`` of a SampleBlock topic as one array.

    Memory holds the result and one block. Blocks outside the range are
    skipped after reading their header.

    Parameters
    ----------
    path
        session ``.mcap``.
    topic
        e.g. ``"/amb/measurement"``.
    start_index, stop_index
        sample range, 0 <= start < stop.
    channels
        column names to keep, in this order; ``None`` for all
        channels of the first block.
    recover
        read a killed writer's file.

    Returns
    -------
    :class:`SampleRange` with data of shape (stop - start, n_channels).

    Raises
    ------
    ValueError
        on a bad range, a channel missing from a block, or blocks
        whose channel layout changes within the range.
    """
    if not (isinstance(start_index, (int, np.integer)) and isinstance(stop_index, (int, np.integer))):
        raise ValueError(f"start_index and stop_index must be integers, got {start_index!r}, {stop_index!r}")
    if not 0 <= start_index < stop_index:
        raise ValueError(f"need 0 <= start_index < stop_index, got [{start_index}, {stop_index})")
    n = int(stop_index - start_index)
    data: np.ndarray | None = None
    present = np.zeros(n, dtype=bool)
    names: tuple[str, ...] | None = None
    layout: tuple[str, ...] | None = None
    columns: np.ndarray | None = None
    period = float("nan")
    for msg in iter_messages(path, topic, recover=recover):
        first, count = sample_block_span(msg.data)
        lo, hi = max(first, start_index), min(first + count, stop_index)
        if lo >= hi:
            continue
        block = decode_sample_block(msg.data)
        if layout is None:
            layout = block.channel_names
            names = tuple(channels) if channels is not None else layout
            missing = [c for c in names if c not in layout]
            if missing:
                raise ValueError(f"{topic}: channels {missing} not in the blocks' channels {list(layout)}")
            columns = np.array([layout.index(c) for c in names], dtype=np.intp)
            data = np.full((n, len(names)), np.nan)
            period = block.sample_period_s
        elif block.channel_names != layout:
            raise ValueError(
                f"{topic}: block at index {first} has channels {list(block.channel_names)}, "
                f"earlier blocks {list(layout)}"
            )
        data[lo - start_index : hi - start_index] = block.data[lo - first : hi - first][:, columns]
        present[lo - start_index : hi - start_index] = True
    if data is None:
        names = tuple(channels) if channels is not None else ()
        data = np.full((n, len(names)), np.nan)
    return SampleRange(
        first_index=int(start_index), channel_names=names, data=data, present=present, sample_period_s=period
    )


def encode_sample_block(first_index: int, sample_period_s: float, channel_names: Sequence[str],
                        channel_units: Sequence[str], data: np.ndarray, experiment_id: str = "",
                        stamp_ns: int = 0, flags: int = 0, session_id: int = 0) -> bytes:
    """CDR bytes of a SampleBlock (the layout in the module docstring), as rclpy serialises it.

    Parameters
    ----------
    first_index
        sample index of the first row.
    sample_period_s
        sample period [s].
    channel_names, channel_units
        (k,) per column.
    data
        (n, k) values [channel units].
    experiment_id
        the experiment, or "".
    stamp_ns
        time of the first sample [ns].
    flags
        OR of the rows' flags (no per-row flags are written).
    session_id
        the session the block belongs to, or 0.
    """
    data = np.ascontiguousarray(data, dtype="<f8")
    n, k = data.shape
    if k != len(channel_names) or k != len(channel_units):
        raise ValueError(f"{k} columns for {len(channel_names)} names and {len(channel_units)} units")
    out = bytearray(_CDR_LE + b"\x00\x00")

    def align(a: int) -> None:
        out.extend(b"\x00" * (-(len(out) - 4) % a))

    def string(s: str) -> None:
        b = s.encode("utf-8") + b"\x00"
        align(4)
        out.extend(struct.pack("<I", len(b)) + b)

    out.extend(struct.pack("<iI", stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000))
    string(experiment_id)
    align(8)
    out.extend(struct.pack("<QdI", int(first_index), float(sample_period_s), n))
    for seq in (channel_names, channel_units):
        align(4)
        out.extend(struct.pack("<I", len(seq)))
        for s in seq:
            string(s)
    align(4)
    out.extend(struct.pack("<I", n * k))
    align(8)
    out.extend(data.tobytes())
    align(4)
    out.extend(struct.pack("<I", 0))
    out.extend(struct.pack("<I", int(flags)))
    align(8)
    out.extend(struct.pack("<Q", int(session_id)))
    return bytes(out)
