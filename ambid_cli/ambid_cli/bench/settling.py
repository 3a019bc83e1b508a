"""Measurement time at equal FRF error with and without settling periods (each segment's transient removed by one
rational model of all the segments' transients, :mod:`ambid.frf.transient_model`), on the core lock-step loop of
``ambid compare``.

Before: identify's default experiment (:class:`ambid.excitation.spec.DesignSpec`, 3 settling periods per segment)
and its median FRF error against the true rig. After: the same experiment without settling periods, run with
more realisations than the default; its measurement time at equal error is the shortest prefix of whole
realisations whose error is at most the default's (:func:`ambid.comparison.thesis.realisation_ladder`), and, as one
step's error is a draw of the noise, by the law ``error = c / sqrt(time)`` fitted to each whole ladder.
Both from the same levitated state and seed, with the nonlinear magnets identify runs.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ambid.excitation.spec import DesignSpec
from ambid.plant.rig import make_rig
from ambid.comparison.thesis import realisation_ladder
from ambid.control.simulated_loop import levitate, run_loop
from ambid.plant.true_rig import true_frf


def settling_figures(overrides: dict | None = None, extra_realisations: int = 2) -> dict:
    """Run both experiments and compare them at equal FRF error.

    Args:
        overrides: DesignSpec fields to change (a smaller experiment); None = identify's default.
        extra_realisations: realisations the no-settling run has beyond the default's, for its ladder.

    Returns:
        dict: ``before`` (time_s, median_error, transient_periods), ``after`` (ladder of
        {realisations, measurement_time_s, median_error}, time_at_equal_error_s or None,
        error_at_default_realisations, time_at_default_realisations_s) and ``ratio_at_default_realisations``
        (the no-settling error over the default's with the default's realisations); ``error_law_constant``
        c of ``median_error = c / sqrt(measurement_time)`` fitted to each ladder, and
        ``time_at_equal_error_by_law_s``, the no-settling time at the default's error by that law.
    """
    rig = make_rig()
    fs = rig.sample_rate_hz
    spec = DesignSpec(**(overrides or {}))
    start = levitate(rig, spec.seed, True, 0.5)
    t0 = time.perf_counter()
    before = spec.build(fs)
    rec = run_loop(start, before.samples(0, before.total_samples))
    g_ref = true_frf(rig, before.freq_hz)
    ladder_before = realisation_ladder(before, rec, g_ref, before.excited_lines)
    e_before = ladder_before[-1]["median_error"]
    after = replace(spec, n_transient_periods=0, n_realisations=spec.n_realisations + extra_realisations).build(fs)
    rec = run_loop(start, after.samples(0, after.total_samples))
    ladder = realisation_ladder(after, rec, g_ref, after.excited_lines)
    same = ladder[spec.n_realisations - 1]
    hit = [s for s in ladder if s["median_error"] <= e_before]
    strip = [{k: v for k, v in s.items() if k != "error_per_line"} for s in ladder]
    # the noise averages down as 1/sqrt(T): the constant of each ladder (geometric mean of e sqrt(T) over its
    # steps) gives the time at equal error without betting on one step's luck
    law = {k: float(np.exp(np.mean([np.log(st["median_error"] * np.sqrt(st["measurement_time_s"])) for st in lad])))
           for k, lad in (("before", ladder_before), ("after", ladder))}
    return {
        "error_law_constant": law,
        "time_at_equal_error_by_law_s": before.measurement_time_s * (law["after"] / law["before"]) ** 2,
        "before": {"time_s": before.measurement_time_s, "median_error": e_before,
                   "transient_periods": before.n_transient_periods, "realisations": before.n_realisations,
                   "ladder": [{k: v for k, v in s.items() if k != "error_per_line"} for s in ladder_before]},
        "after": {"ladder": strip, "time_at_equal_error_s": hit[0]["measurement_time_s"] if hit else None,
                  "error_at_default_realisations": same["median_error"],
                  "time_at_default_realisations_s": same["measurement_time_s"]},
        "ratio_at_default_realisations": same["median_error"] / e_before,
        "wall_s": time.perf_counter() - t0,
    }
