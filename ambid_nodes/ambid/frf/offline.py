"""FRF estimation after the fact: a recorded session, or arrays a user loads.

The same :class:`ambid.frf.streaming.FrfStream` the ``frf_consumer`` node
runs live is fed with the recorded samples, so a recording gives exactly
the estimate the node published.

* :func:`frf_from_session`: an ambid session MCAP file; the design comes
  from the recorded ``excitation/design`` message (its ``design_json``,
  ``start_index`` and ``total_samples``), the samples from the
  ``measurement`` SampleBlocks of the same namespace.
* :func:`frf_from_arrays`: channels in a dict (name -> (n_samples,)
  array) with the design as an ``ExcitationDesign``, its dict or a JSON
  file; :func:`frf_from_files` loads the channels from .npz, .mat or .csv
  first (:func:`ambid.frf.arrays_io.load_arrays`).
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ambid.excitation.design import ExcitationDesign
from ambid.frf.arrays_io import load_arrays, stack_channels
from ambid.frf.streaming import FrfResult, FrfStream, match_inputs
from ambid.rig import AXES, CURRENT_NAMES, DISPLACEMENT_NAMES

__all__ = ["DEFAULT_OUTPUTS", "DEFAULT_INPUTS", "DEFAULT_REFERENCES", "load_design",
           "frf_from_arrays", "frf_from_files", "frf_from_session", "session_designs"]

DEFAULT_OUTPUTS: tuple[str, ...] = DISPLACEMENT_NAMES
DEFAULT_INPUTS: tuple[str, ...] = CURRENT_NAMES
DEFAULT_REFERENCES: tuple[str, ...] = tuple(f"r_{a}" for a in AXES)

_DESIGN_TOPIC = "excitation/design"
_MEASUREMENT_TOPIC = "measurement"


def load_design(design: ExcitationDesign | Mapping[str, Any] | str | os.PathLike) -> ExcitationDesign:
    """An ExcitationDesign from itself, its ``to_dict`` dict, or a JSON file of that dict."""
    if isinstance(design, ExcitationDesign):
        return design
    if isinstance(design, Mapping):
        return ExcitationDesign.from_dict(dict(design))
    path = Path(design)
    if not path.is_file():
        raise FileNotFoundError(f"no design file {path}; pass the JSON of ExcitationDesign.to_dict()")
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected a JSON object (ExcitationDesign.to_dict()), got {type(d).__name__}")
    return ExcitationDesign.from_dict(d)


def _run(stream: FrfStream, blocks, estimator: str) -> FrfResult:
    n_blocks = 0
    for first_index, data in blocks:
        stream.add(first_index, data)
        n_blocks += 1
    result = stream.estimate(estimator)
    if result is None:
        p = stream.progress()
        raise ValueError(f"no complete realisation in the data: {n_blocks} block(s) covered "
                         f"{p.samples_done} of the experiment's {p.total_samples} samples from index "
                         f"{stream.start_index}; check start_row / the recording's extent")
    return result


def frf_from_arrays(data: Mapping[str, np.ndarray],
                    design: ExcitationDesign | Mapping[str, Any] | str | os.PathLike,
                    estimator: str = "indirect", outputs: Sequence[str] = DEFAULT_OUTPUTS,
                    inputs: Sequence[str] = DEFAULT_INPUTS,
                    references: Sequence[str] = DEFAULT_REFERENCES, start_row: int = 0,
                    total_samples: int | None = None) -> FrfResult:
    """FRF of an experiment recorded as named channels.

    Args:
        data: channel name -> samples (n_samples,) [m for y, A for u and r],
            all the same length; row i is sample i.
        design: the experiment's ExcitationDesign, its dict, or a JSON file.
        estimator: one of :data:`ambid.frf.streaming.ESTIMATORS`.
        outputs: y channel names (Ny,).
        inputs: u channel names; those of the design's inputs are used
            (:func:`ambid.frf.streaming.match_inputs`).
        references: r channel names, one per entry of ``inputs``.
        start_row: row where the experiment's first sample is.
        total_samples: the experiment was stopped after this many samples.

    Returns:
        :class:`ambid.frf.streaming.FrfResult`; ``complete`` is False if the
        record ends before the experiment does.
    """
    d = load_design(design)
    u_names, r_names = match_inputs(d.input_names, inputs, references)
    stream = FrfStream(d, outputs, u_names, r_names, start_index=start_row, total_samples=total_samples)
    x = stack_channels(dict(data), stream.channel_names)
    if not np.all(np.isfinite(x)):
        raise ValueError("data contains NaN or inf; clean or cut the record first")
    return _run(stream, [(0, x)], estimator)


def frf_from_files(data_path: str | os.PathLike, design_path: str | os.PathLike, **kwargs) -> FrfResult:
    """:func:`frf_from_arrays` on a .npz, .mat or .csv file and a design JSON file (same kwargs)."""
    return frf_from_arrays(load_arrays(data_path), design_path, **kwargs)


# ------------------------------------------------------------------ sessions

def _topics(path: str | os.PathLike, recover: bool) -> dict[str, str]:
    """topic -> type name, from the summary (or a front-to-back scan with recover)."""
    if recover:
        from ambid.mcap_session.reader import scan_session
        return dict(scan_session(path).topic_types)
    from mcap.reader import make_reader

    from ambid.mcap_session.reader import IncompleteSessionError
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception as exc:  # noqa: BLE001 - mcap raises several types for a missing footer
            raise IncompleteSessionError(f"{os.fspath(path)} has no valid summary ({exc}); "
                                         "pass recover=True") from exc
    if summary is None:
        raise ValueError(f"{os.fspath(path)} has no summary section; pass recover=True")
    schemas = summary.schemas
    return {c.topic: (schemas[c.schema_id].name if c.schema_id in schemas else "")
            for c in summary.channels.values()}


def session_designs(path: str | os.PathLike, recover: bool = False) -> list[dict[str, Any]]:
    """The excitation designs recorded in a session, last message per experiment.

    Returns:
        List (in recording order) of dicts with keys ``topic``,
        ``experiment_id``, ``start_index``, ``total_samples`` and ``design``
        (ExcitationDesign); a republished design (an experiment stopped
        early) replaces the earlier one.
    """
    return _designs(path, _topics(path, recover), recover)


def _designs(path: str | os.PathLike, all_topics: Mapping[str, str], recover: bool) -> list[dict[str, Any]]:
    from ambid.mcap_session.reader import iter_decoded

    topics = [t for t in all_topics if t.rstrip("/").endswith(_DESIGN_TOPIC)]
    found: dict[tuple[str, str], dict[str, Any]] = {}
    for message, msg in (iter_decoded(path, topics, recover=recover) if topics else ()):
        key = (message.topic, msg.experiment_id)
        found.pop(key, None)  # keep the order of the last message
        found[key] = {"topic": message.topic, "experiment_id": msg.experiment_id,
                      "start_index": int(msg.start_index), "total_samples": int(msg.total_samples),
                      "design_json": msg.design_json}
    out = []
    for entry in found.values():
        try:
            design = ExcitationDesign.from_dict(json.loads(entry.pop("design_json")))
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{os.fspath(path)}: the design of experiment {entry['experiment_id']!r} "
                             f"on {entry['topic']} cannot be read: {exc}") from None
        out.append({**entry, "design": design})
    return out


def _read_sample_block(buf: bytes) -> tuple[int, float, list[str], np.ndarray]:
    """(first_index, sample_period, channel_names, data (n, ch)) of a CDR SampleBlock.

    A direct little-endian CDR reader: the generic decoder unpacks the data
    array one float at a time, this one takes it with one ``frombuffer``.
    Field order and alignment follow ambid_msgs/msg/SampleBlock.msg (XCDR1:
    each primitive aligned to its size from the start of the payload).
    """
    if bytes(buf[:2]) not in (b"\x00\x01", b"\x00\x03"):
        raise ValueError(f"SampleBlock: only little-endian CDR is read here, got encapsulation "
                         f"{bytes(buf[:4]).hex()}")
    body = memoryview(buf)[4:]
    pos = 0

    def align(n: int) -> None:
        nonlocal pos
        pos += -pos % n

    def u32() -> int:
        nonlocal pos
        align(4)
        (v,) = struct.unpack_from("<I", body, pos)
        pos += 4
        return v

    def string() -> str:
        nonlocal pos
        n = u32()
        s = bytes(body[pos:pos + n - 1]).decode()
        pos += n
        return s

    pos = 8                      # stamp: int32 sec, uint32 nanosec
    string()                     # experiment_id
    align(8)
    first_index, sample_period = struct.unpack_from("<Qd", body, pos)
    pos += 16
    n_samples = u32()
    names = [string() for _ in range(u32())]
    for _ in range(u32()):       # channel_units
        string()
    n_values = u32()
    if n_values:
        align(8)
    if n_values != n_samples * len(names) or pos + 8 * n_values > len(body):
        raise ValueError(f"SampleBlock: {n_values} values for {n_samples} samples x {len(names)} channels")
    data = np.frombuffer(body, dtype="<f8", count=n_values, offset=pos).reshape(n_samples, len(names))
    return int(first_index), float(sample_period), names, data


def _session_blocks(path: str | os.PathLike, topic: str, stream: FrfStream,
                    recover: bool) -> Iterator[tuple[int, np.ndarray]]:
    from ambid.mcap_session.reader import iter_messages

    columns: dict[tuple[str, ...], np.ndarray] = {}
    for message in iter_messages(path, topic, recover=recover):
        first, dt, names, data = _read_sample_block(message.data)
        if first + len(data) <= stream.start_index or first >= stream.end_index:
            continue   # outside the experiment (no gap can be there either)
        key = tuple(names)
        if key not in columns:
            columns[key] = stream.columns(names)
        stream.check_sample_period(dt)
        yield first, data[:, columns[key]]


def frf_from_session(path: str | os.PathLike, estimator: str = "indirect",
                     experiment_id: str | None = None, outputs: Sequence[str] = DEFAULT_OUTPUTS,
                     inputs: Sequence[str] = DEFAULT_INPUTS,
                     references: Sequence[str] = DEFAULT_REFERENCES,
                     recover: bool = False) -> FrfResult:
    """FRF of an experiment in a recorded session (what frf_consumer computes live).

    Args:
        path: session .mcap file.
        estimator: one of :data:`ambid.frf.streaming.ESTIMATORS`.
        experiment_id: which experiment; default the last one recorded.
        outputs, inputs, references: channel names as in
            :func:`frf_from_arrays`.
        recover: read a file a killed recorder left (no summary).

    Returns:
        :class:`ambid.frf.streaming.FrfResult`.
    """
    all_topics = _topics(path, recover)
    designs = _designs(path, all_topics, recover)
    if not designs:
        raise ValueError(f"{os.fspath(path)} holds no '{_DESIGN_TOPIC}' message: no experiment to "
                         "estimate (record the excitation/design topic)")
    if experiment_id is None:
        chosen = designs[-1]
    else:
        match = [d for d in designs if d["experiment_id"] == experiment_id]
        if not match:
            raise ValueError(f"no experiment {experiment_id!r} in {os.fspath(path)}; recorded: "
                             f"{[d['experiment_id'] for d in designs]}")
        chosen = match[-1]
    d = chosen["design"]
    namespace = chosen["topic"].rstrip("/")[:-len(_DESIGN_TOPIC)]
    topic = namespace + _MEASUREMENT_TOPIC
    if topic not in all_topics:
        raise ValueError(f"{os.fspath(path)} has no {topic} topic beside {chosen['topic']}")
    u_names, r_names = match_inputs(d.input_names, inputs, references)
    stream = FrfStream(d, outputs, u_names, r_names, start_index=chosen["start_index"],
                       total_samples=min(chosen["total_samples"], d.total_samples))
    return _run(stream, _session_blocks(path, topic, stream, recover), estimator)
