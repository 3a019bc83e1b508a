"""What the live view shows, as JSON messages ("frames") Foxglove's panels draw.

A :class:`Frame` is one message on one topic (relative to the server's
prefix, e.g. ``frf/y_a_x/u_a_x``), with the name of its JSON schema
(:data:`SCHEMAS`) and its time on the session's sample clock. The kinds:

* ``ambid.live.FrfEntry`` (``frf/<output>/<input>``): one entry of the FRF
  matrix over its lines: ``freq_hz``, ``magnitude_db`` (dB re 1 m/A) with its
  +-2 sigma band ``magnitude_db_lower``/``_upper`` (lower bound floored at
  1e-3 |G|, as the report draws it), ``phase_deg`` with its band (2 sigma /
  |G| rad, 180 deg when wider), ``real``/``imag`` [m/A], and the noise and
  total (noise + stochastic nonlinear distortion) levels ``noise_db`` and
  ``total_db`` (20 log10 of their standard deviations) where known. Foxglove's
  Plot panel draws it against frequency with its x axis on ``.freq_hz[:]``.
  The dB and degree arrays are rounded to 1e-4; ``real`` and ``imag`` are
  exact (JSON's shortest round-trip floats).
* ``ambid.live.Levels`` (``levels/<output>``): the output's amplitude at
  the detection lines (odd and even, sorted) against its noise floor there,
  and the output's noise std and distortion figures.
* ``ambid.live.Signals`` (``signals``): the displacements y_* [m] and
  currents u_* [A] for a time plot, as an envelope: frames in pairs, each
  channel's minimum then its maximum over the samples since the pair before.
* ``ambid.live.Orbit`` (``orbit/<bearing>``): a bearing's x and y
  displacement over one block [m], for an x-y plot.
* ``ambid.live.Progress`` (``progress``): the session's progress as the
  live view follows it, and what it lost or dropped.
* ``ambid.live.Status`` (``status/<node>``): a node's status.
* ``foxglove.Log`` (``events``): the session's events, for the Log panel.

JSON has no NaN: a value that is not finite is sent as null.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ambid.frf.streaming import FrfResult

__all__ = ["Frame", "SCHEMAS", "frf_frames", "levels_frames", "orbit_frame", "status_frame",
           "event_frame", "progress_frame", "time_ns", "STATE_NAMES", "LOG_LEVELS", "envelope_frames"]

#: decimals of the dB and degree arrays: 1e-4, far below what a plot shows (``real`` and ``imag`` are exact)
DB = 4
#: SessionStatus.state -> name.
STATE_NAMES = ("idle", "running", "done", "failed")
#: SessionEvent.severity (INFO, WARN, ERROR, FATAL) -> foxglove.Log level (INFO=2 ... FATAL=5).
LOG_LEVELS = (2, 3, 4, 5)


@dataclass(frozen=True)
class Frame:
    """One message of the live view.

    Attributes
    ----------
    topic
        topic below the server's prefix, e.g. ``"frf/y_a_x/u_a_x"``.
    schema_name
        key of :data:`SCHEMAS`.
    message
        the JSON-safe message; None: the channel is only advertised (its messages come later).
    t_ns
        session time of what it shows [ns] (sample index / fs).
    """

    topic: str
    schema_name: str
    message: dict | None
    t_ns: int


def _array(items: str = "number") -> dict:
    return {"type": "array", "items": {"type": items}}


_NUM, _INT, _STR, _BOOL = ({"type": t} for t in ("number", "integer", "string", "boolean"))
_OPT_NUM = {"type": ["number", "null"]}

#: JSON schema of each kind of frame.
SCHEMAS: dict[str, dict] = {
    "ambid.live.FrfEntry": {"type": "object", "properties": {
        "experiment_id": _STR, "estimator": _STR, "output": _STR, "input": _STR, "t_s": _NUM,
        "records": _INT, "realisations": _INT, "complete": _BOOL, "band": _STR,
        **{k: _array() for k in ("freq_hz", "magnitude_db", "magnitude_db_lower", "magnitude_db_upper",
                                 "phase_deg", "phase_deg_lower", "phase_deg_upper", "real", "imag",
                                 "noise_db", "total_db")}}},
    "ambid.live.Levels": {"type": "object", "properties": {
        "experiment_id": _STR, "output": _STR, "t_s": _NUM, "freq_hz": _array(), "level_db": _array(),
        "noise_db": _array(), "kind": _array("string"), "odd_db": _OPT_NUM, "even_db": _OPT_NUM,
        "noise_std_m": _OPT_NUM, "relative_frf_noise_std": _OPT_NUM, "nonlinear_variance_ratio": _OPT_NUM}},
    "ambid.live.Signals": {"type": "object", "properties": {"t_s": _NUM}, "additionalProperties": _NUM},
    "ambid.live.Orbit": {"type": "object", "properties": {
        "bearing": _STR, "x_channel": _STR, "y_channel": _STR, "t_s": _NUM, "x_m": _array(), "y_m": _array()}},
    "ambid.live.Progress": {"type": "object", "properties": {
        "experiment_id": _STR, "t_s": _NUM, "fraction": _NUM, "periods_done": _INT, "periods": _INT,
        "records": _INT, "realisations_done": _INT, "realisations": _INT, "time_left_s": _NUM,
        "relative_frf_noise_std": _OPT_NUM, "blocks": _INT, "lost_blocks": _INT, "lost_samples": _INT,
        "rejected_blocks": _INT, "estimates": _INT, "dropped_frames": _INT, "finished": _BOOL, "frf_gaps": _INT,
        "frames_thinned": _INT,
        "frf_gap_samples": _INT}},
    "ambid.live.Status": {"type": "object", "properties": {
        "node": _STR, "state": _STR, "t_s": _NUM, "sample_index": _INT, "progress": _NUM, "received": _INT,
        "rejected": _INT, "text": _STR, "figures": {"type": "object"}}},
    # the Log panel's schema (foxglove.Log), JSON-encoded
    "foxglove.Log": {"type": "object", "properties": {
        "timestamp": {"type": "object", "properties": {"sec": _INT, "nsec": _INT}},
        "level": _INT, "message": _STR, "name": _STR, "file": _STR, "line": _INT}},
}


def time_ns(sample_index: int, fs_hz: float) -> int:
    """Session time of a sample [ns]."""
    return int(round(sample_index / fs_hz * 1e9))


def _floats(x: np.ndarray | Iterable[float], decimals: int | None = None) -> list:
    """A float list for JSON, rounded to ``decimals`` if given; non-finite values as None."""
    a = np.asarray(x, dtype=float).ravel()
    out = (a if decimals is None else np.round(a, decimals)).tolist()
    if not np.all(np.isfinite(a)):
        out = [v if math.isfinite(v) else None for v in out]
    return out


def _scalar(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _safe(x: Any) -> Any:
    """A JSON value with every non-finite float as None (status figures come from many nodes)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): _safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_safe(v) for v in x]
    return x


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.abs(x))


