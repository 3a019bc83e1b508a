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

Channels are data: unless given, the FRF's outputs are every displacement
channel ``y_<axis>`` the record holds (in its order), its inputs and
references the ``u_<axis>`` and ``r_<axis>`` of the design's inputs
(:func:`data_channels`), so a record of one axis, one plane, four or five
axes gives its own ny x nu matrix.
"""

from __future__ import annotations

import json
import os
import struct
import sys
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ambid.channels import split_name
from ambid.excitation.design import ExcitationDesign
from ambid.frf.arrays_io import load_arrays, stack_channels
from ambid.frf.lpm import local_frf
from ambid.frf.sensitivity import iso14839_zone, sensitivity_peak
from ambid.frf.streaming import ESTIMATORS, FrfResult, FrfStream, axis_tag, match_inputs
from ambid.recording.blocks import SampleBlockReader, read_samples
from ambid.recording.reader import Ros2Decoder, iter_messages, iter_raw

__all__ = ["data_channels", "load_design", "frf_from_arrays", "frf_from_files", "frf_from_session", "frf_of_record",
           "local_frf_result", "session_designs"]

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


def data_channels(design_inputs: Sequence[str], names: Sequence[str] | None = None,
                  outputs: Sequence[str] | None = None, inputs: Sequence[str] | None = None,
                  references: Sequence[str] | None = None) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """The FRF's channels, those not given taken from the data.

    Parameters
    ----------
    design_inputs
        the design's input names (``u_a_x``, or a bare axis).
    names
        the record's channel names (a measurement block's); its ``y_<axis>`` channels are the
        outputs: those of the design's axes first, in the design's order (so the matrix's rows and
        columns name the same axes in the same order), then the others in the record's order. None:
        the y channels of the design's axes.
    outputs, inputs, references
        given channel names (None: from the data).

    Returns
    -------
    (outputs, inputs, references): the y channels; the u and r channels of the design's inputs.

    Raises
    ------
    ValueError
        the record holds no displacement channel y_<axis>.
    """
    axes = [axis_tag(n) for n in design_inputs]
    if inputs is None:
        inputs = tuple(f"u_{a}" for a in axes)
    if references is None:
        references = tuple(f"r_{a}" for a in axes)
    if outputs is None:
        if names is None:
            outputs = tuple(f"y_{a}" for a in axes)
        else:
            ys = [n for n in names if _signal(n) == "y"]
            first = [f"y_{a}" for a in axes if f"y_{a}" in ys]
            outputs = tuple(first + [n for n in ys if n not in first])
            if not outputs:
                raise ValueError(f"the record's channels {list(names)} hold no displacement y_<axis>; record the "
                                 "measured displacements (y_a_x, ...)")
    return tuple(outputs), tuple(inputs), tuple(references)


def _signal(name: str) -> str:
    try:
        return split_name(name)[0]
    except ValueError:
        return ""


def _run(stream: FrfStream, blocks, estimator: str) -> FrfResult:
    n_blocks = 0
    for first_index, data in blocks:
        stream.add(first_index, data)
        n_blocks += 1
    return _result(stream, n_blocks, estimator)


def _result(stream: FrfStream, n_blocks: int, estimator: str) -> FrfResult:
    result = stream.estimate(estimator)
    if result is None:
        p = stream.progress()
        raise ValueError(f"no complete realisation in the data: {n_blocks} block(s) covered "
                         f"{p.samples_done} of the experiment's {p.total_samples} samples from index "
                         f"{stream.start_index}; check start_row / the recording's extent")
    return result


def frf_from_arrays(data: Mapping[str, np.ndarray],
                    design: ExcitationDesign | Mapping[str, Any] | str | os.PathLike,
                    estimator: str = "indirect", outputs: Sequence[str] | None = None,
                    inputs: Sequence[str] | None = None,
                    references: Sequence[str] | None = None, start_row: int = 0,
                    total_samples: int | None = None) -> FrfResult:
    """FRF of an experiment recorded as named channels.

    Parameters
    ----------
    data
        channel name -> samples (n_samples,) [m for y, A for u and r],
        all the same length; row i is sample i.
    design
        the experiment's ExcitationDesign, its dict, or a JSON file.
    estimator
        one of :data:`ambid.frf.streaming.ESTIMATORS`.
    outputs
        y channel names (Ny,); None: every y_<axis> key of ``data``, in its order.
    inputs
        u channel names; those of the design's inputs are used
        (:func:`ambid.frf.streaming.match_inputs`); None: u_<axis> of the design's inputs.
    references
        r channel names, one per entry of ``inputs``; None: r_<axis> of the design's inputs.
    start_row
        row where the experiment's first sample is.
    total_samples
        the experiment was stopped after this many samples.

    Returns
    -------
    :class:`ambid.frf.streaming.FrfResult`; ``complete`` is False if the
    record ends before the experiment does.
    """
    d = load_design(design)
    outputs, inputs, references = data_channels(d.input_names, list(data), outputs, inputs, references)
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

def _is_design_topic(topic: str) -> bool:
    return topic.rstrip("/").endswith(_DESIGN_TOPIC)


def _measurement_topic(design_topic: str) -> str:
    """The measurement topic in the namespace of a design topic."""
    return design_topic.rstrip("/")[:-len(_DESIGN_TOPIC)] + _MEASUREMENT_TOPIC


def session_designs(path: str | os.PathLike, recover: bool = False) -> list[dict[str, Any]]:
    """The excitation designs recorded in a session, last message per experiment.

    Returns
    -------
    List (in recording order) of dicts with keys ``topic``,
    ``experiment_id``, ``start_index``, ``total_samples`` and ``design``
    (ExcitationDesign); a republished design (an experiment stopped
    early) replaces the earlier one.
    """

    designs = _Designs(os.fspath(path))
    decode = Ros2Decoder()
    for schema, channel, msg in iter_raw(path, _is_design_topic, recover):
        designs.add(channel.topic, decode(schema, channel, msg))
    return designs.final()


class _Designs:
    """The design messages of a session as they are read: the last one per (topic, experiment_id)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.found: dict[tuple[str, str], dict[str, Any]] = {}
        self._parsed: dict[str, ExcitationDesign] = {}   # design_json -> design, each parsed once

    def add(self, topic: str, msg: Any) -> tuple[tuple[str, str], dict[str, Any]]:
        """Record a decoded ExcitationDesign message; returns its (key, entry)."""
        key = (topic, msg.experiment_id)
        self.found.pop(key, None)  # keep the order of the last message
        entry = {"topic": topic, "experiment_id": msg.experiment_id, "start_index": int(msg.start_index),
                 "total_samples": int(msg.total_samples), "design_json": msg.design_json}
        self.found[key] = entry
        return key, entry

    def design(self, entry: dict[str, Any]) -> ExcitationDesign:
        text = entry["design_json"]
        if text not in self._parsed:
            try:
                self._parsed[text] = ExcitationDesign.from_dict(json.loads(text))
            except (ValueError, KeyError, TypeError) as exc:
                raise ValueError(f"{self.path}: the design of experiment {entry['experiment_id']!r} "
                                 f"on {entry['topic']} cannot be read: {exc}") from None
        return self._parsed[text]

    def final(self) -> list[dict[str, Any]]:
        """session_designs' list."""
        out = []
        for entry in self.found.values():
            design = self.design(entry)
            out.append({k: v for k, v in entry.items() if k != "design_json"} | {"design": design})
        return out


