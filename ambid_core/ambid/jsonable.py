"""Plain JSON types from numpy-laden results: one converter for every summary and file ambid writes.

:func:`to_jsonable` turns numpy values, tuples, paths and :class:`JsonRecord` dataclasses into JSON
types; a :class:`JsonRecord` says how its fields are written (:func:`json_field`) and is read back with
:meth:`JsonRecord.from_json`. Results travel between the layers as dataclasses; JSON is made only at the
edge, where a file is written or read.
"""

from __future__ import annotations

import dataclasses
import math
import os
import types
import typing
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

__all__ = ["to_jsonable", "JsonRecord", "json_field"]


def to_jsonable(x: Any) -> Any:
    """``x`` with numpy scalars and arrays, tuples, paths and :class:`JsonRecord` s turned into JSON types.

    Dicts keep their structure (keys become strings), arrays become nested
    lists, NaN and Inf become None (JSON has neither), paths become strings,
    a :class:`JsonRecord` becomes its :meth:`~JsonRecord.to_json`.
    Other objects pass through unchanged, so ``json.dumps`` still refuses them.

    Examples
    --------
    >>> import numpy as np
    >>> to_jsonable({"peak_a": np.array([0.5, np.nan]), "band_hz": (10.0, 1000.0)})
    {'peak_a': [0.5, None], 'band_hz': [10.0, 1000.0]}
    """
    if isinstance(x, JsonRecord):
        return x.to_json()
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    return x


def json_field(default: Any = dataclasses.MISSING, *, omit_none: bool = False, flatten: bool = False) -> Any:
    """A :class:`JsonRecord` field: ``omit_none``: left out of the JSON while None (a key that is there only
    when it applies); ``flatten``: a nested record whose keys are written in this one's, in its place."""
    meta = {"omit_none": omit_none or flatten, "flatten": flatten}
    if default is dataclasses.MISSING and (omit_none or flatten):
        default = None
    return dataclasses.field(default=default, metadata=meta)


class JsonRecord(Mapping):
    """A dataclass written as one JSON object: its fields in their order, as :func:`json_field` says.

    A record also reads as that object (``record["total_lag"]["value"]``: JSON types, as a file holding
    it reads), and two records are equal when their JSON objects are; code that knows the record reads its
    attributes. Declare subclasses ``@dataclass(frozen=True, eq=False)`` (arrays have no plain ``==``).

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True, eq=False)
    ... class Lag(JsonRecord):
    ...     value: float
    ...     true: float | None = json_field(omit_none=True)
    >>> Lag(1.5e-4).to_json()
    {'value': 0.00015}
    >>> lag = Lag.from_json({"value": 1.5e-4, "true": 1.4e-4})
    >>> lag.true, lag["true"], dict(lag)
    (0.00014, 0.00014, {'value': 0.00015, 'true': 0.00014})
    """

    def __getitem__(self, key: str) -> Any:
        return to_jsonable(self.json_items()[key])

    def __iter__(self) -> Iterator[str]:
        return iter(self.json_items())

    def __len__(self) -> int:
        return len(self.json_items())

    def json_items(self) -> dict[str, Any]:
        """The JSON object's items before conversion, in field order."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if value is None and f.metadata.get("omit_none"):
                continue
            if f.metadata.get("flatten"):
                out.update(value.json_items())
            else:
                out[f.name] = value
        return out

    def to_json(self) -> dict[str, Any]:
        """The record as JSON types (:func:`to_jsonable`)."""
        return to_jsonable(self.json_items())

    @classmethod
    def from_json(cls, data: dict[str, Any]):
        """The record from its JSON object (as :meth:`to_json` wrote it, or a file's): nested records,
        lists and dicts of them rebuilt from their annotations; keys it does not know are ignored."""
        hints = typing.get_type_hints(cls)
        kwargs = {}
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            if f.metadata.get("flatten"):
                sub = _record_type(hints[f.name])
                names = {g.name for g in dataclasses.fields(sub)}
                kwargs[f.name] = sub.from_json(data) if names & set(data) else None
            elif f.name in data:
                kwargs[f.name] = _from_json(hints[f.name], data[f.name])
        return cls(**kwargs)


def _record_type(tp: Any) -> Any:
    """The JsonRecord class in an annotation (``X`` or ``X | None``), or None."""
    if isinstance(tp, type) and issubclass(tp, JsonRecord):
        return tp
    for arm in typing.get_args(tp):
        if isinstance(arm, type) and issubclass(arm, JsonRecord):
            return arm
    return None


def _from_json(tp: Any, value: Any) -> Any:
    if value is None:
        return None
    record = _record_type(tp)
    if record is not None and isinstance(value, dict):
        return record.from_json(value)
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        arms = [a for a in typing.get_args(tp) if a is not type(None)]
        return _from_json(arms[0], value) if len(arms) == 1 else value
    args = typing.get_args(tp)
    if origin is list and args and isinstance(value, list):
        return [_from_json(args[0], v) for v in value]
    if origin is dict and len(args) == 2 and isinstance(value, dict):
        return {k: _from_json(args[1], v) for k, v in value.items()}
    if origin is tuple and isinstance(value, list):
        return tuple(value)
    return value
