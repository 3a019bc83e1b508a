"""A controller for the plant a run measured: candidates designed, checked, the best chosen and its peak
predicted.

:func:`tune` designs each kind asked for (``structured``: :mod:`ambid.commissioning.structured_tuning`,
``hinf``: :mod:`ambid.commissioning.hinf_tuning`) on a few design plants (the estimate and draws from the
posterior), then checks every candidate, and the controller that ran, on many more drawn plants
(``n_check``): its loop must be stable on every one of them and on the rig file's nominal model, and its
noise within the amplifier's budget
(:mod:`ambid.commissioning.limits`). Of the candidates that pass, the one with the lowest worst peak over
the check plants is chosen; the controller that ran is a candidate too, so a tuning never makes a good
loop worse (it keeps it). The chosen controller's peak is then predicted
(:func:`ambid.commissioning.prediction.predict_peak`), and the running one's beside it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ambid.channels import Layout
from ambid.commissioning.hinf_tuning import tune_hinf
from ambid.commissioning.limits import CurrentBudget, CurrentCheck, check_current
from ambid.commissioning.loops import worst_peak
from ambid.commissioning.plants import PlantUncertainty, draw_parameters, peak_grid, plant_set
from ambid.commissioning.prediction import MeasurementModel, PeakPrediction, predict_peak
from ambid.commissioning.structured_tuning import tune_structured
from ambid.control.closed_loop import LoopRobustness, close_loop, loop_robustness, residue_freqresp
from ambid.control.structured import StructuredAxis
from ambid.statespace import StateSpace

__all__ = ["KINDS", "TuneSettings", "Candidate", "TuneResult", "tune"]

#: the kinds :func:`tune` designs: name -> description
KINDS: dict[str, str] = {
    "structured": "per-axis PID with lead/lag, low-pass and notch filters at the bending modes",
    "hinf": "H-infinity mixed sensitivity on the updated model, reduced in order",
}


@dataclass(frozen=True)
class TuneSettings:
    """How hard :func:`tune` works.

    Attributes
    ----------
    kinds
        the kinds to design (:data:`KINDS`).
    n_design
        design plants (the estimate and draws).
    n_check
        drawn plants every candidate must hold.
    n_prediction
        simulated verifying measurements of the prediction.
    max_evaluations
        objective evaluations per stage of the structured tuning.
    seed
        the draws' seed.
    """

    kinds: tuple[str, ...] = ("structured", "hinf")
    n_design: int = 5
    n_check: int = 100
    n_prediction: int = 100
    max_evaluations: int = 600
    seed: int = 0

    def __post_init__(self) -> None:
        unknown = [k for k in self.kinds if k not in KINDS]
        if unknown or not self.kinds:
            raise ValueError(f"tune: kinds {unknown or '(none)'} unknown; choose from {', '.join(KINDS)}")
        for name in ("n_design", "n_check", "n_prediction", "max_evaluations"):
            if getattr(self, name) < (3 if name == "n_prediction" else 1):
                raise ValueError(f"tune: {name} = {getattr(self, name)} is too small")


@dataclass(frozen=True)
class Candidate:
    """A controller :func:`tune` considered.

    Attributes
    ----------
    kind
        ``structured``, ``hinf`` or ``running`` (the controller that ran).
    model
        discrete y (na) [m] -> ic (na) [A].
    parameters
        its design parameters (JSON-able).
    worst_peak
        its worst input-sensitivity peak over the check plants (inf: a loop unstable) [-].
    stable_share
        share of the check plants its loop holds [-].
    current
        its noise against the amplifier's budget (on the estimate).
    design_s
        wall time of its design [s].
    holds_nominal
        its loop with the rig file's nominal model is stable.
    note
        why it was not chosen, or "".
    """

    kind: str
    model: StateSpace
    parameters: dict
    worst_peak: float
    stable_share: float
    current: CurrentCheck | None
    design_s: float
    holds_nominal: bool = True
    note: str = ""

    @property
    def admissible(self) -> bool:
        return (self.stable_share == 1.0 and self.holds_nominal and self.current is not None and self.current.ok
                and bool(np.isfinite(self.worst_peak)))

    def to_dict(self) -> dict:
        return dict(kind=self.kind, order=int(self.model.n_states), worst_peak=self.worst_peak,
                    stable_share=self.stable_share, current=None if self.current is None else self.current.to_dict(),
                    design_s=self.design_s, holds_nominal=self.holds_nominal, admissible=self.admissible,
                    note=self.note, parameters=self.parameters)


@dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` found.

    Attributes
    ----------
    chosen
        the controller to run.
    candidates
        every candidate, the chosen among them.
    prediction
        the chosen controller's predicted peak.
    before
        the running controller's predicted peak, or None (none ran, or its loop is unstable on the
        updated model).
    robustness
        the chosen loop's figures on the estimate (peaks, zone, loop-at-a-time margins).
    design_s
        the whole tuning's wall time [s].
    notes
        what the caller should say.
    """

    chosen: Candidate
    candidates: list[Candidate]
    prediction: PeakPrediction
    before: PeakPrediction | None
    robustness: LoopRobustness
    design_s: float
    notes: list[str] = field(default_factory=list)


