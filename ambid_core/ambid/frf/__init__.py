"""Nonparametric FRF estimation for open- and closed-loop (AMB) experiments.

Pure numpy/scipy. Convention: plant ``y = P u``, controller ``ic = -C y``,
applied current ``u = ic + r = r - C y`` with r the known excitation.

Modules: :mod:`periods` (split a record, period spectra), :mod:`estimators`
(H1, H2, means, EIV, indirect, coherence, stepped sine, Welch),
:mod:`uncertainty` (noise / BLA / distortion), :mod:`sensitivity` (input
sensitivity, ISO 14839-3 zone), :mod:`arrays_io` (load user arrays).
"""

from ambid.frf.arrays_io import load_arrays, stack_channels
from ambid.frf.estimators import (SpectralFrf, arithmetic_mean, errors_in_variables, h1, h2, indirect, log_mean,
                                  multiple_coherence, per_period_frf, sine_amplitude, stepped_sine_frf, welch_frf)
from ambid.frf.periods import layout_length, period_spectra, split_periods
from ambid.frf.sensitivity import (ZONE_LIMITS, input_sensitivity, input_sensitivity_from_models, iso14839_zone,
                                   sensitivity_diagonal, sensitivity_peak)
from ambid.frf.uncertainty import (BlaEstimate, DistortionLevels, bla_robust, distortion_levels, fit_weight_variance,
                                   frf_noise_variance, noise_std_interval, output_noise_std, period_mean_variance, row_covariance)

__all__ = [
    "load_arrays", "stack_channels",
    "SpectralFrf", "arithmetic_mean", "errors_in_variables", "h1", "h2", "indirect", "log_mean",
    "multiple_coherence", "per_period_frf", "sine_amplitude", "stepped_sine_frf", "welch_frf",
    "layout_length", "period_spectra", "split_periods",
    "ZONE_LIMITS", "input_sensitivity", "input_sensitivity_from_models", "iso14839_zone",
    "sensitivity_diagonal", "sensitivity_peak",
    "BlaEstimate", "DistortionLevels", "bla_robust", "distortion_levels", "fit_weight_variance", "frf_noise_variance",
    "noise_std_interval", "output_noise_std", "period_mean_variance", "row_covariance",
]
