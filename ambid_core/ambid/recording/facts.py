"""Session facts: JSON-able summaries of the latched description messages.

The recorder stores them as MCAP metadata (``ambid.session``) so a session is
readable without decoding messages; ``ambid inspect`` prints them, or builds
them from the recorded latched messages when a file lacks the metadata.

The functions take any object with the message's field names as attributes:
an rclpy message (``ambid_msgs.msg.PlantDescription``) or an mcap_ros2
decoded one. Pure Python; nothing here imports rclpy.
"""

from __future__ import annotations

import json
import math
from typing import Any, Mapping

import numpy as np

from ambid.statespace import StateSpace

__all__ = [
    "FACT_TYPES",
    "plant_facts",
    "controller_facts",
    "controller_model",
    "design_facts",
    "design_fields",
    "rig_summary",
    "design_summary",
]

#: message type -> fact key written by the recorder.
FACT_TYPES = {
    "ambid_msgs/msg/PlantDescription": "plant",
    "ambid_msgs/msg/ControllerDescription": "controller",
    "ambid_msgs/msg/ExcitationDesign": "excitation",
}

# rig fields an engineer wants at a glance (ambid.plant.rig.Rig.to_dict names)
_RIG_SHORT = (
    "name", "sample_rate_hz", "shaft_length_m", "shaft_diameter_m", "bias_current_a",
    "current_limit_a", "air_gap_m", "backup_clearance_m", "sensor_noise_m", "rotor_speed_rpm",
)


def _floats(values: Any) -> list[float]:
    return [float(v) for v in values]


def _json_or_text(text: str) -> Any:
    if not text:
        return {}
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text  # kept verbatim: a fact must never be lost to a parse error


def plant_facts(msg: Any) -> dict[str, Any]:
    """Facts of a PlantDescription: names, sample period [s], limits [A, m], rig parameters.

    Returns
    -------
    dict with ``name, source, rig_name, sample_period_s, displacement_names,
    current_names, bias_current_a, current_limit_a, backup_clearance_m,
    seed, controller_timeout_samples`` and ``rig`` (the rig JSON parsed).
    """
    return {
        "name": str(msg.name),
        "source": str(msg.source),
        "rig_name": str(msg.rig_name),
        "sample_period_s": float(msg.sample_period),
        "displacement_names": [str(s) for s in msg.displacement_names],
        "current_names": [str(s) for s in msg.current_names],
        "bias_current_a": _floats(msg.bias_current),
        "current_limit_a": _floats(msg.current_limit),
        "backup_clearance_m": _floats(msg.backup_clearance),
        "seed": int(msg.seed),
        "controller_timeout_samples": int(msg.controller_timeout_samples),
        "rig": _json_or_text(str(msg.rig_json)),
    }


def controller_facts(msg: Any) -> dict[str, Any]:
    """Facts of a ControllerDescription: kind, delay [samples], limits [A], parameters, model size."""
    model = msg.model
    return {
        "name": str(msg.name),
        "kind": str(msg.kind),
        "delay_samples": int(msg.delay_samples),
        "current_limit_a": _floats(msg.current_limit),
        "sample_period_s": float(model.sample_period),
        "n_states": int(model.n_states),
        "n_inputs": int(model.n_inputs),
        "n_outputs": int(model.n_outputs),
        "parameters": _json_or_text(str(msg.parameters_json)),
    }


def controller_model(msg: Any) -> StateSpace:
    """The discrete state space (y [m] -> ic [A]) a ControllerDescription carries."""
    m = msg.model
    n, nu, ny = int(m.n_states), int(m.n_inputs), int(m.n_outputs)
    return StateSpace(np.reshape(m.a, (n, n)), np.reshape(m.b, (n, nu)), np.reshape(m.c, (ny, n)),
                      np.reshape(m.d, (ny, nu)), float(m.sample_period))


