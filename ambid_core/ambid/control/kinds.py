"""The controllers a session can run: the one place that turns what a user names into a controller.

A built-in kind is a description and a function ``design(rig, pid) ->
ControllerDesign``; the position controller node, the CLI's
``--controller`` choices and the stability check all go through
:data:`CONTROLLER_KINDS`, so adding a kind is one design module in this
folder and one entry here (docs/architecture.md).

Besides a kind's name, a user names a controller as a file of their own
(:mod:`ambid.control.user_controller`), or, in a rig file's ``controller:``,
as a mapping: ``{kind: pid, kp_a_per_m: 9000, ...}`` (the kind's parameters)
or ``{file: my_controller.npz}``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from ambid.control.lqg import LqgParameters, lqg_controller
from ambid.control.closed_loop import check_controller_on_rig
from ambid.control.pid import PidParameters, pid_controller, pid_parameters_dict
from ambid.control.user_controller import load_controller
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace


@dataclass(frozen=True)
class ControllerDesign:
    """A designed position controller, ready to step.

    Attributes
    ----------
    kind
        the name it was designed under.
    model
        discrete state space, y (na) [m] -> ic (na) [A] on the rig's axes, computational delay included.
    current_limit_a
        saturation of ic [A].
    delay_samples
        computational delay [samples].
    parameters
        JSON-able design parameters (they travel in the controller description).
    """

    kind: str
    model: StateSpace
    current_limit_a: float
    delay_samples: int
    parameters: dict[str, Any]


def design_pid(rig: Rig, pid: PidParameters) -> ControllerDesign:
    """The decentralised PID with its filters (:mod:`ambid.control.pid`)."""
    return ControllerDesign("pid", pid_controller(pid, rig.dt, rig.layout), pid.current_limit_a, pid.delay_samples,
                            pid_parameters_dict(pid))


def design_lqg(rig: Rig, pid: PidParameters, lqg: LqgParameters | None = None) -> ControllerDesign:
    """The centralised LQG from the analytical model (:mod:`ambid.control.lqg`); the PID's current limit."""
    lqg = LqgParameters() if lqg is None else lqg
    return ControllerDesign("lqg", lqg_controller(rig, lqg), pid.current_limit_a, lqg.delay_samples, asdict(lqg))


@dataclass(frozen=True)
class ControllerKind:
    """One entry of :data:`CONTROLLER_KINDS`: what the kind is (for help texts), and its design."""

    description: str
    design: Callable[[Rig, PidParameters], ControllerDesign]


CONTROLLER_KINDS: dict[str, ControllerKind] = {
    "pid": ControllerKind("decentralised PID with filters", design_pid),
    "lqg": ControllerKind("centralised LQG from the analytical model", design_lqg),
}


FILE_SUFFIXES = (".npz", ".mat", ".yaml", ".yml")


def is_controller_file(text: str) -> bool:
    """True if ``text`` names a controller file rather than a kind (by its suffix)."""
    return Path(text).suffix.lower() in FILE_SUFFIXES


def _alternatives(kind: str) -> str:
    others = [f"'{k}'" for k in CONTROLLER_KINDS if k != kind]
    return f"Try {' or '.join(others)} (--controller), or your own controller file (--controller FILE)"


def _with_parameters(cls, params: Mapping, what: str):
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(f"{what}: unknown parameter(s) {unknown}; known are {', '.join(sorted(known))}")
    for name, value in params.items():  # a rig file's YAML can hold any type: the ranges below want numbers
        default = known[name].default
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if isinstance(default, str) and not isinstance(value, str):
            raise ValueError(f"{what}: {name} is {value!r}; give a word, e.g. {default!r}")
        if not isinstance(default, str) and not number and not (default is None and value is None):
            raise ValueError(f"{what}: {name} is {value!r}; give a number, e.g. {default!r}")
    return cls(**params)


def design_file(path: str | Path, rig: Rig, pid: PidParameters) -> ControllerDesign:
    """A user's controller from a file, saturated at the PID's current limit."""
    model = load_controller(path, rig.dt, layout=rig.layout)
    feedthrough = bool(np.any(model.d != 0))
    return ControllerDesign("file", model, pid.current_limit_a, 0 if feedthrough else 1,
                            {"file": str(Path(path).resolve()), "n_states": model.n_states,
                             "feedthrough": feedthrough})


def design_controller(spec: str | Mapping | None, rig: Rig, pid: PidParameters | None = None) -> ControllerDesign:
    """The controller ``spec`` names, for ``rig``.

    Parameters
    ----------
    spec
        a kind of :data:`CONTROLLER_KINDS`, a controller file (.npz, .mat,
        .yaml), a rig file's mapping ({kind: ..., parameters} or
        {file: ...}), or None/"" for the rig's own ``controller:`` (the
        PID when the rig names none).
    rig
        the rig (sample period, models).
    pid
        the PID's gains and the current limit of every kind (default
        PidParameters()).

    Raises
    ------
    ValueError
        an unknown kind (the message lists the known ones), a
        bad file or parameter (named).
    """
    pid = PidParameters() if pid is None else pid
    if spec is None or spec == "":
        spec = getattr(rig, "controller", None) or "pid"
    if isinstance(spec, Mapping):
        params = dict(spec)
        if "file" in params:
            if len(params) > 1:
                raise ValueError(f"controller: a file takes no other keys, got {sorted(set(params) - {'file'})}")
            return design_file(params["file"], rig, pid)
        kind = params.pop("kind", None)
        if kind == "pid":
            p = _with_parameters(PidParameters, {**asdict(pid), **params}, "controller pid")
            return design_pid(rig, p)
        if kind == "lqg":
            return design_lqg(rig, pid, _with_parameters(LqgParameters, params, "controller lqg"))
        if kind in CONTROLLER_KINDS and not params:
            return CONTROLLER_KINDS[kind].design(rig, pid)
        raise ValueError(f"controller: give kind: pid or kind: lqg with its parameters, or file: PATH; got {spec}")
    spec = str(spec)
    if spec in CONTROLLER_KINDS:
        return CONTROLLER_KINDS[spec].design(rig, pid)
    if is_controller_file(spec):
        return design_file(spec, rig, pid)
    known = ", ".join(f"'{k}'" for k in CONTROLLER_KINDS)
    raise ValueError(f"controller '{spec}' is unknown; use one of {known} or a controller file "
                     f"({', '.join(FILE_SUFFIXES)})")


def checked_design(spec: str | Mapping | None, rig: Rig, pid: PidParameters | None = None) -> ControllerDesign:
    """:func:`design_controller`, then refused unless the loop is stable on the analytical and the true
    linearised rig; the refusal names the unstable poles and suggests the other controllers."""
    design = design_controller(spec, rig, pid)
    try:
        check_controller_on_rig(rig, design.model)
    except ValueError as exc:
        raise ValueError(f"the {design.kind} controller cannot hold this rig: {exc} "
                         f"{_alternatives(design.kind)}.") from None
    return design


def describe_kinds() -> str:
    """'pid (...) | lqg (...)': each kind with its description, for help texts."""
    return " | ".join(f"{name} ({k.description})" for name, k in CONTROLLER_KINDS.items())
