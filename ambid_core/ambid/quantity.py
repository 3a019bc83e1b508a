"""A dataclass field that says what it is: its description, SI unit and allowed range.

The core's small dataclasses (:class:`ambid.excitation.spec.DesignSpec`,
:class:`ambid.control.pid.PidParameters`) are the one home of a quantity's name
(its unit in the name: ``peak_current_a``), default, description and range. A
node declares its ROS parameters from them (``ambid_nodes.parameters.declare_fields``)
and its YAML config file is checked against them (tests/nodes/test_config_files.py),
so neither repeats a name, a default or a description.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

KEY = "quantity"


@dataclass(frozen=True)
class Quantity:
    """What a field says of itself beyond its type and default.

    Attributes
    ----------
    doc
        what the value is, in a few words.
    unit
        SI unit ("" for a count, a name or a ratio).
    low, high
        allowed range (None: any value of the type).
    empty
        for a tuple field whose default is empty: the one-entry list a ROS parameter
        writes instead (an empty array parameter has no type), e.g. ``"auto"``.
    """

    doc: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    empty: str = ""

    def description(self) -> str:
        """``doc [unit]``: a parameter's description and its config file's comment."""
        return self.doc + (f" [{self.unit}]" if self.unit else "")


def quantity(default: Any, doc: str, unit: str = "", low: float | None = None, high: float | None = None,
             empty: str = "") -> Any:
    """A dataclass field with ``default`` that carries a :class:`Quantity`.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Pulse:
    ...     peak_current_a: float = quantity(0.4, "pulse peak", "A", 0.0, 10.0)
    >>> [(name, default, q.description()) for name, default, q in quantities(Pulse)]
    [('peak_current_a', 0.4, 'pulse peak [A]')]
    """
    return dataclasses.field(default=default, metadata={KEY: Quantity(doc, unit, low, high, empty)})


def required(doc: str, unit: str = "", low: float | None = None, high: float | None = None) -> Any:
    """A dataclass field without a default that carries a :class:`Quantity` (as :func:`quantity`)."""
    return dataclasses.field(metadata={KEY: Quantity(doc, unit, low, high)})


def check_ranges(obj: Any, what: str) -> None:
    """ValueError ``"<what> <field> = <value> is outside [low, high]"`` for the first field of the dataclass
    ``obj`` whose value is not finite or outside its Quantity's range (fields without a range pass).

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Gain:
    ...     kp_a_per_m: float = quantity(1e4, "proportional gain", "A/m", 1.0, 1e9)
    >>> check_ranges(Gain(kp_a_per_m=-1.0), "PID parameter")
    Traceback (most recent call last):
    ...
    ValueError: PID parameter kp_a_per_m = -1.0 is outside [1, 1e+09]
    """
    for name, _, q in quantities(type(obj)):
        if q.low is None:
            continue
        v = getattr(obj, name)
        if not (math.isfinite(v) and q.low <= v <= q.high):
            raise ValueError(f"{what} {name} = {v!r} is outside [{q.low:g}, {q.high:g}]")


def quantities(cls: type) -> list[tuple[str, Any, Quantity]]:
    """(name, default, :class:`Quantity`) of each field of the dataclass ``cls`` that carries one, in order."""
    return [(f.name, f.default, f.metadata[KEY]) for f in dataclasses.fields(cls) if KEY in f.metadata]