def design_fields(design: Any, experiment_id: str, start_index: int, total_samples: int) -> dict[str, Any]:
    """The fields of an ``ambid_msgs/ExcitationDesign`` message (all but ``stamp``) for an
    :class:`ambid.excitation.ExcitationDesign` placed at ``start_index`` and cut at ``total_samples``:
    the excitation generator's message and the import's are one layout."""
    d = design
    return dict(experiment_id=experiment_id, kind=d.kind, multi_input=str(d.options.get("mimo", "one_at_a_time")),
                start_index=int(start_index), total_samples=int(total_samples), sample_rate=float(d.fs_hz),
                samples_per_period=int(d.n_per_period), n_periods=int(d.n_periods),
                n_transient_periods=int(d.n_transient_periods), n_realisations=int(d.n_realisations),
                n_experiments=int(d.n_experiments), input_names=list(d.input_names),
                excited_lines=d.excited_lines.tolist(), detection_lines_odd=d.detection_lines_odd.tolist(),
                detection_lines_even=d.detection_lines_even.tolist(), rms=d.rms_a.tolist(), peak=d.peak_a.tolist(),
                crest_factor=d.crest_factor.tolist(), measurement_time=total_samples / d.fs_hz,
                seed=int(d.seed or 0), design_json=json.dumps(d.to_dict()))


def design_facts(msg: Any) -> dict[str, Any]:
    """Facts of an ExcitationDesign: layout [samples], band [Hz], levels [A], the full design.

    ``band_hz`` is the lowest and highest excited line, ``line * sample_rate /
    samples_per_period``; None without lines.
    """
    lines = [int(v) for v in msg.excited_lines]
    n = int(msg.samples_per_period)
    fs = float(msg.sample_rate)
    band = [min(lines) * fs / n, max(lines) * fs / n] if lines and n > 0 else None
    return {
        "experiment_id": str(msg.experiment_id),
        "kind": str(msg.kind),
        "multi_input": str(msg.multi_input),
        "start_index": int(msg.start_index),
        "total_samples": int(msg.total_samples),
        "sample_rate_hz": fs,
        "samples_per_period": n,
        "n_periods": int(msg.n_periods),
        "n_transient_periods": int(msg.n_transient_periods),
        "n_realisations": int(msg.n_realisations),
        "n_experiments": int(msg.n_experiments),
        "input_names": [str(s) for s in msg.input_names],
        "n_excited_lines": len(lines),
        "band_hz": band,
        "rms_a": _floats(msg.rms),
        "peak_a": _floats(msg.peak),
        "crest_factor": _floats(msg.crest_factor),
        "measurement_time_s": float(msg.measurement_time),
        "seed": int(msg.seed),
        "design": _json_or_text(str(msg.design_json)),
    }


def rig_summary(rig: Mapping[str, Any] | str) -> dict[str, Any]:
    """The few rig parameters worth a line (name, sample rate, sizes, currents, clearances).

    Parameters
    ----------
    rig
        the rig dict (``Rig.to_dict()``) or its JSON text.
    """
    if isinstance(rig, str):
        rig = _json_or_text(rig)
    if not isinstance(rig, Mapping):
        return {}
    return {k: rig[k] for k in _RIG_SHORT if k in rig}


def design_summary(design: Mapping[str, Any]) -> str:
    """One line describing a design from :func:`design_facts`."""
    band = design.get("band_hz")
    band_text = f"{band[0]:g}-{band[1]:g} Hz" if band else "no lines"
    fs = design.get("sample_rate_hz") or math.nan
    rms = design.get("rms_a") or []
    # each excitation channel's unit where the caller knows it (an imported record's, injected at the reference,
    # is in V or m), else A: ambid's own sessions add the excitation to the current
    units = list(design.get("excitation_units") or []) or ["A"] * len(rms)
    rms_text = ", ".join(f"{r:.3g} {u}" for r, u in zip(rms, units + ["A"] * len(rms))) or "-"
    return (
        f"{design.get('experiment_id', '?')}: {design.get('kind', '?')} ({design.get('multi_input', '')}) "
        f"on {', '.join(design.get('input_names', [])) or '-'}, {band_text}, "
        f"{design.get('n_excited_lines', 0)} lines, N={design.get('samples_per_period', 0)}, "
        f"P={design.get('n_periods', 0)}+{design.get('n_transient_periods', 0)} transient, "
        f"M={design.get('n_realisations', 0)}, Ne={design.get('n_experiments', 0)}, "
        f"samples {design.get('start_index', 0)}+{design.get('total_samples', 0)} "
        f"({design.get('total_samples', 0) / fs:.3g} s), rms {rms_text}"
    )
