"""Save and load fitted rational models (.npz and JSON).

Both files hold the pole-residue model (poles, residues, feed-through,
delay, labels) and, for other tools, its state-space realisation
(:func:`ambid.fit.modes.to_statespace`); JSON also holds the modal summary.
Loading returns the :class:`RationalModel`; floats are written exactly
(JSON with Python's shortest round-trip repr), so the FRF of a loaded model
equals the saved one.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ambid.fit.common_denominator import RationalModel
from ambid.fit.modes import modal_summary, to_statespace
from ambid.statespace import StateSpace, statespace_from_dict

__all__ = ["FORMAT", "save_model_npz", "load_model_npz", "save_model_json", "load_model_json",
           "load_statespace_npz", "load_statespace_json"]

#: Format tag written into every file.
FORMAT = "ambid.fit.rational_model/1"


def _labels(model: RationalModel) -> dict:
    return dict(input_names=list(model.input_names), output_names=list(model.output_names),
                input_units=list(model.input_units), output_units=list(model.output_units))


def save_model_npz(path: str | Path, model: RationalModel) -> None:
    """Write ``model`` and its realisation to a .npz file.

    Arrays: poles (n,) complex [rad/s], residues (n, Ny, Nu) complex,
    feedthrough (Ny, Nu), delay_s (), ss_a, ss_b, ss_c, ss_d, and
    ``meta`` (a JSON string: format tag and channel labels).
    """
    ss = to_statespace(model)
    np.savez(path, poles=model.poles, residues=model.residues, feedthrough=model.feedthrough,
             delay_s=np.float64(model.delay_s), ss_a=ss.a, ss_b=ss.b, ss_c=ss.c, ss_d=ss.d,
             meta=np.array(json.dumps(dict(format=FORMAT, **_labels(model)))))


def _meta(data, path) -> dict:
    if "meta" not in data:
        raise ValueError(f"{path}: not an ambid rational-model file (no 'meta' entry)")
    meta = json.loads(str(data["meta"]))
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: format {meta.get('format')!r}, expected {FORMAT!r}")
    return meta


def load_model_npz(path: str | Path) -> RationalModel:
    """Read a model written by :func:`save_model_npz`."""
    with np.load(path, allow_pickle=False) as data:
        meta = _meta(data, path)
        return RationalModel(poles=data["poles"], residues=data["residues"], feedthrough=data["feedthrough"],
                             delay_s=float(data["delay_s"]), input_names=tuple(meta["input_names"]),
                             output_names=tuple(meta["output_names"]), input_units=tuple(meta["input_units"]),
                             output_units=tuple(meta["output_units"]))


def load_statespace_npz(path: str | Path) -> StateSpace:
    """The state-space realisation stored by :func:`save_model_npz` (delay not included)."""
    with np.load(path, allow_pickle=False) as data:
        meta = _meta(data, path)
        return StateSpace(data["ss_a"], data["ss_b"], data["ss_c"], data["ss_d"], 0.0,
                          tuple(meta["input_names"]), tuple(meta["output_names"]),
                          tuple(meta["input_units"]), tuple(meta["output_units"]))


def save_model_json(path: str | Path, model: RationalModel) -> None:
    """Write ``model``, its realisation and modal summary to a JSON file.

    Keys: format, poles_re, poles_im [rad/s], residues_re, residues_im
    (n, Ny, Nu), feedthrough (Ny, Nu), delay_s, the labels, statespace
    (:meth:`StateSpace.to_dict`), modes (:meth:`ModalSummary.to_dict`).
    """
    doc = dict(format=FORMAT, poles_re=model.poles.real.tolist(), poles_im=model.poles.imag.tolist(),
               residues_re=model.residues.real.tolist(), residues_im=model.residues.imag.tolist(),
               feedthrough=model.feedthrough.tolist(), delay_s=model.delay_s, **_labels(model),
               statespace=to_statespace(model).to_dict(), modes=modal_summary(model).to_dict())
    Path(path).write_text(json.dumps(doc, indent=1), encoding="utf-8")


def _read_json(path: str | Path) -> dict:
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{path}: not an ambid rational-model JSON (format should be {FORMAT!r})")
    return doc


def load_model_json(path: str | Path) -> RationalModel:
    """Read a model written by :func:`save_model_json`."""
    doc = _read_json(path)
    n = len(doc["poles_re"])
    d = np.asarray(doc["feedthrough"], dtype=float).reshape(len(doc["feedthrough"]), -1)
    res = (np.asarray(doc["residues_re"], dtype=float) + 1j * np.asarray(doc["residues_im"], dtype=float))
    return RationalModel(poles=np.asarray(doc["poles_re"], dtype=float) + 1j * np.asarray(doc["poles_im"], dtype=float),
                         residues=res.reshape(n, *d.shape), feedthrough=d, delay_s=float(doc["delay_s"]),
                         input_names=tuple(doc["input_names"]), output_names=tuple(doc["output_names"]),
                         input_units=tuple(doc["input_units"]), output_units=tuple(doc["output_units"]))


def load_statespace_json(path: str | Path) -> StateSpace:
    """The state-space realisation stored by :func:`save_model_json` (delay not included)."""
    return statespace_from_dict(_read_json(path)["statespace"])
