"""Tuning the structured controller (:mod:`ambid.control.structured`) on the plants a run allows.

The axes are tuned in groups that share one set of parameters: the radial axes together, an axial axis
on its own (:func:`axis_groups`). Each group's parameters are found by Nelder-Mead in their logarithms,
minimising the worst input-sensitivity peak (the largest ``|S_jj|``, ``S = (I - K G)^-1``, over the axes,
the grid and the design plants), with

* the nominal plant's closed loop stable (its poles; every design plant is checked after each stage),
* the sensor noise through the loop costing at most ``noise_limit_a`` of control current (RMS per axis),

first the PID with its low-pass from the running controller and from the default PID, then with a lead/lag
and a notch at each lightly damped plant mode above the band where the loop crosses over, started as mild
notches (the tuning deepens, widens, moves or flattens them: depth 1 is no notch).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize

from ambid.channels import Layout, direction_of
from ambid.commissioning.loops import current_noise_rms, loop_blocks, worst_peak
from ambid.commissioning.plants import PlantSet
from ambid.control.closed_loop import close_loop
from ambid.control.structured import Notch, StructuredAxis, structured_axis_frf, structured_controller
from ambid.statespace import StateSpace

__all__ = ["StructuredDesign", "axis_groups", "tune_structured"]


@dataclass(frozen=True)
class StructuredDesign:
    """A tuned structured controller.

    Attributes
    ----------
    axes
        one :class:`ambid.control.structured.StructuredAxis` per axis of the layout.
    model
        the discrete controller, y (na) [m] -> ic (na) [A], one sample of computational delay.
    design_peak
        its worst input-sensitivity peak over the design plants and the grid [-].
    n_evaluations
        objective evaluations the tuning took.
    """

    axes: tuple[StructuredAxis, ...]
    model: StateSpace
    design_peak: float
    n_evaluations: int


def axis_groups(layout: Layout) -> list[list[int]]:
    """Indices of the axes that share one parameter set: the radial (and any other) axes, then each axial one."""
    axial = list(layout.axial)
    radial = [i for i in range(len(layout)) if i not in axial]
    return [g for g in [radial] + [[i] for i in axial] if g]


# the tuned parameters of one group, in the logarithm, with their bounds
_PID_KEYS = ("kp_a_per_m", "ti_s", "td_s", "derivative_filter_n", "lowpass_hz")


def _bounds(key: str, start: float, fs: float) -> tuple[float, float]:
    return {"kp_a_per_m": (0.2 * start, 5 * start), "ti_s": (0.01, 0.1), "td_s": (2e-5, 2e-2),
            "derivative_filter_n": (2.0, 60.0), "lowpass_hz": (0.02 * fs, 0.45 * fs),
            "lead_zero_hz": (5.0, 0.45 * fs), "lead_pole_hz": (5.0, 0.45 * fs)}[key]


@dataclass
class _Problem:
    plants: PlantSet
    layout: Layout
    dt: float
    axes: list[StructuredAxis]
    group: list[int]
    keys: tuple[str, ...]
    notch_count: int
    noise_grid: tuple[np.ndarray, np.ndarray] | None
    noise_std_m: np.ndarray | None
    noise_limit_a: float
    n_eval: int = 0
    best: float = np.inf
    blocks: list | None = None

    def decode(self, x: np.ndarray) -> StructuredAxis:
        base = self.axes[self.group[0]]
        v = np.exp(x)
        changes = dict(zip(self.keys, (float(a) for a in v[:len(self.keys)])))
        notches = []
        for k in range(self.notch_count):
            depth, width, freq = v[len(self.keys) + 3 * k: len(self.keys) + 3 * k + 3]
            notches.append(Notch(float(freq), float(min(depth, 1.0)), float(min(max(width, 1e-4), 2.0))))
        if self.notch_count:
            changes["notches"] = tuple(notches)
        return replace(base, **changes)

    def controller_frf(self, axes: Sequence[StructuredAxis], f: np.ndarray) -> np.ndarray:
        built: dict[StructuredAxis, np.ndarray] = {}
        for p in axes:
            if p not in built:
                built[p] = structured_axis_frf(p, f, self.dt)
        return np.stack([built[p] for p in axes], axis=1)

    def with_group(self, p: StructuredAxis) -> list[StructuredAxis]:
        axes = list(self.axes)
        for i in self.group:
            axes[i] = p
        return axes

    def objective(self, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
        self.n_eval += 1
        if np.any(x < lo) or np.any(x > hi):
            return 1e3 + float(np.sum(np.maximum(lo - x, 0) + np.maximum(x - hi, 0)))
        try:
            axes = self.with_group(self.decode(x))
        except ValueError:
            return 1e3
        k = self.controller_frf(axes, self.plants.freq_hz)
        if self.blocks is None:
            self.blocks = loop_blocks(k, self.plants.frf)
        peak = float(worst_peak(k, self.plants.frf, self.blocks).max())
        if self.noise_grid is not None:
            f_u, g_u = self.noise_grid
            rms = current_noise_rms(self.controller_frf(axes, f_u), g_u, self.noise_std_m).max()
            if rms > self.noise_limit_a:
                peak += 10.0 * (rms / self.noise_limit_a - 1.0) + 1.0
        # the poles cost more than the rest: only a point that could join the simplex's best is checked
        if peak < 1.2 * self.best:
            if not _stable(self.plants.models[0], structured_controller(axes, self.dt, self.layout)):
                return 100.0 + peak
            self.best = min(self.best, peak)
        return peak


def _stable(plant: StateSpace, controller: StateSpace) -> bool:
    return bool(np.all(np.abs(close_loop(plant, controller).poles()) < 1.0))


def _minimise(problem: _Problem, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_evaluations: int
              ) -> tuple[np.ndarray, float]:
    res = optimize.minimize(problem.objective, x0, args=(lo, hi), method="Nelder-Mead",
                            options=dict(maxfev=max_evaluations, xatol=2e-3, fatol=2e-4, adaptive=x0.size > 6))
    return res.x, float(res.fun)


def _lightly_damped_hz(model: StateSpace, f_lo: float, f_hi: float) -> list[float]:
    z = model.poles()
    z = z[np.abs(z) > 1e-12]
    s = np.log(z.astype(complex)) / model.dt
    out: list[float] = []
    for v in sorted(s, key=lambda v: abs(v.imag)):
        f0, zeta = abs(v.imag) / (2 * np.pi), -v.real / max(abs(v), 1e-300)
        if v.imag > 0 and f_lo < f0 < f_hi and 0 < zeta < 0.05 and all(abs(f0 - g) > 0.02 * f0 for g in out):
            out.append(float(f0))
    return out


def _crossover_hz(axes: Sequence[StructuredAxis], plants: PlantSet, dt: float) -> float:
    """The highest frequency where the nominal loop gain of the first axis crosses 1 [Hz]."""
    f = plants.freq_hz
    lj = structured_axis_frf(axes[0], f, dt) * plants.frf[0][:, 0, 0]
    above = np.flatnonzero(np.abs(lj) >= 1.0)
    return float(f[above[-1]]) if above.size else float(f[0])


def tune_structured(plants: PlantSet, layout: Layout, starts: Sequence[Sequence[StructuredAxis]], *,
                    noise_grid: tuple[np.ndarray, np.ndarray] | None = None,
                    noise_std_m: np.ndarray | None = None, noise_limit_a: float = np.inf,
                    max_evaluations: int = 600, notches: bool = True, guards: Sequence[StateSpace] = (),
                    progress: Callable[[str], None] | None = None) -> StructuredDesign:
    """Tune the structured controller on ``plants`` (module docstring).

    Parameters
    ----------
    plants
        the design plants, the first the nominal one (:func:`ambid.commissioning.plants.plant_set`);
        their grid should resolve the peaks (:func:`ambid.commissioning.plants.peak_grid`).
    layout
        the rig's axes.
    starts
        candidate starting controllers, one :class:`StructuredAxis` per axis each (e.g. the running
        one and the default); the tuning starts from each and keeps the best.
    noise_grid
        (uniform grid over (0, Nyquist) [Hz], the nominal plant's response there) for the
        current-noise constraint, or None for none.
    noise_std_m
        (na,) sensor noise std per sample [m].
    noise_limit_a
        the largest RMS control current the noise may cause per axis [A].
    max_evaluations
        objective evaluations per group and stage.
    notches
        add the lead/lag and the notches in a second stage.
    guards
        plants the loop must also hold, outside the peak (the nominal model).
    progress
        called with a line per stage.

    Returns
    -------
    :class:`StructuredDesign`.

    Raises
    ------
    ValueError
        no start and no tuned controller holds the nominal plant.
    """
    dt = plants.models[0].dt
    fs = 1.0 / dt
    say = progress or (lambda _line: None)
    best: tuple[float, list[StructuredAxis]] | None = None
    evaluations = 0
    for start in starts:
        axes = list(start)
        for group in axis_groups(layout):
            sub = _Problem(plants, layout, dt, axes, group, _PID_KEYS, 0, noise_grid, noise_std_m, noise_limit_a)
            base = axes[group[0]]
            x0 = np.log([getattr(base, k) for k in _PID_KEYS])
            lo = np.log([_bounds(k, getattr(base, k), fs)[0] for k in _PID_KEYS])
            hi = np.log([_bounds(k, getattr(base, k), fs)[1] for k in _PID_KEYS])
            x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
            x, val = _minimise(sub, x0, lo, hi, max_evaluations)
            axes = sub.with_group(sub.decode(x))
            evaluations += sub.n_eval
            say(f"group {' '.join(layout.axes[i] for i in group)}: PID stage, worst peak {val:.3f}")
            if notches:
                axes, val, n = _second_stage(plants, layout, dt, axes, group, noise_grid, noise_std_m, noise_limit_a,
                                             max_evaluations, val)
                evaluations += n
                say(f"group {' '.join(layout.axes[i] for i in group)}: lead/lag and notches, worst peak {val:.3f}")
        total = float(worst_peak(np.stack([structured_axis_frf(p, plants.freq_hz, dt) for p in axes], axis=1),
                                 plants.frf).max())
        model = structured_controller(axes, dt, layout)
        if not all(_stable(m, model) for m in [*plants.models, *guards]):
            say("this start's result does not hold every design plant and the nominal model")
            continue
        if best is None or total < best[0]:
            best = (total, axes)
    if best is None:
        raise ValueError("no structured controller found that holds every design plant")
    return StructuredDesign(tuple(best[1]), structured_controller(best[1], dt, layout), best[0], evaluations)


def _second_stage(plants: PlantSet, layout: Layout, dt: float, axes: list[StructuredAxis], group: list[int],
                  noise_grid, noise_std_m, noise_limit_a: float, max_evaluations: int, current: float
                  ) -> tuple[list[StructuredAxis], float, int]:
    """The lead/lag and the notches at the lightly damped modes above the crossover, tuned with the PID."""
    fs = 1.0 / dt
    cross = _crossover_hz(axes, plants, dt)
    modes = _lightly_damped_hz(plants.models[0], 1.3 * cross, 0.45 * fs)
    base = replace(axes[group[0]], lead_zero_hz=cross, lead_pole_hz=cross * 1.05,
                   notches=tuple(Notch(f0, 0.7, 0.1) for f0 in modes))
    keys = _PID_KEYS + ("lead_zero_hz", "lead_pole_hz")
    trial = list(axes)
    for i in group:
        trial[i] = base
    prob = _Problem(plants, layout, dt, trial, group, keys, len(modes), noise_grid, noise_std_m, noise_limit_a)
    x0 = [np.log(getattr(base, k)) for k in keys]
    lo = [np.log(_bounds(k, getattr(axes[group[0]], k) if k in _PID_KEYS else 1.0, fs)[0]) for k in keys]
    hi = [np.log(_bounds(k, getattr(axes[group[0]], k) if k in _PID_KEYS else 1.0, fs)[1]) for k in keys]
    for n in base.notches:   # depth 0.05..1, width 0.01..1, the centre within +-15 % of the mode
        x0 += [np.log(n.depth), np.log(n.width), np.log(n.freq_hz)]
        lo += [np.log(0.05), np.log(0.01), np.log(0.85 * n.freq_hz)]
        hi += [0.0, 0.0, np.log(min(1.15 * n.freq_hz, 0.45 * fs))]
    x0, lo, hi = np.array(x0), np.array(lo), np.array(hi)
    # the PID bounds stay those of the first stage's start
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
    x, val = _minimise(prob, x0, lo, hi, 2 * max_evaluations)
    if val < current:
        return prob.with_group(prob.decode(x)), val, prob.n_eval
    return axes, current, prob.n_eval
