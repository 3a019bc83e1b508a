"""What spoils the record: the experiment's samples read once, judged for clipping, saturation, dropouts,
too little excitation and low coherence (:func:`ambid.frf.quality.record_quality`), with the FRF's coherence."""

from __future__ import annotations

import numpy as np

from ambid.frf.quality import record_quality
from ambid.identification.inputs import MEASUREMENT_TOPIC, SessionInputs
from ambid.identification.references import axis_of
from ambid.identification.result import CoherenceFigures, QualityFigures
from ambid.recording.blocks import read_samples

__all__ = ["experiment_samples", "quality_figures"]


def experiment_samples(path: str, inputs: SessionInputs, recover: bool = False):
    """The experiment's samples of the FRF's outputs, inputs and excitation (a SampleRange), or None."""
    frf, design, chosen = inputs.frf, inputs.design, inputs.experiment
    topic = inputs.namespace() + MEASUREMENT_TOPIC
    refs = [("r_" + n[2:]) if n.startswith("u_") else "r_" + n for n in frf.input_names]
    names = list(frf.output_names) + list(frf.input_names) + refs
    start = chosen["start_index"]
    total = min(chosen["total_samples"], design.total_samples)
    try:
        return read_samples(path, topic, start, start + total, names, recover=recover)
    except ValueError:
        return None


def quality_figures(samples, inputs: SessionInputs) -> QualityFigures:
    """What spoils the record, one finding each ([] without samples), and the FRF's coherence."""
    frf = inputs.frf
    findings = []
    if samples is not None:
        ny, nu = len(frf.output_names), len(frf.input_names)
        names = list(frf.output_names) + list(frf.input_names) + [f"r_{axis_of(n)}" for n in frf.input_names]
        found = record_quality(samples.data, names, inputs.design.fs_hz, frf.freq_hz, frf.coherence,
                               frf.output_names, names[ny + nu:], first_row=int(inputs.experiment["start_index"]))
        findings = [q.to_dict() for q in found]
    return QualityFigures(findings=findings, coherence=CoherenceFigures(
        min=float(np.nanmin(frf.coherence)) if np.size(frf.coherence) else None,
        median=float(np.nanmedian(frf.coherence)) if np.size(frf.coherence) else None,
        per_line="frf.npz: coherence (L, Ny), each output's multiple coherence with the excitation"))
