"""What an identification finds, as dataclasses: the contract between the pipeline and whoever shows it.

:class:`Identification` is the result of :func:`ambid.identification.identify_session`; its sections are
the small records below. ``to_json()`` writes it as ``identification.json`` holds it (the keys and their
order are the file's format); ``Identification.from_json`` reads such a file back. Only the edges (the
files, the report page) see JSON; the command line reads attributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ambid.excitation.design import ExcitationDesign
from ambid.jsonable import JsonRecord, json_field

__all__ = ["ExcitationFacts", "FrfErrorFigures", "NoiseFigures", "ModeInterval", "ModeRow", "RealPole",
           "ComputationalPole", "SensitivityChannel", "LoopSensitivity", "CoherenceFigures", "QualityFigures",
           "FitFigures", "ModeComparison", "ParameterPrior", "ParameterRow", "TotalLag", "UpdateFigures",
           "SensitivityFigures", "Harmonic", "SynchronousFigures", "IntervalNotes", "OutputFiles",
           "Identification", "MeasuredFrfFit", "session_intervals"]


@dataclass(frozen=True, eq=False)
class ExcitationFacts(JsonRecord):
    """The experiment as the identification read it from the session's design (per input: rms_a, peak_a,
    crest_factor [A], [A], [-])."""

    kind: str
    mimo: str | None
    grid: str | None
    sample_rate_hz: float
    samples_per_period: int
    n_periods: int
    n_transient_periods: int
    n_realisations: int
    n_experiments: int
    n_excited_lines: int
    design_band_hz: list[float]
    rms_a: np.ndarray
    peak_a: np.ndarray
    crest_factor: np.ndarray
    measurement_time_s: float
    synchronous: dict | None

    @classmethod
    def of(cls, design: ExcitationDesign) -> ExcitationFacts:
        """The facts of ``design``.

        Examples
        --------
        >>> from ambid.excitation.spec import DesignSpec
        >>> facts = ExcitationFacts.of(DesignSpec(n_realisations=1).build(10_000.0))
        >>> facts.kind, facts.sample_rate_hz, facts.n_realisations
        ('multisine', 10000.0, 1)
        """
        d = design
        return cls(kind=d.kind, mimo=d.options.get("mimo"), grid=d.options.get("grid"), sample_rate_hz=d.fs_hz,
                   samples_per_period=d.n_per_period, n_periods=d.n_periods,
                   n_transient_periods=d.n_transient_periods, n_realisations=d.n_realisations,
                   n_experiments=d.n_experiments, n_excited_lines=int(d.excited_lines.size),
                   design_band_hz=list(d.band_hz), rms_a=d.rms_a, peak_a=d.peak_a, crest_factor=d.crest_factor,
                   measurement_time_s=d.measurement_time_s, synchronous=d.options.get("synchronous"))


@dataclass(frozen=True, eq=False)
class FrfErrorFigures(JsonRecord):
    """The measured, fitted and updated FRFs against the truth: relative matrix error per line
    (:func:`ambid.frf.accuracy.frf_relative_error`), its median and worst value [-]."""

    reference: str
    median: float
    worst: float
    worst_at_hz: float
    fitted_median: float
    fitted_worst: float
    updated_median: float | None = json_field(omit_none=True)
    updated_worst: float | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class NoiseFigures(JsonRecord):
    """The FRF's noise and distortion: output noise std per output [m] with its 95 % interval, the truth
    through the loop where simulated, distortion at the detection lines [dB above the noise]."""

    output_noise_std_m: np.ndarray
    output_noise_std_ci95_m: Any
    output_noise_std_sd_m: Any
    true_output_noise_std_m: np.ndarray | None
    relative_frf_noise_std: float
    nonlinear_variance_ratio: Any
    distortion_odd_db: Any
    distortion_even_db: Any
    fit_weights: str


@dataclass(frozen=True, eq=False)
class ModeInterval(JsonRecord):
    """A fitted mode's standard deviations and 95 % intervals (Student t with ``ci_dof`` where the
    realisations' scatter joins the variance, else 1.96 sigma)."""

    freq_hz_std: float
    freq_hz_ci95: list[float]
    damping_std: float
    damping_ci95: list[float]
    ci_dof: float | None
    noise_only: bool