def _band_std(result: FrfResult) -> tuple[np.ndarray | None, str]:
    """Standard deviation of G for the band: total where known (M >= 2), else noise, else none."""
    for name, label in (("var_total", "total"), ("var_noise", "noise")):
        v = np.asarray(getattr(result, name), dtype=float)
        if np.all(np.isfinite(v)):
            return np.sqrt(v), label
    return None, "none"


def frf_frames(result: FrfResult, experiment_id: str, t_ns: int) -> list[Frame]:
    """One ``ambid.live.FrfEntry`` frame per entry (output, input) of an estimate.

    Parameters
    ----------
    result
        the estimate (:class:`ambid.frf.streaming.FrfResult`).
    experiment_id
        the experiment it belongs to.
    t_ns
        session time of the last sample it used [ns].
    """
    g = result.frf
    f = _floats(result.freq_hz)
    std, band = _band_std(result)
    mag = np.abs(g)
    mag_db, phase = _db(g), np.angle(g, deg=True)
    noise = {k: np.sqrt(np.asarray(getattr(result, k), dtype=float)) for k in ("var_noise", "var_total")}
    head = dict(experiment_id=experiment_id, estimator=result.estimator, t_s=t_ns * 1e-9,
                records=int(result.n_periods), realisations=int(result.n_realisations),
                complete=bool(result.complete), band=band)
    frames = []
    for i, out in enumerate(result.output_names):
        for j, inp in enumerate(result.input_names):
            msg = dict(head, output=out, input=inp, freq_hz=f, magnitude_db=_floats(mag_db[:, i, j], DB),
                       phase_deg=_floats(phase[:, i, j], DB), real=_floats(g[:, i, j].real),
                       imag=_floats(g[:, i, j].imag))
            if std is not None:
                s2 = 2 * std[:, i, j]
                m = mag[:, i, j]
                half = np.degrees(np.where(s2 < m, np.arcsin(np.minimum(s2 / np.maximum(m, 1e-300), 1.0)), np.pi))
                msg.update(magnitude_db_lower=_floats(_db(np.maximum(m - s2, 1e-3 * m)), DB),
                           magnitude_db_upper=_floats(_db(m + s2), DB),
                           phase_deg_lower=_floats(phase[:, i, j] - half, DB),
                           phase_deg_upper=_floats(phase[:, i, j] + half, DB))
            for key, name in (("var_noise", "noise_db"), ("var_total", "total_db")):
                if np.all(np.isfinite(noise[key][:, i, j])):
                    msg[name] = _floats(_db(noise[key][:, i, j]), DB)
            frames.append(Frame(f"frf/{out}/{inp}", "ambid.live.FrfEntry", msg, t_ns))
    return frames


