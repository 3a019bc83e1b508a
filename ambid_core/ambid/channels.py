"""Channels are data: the axes a session controls, and the names of the signals on each.

An *axis* is one controlled degree of freedom of the rotor: a radial bearing
axis ``<bearing>_<x|y>`` (``a_x``, ``b_y``; the x and y axes are turned 45 deg
from the vertical, A on the negative side of the shaft's middle), an axial
one (``z``, or ``<bearing>_z``), or any other name a user's rig gives it. On
every axis a session carries four signals, named by a prefix:

====== ============================================== ====
prefix signal                                         unit
====== ============================================== ====
y      measured displacement                          m
u      current reference applied to the amplifier     A
ic     the position controller's current              A
r      the excitation added to it (u = ic + r)        A
====== ============================================== ====

A :class:`Layout` is the ordered tuple of axes; every array of a session
(FRF matrices, state-space inputs and outputs, measurement columns) is in that
order. The messages carry the names (``PlantDescription.displacement_names``,
``SampleBlock.channel_names``, ``ExcitationDesign.input_names``), so a layout is
read from them (:meth:`Layout.from_names`), never assumed. :data:`RADIAL` is
the default rig's four radial axes; a rig file says its own
(:attr:`ambid.plant.rig.Rig.layout`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

# signal prefix -> SI unit
SIGNALS: dict[str, str] = {"y": "m", "u": "A", "ic": "A", "r": "A"}
_DIRECTIONS = ("x", "y", "z")


def split_name(name: str) -> tuple[str, str]:
    """``"y_a_x"`` -> ``("y", "a_x")``: a channel name's signal prefix and axis.

    Raises
    ------
    ValueError
        the name has no known prefix (:data:`SIGNALS`) or no axis.

    Examples
    --------
    >>> split_name("y_a_x")
    ('y', 'a_x')
    >>> split_name("u_z")
    ('u', 'z')
    """
    prefix, sep, axis = name.partition("_")
    if not sep or prefix not in SIGNALS or not axis:
        raise ValueError(f"channel name {name!r} is not <signal>_<axis> with signal one of {sorted(SIGNALS)} "
                         f"(e.g. y_a_x, u_z)")
    return prefix, axis


def bearing_of(axis: str) -> str:
    """The bearing (or plane) an axis belongs to: ``"a_x"`` -> ``"a"``; ``"z"`` -> ``"z"``.

    Examples
    --------
    >>> bearing_of("a_x"), bearing_of("b_y")
    ('a', 'b')
    """
    head, sep, tail = axis.rpartition("_")
    return head if sep and tail in _DIRECTIONS else axis


def direction_of(axis: str) -> str:
    """``"x"``, ``"y"`` (radial) or ``"z"`` (axial) for the conventional names; ``""`` for others.

    Examples
    --------
    >>> direction_of("a_x"), direction_of("b_y")
    ('x', 'y')
    """
    if axis in _DIRECTIONS:
        return axis
    head, sep, tail = axis.rpartition("_")
    return tail if sep and tail in _DIRECTIONS else ""


@dataclass(frozen=True)
class Layout:
    """The ordered axes of a session, and the channel names that follow from them.

    Attributes
    ----------
    axes
        axis names in session order, e.g. ``("a_x", "b_x", "a_y", "b_y")``.

    Examples
    --------
    >>> layout = Layout.from_names(["y_a_x", "y_a_y", "y_b_x", "y_b_y"])
    >>> layout.axes
    ('a_x', 'a_y', 'b_x', 'b_y')
    >>> layout.inputs
    ('u_a_x', 'u_a_y', 'u_b_x', 'u_b_y')
    >>> layout.bearings, layout.radial_pairs
    (('a', 'b'), ((0, 1), (2, 3)))
    >>> layout.index("b_x"), layout.units("y")
    (2, ('m', 'm', 'm', 'm'))
    """

    axes: tuple[str, ...]

    def __post_init__(self) -> None:
        axes = tuple(self.axes)
        object.__setattr__(self, "axes", axes)
        if not axes:
            raise ValueError("a layout needs at least one axis")
        if len(set(axes)) != len(axes):
            raise ValueError(f"axes repeat in {list(axes)}")
        for a in axes:
            if not a or "/" in a or " " in a:
                raise ValueError(f"axis name {a!r} is empty or holds '/' or a space")

    def __len__(self) -> int:
        return len(self.axes)

    def names(self, signal: str) -> tuple[str, ...]:
        """Channel names of one signal (a :data:`SIGNALS` prefix) on every axis, in order."""
        if signal not in SIGNALS:
            raise ValueError(f"signal {signal!r} is not one of {sorted(SIGNALS)}")
        return tuple(f"{signal}_{a}" for a in self.axes)

    def units(self, signal: str) -> tuple[str, ...]:
        """SI unit of that signal on every axis."""
        return (SIGNALS[signal],) * len(self.axes)

    @property
    def outputs(self) -> tuple[str, ...]:
        """Measured displacements ``y_<axis>`` [m]: the FRF's outputs."""
        return self.names("y")

    @property
    def inputs(self) -> tuple[str, ...]:
        """Applied current references ``u_<axis>`` [A]: the FRF's inputs."""
        return self.names("u")

    @property
    def controls(self) -> tuple[str, ...]:
        """Controller currents ``ic_<axis>`` [A]."""
        return self.names("ic")

    @property
    def excitations(self) -> tuple[str, ...]:
        """Excitation currents ``r_<axis>`` [A]."""
        return self.names("r")

    @property
    def measurement_names(self) -> tuple[str, ...]:
        """The columns of a measurement block: y, u, ic, r, each on every axis."""
        return self.outputs + self.inputs + self.controls + self.excitations

    def index(self, axis_or_name: str) -> int:
        """Position of an axis (``"a_x"``) or of a channel on it (``"y_a_x"``)."""
        axis = axis_or_name if axis_or_name in self.axes else split_name(axis_or_name)[1]
        return self.axes.index(axis)

    @property
    def bearings(self) -> tuple[str, ...]:
        """The bearings (planes) in order of their first axis."""
        return tuple(dict.fromkeys(bearing_of(a) for a in self.axes))

    @property
    def radial_pairs(self) -> tuple[tuple[int, int], ...]:
        """(x index, y index) of every bearing with both radial axes: an orbit, a whirl direction."""
        pairs = []
        for b in self.bearings:
            dirs = {direction_of(a): i for i, a in enumerate(self.axes) if bearing_of(a) == b}
            if "x" in dirs and "y" in dirs:
                pairs.append((dirs["x"], dirs["y"]))
        return tuple(pairs)

    @property
    def axial(self) -> tuple[int, ...]:
        """Indices of the axial axes."""
        return tuple(i for i, a in enumerate(self.axes) if direction_of(a) == "z")

    @classmethod
    def from_names(cls, names: Iterable[str]) -> "Layout":
        """The layout of channel names of one signal, e.g. ``["y_a_x", "y_b_x"]`` -> axes (a_x, b_x).

        Raises
        ------
        ValueError
            a name is not <signal>_<axis>, or the names mix signals.
        """
        parts = [split_name(n) for n in names]
        signals = {p for p, _ in parts}
        if len(signals) > 1:
            raise ValueError(f"channel names {list(names)} mix the signals {sorted(signals)}")
        return cls(tuple(a for _, a in parts))


# The default rig: two radial bearings A and B, x and y each. Order: A x, B x, A y, B y.
RADIAL = Layout(("a_x", "b_x", "a_y", "b_y"))
# The five-axis machine: the four radial axes and the axial bearing.
FIVE_AXIS = Layout(("a_x", "b_x", "a_y", "b_y", "z"))