@dataclass(frozen=True, eq=False)
class ModeRow(JsonRecord):
    """One fitted mode: frequency [Hz], damping ratio [-], ``stable`` (found again within 1 % at the next
    lower order), its interval where the fit gives one, and its whirl where the channels hold a bearing's
    x and y (``forward_share`` of the residue in the forward whirl, [-])."""

    freq_hz: float
    damping: float
    stable: bool
    interval: ModeInterval | None = json_field(flatten=True)
    whirl: str | None = json_field(omit_none=True)
    forward_share: float | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class RealPole(JsonRecord):
    """A real pole of the fitted model: ``pole_hz`` signed (> 0: unstable) [Hz]; whether it is the plant's (a
    physical pole) and why (:func:`ambid.fit.physical_modes.judge_poles`)."""

    pole_hz: float
    unstable: bool
    physical: bool
    reason: str


@dataclass(frozen=True, eq=False)
class ComputationalPole(JsonRecord):
    """A complex pole of the fit that is not a mode of the data: frequency [Hz], damping ratio [-], why, the
    share of the diagram's orders it is stable in and its level above the noise."""

    freq_hz: float
    damping: float
    reason: str
    stable_share: float | None
    snr: float | None


@dataclass(frozen=True, eq=False)
class FitFigures(JsonRecord):
    """The common-denominator fit: its order and how it was chosen, chi^2/dof, the known delay [s], what
    it was weighted by, the stabilisation diagram's orders and costs, the modes and real poles."""

    order: int
    order_rule: str
    chi2_per_dof: float
    delay_s: float
    weights: str
    orders_tried: np.ndarray
    chi2_per_dof_by_order: np.ndarray
    modes: list[ModeRow]
    computational_poles: list[ComputationalPole]
    real_poles: list[RealPole]
    refine_message: str


@dataclass(frozen=True, eq=False)
class ModeComparison(JsonRecord):
    """A cluster of true modes (closer than the resolution) against the fitted modes near it: mean
    frequencies [Hz] and dampings [-], relative errors, how many of each; the fitted mode's interval
    where one true mode meets one fitted mode."""

    true_freq_hz: float
    true_damping: float
    freq_hz: float
    damping: float
    freq_error: float
    damping_error: float
    n_true: int
    n_fitted: int
    interval: ModeInterval | None = json_field(flatten=True)


@dataclass(frozen=True, eq=False)
class ParameterPrior(JsonRecord):
    """A parameter's prior: its mean and 95 % interval, normal or log-normal (``log``)."""

    mean: float
    ci95: list[float]
    log: bool


@dataclass(frozen=True, eq=False)
class ParameterRow(JsonRecord):
    """One physical parameter of the update: its value, start, unit, whether it was free, std and 95 %
    interval, its prior (and whether the prior dominates it), the nominal value, the truth where simulated
    (``true_small_signal``: at rest, where ``true`` is at the excitation level) and the relative error."""

    value: float
    start: float
    unit: str
    free: bool
    std: float | None
    ci95: list[float] | None
    prior: ParameterPrior | None = json_field(omit_none=True)
    prior_ratio: float | None = json_field(omit_none=True)
    prior_dominated: bool | None = json_field(omit_none=True)
    nominal: float | None = None
    true: float | None = None
    true_small_signal: float | None = json_field(omit_none=True)
    error: float | None = None


@dataclass(frozen=True, eq=False)
class TotalLag(JsonRecord):
    """The total lag (amplifier + sensor + delay) the data tell [s], with its interval and the truth."""

    value: float
    std: float
    ci95: list[float]
    unit: str
    parts: list[str]
    true: float | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class UpdateFigures(JsonRecord):
    """The physical-model update (:meth:`ambid.fit.model_update.PhysicalUpdate.to_dict` with the nominal
    values and the truths joined), or only ``error`` when it failed."""

    parameters: dict[str, ParameterRow] | None = None
    chi2_per_dof: float | None = None
    dof: float | None = None
    success: bool | None = None
    covariance_inflation: float | None = None
    total_lag: TotalLag | None = None
    prior_dominated: list[str] | None = None
    message: str | None = None
    n_evaluations: int | None = None
    correlation: list | None = None
    free: list[str] | None = None
    true_centre: dict[str, float] | None = json_field(omit_none=True)
    error: str | None = json_field(omit_none=True)

    def json_items(self) -> dict[str, Any]:
        return {"error": self.error} if self.error is not None else super().json_items()


