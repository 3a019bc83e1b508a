"""The identification of a recorded session, as stages that each return a small dataclass.

inputs (:mod:`.inputs`) -> FRF (:mod:`.session_frf`) -> fit (:mod:`.model_fit`) -> update
(:mod:`.update`) -> truth (:mod:`.truth`, where there is one) -> sensitivity (:mod:`.sensitivity`) ->
report (:mod:`.report`), chained by :func:`identify_session` (:mod:`.pipeline`) into one
:class:`~.result.Identification`. Beside them: what it compares with (:mod:`.references`), the analysis
started with the session (:mod:`.early`), a measured FRF file fitted (:mod:`.frf_file_fit`) and a
measured Campbell diagram from one identification per speed (:mod:`.campbell`).
"""

from ambid.identification.inputs import (SessionInputs, inputs_from_messages, read_session_inputs,
                                         recorded_controller, session_rig)
from ambid.identification.model_fit import FrfFit, fit_frf, select_order
from ambid.identification.pipeline import identify_session
from ambid.identification.references import ReferenceModels, reference_key, reference_models
from ambid.identification.result import Identification, MeasuredFrfFit
from ambid.identification.truth import compare_modes, true_modes
from ambid.identification.update import RigUpdate, refit_parameters, update_rig

__all__ = ["identify_session", "Identification", "MeasuredFrfFit", "SessionInputs", "read_session_inputs",
           "inputs_from_messages", "session_rig", "recorded_controller", "ReferenceModels", "reference_key", "reference_models", "FrfFit", "fit_frf",
           "select_order", "RigUpdate", "update_rig", "refit_parameters", "compare_modes", "true_modes"]