def _session_blocks(path: str | os.PathLike, topic: str, stream: FrfStream,
                    recover: bool) -> Iterator[tuple[int, np.ndarray]]:

    feed, read = _Feeder(stream), SampleBlockReader()
    for message in iter_messages(path, topic, recover=recover):
        block = feed.block(*read(message.data))
        if block is not None:
            yield block


class _Feeder:
    """What of a SampleBlock goes to a stream: the blocks inside the experiment, its columns."""

    def __init__(self, stream: FrfStream) -> None:
        self.stream = stream
        self.n_blocks = 0
        self._columns: dict[tuple[str, ...], np.ndarray] = {}

    def block(self, first: int, dt: float, names: list[str],
              data: np.ndarray) -> tuple[int, np.ndarray] | None:
        stream = self.stream
        if first + len(data) <= stream.start_index or first >= stream.end_index:
            return None   # outside the experiment (no gap can be there either)
        key = tuple(names)
        if key not in self._columns:
            self._columns[key] = stream.columns(names)
        stream.check_sample_period(dt)
        self.n_blocks += 1
        return first, data[:, self._columns[key]]


class _Pending:
    """The experiment a single pass over a session estimates while reading.

    ``exact`` stays True while the stream holds exactly what a stream made
    from the final design message, fed every block of the topic, would hold.
    """

    def __init__(self, key: tuple[str, str], entry: dict[str, Any], feed: _Feeder | None,
                 exact: bool) -> None:
        self.key, self.entry, self.feed, self.exact = key, entry, feed, exact and feed is not None
        self.topic = _measurement_topic(key[0])

    def update(self, entry: dict[str, Any], seen_end: int) -> None:
        """A later message of the same experiment (a stop republishes it with fewer samples)."""
        old, self.entry = self.entry, entry
        if not self.exact or entry == old:
            return
        same = all(entry[k] == old[k] for k in ("start_index", "design_json"))
        stream = self.feed.stream
        new_end = min(entry["total_samples"], stream.design.total_samples)
        old_end = stream.end_index - stream.start_index
        # exact while no block reached the earlier of the two ends: nothing was cut or skipped at either
        if same and seen_end - stream.start_index <= min(old_end, new_end):
            stream.truncate(new_end)
        else:
            self.exact = False