def _check(k: StateSpace, models: Sequence[StateSpace], grid: np.ndarray, frf: np.ndarray) -> tuple[float, float]:
    """(worst peak over the plants whose loop is stable, or inf if any is not; the share stable)."""
    stable = np.array([np.all(np.abs(close_loop(m, k).poles()) < 1.0) for m in models])
    peak = float(worst_peak(residue_freqresp(k, grid), frf[stable]).max()) if stable.any() else np.inf
    return (peak if stable.all() else np.inf), float(stable.mean())


def tune(unc: PlantUncertainty, measurement: MeasurementModel, layout: Layout, budget: CurrentBudget,
         starts: Sequence[Sequence[StructuredAxis]], running: StateSpace | None = None,
         running_parameters: dict | None = None, nominal: StateSpace | None = None,
         settings: TuneSettings = TuneSettings(), progress: Callable[[str], None] | None = None,
         operating_point: Callable[[StateSpace], PlantUncertainty] | None = None) -> TuneResult:
    """Design, check, choose and predict (module docstring).

    Args:
        unc: the run's updated model and its posterior (:func:`ambid.commissioning.plants.plant_uncertainty`).
        measurement: how the run measured (:func:`ambid.commissioning.prediction.measurement_model`).
        layout: the rig's axes.
        budget: the amplifier's limits.
        starts: starting points of the structured tuning (one :class:`StructuredAxis` per axis each).
        running: the controller that ran, or None.
        running_parameters: its description (JSON-able), for the report.
        nominal: the rig file's nominal model (discrete, or continuous: sampled with a zero-order hold); every
            candidate must hold it too, so that a controller does not rely on a mode the data found and the
            drawing lacks (and identify's own check before a run, on that model, passes).
        settings: how hard to work.
        progress: called with a line per step.
        operating_point: the posterior where a controller's loop holds the plant in the verifying run (the
            magnets' slopes move with the excursions the loop lets the excitation cause); default ``unc``.

    Raises:
        ValueError: no candidate holds every check plant within the budget.
    """
    t0 = time.perf_counter()
    say = progress or (lambda _line: None)
    guards = [] if nominal is None else [nominal if nominal.dt > 0 else nominal.to_discrete(unc.dt_s)]
    rng = np.random.default_rng([settings.seed, 3600])
    draws = draw_parameters(unc, max(settings.n_design, settings.n_check + 1), rng)
    estimate = plant_set(unc, draws[:1], measurement.freq_hz)
    grid = peak_grid(estimate.models)
    design = plant_set(unc, draws[:settings.n_design], grid)
    check = plant_set(unc, draws[1:settings.n_check + 1], grid)
    say(f"plants: {settings.n_design} to design on, {settings.n_check} to check, {grid.size} lines "
        f"({time.perf_counter() - t0:.0f} s)")
    f_u = (np.arange(1024) + 0.5) / 1024 * 0.5 / unc.dt_s
    noise_grid = (f_u, residue_freqresp(design.models[0], f_u))
    candidates: list[Candidate] = []
    failed: list[str] = []  # designs that ended without a controller, and why (the refusal names them)

    def judged(kind: str, k: StateSpace, params: dict, t_start: float, note: str = "") -> Candidate:
        peak, share = _check(k, check.models, grid, check.frf)
        holds = all(np.all(np.abs(close_loop(g, k).poles()) < 1.0) for g in guards)
        if not holds:
            note = note or "its loop with the rig file's nominal model is unstable"
        if np.all(np.abs(close_loop(design.models[0], k).poles()) < 1.0):
            current = check_current(design.models[0], k, budget)
        else:
            current = None
        c = Candidate(kind, k, params, peak, share, current, time.perf_counter() - t_start, holds, note)
        say(f"{kind}: worst peak {peak:.3f} over {settings.n_check} drawn plants, stable on {100 * share:.0f} %"
            + ("" if holds else ", unstable with the nominal model")
            + (f", noise {current.noise_rms_a.max():.3f} A RMS" if current is not None else ""))
        return c

    if running is not None:
        candidates.append(judged("running", running, running_parameters or {}, time.perf_counter()))
    for kind in settings.kinds:
        t1 = time.perf_counter()
        try:
            if kind == "structured":
                d = tune_structured(design, layout, starts, noise_grid=noise_grid, noise_std_m=budget.noise_std_m,
                                    noise_limit_a=float(np.min(budget.noise_current_limit_a)),
                                    max_evaluations=settings.max_evaluations, guards=guards, progress=say)
                candidates.append(judged(kind, d.model, dict(axes=[a.to_dict() for a in d.axes],
                                                             axes_names=list(layout.axes)), t1))
            else:
                d = tune_hinf(design, float(np.max(budget.noise_std_m)), guards=guards, progress=say)
                candidates.append(judged(kind, d.model, d.parameters(), t1))
        except ValueError as exc:
            say(f"{kind}: {exc}")
            failed.append(f"{kind}: {exc}")
    admissible = [c for c in candidates if c.admissible]
    if not admissible:
        reasons = [f"{c.kind}: stable on {100 * c.stable_share:.0f} %"
                   + ("" if c.holds_nominal else ", not on the nominal model") for c in candidates] + failed
        raise ValueError("no controller holds every drawn plant and the nominal model within the amplifier's "
                         "limits: " + "; ".join(reasons))
    chosen = min(admissible, key=lambda c: c.worst_peak)
    notes = []
    if chosen.kind == "running":
        notes.append("no designed controller beats the running one on the drawn plants: it is kept")
    say(f"chosen: {chosen.kind}; predicting its measured peak ({settings.n_prediction} simulated measurements)")
    at = unc if operating_point is None or chosen.kind == "running" else operating_point(chosen.model)
    prediction = predict_peak(at, chosen.model, measurement, n_samples=settings.n_prediction, seed=settings.seed,
                              axes=layout.axes)
    before = None
    if running is not None and chosen.kind != "running":
        try:
            before = predict_peak(unc, running, measurement, n_samples=max(settings.n_prediction // 4, 10),
                                  seed=settings.seed + 1, axes=layout.axes)
        except ValueError as exc:
            notes.append(f"the running controller's peak is not predicted: {exc}")
    elif chosen.kind == "running":
        before = prediction
    robustness = loop_robustness(design.models[0], chosen.model)
    return TuneResult(chosen, candidates, prediction, before, robustness, time.perf_counter() - t0, notes)
