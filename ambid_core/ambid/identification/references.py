"""What an identification compares the measurement with, which the measurement does not change.

The simulated rig's true models and parameters (at rest and at this excitation's level), the sensor noise
through its loop, its modes, and the recorded controller on a dense grid: all from what the session's
inputs say, none of what it measured, so they can be computed while the session still runs
(:mod:`ambid.identification.early`). :func:`reference_key` says whether models made ahead fit the inputs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ambid.channels import split_name
from ambid.control.closed_loop import loop_robustness
from ambid.fit.model_update import closed_loop_noise_std, excitation_slopes, slopes_as_parameters, true_parameters
from ambid.frf.streaming import axis_tag
from ambid.identification.inputs import SessionInputs, digest
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model, true_plant
from ambid.statespace import StateSpace

__all__ = ["ReferenceModels", "reference_key", "reference_models", "on_channels", "axis_of"]


@dataclass(frozen=True)
class ReferenceModels:
    """What an identification compares the measurement with that the measurement does not change.

    Attributes
    ----------
    key
        :func:`reference_key` of the inputs it was made for.
    true_g
        (L, Ny, Nu) the simulated true rig's small-signal FRF at the lines (sampled), or None.
    true_params
        its physical parameters (and the magnets' slopes at this excitation), or None.
    true_g_x
        (L, Ny, Nu) the true rig linearised at this excitation's level, or None.
    true_noise
        (Ny,) the sensor noise through the true loop [m], or None.
    true_poles
        s-plane poles [rad/s] of the linear system this excitation measures, or None.
    sens_freq_hz
        (8000,) the band's dense grid of the input-sensitivity check [Hz], or None.
    controller_frf
        (8000, Nu, Ny) the recorded controller there, or None.
    true_loop
        the true loop's input-sensitivity peak (true_peak, true_peak_hz, true_iso_zone), or None.
    """

    key: str
    true_g: np.ndarray | None = None
    true_params: dict | None = None
    true_g_x: np.ndarray | None = None
    true_noise: np.ndarray | None = None
    true_poles: np.ndarray | None = None
    sens_freq_hz: np.ndarray | None = None
    controller_frf: np.ndarray | None = None
    true_loop: dict | None = None


def reference_key(inputs: SessionInputs, freq_hz: np.ndarray, output_names: Sequence[str],
                  input_names: Sequence[str]) -> str:
    """What :func:`reference_models` depends on, hashed: the rig facts, the controller's model, the design,
    the magnets, the lines and the FRF's channels."""
    d = inputs.experiment["design"]
    k = None if inputs.controller is None else inputs.controller[0]
    return digest([inputs.rig_facts, inputs.plant_source, None if k is None else [k.a, k.b, k.c, k.d, k.dt],
                   d.to_dict(), inputs.nonlinear_magnets, np.asarray(freq_hz, dtype=float), list(output_names),
                   list(input_names)])


def reference_models(inputs: SessionInputs, freq_hz: np.ndarray, output_names: Sequence[str],
                     input_names: Sequence[str]) -> ReferenceModels:
    """The models :func:`ambid.identification.identify_session` compares with (:class:`ReferenceModels`),
    from what ``inputs`` say of the session, none of what it measured (``inputs.frf`` is not read): so
    they can be computed while the session still runs.

    Parameters
    ----------
    inputs
        the session's inputs.
    freq_hz
        (L,) the FRF's lines [Hz].
    output_names, input_names
        the FRF's channels (``y_<axis>``, ``u_<axis>``): the truths are picked on
        them, the controller aligned to them by axis; the noise through the loop needs every sensor of the rig.
    """
    f = np.asarray(freq_hz, dtype=float)
    refs: dict[str, Any] = {}
    facts, design = inputs.rig_facts, inputs.experiment["design"]
    recorded = inputs.controller
    if inputs.simulated:
        refs.update(_truths(make_rig(facts), recorded, design, inputs.nonlinear_magnets, f, output_names,
                            input_names))
    k = None if recorded is None else _aligned_controller(recorded[0], output_names, input_names)
    if k is not None and f.size:   # the loop needs the plant on the controller's channels
        refs["sens_freq_hz"] = grid = np.linspace(float(f.min()), float(f.max()), 8000)
        refs["controller_frf"] = k.freqresp(grid)
        if inputs.simulated:
            truth = loop_robustness(true_linear_model(make_rig(facts)), recorded[0])
            refs["true_loop"] = dict(true_peak=truth.sensitivity_peak, true_peak_hz=truth.peak_freq_hz,
                                     true_iso_zone=truth.zone)
    return ReferenceModels(key=reference_key(inputs, f, output_names, input_names), **refs)


def _truths(true_rig, recorded, design, nonlinear_magnets: bool, f: np.ndarray, output_names: Sequence[str],
            input_names: Sequence[str]) -> dict[str, Any]:
    """The simulated rig's truths: its FRF at rest and at this excitation, its parameters, the noise through
    its loop and the poles of the linear system this excitation measures."""
    refs: dict[str, Any] = {"true_g": on_channels(true_linear_model(true_rig, discrete=True), f, output_names,
                                                  input_names)}
    true_params = true_parameters(true_rig)
    true_plant_x = None
    if recorded is not None and design.is_periodic and nonlinear_magnets:
        # what this excitation measures: the magnets' slopes averaged over the excursions it causes
        ki_x, ks_x = excitation_slopes(true_rig, recorded[0], design)
        true_params.update({f"{k.split('_n_per')[0]}_at_excitation": v
                            for k, v in slopes_as_parameters(ki_x, ks_x, true_rig.layout).items()})
        true_plant_x = true_plant(true_rig, ki_x, ks_x)
        refs["true_g_x"] = on_channels(true_linear_model(true_rig, discrete=True, plant=true_plant_x), f,
                                       output_names, input_names)
    refs["true_params"] = true_params
    if recorded is not None and tuple(output_names) == true_rig.layout.outputs:
        # the sensor noise through the loop this excitation linearises
        refs["true_noise"] = closed_loop_noise_std(true_rig, recorded[0], true_plant_x)
    # the modes of the linear system this excitation measures (the magnets' stiffness moves them)
    refs["true_poles"] = true_linear_model(true_rig, plant=true_plant_x).poles()
    return refs


def on_channels(model: StateSpace, freq_hz: np.ndarray, output_names: Sequence[str],
                input_names: Sequence[str]) -> np.ndarray:
    """A model's FRF at ``freq_hz`` on the measured FRF's channels: its rows and columns picked by name, so a
    session that excited some of the rig's inputs is compared with the same entries of the truth."""
    g = model.freqresp(freq_hz)
    rows = [model.output_names.index(n) for n in output_names]
    cols = [model.input_names.index(n) for n in input_names]
    # C order, as freqresp gives it: the error norms sum in memory order, the default rig's to the last bit
    return np.ascontiguousarray(g[:, rows][:, :, cols])


def axis_of(name: str) -> str:
    """The axis of a channel name (``y_a_x``, ``ic_a_x``, ``u_a_x`` -> ``a_x``); another name as it is."""
    try:
        return split_name(name)[1]
    except ValueError:
        return axis_tag(name)


def _aligned_controller(k: StateSpace, output_names: Sequence[str],
                        input_names: Sequence[str]) -> StateSpace | None:
    """The controller y -> ic with its inputs in the FRF's output order and its outputs in the FRF's input
    order, matched by axis (``y_a_x`` <-> ``y_a_x``, ``u_a_x`` <-> ``ic_a_x``); as it is when its
    channels are unnamed and the sizes agree; None when the two do not close one loop."""
    if not (k.input_names and k.output_names and output_names and input_names):
        return k if (k.n_inputs, k.n_outputs) == (len(output_names), len(input_names)) else None
    ins, outs = [axis_of(n) for n in k.input_names], [axis_of(n) for n in k.output_names]
    want_in, want_out = [axis_of(n) for n in output_names], [axis_of(n) for n in input_names]
    if sorted(ins) != sorted(want_in) or sorted(outs) != sorted(want_out):
        return None
    rows, cols = [outs.index(a) for a in want_out], [ins.index(a) for a in want_in]
    if rows == sorted(rows) and cols == sorted(cols):
        return k  # already in order: the very matrices, so the figures do not move by a rounding
    return k._replace(b=np.ascontiguousarray(k.b[:, cols]), c=k.c[rows], d=k.d[np.ix_(rows, cols)],
                      input_names=tuple(k.input_names[i] for i in cols),
                      output_names=tuple(k.output_names[i] for i in rows))