def frf_from_session(path: str | os.PathLike, estimator: str = "indirect",
                     experiment_id: str | None = None, outputs: Sequence[str] | None = None,
                     inputs: Sequence[str] | None = None,
                     references: Sequence[str] | None = None,
                     recover: bool = False) -> FrfResult:
    """FRF of an experiment in a recorded session (what frf_consumer computes live).

    One pass over the file: the design messages and the measurement blocks
    are read together, the blocks fed to the stream of the experiment as
    they come. Should the experiment turn out to be another one than the
    pass followed (a later design message), or its design to change in a way
    the stream cannot follow exactly, the blocks are read a second time.

    Parameters
    ----------
    path
        session .mcap file.
    estimator
        one of :data:`ambid.frf.streaming.ESTIMATORS`.
    experiment_id
        which experiment; default the last one recorded.
    outputs, inputs, references
        channel names as in
        :func:`frf_from_arrays`; None: from the data (every y channel of
        the measurement blocks, the design's u and r).
    recover
        read a file a killed recorder left (no summary).

    Returns
    -------
    :class:`ambid.frf.streaming.FrfResult`.
    """

    if estimator not in ESTIMATORS:   # before reading the file
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    designs = _Designs(os.fspath(path))
    decode = Ros2Decoder()
    readers: dict[str, SampleBlockReader] = {}
    seen_end: dict[str, int] = {}       # measurement topic -> one past the last sample index read
    block_names: dict[str, list[str]] = {}  # measurement topic -> the channel names of its first block
    pending: _Pending | None = None

    def channels(topic: str, d: ExcitationDesign) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        names = None
        if outputs is None:
            if topic not in block_names:   # the design came first: the record's channels from its first block
                block_names[topic] = _first_block_names(path, topic, recover)
            names = block_names[topic]
        return data_channels(d.input_names, names, outputs, inputs, references)

    def start(key: tuple[str, str], entry: dict[str, Any]) -> _Pending:
        topic = _measurement_topic(key[0])
        try:
            d = designs.design(entry)
            if d.kind == "recorded":    # estimated from the whole record after the pass
                return _Pending(key, entry, None, False)
            ys, us, rs = channels(topic, d)
            u_names, r_names = match_inputs(d.input_names, us, rs)
            stream = FrfStream(d, ys, u_names, r_names, start_index=entry["start_index"],
                               total_samples=min(entry["total_samples"], d.total_samples))
        except ValueError:      # raised again below if this is the experiment
            return _Pending(key, entry, None, False)
        return _Pending(key, entry, _Feeder(stream), seen_end.get(topic, 0) <= entry["start_index"])

    def wanted(topic: str) -> bool:
        return _is_design_topic(topic) or topic.rstrip("/").endswith(_MEASUREMENT_TOPIC)

    for schema, channel, msg in iter_raw(path, wanted, recover):
        topic = channel.topic
        if _is_design_topic(topic):
            key, entry = designs.add(topic, decode(schema, channel, msg))
            if experiment_id is None or key[1] == experiment_id:
                if pending is not None and pending.key == key:
                    pending.update(entry, seen_end.get(pending.topic, 0))
                else:
                    pending = start(key, entry)
            continue
        _take_block(topic, msg.data, readers, seen_end, block_names, pending)

    chosen = _chosen(designs.final(), experiment_id, path)
    key = (chosen["topic"], chosen["experiment_id"])
    topic = _measurement_topic(chosen["topic"])
    if topic not in seen_end:
        raise ValueError(f"{os.fspath(path)} has no {topic} messages beside {chosen['topic']}")
    if pending is not None and pending.exact and pending.key == key and pending.entry == designs.found[key]:
        return _result(pending.feed.stream, pending.feed.n_blocks, estimator)
    # the pass followed another experiment or could not follow this one exactly: read its blocks again
    d = chosen["design"]
    ys, us, rs = channels(topic, d)
    u_names, r_names = match_inputs(d.input_names, us, rs)
    if d.kind == "recorded":
        return frf_of_record(path, topic, chosen["start_index"], d, ys, u_names, r_names, estimator, recover)
    stream = FrfStream(d, ys, u_names, r_names, start_index=chosen["start_index"],
                       total_samples=min(chosen["total_samples"], d.total_samples))
    return _run(stream, _session_blocks(path, topic, stream, recover), estimator)


