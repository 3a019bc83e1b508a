"""The main job of ``ambid identify``: a recorded session on the ROS graph, then its offline identification.

The session runs through :func:`ambid_nodes.running.run.run_session` (its layout: composed, hardware or
processes, :mod:`ambid_nodes.running`); :func:`run_identify` adds the analysis, started with the session
where the layout runs in this process, and returns :class:`IdentifyResult` (``summary.json``). Every node
belongs to the session ``session`` (docs/sessions.md): it acts only on that session's messages, and the
recording holds only them.
"""

from __future__ import annotations

import json
import multiprocessing
import sys
import time
from dataclasses import dataclass, fields, replace
from typing import Callable

from ambid.excitation import ExcitationDesign
from ambid.frf.offline import data_channels
from ambid.identification.result import Identification
from ambid.jsonable import JsonRecord, json_field
from ambid.session_id import format_session

from ambid_nodes.running.layout import start_live
from ambid_nodes.running.plan import SessionConfig, SessionPlan, plan_session
from ambid_nodes.running.run import run_session


def run_identify(cfg: SessionConfig, plan: SessionPlan | None = None,
                 report_foreign: Callable[[dict], None] | None = None,
                 on_headline: Callable[[IdentifyResult], None] | None = None,
                 on_phase: Callable[[str], None] | None = None) -> IdentifyResult:
    """The whole job: the recorded session on the graph, then the offline identification of it.

    The analysis runs in a process of its own (:class:`ambid.identification.early.EarlyAnalysis`), started
    with the session: what the measurement does not change is computed while it runs, the fit and the update
    start the moment the last period is in, while the graph and the recording close. ``on_headline`` is called
    with the summary as soon as the results are there, before the report is written (the numbers are those of
    the recording's analysis; should that process fail, the recording is analysed here, as before).
    ``on_phase`` is told each phase after the session as it starts (the analysis, the report).

    Writes ``out_dir/session.mcap``, ``out_dir/summary.json`` and ``out_dir/report/``.
    """
    from ambid.identification.early import EarlyAnalysis, EarlyAnalysisFailed
    from ambid.identification.pipeline import identify_session

    true_model = None
    if cfg.true_model:
        from ambid.hardware.target_model import read_target_model

        true_model = read_target_model(cfg.true_model).plant
    options = dict(estimator=cfg.estimator, true_model=true_model, report=cfg.report)
    live = start_live(cfg)
    # with a real-time target the bridge must never fall silent: the analysis yields it the CPU. A session
    # run by a daemonic worker (a study's on Dask) may not start processes: it analyses the recording itself
    early = (None if multiprocessing.current_process().daemon
             else EarlyAnalysis(cfg.out_dir, nice=5 if cfg.hardware else 0, **options))
    plan = plan_session(cfg) if plan is None else plan
    if early is not None:
        # what the analysis compares with and the measurement does not change, computed while the session runs
        # (from the plan: used if it is what the session then describes, see ambid_nodes.running.composed.SessionMessages); the FRF's
        # channels as the recording will name them: the rig's displacements by the design's inputs
        outputs, inputs, _ = data_channels(plan.design.input_names, plan.rig.layout.measurement_names)
        early.prepare(_planned_inputs(cfg, plan), plan.design.freq_hz, outputs, inputs)
    try:
        # the processes layout feeds no early analysis: the recording is analysed once the session is over
        run = run_session(cfg, plan, report_foreign, live=live, early=early)
        design: ExcitationDesign = run.pop("design")
        shown: dict = {}
        phase = on_phase or (lambda text: None)

        def show(offline: Identification) -> None:   # the headline, as soon as the results are there
            shown["at"] = time.perf_counter()
            if on_headline is not None:
                on_headline(_identify_summary(cfg, run, design, offline, _timing(run, shown)))
            if cfg.report:
                phase("writing the report" if cfg.report is True else "handing the report to a process of its own")

        phase("analysing the recording: FRF, fit, model update")

        offline = notes = None
        if early is not None and early.analysing:
            try:
                early.recording_closed()
                first, how = early.summary()
                shown.update(how, early=True)
                if run.get("final_estimate_at") is not None:
                    shown["analysis_started_after_last_period_s"] = early.times["analyse"] - run["final_estimate_at"]
                show(first)
                offline, notes = early.result()
            except EarlyAnalysisFailed as exc:
                print(f"ambid identify: the analysis process failed ({str(exc).splitlines()[0]}); analysing the "
                      "recording here", file=sys.stderr)
        if offline is None:
            offline = identify_session(run["mcap_path"], cfg.out_dir, on_summary=None if shown else show, **options)
        shown["done"] = time.perf_counter()
        if notes:   # the early inputs differed from the recording's: the results shown were replaced
            print("ambid identify: " + "; ".join(notes), file=sys.stderr)
            offline = replace(offline, notes=list(offline.notes) + notes)
            show(offline)
        summary = _identify_summary(cfg, run, design, offline, _timing(run, shown))
    finally:
        if early is not None:
            early.close()
        live_figures = live.stop() if live is not None else None
    if live_figures is not None:
        summary = replace(summary, live=live_figures)
    (cfg.out_dir / "summary.json").write_text(json.dumps(summary.to_json(), indent=2))
    return summary


