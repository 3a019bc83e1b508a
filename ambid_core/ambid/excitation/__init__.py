"""Excitation design for closed-loop MIMO AMB identification (pure numpy).

Design an excitation in the user's terms (band, resolution, inputs, peak
current), get its measurement time before running it, stream it block by
block, and hand the design to the FRF code (``ExcitationDesign.to_dict``).

Kinds: multisine (random, Schroeder, crest-optimised phases; full, odd,
random-odd grids; linear or log line sets; orthogonal or one-at-a-time
MIMO), stepped sine, swept sine, filtered noise, PRBS/MLS and DIBS.
Reference: Pintelon & Schoukens, System Identification: A Frequency Domain
Approach, 2nd ed., ch. 5; Dobrowiecki, Schoukens & Guillaume (2006).
"""

from .design import ExcitationDesign, SegmentIndex, check_headroom
from .designers import design_dibs, design_multisine, design_noise, design_prbs, design_stepped_sine, design_swept_sine
from .lines import band_bins, detection_lines, line_set, n_per_period, shape_amplitudes
from .multisine import (crest_factor, dft_weights, mimo_phasors, multisine_period, optimise_crest_phases,
                        schroeder_phases)
from .planner import PlanRow, format_plan, plan_measurements
from .preview import describe, plot_design
from .signals import binary_levels, dibs_bits, mls, swept_sine_period

__all__ = [
    "ExcitationDesign", "SegmentIndex", "check_headroom",
    "design_dibs", "design_multisine", "design_noise", "design_prbs", "design_stepped_sine",
    "design_swept_sine",
    "band_bins", "detection_lines", "line_set", "n_per_period", "shape_amplitudes",
    "crest_factor", "dft_weights", "mimo_phasors", "multisine_period", "optimise_crest_phases",
    "schroeder_phases",
    "PlanRow", "format_plan", "plan_measurements",
    "describe", "plot_design",
    "binary_levels", "dibs_bits", "mls", "swept_sine_period",
]
