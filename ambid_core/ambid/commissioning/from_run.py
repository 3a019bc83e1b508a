"""``ambid tune``'s job: a run's folder in, ``controller.npz``, ``tune.json`` and a report page out.

A run is what ``ambid identify`` (or ``ambid import`` then ``ambid fit``) wrote: ``identification.json``
(the update's posterior, the fit, the sensitivity measured), ``frf.npz`` (the FRF's variance, the
sensitivity at the lines), ``model.npz`` (the fitted model) and the session it names (the controller that
ran, its current). A commission folder holds two: its ``after/`` run is the one read, else its ``before/``.
The nominal rig is the one the update was made on: ``rig`` when given, else the rig the session recorded
(of which only the nominal values and the tolerances are used: a simulated session records its true rig's
differences too, and nothing here reads them).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ambid.channels import direction_of
from ambid.commissioning.limits import CurrentBudget
from ambid.commissioning.plants import PlantUncertainty, draw_parameters, moved, plant_set, plant_uncertainty
from ambid.commissioning.prediction import MeasurementModel, measurement_model
from ambid.commissioning.tuning import TuneResult, TuneSettings, tune
from ambid.control.closed_loop import residue_freqresp
from ambid.control.pid import PidParameters
from ambid.control.structured import StructuredAxis
from ambid.control.user_controller import save_controller
from ambid.excitation.design import ExcitationDesign
from ambid.fit import load_model_npz
from ambid.frf.sensitivity import iso14839_zone
from ambid.jsonable import to_jsonable
from ambid.plant.analytical import analytical_model
from ambid.plant.rig import Rig, load_rig, make_rig, without_true_factors
from ambid.plant.sensors import noise_std
from ambid.recording import iter_decoded, read_metadata
from ambid.recording.blocks import read_samples
from ambid.recording.facts import controller_facts, controller_model, plant_facts
from ambid.statespace import StateSpace

__all__ = ["RunInputs", "read_run", "operating_point", "current_rms", "headline_peak", "tune_run", "CLAIM"]

#: what predicted_peak's interval claims (tune.json, docs/uncertainty.md)
CLAIM = ("95 % prediction interval of the input-sensitivity peak that ambid identify measures with this controller "
         "and the run's experiment (its headline: the worst |S_jj| over the axes at the excited lines and between "
         "them on the fitted model), the measurement's own noise and fit included; the plants drawn from the run's "
         "updated physical model and its posterior, the measurement simulated with the run's noise level")


@dataclass(frozen=True)
class RunInputs:
    """What tuning reads from a run.

    Attributes
    ----------
    folder
        the run's folder.
    summary
        its identification.json.
    rig
        the nominal rig.
    rig_source
        where the rig came from (a file, or "the session's").
    controller
        the controller that ran (discrete y -> ic) and its facts, or None.
    static_a
        (na,) the mean control current per axis during the run [A], or None.
    freq_hz, var_g, sensitivity
        the FRF's lines, variance and measured sensitivity.
    poles
        the fitted model's poles [rad/s].
    design
        the run's (last) periodic excitation design, or None.
    nonlinear_magnets
        the run's magnets are nonlinear (a simulated session with linear ones says so; a
        recorded one is real).
    var_noise
        (L, ny, nu) the FRF's noise variance (the periods' scatter), or None where the run has none.
    """

    folder: Path
    summary: dict
    rig: Rig
    rig_source: str
    controller: tuple[StateSpace, dict] | None
    static_a: np.ndarray | None
    freq_hz: np.ndarray
    var_g: np.ndarray
    sensitivity: np.ndarray
    poles: np.ndarray
    design: ExcitationDesign | None = None
    nonlinear_magnets: bool = True
    var_noise: np.ndarray | None = None


def _run_folder(folder: Path) -> Path:
    for sub in ("after", "before"):   # a commission folder
        if (folder / sub / "identification.json").is_file():
            return folder / sub
    return folder


def _session_rig(path: str) -> dict | None:
    facts = read_metadata(path).get("ambid.session", {})
    for key in ("rig", "plant"):
        value = facts.get(key)
        if isinstance(value, str):
            try:
                value = json.loads(value)
            except json.JSONDecodeError:
                continue
        if key == "plant" and isinstance(value, dict):
            value = value.get("rig")
        if isinstance(value, dict) and value:
            return value
    for msg, dec in iter_decoded(path):   # a session without the recorder's facts: its plant's description
        if msg.topic.endswith("plant/description"):
            rig = plant_facts(dec)["rig"]
            return rig if isinstance(rig, dict) and rig else None
    return None


def _controller(path: str) -> tuple[StateSpace, dict] | None:
    for msg, dec in iter_decoded(path):
        if msg.topic.endswith("controller/description"):
            return controller_model(dec), controller_facts(dec)
    return None


def _static_current(path: str, summary: Mapping, axes: tuple[str, ...]) -> np.ndarray | None:
    """The mean controller current per axis over the run's first second of experiment [A]."""
    excitation = summary.get("excitation") or {}
    fs = float(excitation.get("sample_rate_hz") or 0)
    n = int(excitation.get("samples_per_period") or 0) * max(int(excitation.get("n_periods") or 1), 1)
    if fs <= 0 or n <= 0:
        return None
    try:
        from ambid.frf.offline import session_designs

        chosen = session_designs(path)[-1]
        topic = chosen["topic"].rstrip("/")[:-len("excitation/design")] + "measurement"
        start = int(chosen["start_index"])
        data = read_samples(path, topic, start, start + min(n, int(fs)), [f"ic_{a}" for a in axes])
    except (ValueError, IndexError, OSError):
        return None
    return data.data.mean(axis=0)


