"""Stage 1, the inputs: what the identification of one experiment takes from its session, each read once.

:func:`read_session_inputs` reads them from the recording; :func:`inputs_from_messages` makes the same
from the messages a running session publishes (so an analysis can start before its recording is closed,
:mod:`ambid.identification.early`). Equal :meth:`SessionInputs.digest` s give equal numbers.
"""

from __future__ import annotations

import hashlib
import dataclasses
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ambid.excitation.design import ExcitationDesign
from ambid.frf.offline import frf_from_session, session_designs
from ambid.frf.streaming import FrfResult
from ambid.recording import iter_decoded, read_metadata
from ambid.recording.facts import controller_facts, controller_model, plant_facts
from ambid.statespace import StateSpace

__all__ = ["SessionInputs", "read_session_inputs", "inputs_from_messages", "session_rig", "recorded_controller",
           "digest", "PLANT_TOPIC", "DESIGN_TOPIC", "MEASUREMENT_TOPIC"]

PLANT_TOPIC = "plant/description"
DESIGN_TOPIC = "excitation/design"
MEASUREMENT_TOPIC = "measurement"


@dataclass(frozen=True)
class SessionInputs:
    """What the identification of one experiment takes from its session.

    Attributes
    ----------
    path
        the session file.
    experiment
        the experiment's entry as :func:`ambid.frf.offline.session_designs` lists it
        (``topic``, ``experiment_id``, ``start_index``, ``total_samples``, ``design``).
    frf
        its FRF (:func:`ambid.frf.offline.frf_from_session`); None before the measurement ends.
    rig_facts
        the rig parameters the session recorded (:func:`session_rig`), or None.
    plant_source
        ``'sim'``, ``'hardware'`` or None.
    controller
        the controller that ran, (discrete StateSpace y -> ic, facts), or None.
    nonlinear_magnets
        the simulated plant ran the nonlinear magnets.
    injected_at
        excitation channel -> where the rig adds it ('current', 'reference', 'output'); an
        imported record's MAP.yaml says (ambid's own sessions: current, the default).
    units
        channel -> unit, where an imported record says (outputs of any kind).
    """

    path: str
    experiment: dict
    frf: FrfResult | None
    rig_facts: dict | None
    plant_source: str | None
    controller: tuple[StateSpace, dict] | None
    nonlinear_magnets: bool
    injected_at: dict = dataclasses.field(default_factory=dict)
    units: dict = dataclasses.field(default_factory=dict)

    @property
    def design(self) -> ExcitationDesign:
        """The experiment's design."""
        return self.experiment["design"]

    @property
    def simulated(self) -> bool:
        """The session ran the simulated rig and recorded it: there is a truth to compare with."""
        return self.rig_facts is not None and self.plant_source == "sim"

    def namespace(self) -> str:
        """The namespace of the session's topics (the design topic's, ``/amb/``)."""
        return self.experiment["topic"].rstrip("/")[:-len(DESIGN_TOPIC)]

    def digest(self) -> str:
        """A hash of everything the identification reads from these inputs (equal digests: equal numbers)."""
        e = self.experiment
        d = e["design"]
        return digest([e["topic"], e["experiment_id"], e["start_index"], min(e["total_samples"], d.total_samples),
                       d.to_dict(), self.frf, self.rig_facts, self.plant_source, _controller_parts(self.controller),
                       self.nonlinear_magnets])


def read_session_inputs(path: str | os.PathLike, estimator: str = "indirect", experiment_id: str | None = None,
                        recover: bool = False) -> SessionInputs:
    """:class:`SessionInputs` of one experiment (default the last) of a session file, each read once."""
    path = os.fspath(path)
    frf = frf_from_session(path, estimator=estimator, experiment_id=experiment_id, recover=recover)
    designs = session_designs(path, recover=recover)
    chosen = [d for d in designs if experiment_id is None or d["experiment_id"] == experiment_id][-1]
    namespace = chosen["topic"].rstrip("/")[:-len(DESIGN_TOPIC)]
    facts, source = session_rig(path, namespace + PLANT_TOPIC, recover=recover)
    injected_at, units = _import_facts(path, recover)
    return SessionInputs(path, chosen, frf, facts, source, recorded_controller(path, recover),
                         _nonlinear_magnets(path, recover), injected_at, units)


def inputs_from_messages(path: str | os.PathLike, design_topic: str, design_msg: Any, plant_msg: Any,
                         controller_msg: Any, frf: FrfResult | None, nonlinear_magnets: bool) -> SessionInputs:
    """:class:`SessionInputs` from the messages a session publishes, read as the recording's are read.

    For a caller that has the session's messages before its recording is closed (the composed graph):
    ``design_msg`` (the experiment's last ExcitationDesign), ``plant_msg`` (PlantDescription) and
    ``controller_msg`` (ControllerDescription, or None) as rclpy messages or decoded ones, ``frf`` the
    estimate of the FRF consumer, which runs the stream :func:`ambid.frf.offline.frf_from_session` runs
    (None while the measurement runs).
    """
    design = ExcitationDesign.from_dict(json.loads(design_msg.design_json))
    experiment = {"topic": design_topic, "experiment_id": design_msg.experiment_id,
                  "start_index": int(design_msg.start_index), "total_samples": int(design_msg.total_samples),
                  "design": design}
    facts = json.loads(plant_msg.rig_json) if plant_msg is not None and plant_msg.rig_json else None
    source = plant_facts(plant_msg)["source"] if plant_msg is not None else None
    controller = (None if controller_msg is None else
                  (controller_model(controller_msg), controller_facts(controller_msg)))
    return SessionInputs(os.fspath(path), experiment, frf, facts if isinstance(facts, dict) and facts else None,
                         str(source) if source else None, controller, bool(nonlinear_magnets))