def _take_block(topic: str, data: bytes, readers: dict, seen_end: dict, block_names: dict,
                pending: _Pending | None) -> None:
    """One measurement block of the pass: note how far the topic goes, feed the followed experiment."""
    try:
        block = readers.setdefault(topic, SampleBlockReader())(data)
    except (ValueError, struct.error):  # unreadable: what follows on this topic is not exact
        seen_end[topic] = sys.maxsize
        if pending is not None and pending.topic == topic:
            pending.exact = False
        return
    seen_end[topic] = max(seen_end.get(topic, 0), block[0] + len(block[3]))
    block_names.setdefault(topic, list(block[2]))
    if pending is not None and pending.exact and pending.topic == topic:
        try:
            fed = pending.feed.block(*block)
            if fed is not None:
                pending.feed.stream.add(*fed)
        except ValueError:  # raised again by the second pass if this is the experiment
            pending.exact = False


def _chosen(found: list[dict], experiment_id: str | None, path) -> dict:
    """The experiment asked for (default the last one recorded) among the designs found."""
    if not found:
        raise ValueError(f"{os.fspath(path)} holds no '{_DESIGN_TOPIC}' message: no experiment to "
                         "estimate (record the excitation/design topic)")
    if experiment_id is None:
        return found[-1]
    match = [d for d in found if d["experiment_id"] == experiment_id]
    if not match:
        raise ValueError(f"no experiment {experiment_id!r} in {os.fspath(path)}; recorded: "
                         f"{[d['experiment_id'] for d in found]}")
    return match[-1]


