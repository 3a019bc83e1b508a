"""The H-infinity mixed-sensitivity controller (:mod:`ambid.control.hinf`) for the plants a run allows.

The synthesis runs on the updated model at its estimate, for a few weightings of its roll-off
(:data:`WEIGHTINGS`: where the controller must start to roll off, against the current its noise may cost);
each controller is reduced to the lowest order (of :data:`ORDERS`) whose loop on every design plant (and
on the guards: the nominal model) is stable and whose worst input-sensitivity peak there is within 2 % of the full order's; the weighting whose
reduced controller has the lowest worst peak is kept.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from ambid.commissioning.loops import worst_peak
from ambid.commissioning.plants import PlantSet
from ambid.control.closed_loop import close_loop, residue_freqresp
from ambid.control.hinf import MixedSensitivityWeights, mixed_sensitivity, reduce_controller, with_delay
from ambid.statespace import StateSpace

__all__ = ["HinfDesign", "WEIGHTINGS", "ORDERS", "tune_hinf"]

#: the roll-off weightings tried: (effort corner [Hz], effort current [A])
WEIGHTINGS: tuple[tuple[float, float], ...] = ((500.0, 1.0), (800.0, 1.0), (1200.0, 0.5))
#: the reduced orders tried, lowest first
ORDERS: tuple[int, ...] = (8, 12, 16, 20, 24, 28, 32, 40)


@dataclass(frozen=True)
class HinfDesign:
    """A tuned H-infinity controller.

    Attributes
    ----------
    model
        the discrete controller as it runs, y (na) [m] -> ic (na) [A], one sample of delay.
    weights
        the weighting of the synthesis.
    gamma
        the norm the synthesis reached.
    full_order
        the synthesis' order before the reduction.
    design_peak
        the worst input-sensitivity peak over the design plants [-].
    """

    model: StateSpace
    weights: MixedSensitivityWeights
    gamma: float
    full_order: int
    design_peak: float

    def parameters(self) -> dict:
        return dict(weights=asdict(self.weights), gamma=self.gamma, full_order=self.full_order,
                    order=self.model.n_states - self.model.n_outputs)


def _score(k: StateSpace, plants: PlantSet, guards: Sequence[StateSpace]) -> float:
    """The worst peak over the design plants, inf if a loop (or a guard's) is unstable."""
    if not all(np.all(np.abs(close_loop(m, k).poles()) < 1.0) for m in [*plants.models, *guards]):
        return np.inf
    return float(worst_peak(residue_freqresp(k, plants.freq_hz), plants.frf).max())


def tune_hinf(plants: PlantSet, noise_m: float, *, guards: Sequence[StateSpace] = (), sensitivity_peak: float = 2.0,
              progress: Callable[[str], None] | None = None) -> HinfDesign:
    """The H-infinity controller for ``plants`` (module docstring).

    Parameters
    ----------
    plants
        the design plants, the first the estimate.
    noise_m
        the sensors' noise std per sample [m].
    guards
        plants the loop must also hold, outside the peak (the nominal model).
    sensitivity_peak
        the peak the sensitivity weight asks for [-].
    progress
        called with a line per weighting.

    Raises
    ------
    ValueError
        no weighting gives a controller that holds every design plant.
    """
    say = progress or (lambda _line: None)
    plant = plants.models[0]
    best: HinfDesign | None = None
    for corner, effort in WEIGHTINGS:
        w = MixedSensitivityWeights(sensitivity_peak=sensitivity_peak, effort_corner_hz=corner, effort_a=effort,
                                    noise_m=noise_m)
        try:
            k0, gamma = mixed_sensitivity(plant, w)
        except ValueError as exc:
            say(f"H-infinity, roll-off from {corner:g} Hz: {exc}")
            continue
        full = _score(with_delay(k0), plants, guards)
        if not np.isfinite(full):
            say(f"H-infinity, roll-off from {corner:g} Hz: gamma {gamma:.3f}, its loop is not stable on every "
                "design plant and the nominal model")
            continue
        chosen = (with_delay(k0), full)
        for order in ORDERS:
            if order >= k0.n_states:
                break
            try:
                k = with_delay(reduce_controller(k0, order))
            except ValueError:
                continue
            score = _score(k, plants, guards)
            if score <= 1.02 * full:
                chosen = (k, score)
                break
        say(f"H-infinity, roll-off from {corner:g} Hz: gamma {gamma:.3f}, order {chosen[0].n_states - plant.n_inputs} "
            f"of {k0.n_states}, worst peak {chosen[1]:.3f}")
        if best is None or chosen[1] < best.design_peak:
            best = HinfDesign(chosen[0], w, gamma, k0.n_states, chosen[1])
    if best is None:
        raise ValueError("no H-infinity controller holds every design plant")
    return best
