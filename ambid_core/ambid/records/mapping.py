"""MAP.yaml: which column of a rig's record is which ambid channel, in which unit and scale.

::

    sample_rate_hz: 10000            # or: time_column: t  (seconds; time_scale: 1e-3 for ms)
    outputs:    {y_a_x: {column: x1, scale: 2.0e-5, unit: m}, ...}   # the bearings' displacement sensors
                #  and any other sensor by any name with its unit: {acc1: {column: a1, unit: m/s^2}}
    currents:   {u_a_x: {column: i1, scale: 1.0}, ...}                # total applied control currents
    excitation: {r_a_x: {column: exc1, injected_at: current}, ...}     # the injected excitation, same order
    controller: controller.npz       # optional: discrete state space A, B, C, D, dt (.npz, .mat, .yaml)
    design: design.json              # optional: the excitation design as 'ambid design --out' writes it
    transient_periods: 3             # optional, without design: periods per segment to discard
    band_hz: [10, 1000]              # optional, without design: band of the detection lines

A channel's value in SI units is ``scale * (column value) + offset``.
Channels are data: the record's axes are whatever the keys name, any number
of them (one axis, one plane, the four radial axes ``a_x b_x a_y b_y``, five
with the axial ``z``): output keys are displacements ``y_<axis>``, currents
``u_<axis>``, excitation ``r_<axis>`` on the same axes as the currents, in
the same order. Outputs may carry any other name (an accelerometer ``acc1``,
a velocity probe, a probe along the shaft): the session names it ``y_acc1``
and keeps its ``unit:`` (one of :data:`OUTPUT_UNITS`); a unit the record file
itself states (an LMS/Simcenter struct's) is taken where MAP.yaml gives none.
Each excitation channel says where the rig adds it (``injected_at``):
``current`` (the default: added to the control current, u = ic + r, in A),
``reference`` (the controller's position reference) or ``output`` (added to
the sensor signal the controller reads); the last two in the unit of that
signal. Numbers read as people write them (``2e-05``, ``1e3``, ``.5``:
:mod:`ambid.yaml_file`). File paths are relative to MAP.yaml's folder.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ambid.yaml_file import read_yaml
from ambid.channels import split_name

from .readers import RecordError

__all__ = ["INJECTION_POINTS", "OUTPUT_UNITS", "MapChannel", "RecordMap", "load_map", "map_yaml"]

_KEYS = {"sample_rate_hz", "time_column", "time_scale", "outputs", "currents", "excitation", "controller",
         "design", "transient_periods", "band_hz", "experiment_id"}
_UNITS = {"outputs": "m", "currents": "A", "excitation": "A"}
#: units an output (or an excitation injected at the reference or the output) may carry, SI after scaling
OUTPUT_UNITS = ("m", "m/s", "m/s^2", "V", "A", "N", "Pa", "rad", "rad/s", "rad/s^2", "-")
#: where an excitation channel is added to the loop
INJECTION_POINTS = ("current", "reference", "output")
# a few units people write, and the scale that turns them into SI
_CONVERT = {"g": ("m/s^2", 9.80665), "mm": ("m", 1e-3), "um": ("m", 1e-6), "µm": ("m", 1e-6), "mV": ("V", 1e-3),
            "mA": ("A", 1e-3), "mm/s": ("m/s", 1e-3), "m/s2": ("m/s^2", 1.0)}


@dataclass(frozen=True)
class MapChannel:
    """One ambid channel: its name, the record column, value = scale * column + offset [unit].

    ``unit`` '' means: the unit the record file states. ``injected_at`` (excitation only): where the rig adds it.
    ``key`` is the name as MAP.yaml writes it (``acc1`` for the session's ``y_acc1``).
    """

    name: str
    column: str
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    injected_at: str = "current"
    key: str = ""


@dataclass(frozen=True)
class RecordMap:
    """A parsed MAP.yaml (see the module docstring); paths resolved against its folder."""

    path: str
    sample_rate_hz: float | None
    time_column: str | None
    time_scale: float
    outputs: tuple[MapChannel, ...]
    currents: tuple[MapChannel, ...]
    excitation: tuple[MapChannel, ...]
    controller: str | None = None
    design: str | None = None
    transient_periods: int | None = None
    band_hz: tuple[float, float] | None = None
    experiment_id: str = "import"

    @property
    def channels(self) -> tuple[MapChannel, ...]:
        """Outputs, currents, excitation, in that order."""
        return self.outputs + self.currents + self.excitation

    @property
    def columns(self) -> list[str]:
        """Record columns read: the channels' and the time column (once each, in order)."""
        cols = [c.column for c in self.channels] + ([self.time_column] if self.time_column else [])
        return list(dict.fromkeys(cols))


def _bad(path: str, what: str) -> RecordError:
    return RecordError(f"{path}: {what}")


def _number(path: str, where: str, value: Any, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            (positive and value <= 0):
        raise _bad(path, f"{where} is {value!r}; give a finite{' positive' if positive else ''} number")
    return float(value)


_SIGNAL = {"outputs": "y", "currents": "u", "excitation": "r"}


def _allowed(name: Any, signal: str) -> bool:
    try:
        return isinstance(name, str) and split_name(name)[0] == signal
    except ValueError:
        return False


def _channels(path: str, raw: dict, group: str) -> tuple[MapChannel, ...]:
    entries = raw.get(group)
    sig = _SIGNAL[group]
    example = f"{sig}_a_x, {sig}_b_x, ..., {sig}_z"
    if not isinstance(entries, dict) or not entries:
        raise _bad(path, f"'{group}' must map channel names ({sig}_<axis>: {example}) to {{column: ...}}; give "
                         f"at least one")
    out = []
    keys = {"column", "scale", "offset", "unit"} | ({"injected_at"} if group == "excitation" else set())
    for name, spec in entries.items():
        key = str(name)
        if group == "outputs" and isinstance(name, (str, int)) and not _allowed(str(name), sig):
            # any sensor by any name: the session calls it y_<name>
            name = f"y_{name}"
            if not _allowed(name, sig) or "/" in name or " " in name:
                raise _bad(path, f"outputs name '{key}' cannot name a channel (no spaces or '/'); give a name "
                                 "such as acc1 and put the rig's column name under column:")
        elif not _allowed(name, sig):
            raise _bad(path, f"{group} name '{name}' is not an ambid {group[:-1] if group != 'excitation' else group} "
                             f"name {sig}_<axis> ({example}); use those names as keys and put the rig's column "
                             "name under column:")
        if isinstance(spec, str):
            spec = {"column": spec}
        if not isinstance(spec, dict) or not isinstance(spec.get("column"), (str, int)) or set(spec) - keys:
            extra = ", injected_at: current | reference | output" if group == "excitation" else ""
            raise _bad(path, f"{group}.{key} must be {{column: NAME, scale: x, offset: x, unit: {_UNITS[group]}"
                             f"{extra}}}; give at least column:")
        where = str(spec.get("injected_at", "current"))
        if where not in INJECTION_POINTS:
            raise _bad(path, f"{group}.{key}.injected_at is {where!r}; give current (added to the control current), "
                             "reference (the controller's position reference) or output (added to the sensor signal)")
        fixed = group == "currents" or (group == "excitation" and where == "current") or \
            (group == "outputs" and key.startswith("y_"))
        unit = spec.get("unit", _UNITS[group] if fixed else "")
        unit = "" if unit is None else str(unit)
        scale = _number(path, f"{group}.{key}.scale", spec.get("scale", 1.0))
        if unit in _CONVERT:
            si, factor = _CONVERT[unit]
            raise _bad(path, f"{group}.{key}: unit '{unit}' is not SI; give unit: {si} and scale: "
                             f"{scale * factor:.6g} (the scale that turns the column into {si})")
        allowed = (_UNITS[group],) if group == "currents" or (group == "excitation" and where == "current") else \
            OUTPUT_UNITS
        if unit and unit not in allowed:
            want = allowed[0] if len(allowed) == 1 else ", ".join(allowed)
            raise _bad(path, f"{group}.{key}: unit '{unit}' after scaling must be {want}; give the scale that turns "
                             f"the column into it and its unit" + ("" if group != "excitation" else
                                                                   " (or injected_at: reference | output)"))
        if scale == 0:   # every value the same: the channel would be a constant, its FRF zero
            raise _bad(path, f"{group}.{key}.scale is 0; give the factor that turns the column into "
                             f"{unit or 'its SI unit'} (negative if the sensor points the other way)")
        out.append(MapChannel(str(name), str(spec["column"]), scale,
                              _number(path, f"{group}.{key}.offset", spec.get("offset", 0.0)), unit, where, key))
    if len({c.name for c in out}) != len(out):
        dup = next(c.key for c in out if [d.name for d in out].count(c.name) > 1)
        raise _bad(path, f"{group}: '{dup}' names a channel twice; give every channel once")
    return tuple(out)


def _file(base: Path, path: str, key: str, value: Any) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise _bad(path, f"{key}: must be a file name; give the path (relative to MAP.yaml)")
    p = (base / value) if not os.path.isabs(value) else Path(value)
    if not p.is_file():
        raise _bad(path, f"{key}: {p} does not exist or is not a file; give the {key} file's path "
                         "(relative to MAP.yaml)")
    return str(p)


def load_map(path: str | os.PathLike) -> RecordMap:
    """Read and check a MAP.yaml (:class:`RecordError` naming the key and the fix)."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise RecordError(f"{path}: no such file; give the MAP.yaml that names the record's channels")
    if os.path.isdir(path):
        raise RecordError(f"{path} is a folder; give the MAP.yaml file")
    try:
        raw = read_yaml(path, "", "give a MAP.yaml as 'ambid import --help' shows")
    except ValueError as exc:
        raise RecordError(str(exc)) from None
    if raw is None:
        raise RecordError(f"{path} is empty; give sample_rate_hz (or time_column), outputs, currents and "
                          "excitation")
    if not isinstance(raw, dict):
        raise RecordError(f"{path} is not a mapping of keys; give sample_rate_hz, outputs, currents, excitation")
    unknown = sorted(set(raw) - _KEYS)
    if unknown:
        raise _bad(path, f"unknown key '{unknown[0]}'; use {', '.join(sorted(_KEYS))}")
    rate = raw.get("sample_rate_hz")
    tcol = raw.get("time_column")
    # neither: the record file must say its rate itself (an LMS/Simcenter struct's time base); the import checks
    rate = None if rate is None else _number(path, "sample_rate_hz", rate, positive=True)
    outputs = _channels(path, raw, "outputs")
    currents = _channels(path, raw, "currents")
    excitation = _channels(path, raw, "excitation")
    if [c.name[2:] for c in excitation] != [c.name[2:] for c in currents]:
        raise _bad(path, f"excitation {[c.name for c in excitation]} must name the same axes as currents "
                         f"{[c.name for c in currents]}, in the same order; give one r_<axis> per u_<axis>")
    pt = raw.get("transient_periods")
    if pt is not None and (isinstance(pt, bool) or not isinstance(pt, int) or pt < 0):
        raise _bad(path, f"transient_periods is {pt!r}; give a whole number >= 0")
    band = raw.get("band_hz")
    if band is not None:
        if not isinstance(band, list) or len(band) != 2:
            raise _bad(path, f"band_hz is {band!r}; give [f_lo, f_hi] in Hz")
        band = (_number(path, "band_hz[0]", band[0]), _number(path, "band_hz[1]", band[1]))
        if not 0 <= band[0] < band[1]:
            raise _bad(path, f"band_hz is {list(band)}; give [f_lo, f_hi] in Hz with 0 <= f_lo < f_hi")
    exp_id = raw.get("experiment_id", "import")
    if not isinstance(exp_id, (str, int)) or isinstance(exp_id, bool) or not str(exp_id).strip():
        raise _bad(path, f"experiment_id is {exp_id!r}; give a name, e.g. import")
    base = Path(path).resolve().parent
    return RecordMap(path=path, sample_rate_hz=rate, time_column=None if tcol is None else str(tcol),
                     time_scale=_number(path, "time_scale", raw.get("time_scale", 1.0), positive=True),
                     outputs=outputs, currents=currents, excitation=excitation,
                     controller=_file(base, path, "controller", raw.get("controller")),
                     design=_file(base, path, "design", raw.get("design")), transient_periods=pt, band_hz=band,
                     experiment_id=str(exp_id))


def map_yaml(m: RecordMap, comment: str = "") -> str:
    """MAP.yaml text of ``m`` (paths as given), with an optional leading comment."""
    def group(chs):
        return {c.key or c.name: {"column": c.column, "scale": c.scale, "offset": c.offset, "unit": c.unit,
                                  **({"injected_at": c.injected_at} if c.name.startswith("r_") else {})}
                for c in chs}

    d: dict[str, Any] = {}
    if m.sample_rate_hz is not None:
        d["sample_rate_hz"] = m.sample_rate_hz
    if m.time_column is not None:
        d["time_column"] = m.time_column
        d["time_scale"] = m.time_scale
    d.update(outputs=group(m.outputs), currents=group(m.currents), excitation=group(m.excitation))
    for key in ("controller", "design", "transient_periods"):
        if getattr(m, key) is not None:
            d[key] = getattr(m, key)
    if m.band_hz is not None:
        d["band_hz"] = list(m.band_hz)
    d["experiment_id"] = m.experiment_id
    head = "".join(f"# {ln}\n" for ln in comment.splitlines())
    return head + yaml.safe_dump(d, sort_keys=False, default_flow_style=False)
