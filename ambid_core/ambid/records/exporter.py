"""A session's time records out, with the MAP.yaml that imports them again.

The ``measurement`` SampleBlocks of the experiment's namespace, between the
end of the experiment before it and the start of the one after, become rows, one column per channel plus ``t`` [s]; the
MAP.yaml beside the file (``<stem>.MAP.yaml``) maps y, u and r of the
design's inputs back, with the two facts the excitation cannot show
(transient periods, band of the detection lines), and the recorded
controller as ``<stem>.controller.npz`` when the session has one. So
``ambid export`` then ``ambid import`` gives the same FRF.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ambid.control.user_controller import save_controller
from ambid.frf.offline import session_designs
from ambid.recording.blocks import block_spans, iter_sample_blocks
from ambid.recording.facts import controller_model
from ambid.recording.reader import iter_decoded
from ambid.statespace import StateSpace

from .mapping import MapChannel, RecordMap, map_yaml
from .readers import RecordError
from .writers import FORMAT_SUFFIX, atomic_path, write_record

__all__ = ["ExportResult", "export_paths", "export_session"]

_DESIGN = "excitation/design"


@dataclass
class ExportResult:
    """Files written by :func:`export_session` and the rows and channels in them."""

    record: str
    map_yaml: str
    controller: str | None
    n_rows: int
    columns: list[str]


def _controller(path: str, namespace: str) -> StateSpace | None:
    for _, dec in iter_decoded(path, [f"{namespace}controller/description"]):
        return controller_model(dec)
    return None


def export_paths(out: str | os.PathLike) -> tuple[Path, Path, Path]:
    """(record, its MAP.yaml, its controller file): the files an export to ``out`` may write."""
    out = Path(out)
    stem = out.with_suffix("")
    return out, Path(f"{stem}.MAP.yaml"), Path(f"{stem}.controller.npz")


def export_session(session: str | os.PathLike, out: str | os.PathLike, fmt: str,
                   experiment_id: str | None = None) -> ExportResult:
    """Write the session's measurement rows to ``out`` as ``fmt`` ('csv', 'mat', 'mat73', 'npz') and a MAP.yaml.

    Raises
    ------
    RecordError
        no experiment, no measurement blocks, or gaps in them.
    """
    path = os.fspath(session)
    suffix = FORMAT_SUFFIX.get(fmt, "")
    if Path(out).suffix.lower() != suffix:
        raise RecordError(f"{out}: --format {fmt} writes a {suffix} file, and the import tells a record's format "
                          f"by its name; give --out ending in {suffix}")
    try:
        designs = session_designs(path)
    except ValueError as exc:
        raise RecordError(f"{path}: {exc}") from None
    every = designs
    if experiment_id is not None:
        designs = [d for d in designs if d["experiment_id"] == experiment_id]
    if not designs and every:
        ids = ", ".join(dict.fromkeys(d["experiment_id"] for d in every))
        raise RecordError(f"{path} has no experiment '{experiment_id}' (it has {ids}); give one of these to "
                          "--experiment")
    if not designs:
        raise RecordError(f"{path} holds no excitation/design message; give a session 'ambid identify' or the "
                          "recorder wrote")
    chosen = designs[-1]
    design = chosen["design"]
    ns = chosen["topic"].rstrip("/")[:-len(_DESIGN)]
    topic = ns + "measurement"
    spans = sorted(block_spans(path, [topic])[topic], key=lambda s: s[1])
    if not spans:
        raise RecordError(f"{path} has no {topic} blocks beside {chosen['topic']}; record the measurement topic")
    first0 = spans[0][1]
    end = first0
    for _, first, n in spans:
        if first != end:
            raise RecordError(f"{path}: {topic} jumps from sample {end} to {first} (a gap or an overlap); export "
                              "needs an unbroken record: run 'ambid inspect' to see the gaps, and record again")
        end = first + n
    # the rows between the neighbouring experiments: the import finds one experiment in a record
    exp0 = chosen["start_index"]
    exp1 = exp0 + min(chosen["total_samples"], design.total_samples)
    others = [(d["start_index"], d["start_index"] + min(d["total_samples"], d["design"].total_samples))
              for d in every if d is not chosen and d["topic"] == chosen["topic"]]
    lo = max([first0] + [b for a, b in others if b <= exp0])
    hi = min([end] + [a for a, b in others if a >= exp1])
    n_rows = hi - lo
    _, block = next(iter_sample_blocks(path, topic))
    names = list(block.channel_names)
    dt = block.sample_period_s
    columns = ["t"] + names

    def chunks() -> Iterator[tuple[int, np.ndarray]]:
        for _, b in iter_sample_blocks(path, topic):
            if list(b.channel_names) != names:
                raise RecordError(f"{path}: {topic} changes its channels at sample {b.first_index}; export one "
                                  "layout at a time")
            a, z = max(b.first_index, lo), min(b.first_index + b.n_samples, hi)
            if a < z:
                t = np.arange(a, z) * dt
                yield a - lo, np.column_stack([t, b.data[a - b.first_index:z - b.first_index]])

    out, map_path, ctrl_path = export_paths(out)
    ctrl = _controller(path, ns)
    ctrl_path = ctrl_path if ctrl is not None else None
    write_record(out, fmt, columns, n_rows, _in_order(chunks(), n_rows))
    tags = [n.split("_", 1)[-1] for n in design.input_names]
    rmap = RecordMap(
        path=str(map_path), sample_rate_hz=1.0 / dt, time_column="t", time_scale=1.0,
        outputs=tuple(MapChannel(n, n, 1.0, 0.0, "m") for n in names if n.startswith("y_")),
        currents=tuple(MapChannel(f"u_{t}", f"u_{t}", 1.0, 0.0, "A") for t in tags),
        excitation=tuple(MapChannel(f"r_{t}", f"r_{t}", 1.0, 0.0, "A") for t in tags),
        controller=ctrl_path.name if ctrl_path else None, transient_periods=design.n_transient_periods,
        band_hz=design.band_hz, experiment_id=chosen["experiment_id"])
    if ctrl_path is not None:
        with atomic_path(ctrl_path) as tmp:
            save_controller(tmp.with_suffix(".npz"), ctrl)
            os.replace(tmp.with_suffix(".npz"), tmp)
    with atomic_path(map_path) as tmp:
        tmp.write_text(map_yaml(rmap, f"ambid export of {os.path.abspath(path)}, experiment "
                                      f"{chosen['experiment_id']}\nambid import {out.name} --map {map_path.name} "
                                      "--out SESSION.mcap"))
    return ExportResult(str(out), str(map_path), str(ctrl_path) if ctrl_path else None, n_rows, columns)


def _in_order(chunks: Iterator[tuple[int, np.ndarray]], n_rows: int) -> Iterator[tuple[int, np.ndarray]]:
    expect = 0
    for first, x in chunks:
        if first != expect:
            raise RecordError(f"measurement blocks are not in sample order at row {first}; export needs them in "
                              "order, record again")
        expect = first + len(x)
        yield first, x