def session_rig(path: str | os.PathLike, plant_topic: str = "/amb/plant/description",
                recover: bool = False) -> tuple[dict | None, str | None]:
    """The rig parameters and plant source ('sim' | 'hardware') recorded in a session.

    From the ``ambid.session`` metadata the recorder writes, else from the
    first PlantDescription message on ``plant_topic``.

    Returns
    -------
    (rig dict for :func:`ambid.plant.rig.make_rig` or None, source or None).
    """
    facts = read_metadata(path, recover=recover).get("ambid.session", {})
    plant = _parsed(facts.get("plant"))
    plant = plant if isinstance(plant, dict) else {}
    rig = _parsed(facts.get("rig")) or _parsed(plant.get("rig"))
    source = plant.get("source")
    if not isinstance(rig, dict) or not rig:
        rig = None
        for _, msg in iter_decoded(path, [plant_topic], recover=recover):
            pf = plant_facts(msg)
            rig = pf["rig"] if isinstance(pf["rig"], dict) and pf["rig"] else None
            source = pf["source"]
            break
    return rig, (str(source) if source else None)


def recorded_controller(path: str | os.PathLike, recover: bool = False) -> tuple[StateSpace, dict] | None:
    """The controller that ran: its discrete state space and its facts (kind, delay, parameters, ...) from
    the session's ControllerDescription, or None when the session has none."""
    for msg, dec in iter_decoded(path, recover=recover):
        if msg.topic.endswith("controller/description"):
            return controller_model(dec), controller_facts(dec)
    return None


def _parsed(value: Any) -> Any:
    """A metadata value: JSON text parsed (None where it is not JSON), anything else as it is."""
    if isinstance(value, str):
        try:
            return json.loads(value)
        except json.JSONDecodeError:
            return None
    return value


def _session_fact(path: str, key: str, recover: bool) -> dict:
    """One entry of the session's facts (``ambid.session`` metadata) as a dict; {} when it is not there."""
    value = _parsed(read_metadata(path, recover=recover).get("ambid.session", {}).get(key))
    return value if isinstance(value, dict) else {}


def _nonlinear_magnets(path: str, recover: bool) -> bool:
    """Whether the simulated session ran the nonlinear magnets (the session config identify records; the
    plant node's default, linear, when the session does not say)."""
    return bool(_session_fact(path, "config", recover).get("nonlinear_magnets", False))


def _import_facts(path: str, recover: bool) -> tuple[dict, dict]:
    """(injected_at, units) an imported record's session facts carry ({} for ambid's own sessions)."""
    facts = _session_fact(path, "import", recover)
    injected, units = facts.get("injected_at"), facts.get("units")
    return (dict(injected) if isinstance(injected, dict) else {}), (dict(units) if isinstance(units, dict) else {})


def _controller_parts(controller: tuple[StateSpace, dict] | None) -> list | None:
    if controller is None:
        return None
    k, facts = controller
    return [k.a, k.b, k.c, k.d, k.dt, facts]


def digest(obj: Any) -> str:
    """A SHA-256 of nested values: arrays by dtype, shape and bytes, floats exactly, dataclasses by field.

    Examples
    --------
    >>> import numpy as np
    >>> digest([1.0, np.zeros(2)]) == digest([1.0, np.zeros(2)])
    True
    >>> digest([1.0, np.zeros(2)]) == digest([1.0 + 1e-16 * 4, np.zeros(2)])
    False
    """
    h = hashlib.sha256()

    def feed(x: Any) -> None:
        if isinstance(x, np.ndarray):
            h.update(f"a{x.dtype.str}{x.shape}".encode())
            h.update(np.ascontiguousarray(x).tobytes())
        elif dataclasses.is_dataclass(x) and not isinstance(x, type):
            h.update(type(x).__name__.encode())
            for fld in dataclasses.fields(x):
                h.update(fld.name.encode())
                feed(getattr(x, fld.name))
        elif isinstance(x, Mapping):
            h.update(b"{")
            for k in sorted(x, key=str):
                feed(str(k))
                feed(x[k])
            h.update(b"}")
        elif isinstance(x, (list, tuple)):
            h.update(b"[")
            for v in x:
                feed(v)
            h.update(b"]")
        elif isinstance(x, (float, np.floating)):
            h.update(b"f" + float(x).hex().encode())
        else:
            h.update(f"{type(x).__name__}:{x!r}".encode())

    feed(obj)
    return h.hexdigest()