def levels_frames(result: FrfResult, odd_freq_hz: np.ndarray, even_freq_hz: np.ndarray, experiment_id: str,
                  t_ns: int) -> list[Frame]:
    """One ``ambid.live.Levels`` frame per output: detection-line levels against the noise floor.

    Parameters
    ----------
    result
        the estimate, with its distortion levels (None without detection lines or with P < 2).
    odd_freq_hz, even_freq_hz
        (L_odd,), (L_even,) the design's detection lines [Hz].
    experiment_id
        the experiment.
    t_ns
        session time [ns].
    """
    d = result.distortion
    rel, ratio = _scalar(result.relative_noise_std), _scalar(result.nonlinear_ratio)
    frames = []
    freq = np.concatenate([odd_freq_hz, even_freq_hz])
    order = np.argsort(freq, kind="stable")
    kinds = np.array(["odd"] * len(odd_freq_hz) + ["even"] * len(even_freq_hz))[order].tolist()
    for i, out in enumerate(result.output_names):
        msg = dict(experiment_id=experiment_id, output=out, t_s=t_ns * 1e-9, freq_hz=_floats(freq[order]),
                   kind=kinds, noise_std_m=_scalar(result.noise_std[i]) if result.noise_std.size > i else None,
                   relative_frf_noise_std=rel, nonlinear_variance_ratio=ratio, odd_db=None, even_db=None)
        if d is not None:
            power = np.concatenate([d.odd_power[:, i], d.even_power[:, i]])[order]
            noise = np.concatenate([d.odd_noise_power[:, i], d.even_noise_power[:, i]])[order]
            with np.errstate(divide="ignore"):
                msg.update(level_db=_floats(10 * np.log10(power), DB), noise_db=_floats(10 * np.log10(noise), DB),
                           odd_db=_scalar(d.odd_db[i]), even_db=_scalar(d.even_db[i]))
        frames.append(Frame(f"levels/{out}", "ambid.live.Levels", msg, t_ns))
    return frames


