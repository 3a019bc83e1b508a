"""A rig's time records and their MAP.yaml become a session, in the MCAP layout the recorder writes.

One pass over the record in row chunks, one over its checked and scaled
copy spooled to disk (memory flat in the record's length):

1. check: every mapped column is there, finite in every row, all of the same
   length; the time column (if any) is evenly spaced and agrees with
   ``sample_rate_hz``; the excitation's design is found again
   (:class:`ambid.excitation.reconstruct.DesignFinder`) unless MAP.yaml
   gives it;
2. write (from the spool): ``<ns>/measurement`` SampleBlocks of y, u, r (SI units, sample
   index = record row), ``<ns>/excitation/design`` (ExcitationDesign, start
   index = the excitation's first row), ``<ns>/controller/description`` when
   MAP.yaml names a controller, and the session facts, into a file beside
   the output that is renamed onto it only when complete.

So ``ambid inspect``, ``ambid fit`` and the report read the result as they
read a recorded session.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from collections.abc import Sequence
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ambid.channels import Layout
from ambid.control.user_controller import load_controller
from ambid.excitation.design import ExcitationDesign
from ambid.excitation.reconstruct import DesignFinder, DesignNotFound
from ambid.recording.blocks import encode_sample_block
from ambid.recording.cdr import encode_message
from ambid.recording.facts import controller_facts, design_facts, design_fields
from ambid.recording.writer import QosProfile, SessionWriter
from ambid.statespace import StateSpace

from .arbitrary import RecordedExcitation
from .mapping import RecordMap, load_map
from .readers import CHUNK_ROWS, Record, RecordError, open_records
from .writers import atomic_path

__all__ = ["NAMESPACE", "ImportResult", "import_record"]

NAMESPACE = "/amb"
BLOCK_ROWS = 1000   # samples per SampleBlock, as the plant publishes them
_BLOCKS = QosProfile(depth=200)
_LATCHED = QosProfile(depth=1, durability="transient_local")


@dataclass
class ImportResult:
    """What :func:`import_record` did.

    Attributes
    ----------
    session
        the session file written.
    n_rows
        record rows (= samples in the session).
    fs_hz
        sample rate [Hz].
    design
        the experiment's design (given or reconstructed).
    start_row
        record row (= sample index) of the experiment's first sample.
    reconstructed
        True if the design was found from the excitation record.
    estimator
        which FRF estimator the session's design leads to, and why (one line).
    notes
        what was found, a line each.
    bytes_read
        size of the record file [bytes].
    seconds
        wall time [s].
    """

    session: str
    n_rows: int
    fs_hz: float
    design: ExcitationDesign
    start_row: int
    reconstructed: bool
    estimator: str = ""
    notes: list[str] = field(default_factory=list)
    bytes_read: int = 0
    seconds: float = 0.0


class _TimeCheck:
    """The time column: evenly spaced, and at sample_rate_hz when that is given too."""

    def __init__(self, m: RecordMap, path: str) -> None:
        self.m, self.path, self.t0, self.dt, self.last, self.n = m, path, None, None, None, 0

    def add(self, first: int, t: np.ndarray) -> None:
        t = t * self.m.time_scale
        if self.t0 is None:
            if len(t) < 2:
                return
            self.t0 = float(t[0])
            self.dt = 1.0 / self.m.sample_rate_hz if self.m.sample_rate_hz else float(t[1] - t[0])
            if not self.dt > 0:
                raise RecordError(f"{self.path}: time column '{self.m.time_column}' does not increase at row 2; "
                                  "give a time column in seconds that grows by one sample period per row")
        k = first + np.arange(len(t))
        err = np.abs(t - (self.t0 + k * self.dt))
        bad = np.flatnonzero(err > 0.5 * self.dt)
        if bad.size:
            row = first + int(bad[0])
            if self.m.sample_rate_hz:
                span = float(t[bad[0]] - self.t0)
                seen = row / span if span > 0 else float("nan")
                raise RecordError(
                    f"{self.path}: time column '{self.m.time_column}' at row {row + 1} is {t[bad[0]]:.9g} s but "
                    f"sample_rate_hz {self.m.sample_rate_hz:g} puts it at {self.t0 + row * self.dt:.9g} s (the "
                    f"column says {seen:.6g} Hz); check sample_rate_hz and time_scale, or leave one of them out")
            raise RecordError(
                f"{self.path}: time column '{self.m.time_column}' is not evenly spaced: row {row + 1} is "
                f"{t[bad[0]]:.9g} s, {err[bad[0]] / self.dt:.3g} sample periods off the grid of rows 1-2 (a lost "
                "or repeated sample); give a record without gaps, or cut it there")
        self.last, self.n = float(t[-1]), first + len(t)

    def fs(self) -> float:
        if self.t0 is None:
            raise RecordError(f"{self.path}: fewer than two rows: no sample rate in time column "
                              f"'{self.m.time_column}'; give a longer record")
        return float(self.m.sample_rate_hz) if self.m.sample_rate_hz else (self.n - 1) / (self.last - self.t0)


def _controller_message(model: StateSpace, name: str) -> dict:
    nu, ny = model.b.shape[1], model.c.shape[0]
    delay = int(not np.any(model.d))   # D = 0: the output is one sample late, as a digital controller's
    ss = {"sample_period": float(model.dt), "n_states": int(model.a.shape[0]), "n_inputs": int(nu),
          "n_outputs": int(ny), "a": model.a.ravel().tolist(), "b": model.b.ravel().tolist(),
          "c": model.c.ravel().tolist(), "d": model.d.ravel().tolist(), "input_names": list(model.input_names),
          "input_units": list(model.input_units), "output_names": list(model.output_names),
          "output_units": list(model.output_units)}
    return {"stamp": {"sec": 0, "nanosec": 0}, "name": name, "kind": "file", "delay_samples": delay,
            "model": ss, "current_limit": [], "parameters_json": json.dumps({"file": name})}


def _design_message(d: ExcitationDesign, start: int, experiment_id: str) -> dict:
    return {"stamp": {"sec": 0, "nanosec": 0}, **design_fields(d, experiment_id, start, d.total_samples)}


def _given_design(m: RecordMap, fs: float) -> ExcitationDesign:
    try:
        d = ExcitationDesign.from_dict(json.loads(Path(m.design).read_text()))
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise RecordError(f"{m.design}: not an excitation design ({exc}); give the JSON 'ambid design --out' "
                          "writes, or leave design: out to find it from the excitation") from None
    want = [c.name for c in m.currents]
    tags = [n.split("_", 1)[-1] for n in d.input_names]
    if sorted(tags) != sorted(n[2:] for n in want):
        raise RecordError(f"{m.design}: the design excites {list(d.input_names)} but MAP.yaml maps currents "
                          f"{want}; give the currents the design excites")
    if abs(d.fs_hz / fs - 1) > 1e-6:
        raise RecordError(f"{m.design}: the design is for {d.fs_hz:g} Hz, the record is sampled at {fs:g} Hz; "
                          "give the design made for the record's sample rate")
    return d


class _DesignCheck:
    """The recorded excitation over the given design's first period is the design's waveform."""

    def __init__(self, design: ExcitationDesign, start: int, m: RecordMap, path: str) -> None:
        self.d, self.start, self.m, self.path = design, start, m, path
        self.end = start + min(design.n_per_period, design.total_samples)
        tags = [n.split("_", 1)[-1] for n in design.input_names]
        self.cols = [tags.index(c.name[2:]) for c in m.excitation]   # design input of each excitation column
        self.tol = 1e-3 * float(np.max(design.peak_a))

    def add(self, row0: int, r: np.ndarray) -> None:
        lo, hi = max(row0, self.start), min(row0 + len(r), self.end)
        if lo >= hi:
            return
        want = self.d.samples(lo - self.start, hi - lo)[:, self.cols]
        err = np.abs(r[lo - row0:hi - row0] - want)
        if err.max() > self.tol:
            k, j = np.unravel_index(np.argmax(err > self.tol), err.shape)
            c = self.m.excitation[j]
            raise RecordError(f"{self.path}: excitation column '{c.column}' at row {lo + k + 1} is "
                              f"{r[lo - row0 + k, j]:.6g} A but the design {self.m.design} gives {want[k, j]:.6g} A; "
                              "check that the design is the one that ran and the excitation's scale, or leave "
                              "design: out to find it from the record")


def _resolved(m: RecordMap, rec: Record) -> RecordMap:
    """MAP.yaml's channels with the units and the rate the record file states where MAP.yaml gives none, and
    checked against them where it gives both."""
    chans = {}
    for group in ("outputs", "currents", "excitation"):
        out = []
        for c in getattr(m, group):
            said = rec.units.get(c.column, "")
            plain = c.scale == 1.0 and c.offset == 0.0
            if said and plain and c.unit and said != c.unit:
                raise RecordError(f"{rec.path}: column '{c.column}' is in {said} (the file says so) but MAP.yaml "
                                  f"{m.path} makes {c.key or c.name} {c.unit}; give unit: {said}, or the scale that "
                                  f"turns {said} into {c.unit}")
            unit = c.unit or (said if plain else "")
            if not unit:
                raise RecordError(f"{m.path}: {group}.{c.key or c.name} has no unit (and the file states none for "
                                  f"'{c.column}'); give unit: (m, m/s, m/s^2, V, ...)")
            out.append(dataclasses.replace(c, unit=unit))
        chans[group] = tuple(out)
    rate = m.sample_rate_hz
    if rec.sample_period_s:
        said = 1.0 / rec.sample_period_s
        if rate is not None and abs(rate / said - 1) > 1e-6:
            raise RecordError(f"{rec.path}: the file's time base says {said:g} Hz but MAP.yaml {m.path} gives "
                              f"sample_rate_hz {rate:g}; give {said:g} or leave sample_rate_hz out")
        if rate is None and m.time_column is None:
            rate = said
    if rate is None and m.time_column is None:
        raise RecordError(f"{m.path}: neither sample_rate_hz nor time_column, and {rec.path} does not state its "
                          "rate; give one of them")
    return dataclasses.replace(m, sample_rate_hz=rate, **chans)


def import_record(data: str | os.PathLike | Sequence[str | os.PathLike], record_map: str | os.PathLike | RecordMap,
                  out: str | os.PathLike, chunk_rows: int = CHUNK_ROWS) -> ImportResult:
    """Convert a rig's record into a session MCAP (module docstring).

    Parameters
    ----------
    data
        .csv, .mat (v5 or v7.3, LMS/Simcenter structs too) or .npz record, or several .mat/.npz files of
        one recording (their channels side by side).
    record_map
        MAP.yaml path or a parsed :class:`ambid.records.mapping.RecordMap`.
    out
        session .mcap to write (replaced only once complete).
    chunk_rows
        rows read at a time.

    Raises
    ------
    RecordError
        one line naming the file, the column, the row and the fix.
    """
    t_start = time.perf_counter()
    m = record_map if isinstance(record_map, RecordMap) else load_map(record_map)
    rec = open_records([data] if isinstance(data, (str, os.PathLike)) else list(data))
    rec.require(m.columns, f"MAP.yaml {m.path}")
    m = _resolved(m, rec)
    cols = m.columns
    idx = {c: i for i, c in enumerate(cols)}
    y_cols = [idx[c.column] for c in m.outputs]
    u_cols = [idx[c.column] for c in m.currents]
    r_cols = [idx[c.column] for c in m.excitation]
    sel = y_cols + u_cols + r_cols
    scale = np.array([c.scale for c in m.channels])
    offset = np.array([c.offset for c in m.channels])
    ny, nu = len(y_cols), len(u_cols)
    out = Path(out)
    # the checked, scaled rows go to a binary spool on disk (about half a CSV's size, deleted on close): the
    # second pass reads them back instead of parsing or inflating the record again
    spool = tempfile.TemporaryFile(dir=out.parent if out.parent.is_dir() else None)
    with spool:
        return _import(rec, m, out, cols, idx, sel, scale, offset, ny, nu, spool, chunk_rows, t_start)


def _import(rec, m, out, cols, idx, sel, scale, offset, ny, nu, spool, chunk_rows, t_start) -> ImportResult:
    n_rows, fs, first_on, finder, anyway, not_periodic = _spool(rec, m, cols, idx, sel, scale, offset, ny, nu,
                                                               spool, chunk_rows)
    design, start, estimator, notes = _which_design(rec, m, n_rows, fs, first_on, finder, anyway, not_periodic)
    controller = None
    if m.controller:
        try:
            # the controller closes the loop on the record's axes: y of each in, its current out
            controller = load_controller(m.controller, 1.0 / fs, "the record's",
                                         Layout.from_names(c.name for c in m.outputs))
        except ValueError as exc:
            raise RecordError(str(exc)) from None
    notes = _write_session(rec, m, out, spool, chunk_rows, ny, nu, n_rows, fs, design, start, estimator, notes,
                           controller)
    return ImportResult(str(out), n_rows, fs, design, start, not m.design, estimator, notes,
                        sum(os.path.getsize(x) for x in rec.path.split(" + ")), time.perf_counter() - t_start)


def _spool(rec, m, cols, idx, sel, scale, offset, ny, nu, spool, chunk_rows) -> tuple:
    """Pass 1: check the record, look for the periodic design and spool the scaled rows.

    Returns (rows, sample rate [Hz], first excited row, design finder, recorded excitation, why not periodic).
    """
    tcheck = _TimeCheck(m, rec.path) if m.time_column else None
    finder = None if m.design else DesignFinder([f"u_{c.name[2:]}" for c in m.currents], 1.0,
                                                m.transient_periods, m.band_hz)
    first_on = None
    n_rows = 0
    # beside the periodic design's search, the band and level of an excitation that turns out not to repeat
    # itself: its FRF then comes from the local polynomial method over the whole record
    anyway = None if m.design else RecordedExcitation(len(m.currents))
    not_periodic = ""
    # ---- pass 1: check, find the design, spool
    for first, x in rec.chunks(cols, chunk_rows):
        bad = ~np.isfinite(x)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise RecordError(f"{rec.path}: column '{cols[c]}' is {x[r, c]} at row {first + r + 1}; give finite "
                              "values (interpolate the gap, or cut the record before that row)")
        if tcheck is not None:
            tcheck.add(first, x[:, idx[m.time_column]])
        v = x[:, sel] * scale + offset
        spool.write(v.tobytes())
        r = v[:, ny + nu:]
        if first_on is None:
            on = np.flatnonzero(np.any(r != 0, axis=1))
            first_on = first + int(on[0]) if on.size else None
        if anyway is not None and first_on is not None:
            anyway.add(r[max(first_on - first, 0):])
        if finder is not None:
            try:
                finder.add(r, v[:, :ny])
            except DesignNotFound as exc:
                finder, not_periodic = None, _reason(exc)
        n_rows = first + len(x)
    if n_rows == 0:
        raise RecordError(f"{rec.path}: the header has no rows under it; give a record with samples")
    fs = tcheck.fs() if tcheck is not None else m.sample_rate_hz
    if first_on is None:
        raise RecordError(f"{rec.path}: the excitation columns ({', '.join(c.column for c in m.excitation)}) are "
                          "zero in every row; check the excitation: columns in MAP.yaml")
    return n_rows, fs, first_on, finder, anyway, not_periodic


def _which_design(rec, m, n_rows, fs, first_on, finder, anyway, not_periodic) -> tuple:
    """The experiment the record holds: the periodic design found, the recorded excitation, or the given design.

    Returns (design, first row, estimator sentence, notes).
    """
    notes: list[str] = []
    found = None
    if finder is not None:
        finder.fs = fs
        try:
            found = finder.finish()
        except DesignNotFound as exc:
            not_periodic = _reason(exc)
    if found is not None:
        design, start, notes = found.design, found.start_row, found.notes
        estimator = (f"estimator: period averaging through the excitation, S_yr S_ur^-1, as for a session ambid "
                     f"recorded: the excitation repeats itself every {design.n_per_period} rows (a periodic "
                     f"{design.options.get('mimo')} design, {design.n_transient_periods} settling period(s) per "
                     "segment left out)")
    elif anyway is not None:
        design, start = anyway.design([f"u_{c.name[2:]}" for c in m.currents], fs, m.band_hz, rec.path,
                                      not_periodic), first_on
        h = design.options["lpm"]["half_width"]
        estimator = (f"estimator: local polynomial method (rational where it pays) over the whole record, "
                     f"through the excitation: {not_periodic}")
        notes.append(f"excitation from row {start + 1} to {n_rows}: {n_rows - start} rows, band "
                     f"{design.band_hz[0]:g}-{design.band_hz[1]:g} Hz, {design.excited_lines.size} lines "
                     f"{fs * (2 * h + 1) / (n_rows - start):.3g} Hz apart (windows of {2 * h + 1} bins), "
                     f"peak {', '.join(f'{p:.3g} {c.unit}' for p, c in zip(design.peak_a, m.excitation))}")
        if m.transient_periods is not None:
            notes.append("transient_periods: in MAP.yaml is not used: the local polynomial method removes the "
                         "transient itself")
    else:
        design, start = _given_design(m, fs), first_on
        if start + design.total_samples > n_rows:
            raise RecordError(f"{rec.path}: the experiment from row {start + 1} needs {design.total_samples} rows "
                              f"but the record ends at row {n_rows}: shorter than the design; give the whole "
                              "record or the design that ran")
        notes.append(f"design from {m.design}: experiment from row {start + 1} (the excitation's first non-zero row)")
        estimator = (f"estimator: the design's own ({design.kind}), as for a session ambid recorded: the design was "
                     "given")
    return design, start, estimator, notes


def _write_session(rec, m, out, spool, chunk_rows, ny, nu, n_rows, fs, design, start, estimator, notes,
                   controller) -> list[str]:
    """Pass 2: write the session MCAP (design, controller, facts, blocks) from the spool; the notes written."""
    names = [c.name for c in m.channels]
    units = [c.unit for c in m.channels]
    notes = list(rec.notes) + notes
    where = {c.injected_at for c in m.excitation}
    if where != {"current"}:
        notes.append("excitation injected at the " + ", ".join(f"{c.injected_at} ({c.name} [{c.unit}])"
                                                              for c in m.excitation)
                     + ": the FRF through it is the plant's all the same (S_yr S_ur^-1)")
    dt = 1.0 / fs
    ns = NAMESPACE
    design_msg = _design_message(design, start, m.experiment_id)
    facts = {"excitation": {m.experiment_id: design_facts(SimpleNamespace(**design_msg))},
             "import": {"record": " + ".join(os.path.abspath(x) for x in rec.path.split(" + ")),
                        "map": os.path.abspath(m.path), "rows": n_rows,
                        "reconstructed": not m.design, "estimator": estimator, "notes": notes,
                        "injected_at": {c.name: c.injected_at for c in m.excitation},
                        "units": {c.name: c.unit for c in m.channels}}}
    with atomic_path(out) as tmp:
        with SessionWriter(tmp, overwrite=True) as w:
            w.add_topic(f"{ns}/excitation/design", "ambid_msgs/msg/ExcitationDesign", [_LATCHED])
            w.add_topic(f"{ns}/measurement", "ambid_msgs/msg/SampleBlock", [_BLOCKS])
            if controller is not None:
                w.add_topic(f"{ns}/controller/description", "ambid_msgs/msg/ControllerDescription", [_LATCHED])
                cmsg = _controller_message(controller, os.path.basename(m.controller))
                w.write(f"{ns}/controller/description", encode_message("ambid_msgs/msg/ControllerDescription",
                                                                       cmsg), 0)
                facts["controller"] = controller_facts(SimpleNamespace(
                    **{**cmsg, "model": SimpleNamespace(**cmsg["model"])}))
            w.write_session_facts(facts)
            w.write(f"{ns}/excitation/design", encode_message("ambid_msgs/msg/ExcitationDesign", design_msg),
                    int(round(start * dt * 1e9)))
            carry = np.zeros((0, len(names)))
            check = _DesignCheck(design, start, m, rec.path) if m.design else None
            spool.seek(0)
            for first in range(0, n_rows, chunk_rows):
                n = min(chunk_rows, n_rows - first)
                x = np.frombuffer(spool.read(n * len(names) * 8), dtype=float).reshape(n, len(names))
                x = np.concatenate([carry, x])
                if check is not None:
                    check.add(first - len(carry), x[:, ny + nu:])
                row0 = first - len(carry)
                k = 0
                while len(x) - k >= BLOCK_ROWS:
                    _write_block(w, row0 + k, dt, names, units, x[k:k + BLOCK_ROWS], m.experiment_id)
                    k += BLOCK_ROWS
                carry = x[k:]
            if len(carry):
                _write_block(w, n_rows - len(carry), dt, names, units, carry, m.experiment_id)

    return notes

def _reason(exc: DesignNotFound) -> str:
    """Why the excitation is not a periodic design, without the fix (the LPM needs none)."""
    return str(exc).split(";")[0]


def _write_block(w: SessionWriter, first: int, dt: float, names, units, x: np.ndarray, exp: str) -> None:
    stamp = int(round(first * dt * 1e9))
    w.write(f"{NAMESPACE}/measurement", encode_sample_block(first, dt, names, units, x, exp, stamp),
            int(round((first + len(x)) * dt * 1e9)))