def _design(path: str) -> ExcitationDesign | None:
    from ambid.frf.offline import session_designs

    try:
        designs = session_designs(path)
    except (ValueError, OSError):
        return None
    d = designs[-1]["design"] if designs else None
    return d if d is not None and d.is_periodic else None


def _nonlinear(path: str) -> bool:
    config = read_metadata(path).get("ambid.session", {}).get("config")
    try:
        config = json.loads(config) if isinstance(config, str) else config
    except json.JSONDecodeError:
        config = None
    return not isinstance(config, dict) or bool(config.get("nonlinear_magnets", True))


def operating_point(inputs: RunInputs, unc: PlantUncertainty) -> Callable[[StateSpace], PlantUncertainty] | None:
    """The run's posterior carried to where another controller's loop holds the magnets, or None (no
    controller or design recorded, or linear magnets).

    A linear model fitted to data taken with an excitation estimates the magnets' slopes averaged over the
    excursions that excitation causes through the loop (:func:`ambid.fit.model_update.excitation_slopes`), so
    a new controller, with the same excitation, meets slightly other slopes: ki and ks move by the ratio of the
    slopes under the new loop to those under the run's (the data keep the level). The ratio is computed on the
    nominal rig moved to the update's estimates (:func:`ambid.fit.model_update.rig_values_for`, its magnets
    those estimates): the loops' excursions are those of the plant the data showed, not of the drawing's (a nominal model off by its
    tolerances can hold the running loop barely damped and move ks ten times more than the rig does).
    """
    if inputs.controller is None or inputs.design is None or not inputs.nonlinear_magnets:
        return None
    from ambid.fit.model_update import excitation_slopes, rig_values_for, slopes_as_parameters

    design = inputs.design
    try:
        # the magnets as the data found them: no simulated manufacturing factor on top of the estimates
        rig = without_true_factors(replace(inputs.rig, values={**inputs.rig.values,
                                                               **rig_values_for(inputs.rig, unc.values)}))
        ran = slopes_as_parameters(*excitation_slopes(rig, inputs.controller[0], design), rig.layout)
    except (ValueError, np.linalg.LinAlgError):
        return None

    def at(controller: StateSpace) -> PlantUncertainty:
        new = slopes_as_parameters(*excitation_slopes(rig, controller, design), rig.layout)
        return moved(unc, {k: new[k] / ran[k] for k in ran if ran[k] != 0})

    return at


