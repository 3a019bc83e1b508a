"""The controller kinds a session can run, by name: the one place that maps a kind to its design.

A kind is a description and a function ``design(rig, pid) -> ControllerDesign``; the position
controller node, the CLI's ``--controller`` choices and the stability check
all go through :data:`CONTROLLER_KINDS`, so adding a kind is one design
module in this folder and one entry here (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from ambid.control.lqg import LqgParameters, lqg_controller
from ambid.control.pid import PidParameters, pid_controller, pid_parameters_dict
from ambid.plant.rig import Rig
from ambid.statespace import StateSpace


@dataclass(frozen=True)
class ControllerDesign:
    """A designed position controller, ready to step.

    Attributes:
        kind: the name it was designed under.
        model: discrete state space, y (4) [m] -> ic (4) [A], computational delay included.
        current_limit_a: saturation of ic [A].
        delay_samples: computational delay [samples].
        parameters: JSON-able design parameters (they travel in the controller description).
    """

    kind: str
    model: StateSpace
    current_limit_a: float
    delay_samples: int
    parameters: dict[str, Any]


def design_pid(rig: Rig, pid: PidParameters) -> ControllerDesign:
    """The decentralised PID with its filters (:mod:`ambid.control.pid`)."""
    return ControllerDesign("pid", pid_controller(pid, rig.dt), pid.current_limit_a, pid.delay_samples,
                            pid_parameters_dict(pid))


def design_lqg(rig: Rig, pid: PidParameters) -> ControllerDesign:
    """The centralised LQG from the analytical model (:mod:`ambid.control.lqg`); the PID's current limit."""
    lqg = LqgParameters()
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


def design_controller(kind: str, rig: Rig, pid: PidParameters | None = None) -> ControllerDesign:
    """The controller of ``kind`` for ``rig``; ``pid`` gives the PID's gains and the current limit.

    Raises:
        ValueError: an unknown kind (the message lists the known ones).
    """
    try:
        entry = CONTROLLER_KINDS[kind]
    except KeyError:
        known = ", ".join(f"'{k}'" for k in CONTROLLER_KINDS)
        raise ValueError(f"controller '{kind}' is unknown; use one of {known}") from None
    return entry.design(rig, PidParameters() if pid is None else pid)


def describe_kinds() -> str:
    """'pid (...) | lqg (...)': each kind with its description, for help texts."""
    return " | ".join(f"{name} ({k.description})" for name, k in CONTROLLER_KINDS.items())