def envelope_frames(first_index: int, last_index: int, fs_hz: float, names: Sequence[str],
                    envelope: np.ndarray) -> list[Frame]:
    """Two ``ambid.live.Signals`` frames: each channel's minimum, then its maximum, over samples
    ``first_index`` ... ``last_index`` (a time plot drawing them as they come draws the signals' envelope: no
    peak between two frames is lost).

    Parameters
    ----------
    first_index, last_index
        the first and the last sample the envelope covers; the minimum's frame is stamped with the first, the
        maximum's with the last.
    fs_hz
        sample rate [Hz].
    names
        (C,) the channels.
    envelope
        (2, C) their minimum and maximum [m, A].
    """
    out = []
    for k, row in zip((first_index, last_index), _rows(envelope)):
        t = time_ns(k, fs_hz)
        out.append(Frame("signals", "ambid.live.Signals", {"t_s": t * 1e-9, **dict(zip(names, row))}, t))
    return out


def _rows(a: np.ndarray) -> list[list]:
    """The rows of a 2-D array as JSON-safe lists (non-finite values as None)."""
    return [_floats(r) for r in a]


#: significant digits of an orbit's coordinates, relative to its largest: far finer than a plot shows
ORBIT_DIGITS = 5


def _relative_round(x: np.ndarray, digits: int) -> np.ndarray:
    """``x`` rounded to ``digits`` significant digits of its largest magnitude (one decimal count for all)."""
    peak = np.max(np.abs(x), initial=0.0, where=np.isfinite(x))
    if not peak > 0:
        return x
    return np.round(x, digits - 1 - int(np.floor(np.log10(peak))))


def orbit_frame(bearing: str, x_name: str, y_name: str, first_index: int, fs_hz: float, x: np.ndarray,
                y: np.ndarray, max_points: int) -> Frame:
    """A bearing's orbit over one block: x and y displacement [m], at most ``max_points`` of them (every
    k-th sample, the pairs kept), each rounded to :data:`ORBIT_DIGITS` significant digits of the block's
    largest displacement (JSON text half as long; a plot shows three)."""
    step = max(1, -(-x.size // max_points))
    t = time_ns(first_index + x.size - 1, fs_hz)
    xy = _relative_round(np.stack([x[::step], y[::step]]), ORBIT_DIGITS)
    return Frame(f"orbit/{bearing}", "ambid.live.Orbit",
                 dict(bearing=bearing, x_channel=x_name, y_channel=y_name, t_s=t * 1e-9,
                      x_m=_floats(xy[0]), y_m=_floats(xy[1])), t)


def status_frame(node: str, state: int, sample_index: int, progress: float, received: int, rejected: int,
                 text: str, figures: Mapping[str, Any], t_ns: int) -> Frame:
    """A node's status (SessionStatus) on ``status/<node's base name>``."""
    base = node.rstrip("/").rsplit("/", 1)[-1] or "node"
    name = STATE_NAMES[state] if 0 <= state < len(STATE_NAMES) else str(state)
    return Frame(f"status/{base}", "ambid.live.Status",
                 dict(node=node, state=name, t_s=t_ns * 1e-9, sample_index=int(sample_index),
                      progress=_scalar(progress), received=int(received), rejected=int(rejected), text=text,
                      figures=_safe(dict(figures))), t_ns)


def event_frame(node: str, severity: int, code: str, text: str, sample_index: int, t_ns: int) -> Frame:
    """A session event as a ``foxglove.Log`` message on ``events``."""
    level = LOG_LEVELS[severity] if 0 <= severity < len(LOG_LEVELS) else 0
    return Frame("events", "foxglove.Log",
                 dict(timestamp=dict(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000), level=level,
                      message=f"{code} at sample {sample_index}: {text}", name=node, file="", line=0), t_ns)


def progress_frame(figures: Mapping[str, Any], t_ns: int) -> Frame:
    """The live view's own account of the session (``ambid.live.Progress``)."""
    return Frame("progress", "ambid.live.Progress", dict(figures, t_s=t_ns * 1e-9), t_ns)