def current_rms(folder: str | os.PathLike) -> list[float] | None:
    """Per axis the control current's RMS about its mean over a run's experiment [A], from its session (the
    measurement topic's ``ic_`` channels); None when the run's session does not hold them."""
    run = Path(folder)
    try:
        summary = json.loads((run / "identification.json").read_text())
    except (OSError, ValueError):
        return None
    session = summary.get("session")
    session = session if isinstance(session, str) and Path(session).is_file() else str(run / "session.mcap")
    if not Path(session).is_file():
        return None
    from ambid.frf.offline import session_designs

    try:
        chosen = session_designs(session)[-1]
        topic = chosen["topic"].rstrip("/")[:-len("excitation/design")] + "measurement"
        start = int(chosen["start_index"])
        names = [f"ic_{n[2:]}" for n in summary.get("inputs") or [] if n.startswith("u_")]
        data = read_samples(session, topic, start, start + int(chosen["total_samples"]), names).data
    except (ValueError, IndexError, OSError, KeyError):
        return None
    return [float(x) for x in np.std(data, axis=0)]


def read_run(folder: str | os.PathLike, rig: Rig | str | os.PathLike | None = None) -> RunInputs:
    """The :class:`RunInputs` of a run's folder (module docstring).

    Raises
    ------
    ValueError
        one sentence naming what is missing or wrong and what to give instead.
    """
    top = Path(folder)
    if not top.is_dir():
        raise ValueError(f"{top} is not a folder; give the output folder of ambid identify, fit or commission")
    run = _run_folder(top)
    paths = {name: run / name for name in ("identification.json", "frf.npz", "model.npz")}
    missing = [name for name, p in paths.items() if not p.is_file()]
    if missing:
        raise ValueError(f"{run} has no {', '.join(missing)}; give the output folder of ambid identify, fit or "
                         "commission")
    try:
        summary = json.loads(paths["identification.json"].read_text())
        frf = np.load(paths["frf.npz"])
        arrays = {k: np.asarray(frf[k]) for k in frf.files}
        fitted = load_model_npz(paths["model.npz"])
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{run}: a file cannot be read ({exc}); run ambid identify or fit again") from None
    if not isinstance(summary, dict):
        raise ValueError(f"{paths['identification.json']} is not an identification; run ambid identify or fit again")
    session = str(summary.get("session") or "")
    if session and not Path(session).is_file() and (run / "session.mcap").is_file():
        session = str(run / "session.mcap")   # the folder moved
    if isinstance(rig, Rig):
        the_rig, source = rig, "given"
    elif rig:
        the_rig, source = load_rig(rig), str(rig)
    else:
        facts = _session_rig(session) if session and Path(session).is_file() else None
        if facts is None:
            raise ValueError(f"{run}: no rig in the run's session; give the nominal rig with --rig FILE")
        the_rig, source = make_rig(facts), "the session's"
    controller = _controller(session) if session and Path(session).is_file() else None
    static = (_static_current(session, summary, the_rig.layout.axes) if session and Path(session).is_file()
              else None)
    var = arrays.get("var_band", arrays.get("var_total"))
    for key, value in (("freq_hz", arrays.get("freq_hz")), ("sensitivity", arrays.get("sensitivity")),
                       ("var_band", var)):
        if value is None or not np.all(np.isfinite(value)):
            raise ValueError(f"{paths['frf.npz']} has no usable {key}: tuning needs the FRF's variance and the "
                             "measured sensitivity (a session with repeated periods, excited at the currents)")
    has_session = bool(session) and Path(session).is_file()
    return RunInputs(run, summary, the_rig, source, controller, static, arrays["freq_hz"], var,
                     arrays["sensitivity"], np.asarray(fitted.poles), _design(session) if has_session else None,
                     _nonlinear(session) if has_session else True, _usable(arrays.get("var_noise")))


def _usable(var: np.ndarray | None) -> np.ndarray | None:
    """A variance array where every entry is finite and one is positive, else None."""
    return var if var is not None and np.all(np.isfinite(var)) and np.any(var > 0) else None


def headline_peak(sensitivity: Mapping[str, Any]) -> float | None:
    """A run's measured input-sensitivity peak: the worst ``|S_jj|`` at the excited lines and between them on
    the fitted model (identify's headline, ``sensitivity.loop.peak``); None where the run shows none."""
    loop = sensitivity.get("loop")
    if isinstance(loop, Mapping) and loop.get("peak") is not None:
        return float(loop["peak"])
    if sensitivity.get("worst_peak") is None:
        return None
    peaks = [float(sensitivity["worst_peak"])]
    if sensitivity.get("model_peak") is not None:
        peaks.append(float(np.max(sensitivity["model_peak"])))
    return max(peaks)