def _planned_inputs(cfg: SessionConfig, plan: SessionPlan):
    """The session's inputs as the plan foresees them (the rig's JSON as plant_sim publishes it, the
    controller's model, the design), without the FRF: what reference models can be computed from early."""
    from ambid.identification.inputs import SessionInputs

    ctrl = None if plan.controller is None else (plan.controller.model, {})
    experiment = {"topic": "", "experiment_id": "", "start_index": 0, "total_samples": plan.design.total_samples,
                  "design": plan.design}
    return SessionInputs(str(cfg.out_dir / "session.mcap"), experiment, None, json.loads(json.dumps(plan.rig.to_dict())),
                         "hardware" if cfg.hardware else "sim", ctrl, cfg.nonlinear_magnets)


def _timing(run: dict, shown: dict) -> dict:
    """Wall seconds from the last period's estimate (the consumer's final FRF) to the headline and the report."""
    t0 = run.get("final_estimate_at")
    if t0 is None:
        return {}
    out = {k: shown[k] for k in ("early", "references_s", "references_used", "waited_for_references_s",
                                 "analysis_s", "analysis_cpu_s", "analysis_started_after_last_period_s") if k in shown}
    if "at" in shown:
        out["headline_after_last_period_s"] = shown["at"] - t0
    if "done" in shown:
        out["report_after_last_period_s"] = shown["done"] - t0
    return out


def _identify_summary(cfg: SessionConfig, run: dict, design: ExcitationDesign, offline: Identification,
                      timing: dict) -> IdentifyResult:
    rec, plant = run["recorder"], run["plant"]
    return IdentifyResult(
        sample_rate_hz=float(design.fs_hz), simulated_time_s=run["simulated_s"], wall_time_s=run["wall_s"],
        simulated_samples_per_wall_s=run["samples_per_wall_s"], real_time_factor=run["simulated_s"] / run["wall_s"],
        layout=run["layout"], state=plant["state"], levitated=plant["levitated"],
        # lost loop messages the plant asked for again, and the answers that then came twice
        loop_recovery=LoopRecovery(resends=plant.get("resends", 0),
                                   duplicate_answers=plant.get("duplicate_answers", 0)),
        live_frf=run["live_frf"], identification=offline, analysis_timing=timing,
        recording=RecordingFacts(path=run["mcap_path"], messages=rec.get("messages", rec.get("message_count")),
                                 complete=rec.get("complete", True)),
        # what the recorder heard of other sources during the session and kept out, per topic
        session=SessionFacts(id=format_session(cfg.session), foreign_publishers=run["foreign_publishers"],
                             foreign_messages=rec.get("foreign", {})))


@dataclass(frozen=True, eq=False)
class LoopRecovery(JsonRecord):
    """Lost loop messages the plant asked for again, and the answers that then came twice."""

    resends: int
    duplicate_answers: int


@dataclass(frozen=True, eq=False)
class RecordingFacts(JsonRecord):
    """The session's recording: its file, how many messages, whether it was closed completely."""

    path: str
    messages: int | None
    complete: bool


@dataclass(frozen=True, eq=False)
class SessionFacts(JsonRecord):
    """The session's id, the foreign publishers found before it started and what the recorder kept out."""

    id: str
    foreign_publishers: dict
    foreign_messages: dict


@dataclass(frozen=True, eq=False)
class IdentifyResult(JsonRecord):
    """What ``ambid identify`` made: the run on the graph and the identification of its recording
    (``summary.json``; its keys are the run's, then the identification's, as the file has always had them).

    Attributes:
        sample_rate_hz: the plant's sample rate [Hz].
        simulated_time_s, wall_time_s: the session's simulated and wall time [s].
        simulated_samples_per_wall_s, real_time_factor: how fast it ran.
        layout: how it ran (``composed``, ``processes``, ``hardware bridge to HOST:PORT``).
        state, levitated: how the plant ended.
        loop_recovery: lost loop messages asked for again.
        live_frf: the FRF consumer's last figures (relative_noise_std, periods, realisations, iso_zone,
            sensitivity_peak).
        identification: the identification of the recording
            (:class:`ambid.identification.result.Identification`).
        analysis_timing: wall seconds from the last period to the headline and the report.
        recording: the recording's facts.
        session: the session's id and the foreign publishers.
        live: the live view's figures, when it ran.
    """

    sample_rate_hz: float
    simulated_time_s: float
    wall_time_s: float
    simulated_samples_per_wall_s: float
    real_time_factor: float
    layout: str
    state: str
    levitated: bool | None
    loop_recovery: LoopRecovery
    live_frf: dict
    identification: Identification
    analysis_timing: dict
    recording: RecordingFacts
    session: SessionFacts
    live: dict | None = json_field(omit_none=True)

    def json_items(self) -> dict:
        ident = self.identification.json_items()
        out = {"excitation": ident["excitation"], "sample_rate_hz": self.sample_rate_hz, "band_hz": ident["band_hz"],
               "inputs": ident["inputs"]}
        out.update((f.name, getattr(self, f.name)) for f in fields(self)
                   if f.name in ("simulated_time_s", "wall_time_s", "simulated_samples_per_wall_s",
                                 "real_time_factor", "layout", "state", "levitated", "loop_recovery", "live_frf"))
        for k, v in ident.items():
            out.setdefault(k, v)
        out.update(analysis_timing=self.analysis_timing, recording=self.recording, session=self.session)
        if self.live is not None:
            out["live"] = self.live
        return out
