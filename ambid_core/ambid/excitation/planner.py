"""Measurement-time planner: stepped sine, swept sine and multisines side by side.

For one band, resolution and set of inputs, each row is a complete design
whose ``measurement_time_s`` (computed from its layout, before anything
runs) is the length of the record it generates. All rows measure the full
Nu x Nu FRF matrix on the same lines (the multisine's excited lines).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from .design import ExcitationDesign
from .designers import design_multisine, design_stepped_sine, design_swept_sine


@dataclass(frozen=True)
class PlanRow:
    """One measurement option.

    Attributes
    ----------
    name
        human-readable method name.
    n_lines
        lines measured.
    n_experiments
        experiments Ne (x realisations for periodic kinds).
    excited_share
        fraction of the record during which each input is
        excited [-] (1 for orthogonal multisines, 1/Nu one at a time).
    total_samples
        record length [samples].
    measurement_time_s
        record length [s].
    design
        the design itself.
    """

    name: str
    n_lines: int
    n_experiments: int
    excited_share: float
    total_samples: int
    measurement_time_s: float
    design: ExcitationDesign


def _row(name: str, d: ExcitationDesign) -> PlanRow:
    share = 1.0 if d.options.get("mimo") == "orthogonal" else 1.0 / d.n_inputs
    return PlanRow(name, int(d.excited_lines.size), d.n_experiments, share,
                   d.total_samples, d.measurement_time_s, d)


def plan_measurements(band_hz: tuple[float, float], resolution_hz: float, fs_hz: float,
                      input_names: Sequence[str], peak_current_a: float | Sequence[float],
                      n_periods: int = 4, n_transient_periods: int = 1, n_realisations: int = 1,
                      grid: str = "random_odd", settle_s: float = 0.5, n_cycles: int = 10,
                      seed: int = 0) -> list[PlanRow]:
    """Designs of every method for the same measurement, with their times.

    Parameters
    ----------
    band_hz, resolution_hz, fs_hz, input_names, peak_current_a
        as in
        ``design_multisine``.
    n_periods, n_transient_periods, n_realisations
        periods and
        realisations of the periodic methods (swept sine and multisines).
    grid
        multisine grid; the stepped sine measures the same lines.
    settle_s, n_cycles
        stepped-sine settling wait [s] and minimum
        measured cycles per line.
    seed
        multisine seed (random phases).

    Returns
    -------
    Rows: stepped sine, swept sine, multisine one at a time, orthogonal
    multisine (all Nu inputs).
    """
    common = dict(band_hz=band_hz, resolution_hz=resolution_hz, fs_hz=fs_hz,
                  input_names=input_names, peak_current_a=peak_current_a)
    periodic = dict(n_periods=n_periods, n_transient_periods=n_transient_periods,
                    n_realisations=n_realisations)
    ortho = design_multisine(**common, **periodic, grid=grid, phases="random",
                             mimo="orthogonal", seed=seed)
    single = design_multisine(**common, **periodic, grid=grid, phases="random",
                              mimo="one_at_a_time", seed=seed)
    stepped = design_stepped_sine(**common, settle_s=settle_s, n_cycles=n_cycles,
                                  lines=ortho.excited_lines)
    swept = design_swept_sine(**common, **periodic, mimo="one_at_a_time")
    return [_row("stepped sine", stepped), _row("swept sine", swept),
            _row("multisine, one input at a time", single), _row("orthogonal multisine", ortho)]


def format_plan(rows: Sequence[PlanRow]) -> str:
    """Plain-text table of the rows (time relative to the fastest)."""
    fastest = min(r.measurement_time_s for r in rows)
    head = (f"{'method':<32} {'lines':>6} {'exper.':>6} {'excited':>8} {'samples':>12} "
            f"{'time [s]':>10} {'x fastest':>9}")
    body = [f"{r.name:<32} {r.n_lines:>6d} {r.n_experiments:>6d} {r.excited_share:>8.2f} "
            f"{r.total_samples:>12d} {r.measurement_time_s:>10.2f} "
            f"{r.measurement_time_s / fastest:>9.1f}" for r in rows]
    return "\n".join([head, "-" * len(head), *body])