def _starts(rig: Rig, facts: Mapping | None) -> list[list[StructuredAxis]]:
    """The structured tuning's starts: the PID that ran (its gains and filters), and the default PID."""
    def from_pid(p: Mapping[str, float]) -> list[StructuredAxis]:
        radial = StructuredAxis(kp_a_per_m=p["kp_a_per_m"], ti_s=p["ti_s"], td_s=p["td_s"],
                                derivative_filter_n=p["derivative_filter_n"], lowpass_hz=p["lowpass_hz"])
        axial = StructuredAxis(kp_a_per_m=p["axial_kp_a_per_m"], ti_s=p["ti_s"], td_s=p["axial_td_s"],
                               derivative_filter_n=p["derivative_filter_n"], lowpass_hz=p["lowpass_hz"])
        return [axial if direction_of(a) == "z" else radial for a in rig.layout.axes]

    default = vars(PidParameters())
    starts = []
    if facts and facts.get("kind") == "pid":
        try:
            starts.append(from_pid({**default, **(facts.get("parameters") or {})}))
        except (KeyError, TypeError, ValueError):
            pass
    starts.append(from_pid(default))
    return starts


def _budget(inputs: RunInputs, unc: PlantUncertainty) -> CurrentBudget:
    rig = inputs.rig
    axes = rig.layout.axes
    axial = [direction_of(a) == "z" for a in axes]
    values = unc.values
    exc = inputs.summary.get("excitation") or {}
    peak = np.asarray(exc.get("peak_a") or [0.0], dtype=float).ravel()
    peak = peak if peak.size == len(axes) else np.full(len(axes), peak.max())
    if inputs.static_a is not None:
        static = np.asarray(inputs.static_a, dtype=float)
    else:   # the rotor's weight shared by the radial axes at 45 deg, from the updated ki
        g = rig.derived()["gravity_current_a"] * rig.magnet.ki / values["ki_n_per_a"]
        static = np.array([0.0 if ax else g for ax in axial])
    amp = np.array([values.get("axial_amplifier_bandwidth_hz", values["amplifier_bandwidth_hz"]) if ax
                    else values["amplifier_bandwidth_hz"] for ax in axial])
    inductance = np.array([rig.axial_coil_inductance_h if ax else rig.coil_inductance_h for ax in axial])
    return CurrentBudget(float(rig.values["current_limit_a"]), static, peak, noise_std(rig.axis_sensors()),
                         inductance, amp, float(rig.values["dc_link_voltage_v"]))


def _bands(unc: PlantUncertainty, controllers: Mapping[str, StateSpace], freq_hz: np.ndarray, n: int,
           seed: int) -> dict[str, np.ndarray]:
    """|S_jj| of each controller's loop over drawn plants: label -> (3, L, na) its 2.5, 50 and 97.5 % quantiles
    (plants whose loop is unstable left out)."""
    from ambid.commissioning.loops import input_sensitivity_frf

    draws = draw_parameters(unc, n, np.random.default_rng([seed, 3601]))
    ps = plant_set(unc, draws, freq_hz)
    out = {}
    for label, k in controllers.items():
        s = input_sensitivity_frf(residue_freqresp(k, freq_hz), ps.frf)
        mag = np.abs(np.diagonal(s, axis1=-2, axis2=-1))
        out[label] = np.quantile(mag, [0.025, 0.5, 0.975], axis=0)
    return out


