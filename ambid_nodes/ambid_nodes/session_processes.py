"""An identification session in the processes layout: every node its own process, supervised.

The same session as :func:`ambid_nodes.session.run_session_composed` (recorder, plant_sim or the hardware
bridge, excitation_generator, frf_consumer, position_controller; the experiment placed through the
generator's ``start_experiment`` before the loop starts; the same samples for a seed), each node a process
this one supervises (``ambid_nodes.supervisor``) and listens to (``ambid_nodes.watch``). A node that exits
or is stopped before the run is over ends it: the plant gets ``DEATH_GRACE_S`` to end its run by itself,
the nodes are stopped in order (the loop first, the recorder last, so it takes every block published and
closes its file), and :class:`ambid_nodes.session.NodeDied` names the node and the sample, with the
figures up to there and where the recording is.
"""

from __future__ import annotations

import json
import sys
import time

from ambid.recording import scan_session
from ambid.session_id import new_session_id

from ambid_nodes.graph import died_summary, preflight
from ambid_nodes.running.plan import (NodeDied, ProgressBar, SessionConfig, SessionPlan, config_json,
                                      hardware_summary, plan_session, run_facts, session_samples)
from ambid_nodes.supervisor import (SETTLE_S, NodeGone, Supervisor, spin, stopped_words, supervise, supervised,
                                    wait_for)

START_TIMEOUT_S = 120  # processes start in seconds; on a loaded machine in tens of them
RECORDER_CATCH_UP_S = 10.0  # at the end, the recorder's time to record the last blocks (its status says)
RECORDER_STATUS_S = 0.25  # its status period here: how soon it says so


def run_session_processes(cfg: SessionConfig, plan: SessionPlan | None = None, report_foreign=None,
                          live=None) -> dict:
    """Run the session's nodes as processes; returns the run's facts (no offline analysis), as the composed
    run does. NodeDied if a node died before the run was over; RuntimeError/ValueError as the composed run.
    ``live`` (a started :class:`ambid_nodes.live_view.LiveProcess`): the loop starts once it has the design."""
    from ambid_msgs.srv import StartExperiment

    plan = plan_session(cfg) if plan is None else plan
    design, rig = plan.design, plan.rig
    fs = rig.sample_rate_hz
    start_index, total = session_samples(design, fs)
    cfg.out_dir.mkdir(parents=True, exist_ok=True)
    mcap_path = cfg.out_dir / "session.mcap"
    bar = ProgressBar(cfg.progress)
    wall0 = time.perf_counter()
    plant_name = "hardware_bridge" if cfg.hardware else "plant_sim"
    session_id = cfg.session or new_session_id()  # every session has an id, given or fresh
    with supervised(cfg.namespace, session_id, rig.backup_clearance_m, total // 2,
                    int(round(0.5 * fs))) as (executor, sup, watch):

        def spin_until(pred, timeout_s: float, what: str) -> None:
            wait_for(executor, sup, watch, pred, timeout_s, what)

        foreign = preflight(executor, cfg.namespace, watch.context, report_foreign)
        session = {"session": session_id}
        rig_param = {"rig_file": cfg.rig_file} if cfg.rig_file else {}
        try:
            sup.start("recorder", {"output": str(mcap_path), "overwrite": True, "status_period_s": RECORDER_STATUS_S,
                                   **session,
                                   "session_facts": json.dumps({"session": "identify", "config": config_json(cfg)})})
            if cfg.hardware:
                from ambid.hardware.rt_target import parse_address

                host, port = parse_address(cfg.hardware)
                sup.start(plant_name, {"target_host": host, "target_port": port, "local_port": cfg.local_port,
                                       "autostart": False, "start_with_experiment": True, "stop_after_samples": total,
                                       "key_file": cfg.key_file, "protocol_version": cfg.protocol_version,
                                       **rig_param, **session}, finishes=True)
            else:
                sup.start(plant_name, {"sim_seconds": total / fs, "seed": cfg.seed,
                                       "nonlinear_magnets": cfg.nonlinear_magnets, **rig_param, **session},
                          finishes=True)
            sup.start("excitation_generator", {"start_margin": start_index, **rig_param, **session})
            sup.start("frf_consumer", {"estimator": cfg.estimator, **session})
            # the recorder, the consumer and the generator (and a live view) listen to the measurement before the
            # loop starts
            meas = watch.measurement
            listeners = 4
            if live is not None:
                print(f"ambid: live view on {live.wait_ready()} (docs/live.md)", file=sys.stderr, flush=True)
                listeners += 1
            spin_until(lambda: watch.count_subscribers(meas) >= listeners and watch.hears_the_plant(),
                       START_TIMEOUT_S, "the recorder, the consumer and the generator to subscribe"
                       + (" (and the live view)" if live is not None else ""))
            answer = _start_experiment(watch, executor, spin_until, StartExperiment, start_index, design)
            if live is not None:   # it shows the experiment from its first sample: it has the design first
                live.wait_design(answer.experiment_id, START_TIMEOUT_S)
            if not cfg.hardware:
                sup.start("position_controller", {**rig_param, "controller": cfg.controller, **session})
            # the run: until the plant (or the bridge) finishes, or a node dies
            last = [0.0]

            def done() -> bool:
                k = watch.progress
                if time.monotonic() - last[0] > 0.25:
                    last[0] = time.monotonic()
                    rate = k / max(time.perf_counter() - wall0, 1e-9)
                    bar.show(k / total, f"sim {k / fs:6.2f}/{total / fs:.2f} s  {rate / 1000:5.1f}k samples/s")
                return sup.exited(plant_name)

            death = supervise(executor, sup, watch, done)
            if death is not None:
                raise NodeGone(death)
            bar.show(1.0, "simulation done, closing the recording", force=True)
            bar.close()
            plant_summary = sup.nodes[plant_name].summary
            if plant_summary is None:
                raise RuntimeError(f"{plant_name} exited with code {sup.nodes[plant_name].proc.returncode} without a "
                                   "summary")
            if cfg.hardware:
                plant_summary = hardware_summary(plant_summary, total, fs, time.perf_counter() - wall0)
            failure = plant_summary.get("failure")
            if not failure:
                spin_until(lambda: watch.event("frf_done") is not None or watch.event("no_estimate") is not None,
                           60, "the final FRF estimate")
            rec = _close_recording(sup, executor, watch, mcap_path)
            if failure:  # the run stopped short, no estimate will come: the recording kept, say why
                raise RuntimeError(f"the plant ended the session failed ({failure['code']}): {failure['text']}; "
                                   f"the recording so far is in {mcap_path}")
            frf = watch.event("frf_done")
            if frf is None:
                raise RuntimeError(f"the FRF consumer ended without an estimate ({watch.event('no_estimate').text}); "
                                   f"the recording is in {mcap_path}")
            layout = f"processes, hardware bridge to {cfg.hardware}" if cfg.hardware else "processes"
            return run_facts(answer, plant_summary, rec, _live_figures(json.loads(frf.text)),
                             time.perf_counter() - wall0, layout, design, mcap_path, foreign)
        except NodeGone as died:
            bar.close()
            raise _node_died(died.death, sup, executor, watch, mcap_path, plant_name, rig.dt,
                             time.perf_counter() - wall0) from None


