"""Declaring node parameters with type, description and range, refusing unknown ones, and the rig a node runs."""

from __future__ import annotations

from ambid.plant.rig import Rig, rig_or_default
from ambid.quantity import quantities
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node


class ParameterError(ValueError):
    """A parameter given to a node is unknown or invalid."""


def declare(node: Node, name: str, default, description: str, low=None, high=None, unit: str = ""):
    """Declare one parameter with its description, SI unit and allowed range; return its value.

    An override outside [low, high] raises ParameterError naming the parameter and the range.
    """
    desc = ParameterDescriptor(name=name, description=f"{description}" + (f" [{unit}]" if unit else ""))
    if low is not None and isinstance(default, bool):
        raise TypeError("a bool parameter has no range")
    if low is not None and isinstance(default, int):
        desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        desc.additional_constraints = f"{low} <= {name} <= {high}"
    elif low is not None:
        desc.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
        desc.additional_constraints = f"{low} <= {name} <= {high}"
    try:
        return node.declare_parameter(name, default, desc).value
    except Exception as exc:  # rclpy raises several exception types for a bad override
        rng = f" (allowed range [{low}, {high}]{' ' + unit if unit else ''})" if low is not None else ""
        raise ParameterError(f"{node.get_name()}: parameter '{name}' is invalid{rng}: {exc}") from None


def declare_fields(node: Node, cls: type) -> dict:
    """Declare a parameter for each field of the dataclass ``cls`` that carries a Quantity (``ambid.quantity``):
    the field's name, default, description, unit and range; return {field: value}, ready for ``cls(**values)``.

    A tuple field is an array parameter: one of an empty default is written as its Quantity's ``empty``
    word (``[auto]``) and read back as (); one of a non-empty default takes as many entries.
    """
    values = {}
    for name, default, q in quantities(cls):
        if isinstance(default, tuple):
            value = declare(node, name, list(default) or [q.empty], q.doc, unit=q.unit)
            if not default:
                value = () if list(value) == [q.empty] else tuple(value)
            elif len(value) != len(default):
                raise ParameterError(f"{node.get_name()}: parameter '{name}' takes {len(default)} values "
                                     f"({q.description()}), got {list(value)}")
            values[name] = tuple(value)
        else:
            values[name] = declare(node, name, default, q.doc, q.low, q.high, q.unit)
    return values


def refuse_unknown(node: Node) -> None:
    """Raise ParameterError if a parameter override names no declared parameter."""
    overrides = getattr(node, "_parameter_overrides", {}) or {}
    unknown = sorted(n for n in overrides if not node.has_parameter(n))
    if unknown:
        known = ", ".join(sorted(node._parameters))  # noqa: SLF001 - names only, for the message
        raise ParameterError(f"{node.get_name()}: unknown parameter(s) {unknown}; this node takes: {known}")


def node_rig(node: Node, rig_file: str, rig: Rig | None = None) -> Rig:
    """The rig a node runs.

    A composed run parses the rig file once and hands the rig to each node
    (``rig``); a node started on its own, as in the processes layout, reads
    its own parameters, so its process parses its ``rig_file`` once here.
    A bad file is a ParameterError naming the parameter.
    """
    if rig is not None:
        return rig
    try:
        return rig_or_default(rig_file)
    except (ValueError, OSError) as exc:
        raise ParameterError(f"{node.get_name()}: parameter 'rig_file': {exc}") from None