def tune_run(folder: str | os.PathLike, out_dir: str | os.PathLike, *, rig: Rig | str | os.PathLike | None = None,
             settings: TuneSettings = TuneSettings(), report: bool = True,
             progress: Callable[[str], None] | None = None) -> dict:
    """Tune a controller for the plant a run measured; write ``controller.npz``, ``tune.json`` and
    ``report/index.html`` into ``out_dir``.

    Parameters
    ----------
    folder
        the run (module docstring).
    out_dir
        the output folder (created).
    rig
        the nominal rig the run's update was made on (default the session's).
    settings
        how hard to work (:class:`ambid.commissioning.tuning.TuneSettings`).
    report
        write the report page.
    progress
        called with a line per step.

    Returns
    -------
    tune.json's content.

    Raises
    ------
    ValueError
        the run cannot be read or tuned (one sentence with the reason and the fix).
    """
    inputs = read_run(folder, rig)
    s = inputs.summary
    unc = plant_uncertainty(s.get("update") or {}, inputs.rig)
    fit = s.get("fit") or {}
    if "order" not in fit or "delay_s" not in fit:
        raise ValueError(f"{inputs.folder}/identification.json has no fit; run ambid identify or fit again")
    measurement: MeasurementModel = measurement_model(inputs.freq_hz, inputs.var_g, inputs.sensitivity,
                                                      int(fit["order"]), float(fit["delay_s"]), inputs.poles,
                                                      var_noise=inputs.var_noise)
    running, facts = inputs.controller if inputs.controller is not None else (None, None)
    layout = inputs.rig.layout
    result: TuneResult = tune(unc, measurement, layout, _budget(inputs, unc), _starts(inputs.rig, facts), running,
                              facts, analytical_model(inputs.rig), settings, progress, operating_point(inputs, unc))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    chosen = result.chosen
    save_controller(out / "controller.npz", chosen.model)
    p = result.prediction
    rob = result.robustness
    measured_before = headline_peak(s["sensitivity"]) if s.get("sensitivity") else None
    doc: dict[str, Any] = dict(
        run=str(inputs.folder), rig=inputs.rig_source, axes=list(layout.axes),
        controller=str(out / "controller.npz"), kind=chosen.kind, order=int(chosen.model.n_states),
        predicted_peak=dict(value=p.value, ci95=list(p.ci95)), frequency_hz=p.freq_hz, axis=p.axis,
        zones=p.zones, zone=iso14839_zone(p.value), claim=CLAIM,
        loop_peak=dict(value=p.loop_peak, ci95=list(p.loop_ci95),
                       claim="the loop's own peak over all frequencies (no measurement), 2.5-97.5 % of the drawn "
                             "plants"),
        prediction=p.to_dict(),
        margins=dict(sensitivity_peak=rob.sensitivity_peak, peak_freq_hz=rob.peak_freq_hz, zone=rob.zone,
                     gain_margin_low=rob.gain_margin_low, gain_margin_high=rob.gain_margin_high,
                     phase_margin_deg=rob.phase_margin_deg, max_singular_peak=rob.max_singular_peak,
                     note="on the updated model at its estimate; each axis's loop with the others closed"),
        stable_on=dict(plants=settings.n_check, share=chosen.stable_share),
        current=None if chosen.current is None else chosen.current.to_dict(),
        before=dict(measured_peak=measured_before,
                    measured_zone=None if measured_before is None else iso14839_zone(measured_before),
                    controller=facts, predicted=None if result.before is None else result.before.to_dict(),
                    measured_inside=None if result.before is None or measured_before is None else
                    bool(result.before.ci95[0] <= measured_before <= result.before.ci95[1])),
        candidates=[c.to_dict() for c in result.candidates], design_time_s=result.design_s,
        settings=dict(kinds=list(settings.kinds), n_design=settings.n_design, n_check=settings.n_check,
                      n_prediction=settings.n_prediction, seed=settings.seed),
        verify=f"ambid identify --controller {out / 'controller.npz'} with the run's experiment options",
        notes=list(result.notes))
    doc = to_jsonable(doc)
    if report:
        from ambid.report.tune_report import write_tune_report   # matplotlib: optional (ambid[report])

        band = np.geomspace(max(float(inputs.freq_hz.min()) / 2, 1.0), 0.49 / unc.dt_s, 1500)
        controllers = {"after (" + chosen.kind + ")": chosen.model}
        if running is not None and chosen.kind != "running":
            controllers = {"before (the run's)": running, **controllers}
        bands = _bands(unc, controllers, band, min(settings.n_check, 60), settings.seed)
        write_tune_report(out / "report", doc, band, bands, list(layout.axes),
                          measured=(inputs.freq_hz, np.abs(np.diagonal(inputs.sensitivity, axis1=1, axis2=2))))
        doc["report"] = str(out / "report" / "index.html")
    (out / "tune.json").write_text(json.dumps(doc, indent=1))
    return doc
