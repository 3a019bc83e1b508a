"""Parametric fitting of measured MIMO FRFs and physical-model updating.

Pure numpy/scipy/matplotlib. Modules: :mod:`common_denominator` (the model
and its fit: vector fitting / Sanathanan-Koerner, then ML refinement),
:mod:`order_selection` (stabilisation diagram, CMIF), :mod:`modes` (modal
summary, state-space realisation), :mod:`export` (.npz / JSON),
:mod:`updating` (physical parameters with confidence intervals),
:mod:`benchmark` (timing helper). Internal: :mod:`basis`,
:mod:`vector_fitting`, :mod:`refine`.
"""

from ambid.fit.benchmark import benchmark_fit, synthetic_amb_plant
from ambid.fit.common_denominator import FitResult, RationalModel, fit_common_denominator
from ambid.fit.export import (load_model_json, load_model_npz, load_statespace_json, load_statespace_npz,
                              save_model_json, save_model_npz)
from ambid.fit.modes import ModalSummary, Mode, RealPole, modal_summary, to_statespace
from ambid.fit.order_selection import (STATUS_LABELS, StabilisationDiagram, cmif, plot_cmif, plot_stabilisation,
                                       stabilisation_diagram)
from ambid.fit.updating import UpdateResult, update_parameters

__all__ = [
    "RationalModel", "FitResult", "fit_common_denominator",
    "STATUS_LABELS", "StabilisationDiagram", "stabilisation_diagram", "cmif", "plot_stabilisation", "plot_cmif",
    "Mode", "RealPole", "ModalSummary", "modal_summary", "to_statespace",
    "save_model_npz", "load_model_npz", "save_model_json", "load_model_json",
    "load_statespace_npz", "load_statespace_json",
    "UpdateResult", "update_parameters",
    "benchmark_fit", "synthetic_amb_plant",
]