@dataclass(frozen=True, eq=False)
class SensitivityChannel(JsonRecord):
    """The sensitivity one excitation channel shows by where it is injected
    (:func:`ambid.frf.sensitivity.sensitivity_shown`): its kind, or why none; its peak, line [Hz] and ISO
    14839-3 zone where it shows one."""

    excitation: str
    injected_at: str
    kind: str | None
    why: str | None
    peak: float | None = json_field(omit_none=True)
    peak_hz: float | None = json_field(omit_none=True)
    iso_zone: str | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class LoopSensitivity(JsonRecord):
    """The loop's worst sensitivity peak, over the measured lines and the fitted model between them: its
    value, frequency [Hz], where it came from, the channel and its ISO 14839-3 zone; the probability of each
    zone (``zone_probabilities``, :func:`ambid.identification.sensitivity.loop_zone_probabilities`) where the
    data give the peak's uncertainty."""

    peak: float
    peak_hz: float
    source: str
    channel: str
    iso_zone: str
    zone_probabilities: dict[str, float] | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class SensitivityFigures(JsonRecord):
    """The loop sensitivity the session shows, per excitation channel by where it was injected (``channels``);
    for ambid's own sessions (excitation at the current) the input sensitivity at the excited lines (peak per
    input, its line [Hz], the worst input and its ISO 14839-3 zone), between the lines with the fitted plant
    (``model_*``), the true loop's (``true_*``) and the updated model's (``updated_*``) where known; the
    channels that show none (``none``, why) and the loop's worst peak (``loop``)."""

    channels: list[SensitivityChannel]
    peak: np.ndarray | None = json_field(omit_none=True)
    peak_hz: np.ndarray | None = json_field(omit_none=True)
    worst_input: str | None = None
    worst_peak: float | None = None
    peak_hz_worst: float | None = json_field(omit_none=True)
    iso_zone: str | None = None
    model_peak: np.ndarray | None = json_field(omit_none=True)
    model_peak_hz: np.ndarray | None = json_field(omit_none=True)
    model_iso_zone: str | None = json_field(omit_none=True)
    model_note: str | None = json_field(omit_none=True)
    true_peak: np.ndarray | None = json_field(omit_none=True)
    true_peak_hz: np.ndarray | None = json_field(omit_none=True)
    true_iso_zone: str | None = json_field(omit_none=True)
    updated_peak: np.ndarray | None = json_field(omit_none=True)
    updated_peak_hz: np.ndarray | None = json_field(omit_none=True)
    updated_iso_zone: str | None = json_field(omit_none=True)
    updated_note: str | None = json_field(omit_none=True)
    none: list[str] = field(default_factory=list)
    loop: LoopSensitivity | None = None


@dataclass(frozen=True, eq=False)
class CoherenceFigures(JsonRecord):
    """The FRF's coherence: its smallest and median value over the lines and outputs, and where the per-line
    values are."""

    min: float | None
    median: float | None
    per_line: str


@dataclass(frozen=True, eq=False)
class QualityFigures(JsonRecord):
    """What spoils the record (:func:`ambid.frf.quality.record_quality`: clipping, saturation, dropouts, too
    little excitation, low coherence; one finding each, with its text) and the coherence."""

    findings: list[dict]
    coherence: CoherenceFigures | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class Harmonic(JsonRecord):
    """The synchronous response at one harmonic of the speed: amplitude [m or A] and phase [deg] per
    channel, and the amplitude's std."""

    harmonic: int
    freq_hz: float
    amplitude: np.ndarray
    phase_deg: np.ndarray
    amplitude_std: np.ndarray


@dataclass(frozen=True, eq=False)
class SynchronousFigures(JsonRecord):
    """The synchronous response of a run at speed, kept out of the FRF."""

    on_lines: Any
    n_records: int
    channels: list[str]
    harmonics: list[Harmonic]


@dataclass(frozen=True, eq=False)
class IntervalNotes(JsonRecord):
    """What each printed interval holds, in words (``noise_only``: the intervals that hold the noise alone)."""

    noise_only: list[str] | None = json_field(omit_none=True)
    frf_band: str | None = json_field(omit_none=True)
    noise_std: str | None = json_field(omit_none=True)
    parameters: str | None = json_field(omit_none=True)
    modes: str | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class OutputFiles(JsonRecord):
    """The files an identification wrote (``report`` once the report is written)."""

    model_npz: str
    model_json: str
    frf_npz: str
    summary_json: str
    report: str | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class Identification(JsonRecord):
    """The identification of one experiment of a recorded session (``identification.json``).

    Attributes
    ----------
    session : str
        The session file.
    experiment_id, estimator : str
        The experiment identified and the FRF estimator.
    excitation : ExcitationFacts
        The experiment's design.
    band_hz : list of float
        The excited lines' band [Hz].
    inputs, outputs : list of str
        The FRF's channels.
    input_units, output_units : list of str
        Their units (A and m for ambid's own sessions; an imported record's may say others).
    controller : dict or None
        The facts of the controller that ran (kind, n_states, delay_samples, parameters, ...).
    simulated : bool
        The session ran the simulated rig (a truth to compare with).
    frf_error : FrfErrorFigures or None
        Against the truth, where there is one.
    noise : NoiseFigures
    fit : FitFigures
    intervals : IntervalNotes
    modes_vs_true : list of ModeComparison
    synchronous : SynchronousFigures or None
        At speed only.
    max_mode_freq_error, max_mode_damping_error : float or None
        The worst relative errors of ``modes_vs_true``.
    update : UpdateFigures or None
        None without a rig or when not asked for.
    quality : QualityFigures
        What spoils the record, and the coherence.
    sensitivity : SensitivityFigures
    files : OutputFiles
    notes : list of str
        What could not be done, and why.
    wall_s : float or None
        Wall time of the analysis [s].
    """

    session: str
    experiment_id: str
    estimator: str
    excitation: ExcitationFacts
    band_hz: list[float]
    inputs: list[str]
    outputs: list[str]
    input_units: list[str]
    output_units: list[str]
    controller: dict | None
    simulated: bool
    frf_error: FrfErrorFigures | None
    noise: NoiseFigures
    fit: FitFigures
    intervals: IntervalNotes
    modes_vs_true: list[ModeComparison]
    synchronous: SynchronousFigures | None
    max_mode_freq_error: float | None
    max_mode_damping_error: float | None
    update: UpdateFigures | None
    quality: QualityFigures
    sensitivity: SensitivityFigures
    files: OutputFiles
    notes: list[str]
    wall_s: float | None = json_field(omit_none=True)


