"""Comparisons of excitations and FRF estimators on the simulated rig (the thesis's comparisons).

Three comparisons, every experiment on the same rig, with the same
controller and from the same levitated state:

1. **Methods**: stepped sine, swept sine, random noise, one-input-at-a-time
   multisine and orthogonal multisine, each measuring the full FRF
   matrix on the same lines with the same peak excitation current; and the
   orthogonal multisine without settling periods, each segment's transient
   removed by the local polynomial method (:mod:`ambid.frf.lpm`).
2. **Estimators** in closed loop (H1, H2, arithmetic mean, log mean, EIV,
   indirect) on one orthogonal multisine with a small excitation, so that
   the sensor noise fed back through the controller matters: H1 then tends
   to -C^-1 where the noise dominates, the indirect estimator does not.
3. **Odd versus full multisine** with the nonlinear magnets (eq. 2.14) and a
   large excitation: a full grid's FRF error holds nonlinear distortions it
   cannot see; a random-odd grid shows even and odd distortions at its
   detection lines; both give the stochastic nonlinear variance of the best
   linear approximation from the realisation-to-realisation scatter.

Rules that make the methods comparable:

* **Settling.** Every method waits the same time after each change of its
  excitation: ``settle_time_constants`` time constants of the slowest
  closed-loop pole below the band's upper edge (:func:`settling_time`). The
  periodic designs get that many whole transient periods, the noise that
  many discarded blocks, the stepped sine that wait at every line.
* **Ladder.** Each method runs once at its longest length and is estimated
  from prefixes of the record: 1, 2, ... realisations, or for the stepped
  sine 1, 2, 4, ... measured cycles per line. A prefix of a longer
  experiment is the shorter experiment; its measurement time is that of the
  design cut to it. (A stepped-sine line cut shorter hands the next line a
  slightly different start, a residual transient no larger than the one its
  own estimate sees.)
* **Same target accuracy.** The FRF error is the median over the common
  lines of ``||G - G_true||_F / ||G_true||_F`` (:func:`frf_error`); a
  method's measurement time for the target is the shortest ladder step
  whose error is at most ``target_error``. One that never gets there is
  reported as such, with its best error.
* The stepped sine is also evaluated with its settling wait chosen *after
  the fact* as the shortest that still meets the target (an oracle no real
  test has; reported separately as a sensitivity figure).

The experiments run the same plant (:class:`ambid.plant.simulator.PlantSimulator`)
and controller (:class:`ambid.control.stepper.ControllerStepper`) code the ROS
nodes run, in a Python lock-step loop in the order of
``ambid_nodes.plant_sim``: y[k] = output, ic[k] = controller(y[k]),
u[k] = ic[k] + r[k], step. The reference is the true rig's exact sampled
small-signal FRF (:func:`ambid.plant.true_rig.true_linear_model`).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from ambid.control.closed_loop import close_loop
from ambid.control.simulated_loop import LoopRecord, LoopStart, levitate, run_loop
from ambid.excitation import ExcitationDesign, design_multisine, design_noise, design_stepped_sine, design_swept_sine
from ambid.frf.accuracy import frf_relative_error
from ambid.frf.estimators import stepped_sine_frf
from ambid.frf.periods import period_spectra, split_periods
from ambid.frf.streaming import ESTIMATORS, FrfResult, FrfStream
from ambid.plant.rig import Rig, make_rig
from ambid.plant.true_rig import true_frf, true_linear_model
from ambid.statespace import StateSpace

__all__ = ["ComparePreset", "PRESETS", "PARTS", "METHODS", "settling_time", "realisation_ladder", "compare_methods",
           "compare_estimators", "compare_odd_full", "run_comparison", "comparison_markdown"]

PARTS = ("methods", "estimators", "odd_full")
METHODS = ("stepped_sine", "swept_sine", "noise", "multisine_one_at_a_time", "multisine_orthogonal",
           "multisine_orthogonal_no_settling")
METHOD_LABELS = {"stepped_sine": "stepped sine", "swept_sine": "swept sine, one input at a time",
                 "noise": "random noise, all inputs", "multisine_one_at_a_time": "multisine, one input at a time",
                 "multisine_orthogonal": "orthogonal multisine",
                 "multisine_orthogonal_no_settling": "orthogonal multisine, no settling periods (transient removed by "
                                                     "one model across the spectrum)"}
ESTIMATOR_LABELS = {"indirect": "indirect", "h1": "H1", "h2": "H2", "arithmetic_mean": "arithmetic mean",
                    "log_mean": "log mean", "eiv": "EIV"}
CLAIM_RATIO = 10.0


@dataclass(frozen=True)
class ComparePreset:
    """How thorough a comparison is.

    Attributes
    ----------
    name
        preset name.
    band_hz
        (f_lo, f_hi) band of the methods and estimator comparisons [Hz].
    resolution_hz
        line spacing [Hz]; fs / resolution must be an integer.
    peak_current_a
        peak excitation current per input, methods comparison [A].
    target_error
        target median relative FRF error [-] ("same target accuracy").
    multisine_periods
        steady-state periods per multisine / sweep segment.
    max_realisations
        longest ladder of the realisation-based methods.
    noise_blocks
        N-sample blocks per noise realisation (> 4: four
        independent inputs need more blocks than inputs).
    stepped_cycles
        ladder of measured cycles per stepped-sine line (increasing).
    stepped_tuned_settle_s
        shorter settling waits tried after the fact
        for the stepped sine [s] (increasing, below the rule's wait).
    stepped_line_stride
        measure every k-th line of the stepped sine and
        extrapolate its time to the full line set (1 = every line).
    settle_time_constants
        settling wait in time constants of the
        slowest closed-loop pole below the band's upper edge [-].
    estimator_peak_a
        peak excitation of the estimator comparison [A].
    estimator_realisations, estimator_periods
        M and P of that multisine.
    nonlinear_peak_a
        peak excitation of the odd-versus-full comparison [A].
    nonlinear_realisations, nonlinear_periods
        M (>= 2) and P (>= 2) there.
    nonlinear_band_hz, nonlinear_resolution_hz
        band and resolution there [Hz].
    liftoff_s
        simulated lift-off and settling before the experiments [s].
    seed
        seed of the sensor noise and of every random design choice.
    """

    name: str
    band_hz: tuple[float, float]
    resolution_hz: float
    peak_current_a: float
    target_error: float
    multisine_periods: int
    max_realisations: int
    noise_blocks: int
    stepped_cycles: tuple[int, ...]
    stepped_tuned_settle_s: tuple[float, ...]
    stepped_line_stride: int
    estimator_peak_a: float
    estimator_realisations: int
    estimator_periods: int
    nonlinear_peak_a: float
    nonlinear_realisations: int
    nonlinear_periods: int
    nonlinear_band_hz: tuple[float, float]
    nonlinear_resolution_hz: float
    settle_time_constants: float = 3.0
    liftoff_s: float = 0.5
    seed: int = 1

    def __post_init__(self) -> None:
        for key in ("band_hz", "nonlinear_band_hz"):
            lo, hi = getattr(self, key)
            if not (0 < lo < hi):
                raise ValueError(f"preset {self.name}: {key} must be (f_lo, f_hi) with 0 < f_lo < f_hi, "
                                 f"got {getattr(self, key)}")
        for key in ("resolution_hz", "peak_current_a", "target_error", "estimator_peak_a", "nonlinear_peak_a",
                    "nonlinear_resolution_hz", "liftoff_s", "settle_time_constants"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"preset {self.name}: {key} must be finite and > 0, got {v!r}")
        for key, least in (("multisine_periods", 1), ("max_realisations", 1), ("noise_blocks", 5),
                           ("stepped_line_stride", 1), ("estimator_realisations", 1), ("estimator_periods", 2),
                           ("nonlinear_realisations", 2), ("nonlinear_periods", 2)):
            v = getattr(self, key)
            if isinstance(v, bool) or int(v) != v or v < least:
                raise ValueError(f"preset {self.name}: {key} must be an integer >= {least}, got {v!r}")
        cyc = tuple(self.stepped_cycles)
        if not cyc or int(cyc[0]) < 1 or any(int(b) <= int(a) for a, b in zip(cyc, cyc[1:])):
            raise ValueError(f"preset {self.name}: stepped_cycles must be increasing integers >= 1, "
                             f"got {self.stepped_cycles}")
        st = tuple(float(v) for v in self.stepped_tuned_settle_s)
        if any(not 0 <= v < 10 for v in st) or any(b <= a for a, b in zip(st, st[1:])):
            raise ValueError(f"preset {self.name}: stepped_tuned_settle_s must be increasing waits in "
                             f"[0, 10) s, got {self.stepped_tuned_settle_s}")


PRESETS: dict[str, ComparePreset] = {
    "quick": ComparePreset(
        name="quick", band_hz=(20.0, 600.0), resolution_hz=20.0, peak_current_a=0.5, target_error=0.02,
        multisine_periods=2, max_realisations=6, noise_blocks=8, stepped_cycles=(1, 2, 4, 8),
        stepped_tuned_settle_s=(0.0, 0.01, 0.02, 0.05), stepped_line_stride=1,
        estimator_peak_a=0.02, estimator_realisations=2, estimator_periods=8,
        nonlinear_peak_a=0.8, nonlinear_realisations=3, nonlinear_periods=3,
        nonlinear_band_hz=(20.0, 600.0), nonlinear_resolution_hz=20.0),
    "full": ComparePreset(
        name="full", band_hz=(10.0, 1000.0), resolution_hz=5.0, peak_current_a=0.5, target_error=0.02,
        multisine_periods=2, max_realisations=10, noise_blocks=8, stepped_cycles=(1, 2, 4, 8),
        stepped_tuned_settle_s=(0.0, 0.01, 0.02, 0.05, 0.1, 0.2), stepped_line_stride=5,
        estimator_peak_a=0.02, estimator_realisations=4, estimator_periods=8,
        nonlinear_peak_a=0.8, nonlinear_realisations=6, nonlinear_periods=4,
        nonlinear_band_hz=(10.0, 1000.0), nonlinear_resolution_hz=10.0, liftoff_s=1.0),
}


# ---------------------------------------------------------------- settling

def _median(x) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else float("nan")


def settling_time(rig: Rig, controller: StateSpace, f_max_hz: float, n_time_constants: float = 3.0
                  ) -> dict[str, float]:
    """Settling wait after a change of excitation: time constants of the slowest closed-loop pole.

    Only poles whose frequency is at most ``f_max_hz`` count (a lightly
    damped mode far above the band is hardly excited by it).

    Parameters
    ----------
    rig
        rig parameters (the true rig's small-signal model closes the loop).
    controller
        discrete y -> ic controller at rig.dt.
    f_max_hz
        highest pole frequency considered [Hz] (the band's upper edge).
    n_time_constants
        wait in time constants, > 0.

    Returns
    -------
    {"settle_s", "time_constant_s", "pole_hz"}: the wait [s], the slowest
    time constant [s] and that pole's frequency [Hz].
    """
    if not (math.isfinite(n_time_constants) and n_time_constants > 0):
        raise ValueError(f"n_time_constants must be finite and > 0, got {n_time_constants!r}")
    loop = close_loop(true_linear_model(rig, discrete=True), controller)
    z = loop.poles().astype(complex)
    z = z[np.abs(z) > 1e-12]                       # pure delays: no settling
    s = np.log(z) / rig.dt
    s = s[np.abs(s.imag) / (2 * np.pi) <= f_max_hz]
    if s.size == 0 or np.any(s.real >= 0):
        raise ValueError("settling_time: the closed loop is unstable or has no pole below f_max_hz")
    slow = s[np.argmax(s.real)]
    tau = -1.0 / slow.real
    return {"settle_s": float(n_time_constants * tau), "time_constant_s": float(tau),
            "pole_hz": float(abs(slow.imag) / (2 * np.pi))}


# ---------------------------------------------------------------- estimates from records

def _stream_estimate(design: ExcitationDesign, record: LoopRecord, n_samples: int,
                     estimator: str = "indirect") -> FrfResult:
    lay = record.layout
    stream = FrfStream(design, lay.outputs, lay.inputs, lay.excitations, total_samples=n_samples)
    stream.add(0, record.columns()[:n_samples])
    return stream.estimate(estimator)


def _period_spectra(d: ExcitationDesign, x: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """(M, Ne, P, L, ch) spectra of a periodic design's record x (n, ch) at ``lines``."""
    periods = split_periods(x, d.n_per_period, d.n_periods, d.n_transient_periods, d.n_realisations,
                            d.n_experiments)
    return period_spectra(periods, np.asarray(lines, dtype=np.int64))


def realisation_ladder(design: ExcitationDesign, record: LoopRecord, g_ref: np.ndarray,
                        lines: np.ndarray) -> list[dict]:
    """Error after the first 1, 2, ... M realisations of a design (the record's prefixes)."""
    steps = []
    for m in range(1, design.n_realisations + 1):
        n = design.segment_start(m, 0) if m < design.n_realisations else design.total_samples
        res = _stream_estimate(design, record, n)
        err = frf_relative_error(res.frf[np.isin(res.lines, lines)], g_ref)
        steps.append({"realisations": m, "measurement_time_s": n / design.fs_hz, "median_error": _median(err),
                      "error_per_line": err.tolist()})
    return steps


def _stepped_ladder(design: ExcitationDesign, record: LoopRecord, g_ref: np.ndarray,
                    settles_s: tuple[float, ...], cycles: tuple[int, ...]) -> list[dict]:
    """Error and measurement time of the stepped sine cut to each (settling wait, measured cycles) pair.

    Within a line's segment the sine runs on unbroken, so waiting s and then
    measuring c cycles is the segment's first ceil(s fs / p) + ceil(c / cycles
    per period) periods; the time equals that of ``design_stepped_sine(
    settle_s=s, n_cycles=c)`` on the same lines.
    """
    period, transient, periods = design.segment_layout()
    ne, fs = design.n_experiments, design.fs_hz
    cyc_per_period = design.excited_lines // np.gcd(design.excited_lines, design.n_per_period)
    starts = [[design.segment_start(m, e) for e in range(ne)] for m in range(design.n_realisations)]
    steps = []
    for s in settles_s:
        pt = np.array([math.ceil(s * fs / p - 1e-9) for p in period], dtype=np.int64)
        if np.any(pt > transient):
            raise ValueError(f"settling wait {s} s exceeds the design's {design.source['settle_s']} s")
        for c in cycles:
            keep = np.minimum(-(-int(c) // cyc_per_period), periods)
            n_keep = (pt + keep) * period
            recs = {k: [np.stack([getattr(record, k)[a:a + int(n)] for a in starts[m]])
                        for m, n in enumerate(n_keep)] for k in ("y", "u", "r")}
            g = stepped_sine_frf(recs["y"], recs["u"], design.freq_hz, fs, (pt * period).tolist(), recs["r"])
            err = frf_relative_error(g, g_ref)
            steps.append({"settle_s": float(s), "cycles": int(c),
                          "measurement_time_s": float(ne * n_keep.sum() / fs),
                          "median_error": _median(err), "error_per_line": err.tolist()})
    return steps


def _time_to_target(steps: list[dict], target: float, n_lines: int, time_scale: float = 1.0) -> dict:
    """The shortest ladder step meeting the target, and the best step."""
    finite = [s for s in steps if math.isfinite(s["median_error"])]
    reached = [s for s in finite if s["median_error"] <= target]
    first = min(reached, key=lambda s: s["measurement_time_s"]) if reached else None
    best = min(finite, key=lambda s: s["median_error"]) if finite else None
    t = first["measurement_time_s"] * time_scale if first else None
    return {"reached_target": first is not None, "time_to_target_s": t,
            "error_at_target": first["median_error"] if first else None,
            "time_per_line_s": t / n_lines if t is not None else None,
            "step_at_target": {k: v for k, v in first.items() if k != "error_per_line"} if first else None,
            "error_per_line_at_target": first["error_per_line"] if first else None,
            "best_error": best["median_error"] if best else None,
            "best_time_s": best["measurement_time_s"] * time_scale if best else None}


# ---------------------------------------------------------------- 1. methods

def _transient_periods(settle_s: float, resolution_hz: float) -> int:
    """Whole N-sample periods (N = fs / resolution) covering the settling wait, at least one."""
    return max(1, math.ceil(settle_s * resolution_hz - 1e-9))


def _method_designs(preset: ComparePreset, rig: Rig, settle_s: float) -> dict[str, ExcitationDesign]:
    fs, band, res, pk = rig.sample_rate_hz, preset.band_hz, preset.resolution_hz, preset.peak_current_a
    inputs = rig.layout.inputs
    m, p = preset.max_realisations, preset.multisine_periods
    pt = _transient_periods(settle_s, res)
    # Schroeder phases: crest factor ~1.7-1.9 against ~3.5 for random ones; on the linear rig the
    # realisations need not differ (random phases serve the nonlinear analysis)
    ms = dict(n_periods=p, n_realisations=m, n_transient_periods=pt, grid="full", phases="schroeder",
              seed=preset.seed)
    ortho = design_multisine(band, res, fs, inputs, pk, mimo="orthogonal", **ms)
    lines = ortho.excited_lines[::preset.stepped_line_stride]
    return {
        "stepped_sine": design_stepped_sine(band, res, fs, inputs, pk, settle_s=settle_s,
                                            n_cycles=int(preset.stepped_cycles[-1]), lines=lines),
        "swept_sine": design_swept_sine(band, res, fs, inputs, pk, n_periods=p, n_realisations=m,
                                        n_transient_periods=pt, mimo="one_at_a_time"),
        "noise": design_noise(band, res, fs, inputs, pk, n_periods=preset.noise_blocks, n_realisations=m,
                              n_transient_periods=pt, mimo="simultaneous", seed=preset.seed),
        "multisine_one_at_a_time": design_multisine(band, res, fs, inputs, pk, mimo="one_at_a_time", **ms),
        "multisine_orthogonal": ortho,
        # the same without a settling wait: each segment's transient is removed from its own periods (ambid.frf.lpm)
        "multisine_orthogonal_no_settling": design_multisine(band, res, fs, inputs, pk, mimo="orthogonal",
                                                             **(ms | {"n_transient_periods": 0})),
    }


def compare_methods(preset: ComparePreset, rig: Rig, start: LoopStart | None = None,
                    methods: tuple[str, ...] = METHODS) -> dict:
    """The excitation methods at the same peak current, settling rule and target accuracy.

    Parameters
    ----------
    preset
        the comparison's settings.
    rig
        rig parameters.
    start
        levitated state to start every experiment from (default: lift off now).
    methods
        subset of :data:`METHODS` to run (the time ratio needs
        'stepped_sine' and 'multisine_orthogonal').

    Returns
    -------
    JSON-safe dict: ``freq_hz`` and ``lines`` (the common lines),
    ``target_error``, ``settling`` (:func:`settling_time`), ``methods``
    (name -> design figures, ladder, time to target, wall time, clipped
    and contact samples) and ``orthogonal_vs_stepped`` (None without both methods).
    """
    unknown = sorted(set(methods) - set(METHODS))
    if unknown or not methods:
        raise ValueError(f"methods must be a non-empty subset of {METHODS}, got {tuple(methods)}")
    start = start or levitate(rig, preset.seed, False, preset.liftoff_s)
    settle = settling_time(rig, start.ctl.model, preset.band_hz[1], preset.settle_time_constants)
    designs = _method_designs(preset, rig, settle["settle_s"])
    ortho = designs["multisine_orthogonal"]
    lines, freq = ortho.excited_lines, ortho.freq_hz
    g_ref = true_frf(rig, freq)
    out: dict = {"freq_hz": freq.tolist(), "lines": lines.tolist(), "target_error": preset.target_error,
                 "peak_current_a": preset.peak_current_a, "settling": settle,
                 "true_frf_norm_m_per_a": np.linalg.norm(g_ref, axis=(1, 2)).tolist(), "methods": {}}
    for name, d in designs.items():
        if name not in methods:
            continue
        t0 = time.perf_counter()
        rec = run_loop(start, d.samples(0, d.total_samples))
        entry: dict = {"label": METHOD_LABELS[name], "kind": d.kind, "mimo": d.options.get("mimo", ""),
                       "n_experiments": d.n_experiments, "peak_a": float(d.peak_a.max()),
                       "rms_a": float(d.rms_a.max()), "crest_factor": float(d.crest_factor.max())}
        if d.kind == "stepped_sine":
            sel = np.isin(lines, d.excited_lines)
            settles = tuple(s for s in preset.stepped_tuned_settle_s if s < settle["settle_s"])
            steps = _stepped_ladder(d, rec, g_ref[sel], settles + (settle["settle_s"],), preset.stepped_cycles)
            scale = lines.size / d.excited_lines.size
            rule = [s for s in steps if s["settle_s"] == settle["settle_s"]]
            summary = _time_to_target(rule, preset.target_error, lines.size, scale)
            tuned = _time_to_target(steps, preset.target_error, lines.size, scale)
            entry["tuned_settle"] = {k: tuned[k] for k in ("reached_target", "time_to_target_s", "error_at_target",
                                                           "step_at_target")}
            entry.update(freq_hz=d.freq_hz.tolist(), settle_s=settle["settle_s"])
        else:
            steps = realisation_ladder(d, rec, g_ref, lines)
            scale = 1.0
            summary = _time_to_target(steps, preset.target_error, lines.size)
            entry.update(freq_hz=freq.tolist(), transient_periods=d.n_transient_periods)
        entry.update(summary, ladder=steps, design_measurement_time_s=d.measurement_time_s * scale,
                     lines_measured=int(d.excited_lines.size), time_extrapolated=bool(scale != 1.0),
                     wall_s=time.perf_counter() - t0, simulation_wall_s=rec.wall_s, samples=int(d.total_samples),
                     clipped_samples=rec.n_clipped, contact_samples=rec.n_contact)
        out["methods"][name] = entry
    both = "stepped_sine" in out["methods"] and "multisine_orthogonal" in out["methods"]
    out["orthogonal_vs_stepped"] = _orthogonal_vs_stepped(out["methods"]) if both else None
    return out


def _first_below(steps: list[dict], error: float) -> dict | None:
    hit = [s for s in steps if s["median_error"] <= error]
    return min(hit, key=lambda s: s["measurement_time_s"]) if hit else None


def _orthogonal_vs_stepped(methods: dict) -> dict:
    """The claim's figures: time ratios of the stepped sine to the orthogonal multisine.

    * at the target: both methods' times to the target error;
    * at equal error: the orthogonal multisine's time to the error the
      stepped sine actually reached at its time to target;
    * tuned: the stepped sine with its settling wait chosen after the fact.
    """
    st, ms = methods["stepped_sine"], methods["multisine_orthogonal"]
    out: dict = {"claim_ratio": CLAIM_RATIO}
    both = st["reached_target"] and ms["reached_target"]
    out["target_ratio"] = st["time_to_target_s"] / ms["time_to_target_s"] if both else None
    out["claim_holds"] = bool(both and out["target_ratio"] >= CLAIM_RATIO)
    if st["reached_target"]:
        hit = _first_below(ms["ladder"], st["error_at_target"])
        out["equal_error"] = {"stepped_error": st["error_at_target"], "stepped_time_s": st["time_to_target_s"],
                              "orthogonal_error": hit["median_error"] if hit else None,
                              "orthogonal_time_s": hit["measurement_time_s"] if hit else None,
                              "ratio": st["time_to_target_s"] / hit["measurement_time_s"] if hit else None}
    else:
        out["equal_error"] = None
    tuned = st["tuned_settle"]
    out["tuned_ratio"] = (tuned["time_to_target_s"] / ms["time_to_target_s"]
                          if tuned["reached_target"] and ms["reached_target"] else None)
    return out


# ---------------------------------------------------------------- 2. estimators

def compare_estimators(preset: ComparePreset, rig: Rig, start: LoopStart | None = None) -> dict:
    """Every closed-loop estimator on one orthogonal random-phase multisine with a small excitation.

    Returns
    -------
    JSON-safe dict: ``freq_hz``, ``estimators`` (name -> label, error per
    line, median and largest error), ``noise_to_excitation`` n per line
    (RMS period-to-period scatter of u's spectra over their mean: the
    noise fed back into u against the excitation's part),
    ``h1_fraction_towards_minus_inv_c`` per line (how far H1 has moved
    from G towards -C^-1, :func:`_fraction_towards`; the same for the
    indirect estimator), ``h1_fraction_predicted`` = n^2 / (1 + n^2)
    (the single-input closed form of H1's bias for white noise on y),
    ``coherence_median`` (y with r).
    """
    start = start or levitate(rig, preset.seed, False, preset.liftoff_s)
    fs = rig.sample_rate_hz
    settle = settling_time(rig, start.ctl.model, preset.band_hz[1], preset.settle_time_constants)
    lay = rig.layout
    d = design_multisine(preset.band_hz, preset.resolution_hz, fs, lay.inputs, preset.estimator_peak_a,
                         n_periods=preset.estimator_periods, n_realisations=preset.estimator_realisations,
                         n_transient_periods=_transient_periods(settle["settle_s"], preset.resolution_hz),
                         grid="full", mimo="orthogonal", seed=preset.seed + 1)
    t0 = time.perf_counter()
    rec = run_loop(start, d.samples(0, d.total_samples))
    stream = FrfStream(d, lay.outputs, lay.inputs, lay.excitations)
    stream.add(0, rec.columns())
    results = {name: stream.estimate(name) for name in ESTIMATORS}
    g_ref = true_frf(rig, d.freq_hz)
    # the model maps y to ic = -C y, so -C^-1 is its inverse
    minus_inv_c = np.linalg.inv(start.ctl.model.freqresp(d.freq_hz))
    u = _period_spectra(d, rec.u, d.excited_lines)          # (M, Ne, P, L, Nu)
    mean = u.mean(axis=2, keepdims=True)
    noise2 = np.mean(np.abs(u - mean) ** 2, axis=(0, 1, 2, 4)) * u.shape[2] / max(u.shape[2] - 1, 1)
    ratio2 = noise2 / np.mean(np.abs(mean) ** 2, axis=(0, 1, 2, 4))
    towards = {name: _fraction_towards(results[name].frf, g_ref, minus_inv_c) for name in ("h1", "indirect")}
    estimators = {}
    for name, res in results.items():
        err = frf_relative_error(res.frf, g_ref)
        estimators[name] = {"label": ESTIMATOR_LABELS[name], "error_per_line": err.tolist(),
                            "median_error": _median(err), "max_error": float(np.nanmax(err))}
    return {"freq_hz": d.freq_hz.tolist(), "peak_a": preset.estimator_peak_a,
            "measurement_time_s": d.measurement_time_s, "n_realisations": d.n_realisations,
            "n_periods": d.n_periods, "transient_periods": d.n_transient_periods,
            "wall_s": time.perf_counter() - t0, "estimators": estimators,
            "noise_to_excitation": np.sqrt(ratio2).tolist(),
            "h1_fraction_towards_minus_inv_c": towards["h1"].tolist(),
            "indirect_fraction_towards_minus_inv_c": towards["indirect"].tolist(),
            "h1_fraction_predicted": (ratio2 / (1 + ratio2)).tolist(),
            "coherence_median": float(np.median(results["indirect"].coherence)),
            "clipped_samples": rec.n_clipped, "contact_samples": rec.n_contact}


def _fraction_towards(frf: np.ndarray, g_ref: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(L,) how far an estimate has moved from G towards ``target``: Re<G_est - G, T - G>_F / ||T - G||_F^2.

    0 for an unbiased estimate (random errors scatter around 0), 1 at the target.
    """
    d_est, d_t = frf - g_ref, target - g_ref
    return np.real(np.sum(np.conj(d_t) * d_est, axis=(1, 2))) / np.sum(np.abs(d_t) ** 2, axis=(1, 2))


# ---------------------------------------------------------------- 3. odd versus full

def compare_odd_full(preset: ComparePreset, rig: Rig, start: LoopStart | None = None) -> dict:
    """Full-grid and random-odd orthogonal multisines on the nonlinear magnets at a large excitation.

    Returns
    -------
    JSON-safe dict: ``grids`` with ``full`` and ``random_odd``, each with
    its lines, FRF error per line and median (against the true rig
    linearised at the operating point; also the median over the lines both
    grids excite), median relative noise and total standard deviations of
    G, their variance ratio (about 1 for a linear system), and for
    random-odd the ``distortion`` at the detection lines (odd and even
    levels per output [dB above the noise floor] and the mean output
    powers per line [m^2] at excited, odd and even detection lines).
    """
    start = start or levitate(rig, preset.seed, True, preset.liftoff_s)
    if not start.nonlinear_magnets:
        raise ValueError("compare_odd_full needs a LoopStart with nonlinear_magnets=True")
    fs = rig.sample_rate_hz
    res_hz = preset.nonlinear_resolution_hz
    settle = settling_time(rig, start.ctl.model, preset.nonlinear_band_hz[1], preset.settle_time_constants)
    pt = _transient_periods(settle["settle_s"], res_hz)
    out: dict = {"peak_a": preset.nonlinear_peak_a, "band_hz": list(preset.nonlinear_band_hz),
                 "resolution_hz": res_hz, "transient_periods": pt, "grids": {}}
    fits = {}
    for grid in ("full", "random_odd"):
        d = design_multisine(preset.nonlinear_band_hz, res_hz, fs, rig.layout.inputs, preset.nonlinear_peak_a,
                             n_periods=preset.nonlinear_periods, n_realisations=preset.nonlinear_realisations,
                             n_transient_periods=pt, grid=grid, mimo="orthogonal", seed=preset.seed + 2)
        t0 = time.perf_counter()
        rec = run_loop(start, d.samples(0, d.total_samples))
        res = _stream_estimate(d, rec, d.total_samples)
        err = frf_relative_error(res.frf, true_frf(rig, res.freq_hz))
        mag2 = np.abs(res.frf) ** 2
        big = mag2 > 1e-3 * mag2.max(axis=(1, 2), keepdims=True)  # leave out the structurally zero x-y elements
        fits[grid] = (res.lines, err)
        entry = {"label": f"{grid.replace('_', '-')} multisine", "freq_hz": res.freq_hz.tolist(),
                 "n_lines": int(res.lines.size), "error_per_line": err.tolist(), "median_error": _median(err),
                 "relative_noise_std": float(np.sqrt(np.median(res.var_noise[big] / mag2[big]))),
                 "relative_total_std": float(np.sqrt(np.median(res.var_total[big] / mag2[big]))),
                 "variance_ratio": float(np.median(res.var_total[big] / res.var_noise[big])),
                 "measurement_time_s": d.measurement_time_s, "wall_s": time.perf_counter() - t0,
                 "clipped_samples": rec.n_clipped, "contact_samples": rec.n_contact,
                 "max_abs_u_a": float(np.abs(rec.u).max())}
        if d.detection_lines_odd.size or d.detection_lines_even.size:
            dl = res.distortion
            y_exc = _period_spectra(d, rec.y, d.excited_lines).mean(axis=2)
            step = fs / d.n_per_period
            entry["distortion"] = {
                "odd_db": dl.odd_db.tolist(), "even_db": dl.even_db.tolist(),
                "odd_db_max": float(np.nanmax(dl.odd_db)), "even_db_max": float(np.nanmax(dl.even_db)),
                "excited_freq_hz": d.freq_hz.tolist(),
                "excited_power_m2": (np.abs(y_exc) ** 2).mean(axis=(0, 1, 3)).tolist(),
                "odd_freq_hz": (d.detection_lines_odd * step).tolist(),
                "even_freq_hz": (d.detection_lines_even * step).tolist(),
                "odd_power_m2": dl.odd_power.mean(axis=1).tolist(),
                "odd_noise_power_m2": dl.odd_noise_power.mean(axis=1).tolist(),
                "even_power_m2": dl.even_power.mean(axis=1).tolist(),
                "even_noise_power_m2": dl.even_noise_power.mean(axis=1).tolist()}
        out["grids"][grid] = entry
    common = np.intersect1d(fits["full"][0], fits["random_odd"][0])
    for grid, (lines, err) in fits.items():
        out["grids"][grid]["median_error_common_lines"] = _median(err[np.isin(lines, common)])
    out["common_lines"] = common.tolist()
    return out


# ---------------------------------------------------------------- everything

def run_comparison(preset: ComparePreset | str = "quick", rig: Rig | None = None,
                   parts: tuple[str, ...] = PARTS, methods: tuple[str, ...] = METHODS) -> dict:
    """Run the comparisons of a preset on a rig (default :func:`ambid.plant.rig.make_rig`).

    Parameters
    ----------
    preset
        a :class:`ComparePreset` or the name of one in :data:`PRESETS`.
    rig
        rig parameters.
    parts
        any of :data:`PARTS`.
    methods
        the methods compared (see :func:`compare_methods`).

    Returns
    -------
    JSON-safe dict with ``preset``, ``rig``, ``loop``, one entry per part and ``wall_s``.
    """
    if isinstance(preset, str):
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
        preset = PRESETS[preset]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown or not parts:
        raise ValueError(f"parts must be a non-empty subset of {PARTS}, got {tuple(parts)}")
    rig = rig or make_rig()
    t0 = time.perf_counter()
    out: dict = {"preset": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(preset).items()},
                 "rig": rig.name, "axes": list(rig.layout.axes), "sample_rate_hz": rig.sample_rate_hz,
                 "loop": ("core lock-step loop of ambid.plant.simulator.PlantSimulator and ambid.control.pid."
                          "ControllerStepper (default PID), in the order of the plant_sim node")}
    if "methods" in parts or "estimators" in parts:
        start = levitate(rig, preset.seed, False, preset.liftoff_s)
        if "methods" in parts:
            out["methods"] = compare_methods(preset, rig, start, methods)
        if "estimators" in parts:
            out["estimators"] = compare_estimators(preset, rig, start)
    if "odd_full" in parts:
        out["odd_full"] = compare_odd_full(preset, rig, levitate(rig, preset.seed, True, preset.liftoff_s))
    out["wall_s"] = time.perf_counter() - t0
    return out


# ---------------------------------------------------------------- report text

def _pct(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:.2f} %"


def _pole(f_hz: float) -> str:
    return "a real pole" if f_hz < 1e-6 else f"at {f_hz:.1f} Hz"


def _sec(x) -> str:
    return "-" if x is None else f"{x:.3g} s"


def comparison_markdown(result: dict) -> str:
    """``compare.md``: one table per comparison, each with one line of interpretation."""
    p = result["preset"]
    lines = [f"# ambid compare ({p['name']} preset)", "",
             f"Rig `{result['rig']}` at {result['sample_rate_hz']:g} Hz. Every experiment runs the "
             f"{result['loop']}, from one levitated state; that the ROS graph runs the same loop is tested "
             "elsewhere. Errors: median over the lines of ||G - G_true||_F / ||G_true||_F, G_true the true "
             "rig's sampled small-signal FRF. Wall time of this run: "
             f"{result['wall_s']:.1f} s.", ""]
    for key, section in (("methods", _methods_section), ("estimators", _estimators_section),
                         ("odd_full", _odd_full_section)):
        if key in result:
            lines += section(result)
    return "\n".join(lines)


def _methods_section(result: dict) -> list[str]:
    """The excitation methods' table and the time ratios."""
    p = result["preset"]
    m = result["methods"]
    lines: list[str] = []
    st = m["settling"]
    lines += ["## Excitation methods", "",
              f"Band {p['band_hz'][0]:g}-{p['band_hz'][1]:g} Hz, {p['resolution_hz']:g} Hz resolution, "
              f"{len(m['lines'])} lines, full FRF matrix, peak {m['peak_current_a']:g} A per input, "
              f"indirect estimator. Settling after every change of excitation: "
              f"{p['settle_time_constants']:g} x {1e3 * st['time_constant_s']:.1f} ms (slowest closed-loop "
              f"pole below {p['band_hz'][1]:g} Hz, {_pole(st['pole_hz'])}) = {1e3 * st['settle_s']:.0f} ms. "
              f"Measurement time to the target = the shortest prefix of the run whose error is at most "
              f"{_pct(m['target_error'])}.", "",
              "| method | measurement time to target | error there | time per line | best error (at time) "
              "| wall time | clipped samples |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, e in m["methods"].items():
        extra = " (extrapolated)" if e["time_extrapolated"] else ""
        t = _sec(e["time_to_target_s"]) + extra if e["reached_target"] else "not reached"
        lines.append(f"| {e['label']} | {t} | {_pct(e['error_at_target'])} | {_sec(e['time_per_line_s'])} "
                     f"| {_pct(e['best_error'])} ({_sec(e['best_time_s'])}) | {e['wall_s']:.1f} s "
                     f"| {e['clipped_samples']} |")
    ns = m["methods"].get("multisine_orthogonal_no_settling")
    ms = m["methods"].get("multisine_orthogonal")
    if ns and ms:
        if ns["reached_target"] and ms["reached_target"]:
            lines += ["", f"Without settling periods, its transient removed by the local polynomial method, the "
                          f"orthogonal multisine reaches the target in {_sec(ns['time_to_target_s'])} against "
                          f"{_sec(ms['time_to_target_s'])} with them ({ms['time_to_target_s'] / ns['time_to_target_s']:.2f} "
                          f"times faster; errors {_pct(ns['error_at_target'])} and {_pct(ms['error_at_target'])})."]
        else:
            lines += ["", f"Without settling periods the orthogonal multisine's best error is "
                          f"{_pct(ns['best_error'])} ({_sec(ns['best_time_s'])}), with them {_pct(ms['best_error'])} "
                          f"({_sec(ms['best_time_s'])})."]
    c = m["orthogonal_vs_stepped"]
    if c is None:
        lines += ["", "Stepped sine or orthogonal multisine not run: no time ratio."]
    elif c["target_ratio"] is not None:
        tuned = m["methods"]["stepped_sine"]["tuned_settle"]
        text = (f"The orthogonal multisine reaches the {_pct(m['target_error'])} target "
                f"{c['target_ratio']:.1f} times faster than the stepped sine "
                f"({'meets' if c['claim_holds'] else 'misses'} the {c['claim_ratio']:g}x claim)")
        eq = c["equal_error"]
        if eq and eq["ratio"] is not None:
            text += (f"; to match the stepped sine's own {_pct(eq['stepped_error'])} it needs "
                     f"{_sec(eq['orthogonal_time_s'])}, {eq['ratio']:.1f} times less")
        elif eq:
            text += (f"; its run is too short to match the stepped sine's own {_pct(eq['stepped_error'])} "
                     "(no equal-error ratio)")
        if c["tuned_ratio"] is not None:
            step = tuned["step_at_target"]
            text += (f"; a stepped sine whose wait is tuned after the fact ({1e3 * step['settle_s']:.0f} ms, "
                     f"{step['cycles']} cycles) still takes {c['tuned_ratio']:.1f} times longer")
        lines += ["", text + "."]
    else:
        lines += ["", "The orthogonal multisine or the stepped sine did not reach the target within its "
                      "run: no time ratio (claim not shown)."]
    lines.append("")
    return lines


def _estimators_section(result: dict) -> list[str]:
    """The closed-loop estimators' table and why H1 is biased."""
    p = result["preset"]
    e = result["estimators"]
    lines: list[str] = []
    lines += ["## Estimators in closed loop", "",
              f"Orthogonal random-phase multisine, peak {e['peak_a']:g} A (small, so the fed-back sensor "
              f"noise matters), M = {e['n_realisations']}, P = {e['n_periods']}, "
              f"{_sec(e['measurement_time_s'])}; median fed-back noise / excitation in u: "
              f"{_median(e['noise_to_excitation']):.2f}.", "",
              "| estimator | median error | largest error |", "| --- | --- | --- |"]
    for v in e["estimators"].values():
        lines.append(f"| {v['label']} | {_pct(v['median_error'])} | {_pct(v['max_error'])} |")
    est = e["estimators"]
    best = min(est, key=lambda k: est[k]["median_error"])
    lines += ["", f"The {est[best]['label']} estimator is the most accurate; H1's error is "
                  f"{est['h1']['median_error'] / est['indirect']['median_error']:.1f} times the indirect "
                  f"one's: it has moved a median {_median(e['h1_fraction_towards_minus_inv_c']):.2f} of the way "
                  f"from G towards -1/C (closed form n^2/(1+n^2): "
                  f"{_median(e['h1_fraction_predicted']):.2f}; indirect: "
                  f"{_median(e['indirect_fraction_towards_minus_inv_c']):+.2f}).", ""]
    return lines


def _odd_full_section(result: dict) -> list[str]:
    """Odd versus full multisine grids under the magnets' nonlinearity."""
    p = result["preset"]
    o = result["odd_full"]
    lines: list[str] = []
    lines += ["## Odd versus full multisine under the magnets' nonlinearity", "",
              f"Nonlinear magnet force (eq. 2.14), orthogonal random-phase multisines, peak {o['peak_a']:g} A, "
              f"band {o['band_hz'][0]:g}-{o['band_hz'][1]:g} Hz at {o['resolution_hz']:g} Hz; error against "
              "the rig linearised at its operating point.", "",
              "| grid | lines | median error | on common lines | rel. noise std | rel. total std "
              "| var total / var noise | odd distortion | even distortion | clipped samples |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for g in o["grids"].values():
        dist = g.get("distortion")
        odd = f"{dist['odd_db_max']:.1f} dB" if dist else "not visible"
        even = f"{dist['even_db_max']:.1f} dB" if dist else "not visible"
        lines.append(f"| {g['label']} | {g['n_lines']} | {_pct(g['median_error'])} "
                     f"| {_pct(g['median_error_common_lines'])} | {_pct(g['relative_noise_std'])} "
                     f"| {_pct(g['relative_total_std'])} | {g['variance_ratio']:.2f} | {odd} | {even} "
                     f"| {g['clipped_samples']} |")
    ro = o["grids"]["random_odd"].get("distortion")
    if ro:
        lines += ["", f"Distortion levels are the largest over the outputs, in dB above the noise floor at the "
                      f"detection lines: the random-odd grid shows even distortions at {ro['even_db_max']:.1f} dB "
                      f"and odd ones at {ro['odd_db_max']:.1f} dB, which the full grid mixes into its FRF "
                      "unseen."]
    lines.append("")
    return lines