def _start_experiment(watch, executor, spin_until, StartExperiment, start_index: int, design):
    """The experiment placed through the generator's service; asked again while the generator has not heard
    the plant yet (it refuses then, naming it)."""
    client = watch.create_client(StartExperiment, "start_experiment")
    spin_until(client.service_is_ready, START_TIMEOUT_S, "the start_experiment service")
    end = time.monotonic() + START_TIMEOUT_S
    while True:
        future = client.call_async(StartExperiment.Request(start_index=start_index,
                                                           design_json=json.dumps(design.to_dict())))
        spin_until(future.done, 30, "the start_experiment answer")
        answer = future.result()
        if answer.accepted:
            return answer
        if not answer.message.startswith("no plant/description") or time.monotonic() > end:
            raise ValueError(f"identify: the excitation generator refused the experiment: {answer.message}")
        pause = time.monotonic() + 0.2
        while time.monotonic() < pause:
            spin(executor, watch, 0.05)


def _close_recording(sup: Supervisor, executor, watch, mcap_path) -> dict:
    """Stop the nodes, the loop first, the recorder last once it took the last blocks (SIGTERM: it closes the file
    completely); its summary from its recording_closed event, else from the file."""
    loop = [n for n in ("position_controller", "plant_sim", "hardware_bridge", "excitation_generator", "frf_consumer")
            if n in sup.nodes]
    sup.stop(loop)
    end = time.monotonic() + SETTLE_S
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    recorder = sup.nodes.get("recorder")
    if recorder is not None and recorder.proc.poll() is None and stopped_words(recorder.proc.pid) is None:
        # a SIGTERM drops what waits in its queue: first it records every block the session published
        end = time.monotonic() + RECORDER_CATCH_UP_S
        meas = f"end_index:{watch.measurement}"
        while time.monotonic() < end and watch.figures("recorder").get(meas, -1) < watch.progress:
            executor.spin_once(timeout_sec=0.05)
    if recorder is not None and recorder.proc.poll() is None:
        sup.stop(["recorder"])
        end = time.monotonic() + SETTLE_S
        while time.monotonic() < end and watch.event("recording_closed") is None:
            executor.spin_once(timeout_sec=0.05)
    closed = watch.event("recording_closed")
    if closed is not None:
        try:
            return json.loads(closed.text)
        except json.JSONDecodeError:
            pass
    try:
        scan = scan_session(mcap_path)
        return {"messages": scan.message_count, "complete": scan.complete}
    except (OSError, ValueError) as exc:
        return {"messages": None, "complete": False, "error": str(exc)}


def _node_died(death, sup, executor, watch, mcap_path, plant_name: str, dt: float, wall_s: float) -> NodeDied:
    """The run's end after ``death``: the nodes stopped in order, the figures up to there, the line's facts."""
    plant_summary = sup.nodes[plant_name].summary if plant_name in sup.nodes else None
    rec = _close_recording(sup, executor, watch, mcap_path)
    summary = died_summary(death, plant_summary, watch, dt, wall_s)
    complete = bool(rec.get("complete", rec.get("state") == "done"))
    return NodeDied(summary["death"], str(mcap_path), complete, rec.get("messages"), summary)


def _live_figures(f: dict) -> dict:
    """The consumer's final figures (its frf_done event) as the composed run reports its estimate's."""
    return {"relative_noise_std": f.get("relative_noise_std"), "periods": f.get("periods_used"),
            "realisations": f.get("realisations_used"), "iso_zone": f.get("iso_zone"),
            "sensitivity_peak": f.get("sensitivity_peak")}