# ------------------------------------------------------------------ records that do not repeat

def local_frf_result(y: np.ndarray, u: np.ndarray, r: np.ndarray, design: ExcitationDesign,
                     output_names: Sequence[str], input_names: Sequence[str]) -> FrfResult:
    """The FRF of a 'recorded' design's samples by the local polynomial method, as a :class:`FrfResult`.

    Parameters
    ----------
    y, u, r
        (n, Ny), (n, Nu), (n, Nu) the experiment's samples [m, A, A],
        n = design.n_per_period.
    design
        the 'recorded' design (its band and ``options['lpm']``).
    output_names, input_names
        labels.

    Returns
    -------
    :class:`FrfResult` at the LPM's window centres (the design's lines):
    var_noise from the local fits' residuals (first order, ``dof`` each),
    no total variance (one record), coherence ``1 - noise / power`` of y.
    """
    opt = design.options.get("lpm") or {}
    est = local_frf(y, u, r, fs_hz=design.fs_hz, band_hz=design.band_hz, degree=int(opt.get("degree", 2)),
                    half_width=opt.get("half_width"), method=str(opt.get("method", "auto")),
                    output_names=output_names, input_names=input_names)
    ny = y.shape[1]
    noise = np.real(np.diagonal(est.noise_cov[:, :ny, :ny], axis1=1, axis2=2))
    with np.errstate(divide="ignore", invalid="ignore"):
        coherence = np.clip(1.0 - noise / est.power[:, :ny], 0.0, 1.0)
    peak, idx = sensitivity_peak(est.sensitivity)
    nan = np.full(est.frf.shape, np.nan)
    return FrfResult(
        estimator="indirect", freq_hz=est.freq_hz, lines=est.bins, frf=est.frf, var_noise=est.var, var_total=nan,
        coherence=coherence, sensitivity=est.sensitivity, sensitivity_peak=peak,
        sensitivity_peak_hz=est.freq_hz[idx], iso_zone=iso14839_zone(float(peak.max())), distortion=None,
        noise_std=np.full(ny, np.nan), output_names=tuple(output_names), input_names=tuple(input_names),
        n_realisations=1, n_periods=1, n_experiments=1, gaps=(), complete=True)


def frf_of_record(path: str | os.PathLike, topic: str, start_index: int, design: ExcitationDesign,
                  outputs: Sequence[str], inputs: Sequence[str], references: Sequence[str], estimator: str,
                  recover: bool = False) -> FrfResult:
    """:func:`local_frf_result` of a 'recorded' experiment in a session (the whole experiment in memory)."""
    if estimator != "indirect":
        raise ValueError(f"a recorded excitation that does not repeat is estimated through the excitation by the "
                         f"local polynomial method; use the indirect estimator, not {estimator!r}")
    names = list(outputs) + list(inputs) + list(references)
    data = read_samples(path, topic, start_index, start_index + design.total_samples, names, recover=recover)
    if not data.present.all():
        missing = int(np.count_nonzero(~data.present))
        raise ValueError(f"{os.fspath(path)}: {missing} samples of the recorded experiment are missing; the local "
                         "polynomial method needs the record without gaps (import it again)")
    ny, nu = len(outputs), len(inputs)
    x = data.data
    return local_frf_result(x[:, :ny], x[:, ny:ny + nu], x[:, ny + nu:], design, outputs, inputs)


def _first_block_names(path: str | os.PathLike, topic: str, recover: bool) -> list[str] | None:
    """The channel names of the first readable SampleBlock on ``topic``, or None without one."""
    read = SampleBlockReader()
    for message in iter_messages(path, topic, recover=recover):
        try:
            return list(read(message.data)[2])
        except (ValueError, struct.error):
            continue
    return None