@dataclass(frozen=True, eq=False)
class MeasuredFrfFit(JsonRecord):
    """The fit of a measured FRF file (:func:`ambid.identification.frf_file_fit.identify_frf`,
    ``identification.json``): its source and format, the FRF's form and unit, channels and their units, lines,
    whether it gave a variance, the fit, what spoils it, what the intervals hold, the files, notes and wall
    time [s]."""

    source: str
    format: str
    form: str | None
    unit: str | None
    output_units: list[str]
    input_units: list[str]
    outputs: list[str]
    inputs: list[str]
    n_lines: int
    band_hz: list[float]
    var_given: bool
    fit: FitFigures
    quality: QualityFigures
    intervals: IntervalNotes
    files: OutputFiles
    notes: list[str]
    wall_s: float | None = json_field(omit_none=True)


def session_intervals(var_kind: str, weights_kind: str, total: bool) -> IntervalNotes:
    """What a session's printed intervals hold (``total``: the variance is the realisations' scatter)."""
    return IntervalNotes(
        noise_only=[] if total else ["frf band", "parameters", "modes"],
        frf_band=f"+-2 sigma with sigma^2 = {var_kind} (total: noise and the stochastic nonlinear "
                 "distortion, from the realisation-to-realisation scatter; noise only with one realisation). "
                 "It covers the best linear approximation at this excitation level (the magnets' slopes "
                 "averaged over the excursions the excitation causes), not the small-signal model at rest: "
                 "the magnets' nonlinearity shifts the low lines by about 0.5-1 %, a bias no variance holds",
        noise_std="95 % interval (Student t) of each output's noise std from the scatter of the segments' "
                  "period-to-period variances (the noise is coloured by the loop, so the samples' chi2 "
                  "degrees of freedom would be too many); the truth is the sensor noise through the loop",
        parameters="95 % intervals (Student t) of the physical parameters of the linear model that best "
                   "describes the rig at this excitation level (its best linear approximation), the data and "
                   "each parameter's tolerance together (maximum a posteriori; where prior_dominated, mostly "
                   "the tolerance about the nominal value). On a nonlinear rig these differ from the "
                   "parameters at rest by a bias no variance holds: ki and ks by the magnets' slopes averaged "
                   "over the excursions (true: those slopes, true_small_signal: at rest), the lags by the "
                   "approximation's phase (the total lag by about 0.1 % on the default rig; true: at rest). "
                   "From a sandwich covariance pooled with the realisations' scatter "
                   "(ambid.fit.correlated.realisation_inflation): the Jacobian of the fit weighted "
                   f"by {weights_kind}, the line covariance {var_kind}, the errors of a line correlated (within a "
                   "row through U^-1, between rows as the residuals show), scaled by the generalised "
                   "chi2/dof, so they hold the misfit too. The sensor bandwidth, amplifier bandwidth and "
                   "delay are strongly correlated; their sum is update.total_lag. ambid validate measures "
                   "the coverage against the parameters of the best linear approximation (docs/uncertainty.md)",
        modes="95 % intervals (Student t of 2 + M - 1 degrees of freedom where M >= 2 realisations' scatter "
              "joins the sandwich in the variance; else 1.96 sigma) of the "
              "fitted modes from the variable-projection sandwich "
              "covariance of the common denominator's factors (the same line covariance as the parameters); "
              "a cluster of true modes closer than the resolution has none")


