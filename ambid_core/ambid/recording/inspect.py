"""Summarise a session file: topics, counts, rates, session facts, sample-index gaps.

``inspect_session`` streams the file once (front to back, so it also works on
files a killed writer left with ``recover=True``) and returns a plain dict;
``format_inspection`` turns that dict into text for a terminal.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Mapping

from .reader import IncompleteSessionError, iter_decoded, scan_session

__all__ = ["SampleIndexExtractor", "inspect_session", "format_inspection"]

#: ``decoded message -> (first_sample_index, n_samples)`` for block topics.
SampleIndexExtractor = Callable[[Any], "tuple[int, int]"]

_MAX_LISTED_GAPS = 20


def gap_report(blocks: list[tuple[int, int, int]]) -> dict[str, Any]:
    """Gaps/overlaps between consecutive sample blocks.

    Parameters
    ----------
    blocks
        ``(log_time_ns, first_index, n_samples)`` in log-time order.

    A gap is a block starting after the end of all earlier blocks (its
    missing samples are counted); an overlap is one starting before it.
    """
    gaps: list[dict[str, int]] = []
    n_gaps = missing = overlaps = overlapped = 0
    expected = None
    for t_ns, first, n in blocks:
        if expected is not None and first > expected:
            n_gaps += 1
            missing += first - expected
            if len(gaps) < _MAX_LISTED_GAPS:
                gaps.append({"log_time_ns": t_ns, "expected_index": expected, "got_index": first})
        elif expected is not None and first < expected:
            overlaps += 1
            overlapped += min(expected, first + n) - first
        expected = first + n if expected is None else max(expected, first + n)
    return {
        "blocks": len(blocks),
        "samples": int(sum(b[2] for b in blocks)),
        "first_index": blocks[0][1] if blocks else None,
        "end_index": expected,
        "gap_count": n_gaps,
        "missing_samples": missing,
        "overlapping_blocks": overlaps,
        "overlapping_samples": overlapped,
        "gaps": gaps,
    }


def inspect_session(
    path: str | os.PathLike,
    recover: bool = False,
    sample_index: Mapping[str, SampleIndexExtractor] | None = None,
) -> dict[str, Any]:
    """Describe a session file.

    Parameters
    ----------
    path
        session ``.mcap``.
    recover
        accept a file without footer (killed writer); only complete
        chunks are counted. Without it, an incomplete file raises
        :class:`~ambid.recording.reader.IncompleteSessionError`.
    sample_index
        extractors keyed by topic name or by type name
        (``pkg/msg/Type``; a topic key wins), each returning
        ``(first_index, n_samples)`` of a decoded message; those topics
        are decoded and checked for sample-index gaps.

    Returns
    -------
    dict with keys ``path``, ``file_bytes``, ``complete``, ``problem``,
    ``profile``, ``library``, ``message_count``, ``chunk_count``,
    ``compressions``, ``start_time_ns``, ``end_time_ns``, ``duration_s``,
    ``topics`` (``{topic: {type, message_count, first_time_ns,
    last_time_ns, rate_hz, type_hash, offered_qos_profiles}}``; rate =
    (count - 1) / span, None below two messages), ``metadata``
    (``{record name: {key: value}}``, session facts under
    ``"ambid.session"``), ``attachments`` and ``sample_index``
    (``{topic: {blocks, samples, first_index, end_index, gap_count, missing_samples,
    overlapping_blocks, overlapping_samples, gaps: [...]}}``).
    """
    scan = scan_session(path)
    if not scan.complete and not recover:
        raise IncompleteSessionError(
            f"{os.fspath(path)} is incomplete ({scan.problem}); inspect it with recover=True"
        )
    topics: dict[str, dict[str, Any]] = {}
    for topic, type_name in scan.topic_types.items():
        n = scan.topic_message_counts.get(topic, 0)
        first, last = scan.topic_time_ranges.get(topic, (None, None))
        span_s = (last - first) * 1e-9 if n >= 2 else 0.0
        meta = scan.channel_metadata.get(topic, {})
        topics[topic] = {
            "type": type_name,
            "message_count": n,
            "first_time_ns": first,
            "last_time_ns": last,
            "rate_hz": (n - 1) / span_s if span_s > 0 else None,
            "type_hash": meta.get("topic_type_hash", ""),
            "offered_qos_profiles": meta.get("offered_qos_profiles", ""),
        }

    extractors: dict[str, SampleIndexExtractor] = {}
    for topic, type_name in scan.topic_types.items():
        fn = (sample_index or {}).get(topic) or (sample_index or {}).get(type_name)
        if fn is not None:
            extractors[topic] = fn
    sample_reports: dict[str, Any] = {}
    if extractors:
        blocks: dict[str, list[tuple[int, int, int]]] = {t: [] for t in extractors}
        # recover=True reads the same complete chunks the scan counted.
        for msg, decoded in iter_decoded(path, list(extractors), recover=True):
            first, n = extractors[msg.topic](decoded)
            blocks[msg.topic].append((msg.log_time_ns, int(first), int(n)))
        sample_reports = {t: gap_report(b) for t, b in blocks.items()}

    duration_s = (
        (scan.end_time_ns - scan.start_time_ns) * 1e-9 if scan.start_time_ns is not None else 0.0
    )
    return {
        "path": scan.path,
        "file_bytes": scan.file_bytes,
        "complete": scan.complete,
        "problem": scan.problem,
        "profile": scan.profile,
        "library": scan.library,
        "message_count": scan.message_count,
        "chunk_count": scan.chunk_count,
        "compressions": list(scan.compressions),
        "start_time_ns": scan.start_time_ns,
        "end_time_ns": scan.end_time_ns,
        "duration_s": duration_s,
        "topics": topics,
        "metadata": scan.metadata,
        "attachments": list(scan.attachments),
        "sample_index": sample_reports,
    }


def _short(text: str, width: int = 60) -> str:
    text = text.replace("\n", " ")
    return text if len(text) <= width else text[: width - 3] + "..."


def format_inspection(d: Mapping[str, Any]) -> str:
    """Human-readable text of an :func:`inspect_session` result."""
    lines = [
        f"session   {d['path']}",
        f"state     {'complete' if d['complete'] else 'INCOMPLETE: ' + str(d['problem'])}",
        f"size      {d['file_bytes'] / 1e6:.3f} MB in {d['chunk_count']} chunks "
        f"({', '.join(c or 'uncompressed' for c in d['compressions']) or 'no chunks'})",
        f"profile   {d['profile']}   library {d['library']}",
        f"messages  {d['message_count']} over {d['duration_s']:.3f} s",
        "",
        f"{'topic':<28} {'type':<36} {'count':>8} {'rate [Hz]':>10}",
    ]
    for topic, info in sorted(d["topics"].items()):
        rate = f"{info['rate_hz']:.2f}" if info["rate_hz"] is not None else "-"
        lines.append(f"{topic:<28} {info['type']:<36} {info['message_count']:>8} {rate:>10}")
    for topic, rep in sorted(d.get("sample_index", {}).items()):
        lines.append("")
        lines.append(
            f"samples on {topic}: {rep['samples']} in {rep['blocks']} blocks, index "
            f"{rep['first_index']}..{rep['end_index']}, missing {rep['missing_samples']}, "
            f"overlapping blocks {rep['overlapping_blocks']}"
        )
        for gap in rep["gaps"]:
            lines.append(
                f"  gap at t={gap['log_time_ns'] * 1e-9:.6f} s: expected index "
                f"{gap['expected_index']}, got {gap['got_index']}"
            )
    for name, record in sorted(d["metadata"].items()):
        if name == "rosbag2":
            continue  # the bag metadata repeats the topic table above
        lines.append("")
        lines.append(f"metadata {name}:")
        for key, value in sorted(record.items()):
            lines.append(f"  {key:<20} {_short(value)}")
    if d["attachments"]:
        lines.append("")
        lines.append("attachments: " + ", ".join(d["attachments"]))
    return "\n".join(lines)
