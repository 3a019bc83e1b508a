"""The processes layout: every node of the session its own process, supervised.

The same session as the composed layout (recorder, plant_sim or the hardware bridge, excitation_generator,
frf_consumer, position_controller; the experiment placed through the generator's ``start_experiment``
before the loop starts; the same samples for a seed), each node a process this one supervises
(``ambid_nodes.supervisor``) and listens to (``ambid_nodes.watch``). A node that exits or is stopped before
the run is over ends it: the plant gets ``DEATH_GRACE_S`` to end its run by itself, the nodes are stopped in
order (the loop first, the recorder last, so it takes every block published and closes its file), and
:class:`ambid_nodes.running.plan.NodeDied` names the node and the sample, with the figures up to there and
where the recording is. Where the loop runs alone (``ambid graph --processes``) the run's summary says the
death and the figures up to there instead.
"""

from __future__ import annotations

import contextlib
import json
import os
import time

from ambid.recording import scan_session
from ambid.recording.blocks import sample_index_report

from ambid_nodes.running.domain import session_domain_id
from ambid_nodes.running.hardware import bridge_parameters
from ambid_nodes.running.layout import Layout, announce_live
from ambid_nodes.running.plan import NodeDied, ProgressBar, config_json, hardware_summary
from ambid_nodes.supervisor import POLL_S, Death, Supervisor, consequence, stopped_words
from ambid_nodes.watch import SessionWatch

START_TIMEOUT_S = 120  # processes start in seconds; on a loaded machine in tens of them
DEATH_GRACE_S = 3.0  # after a death, the plant's time to end its run itself (its controller_timeout_s is 2 s)
# after the controller's death the plant is sure to end its run (safe state, landing) once its 2 s wall-clock
# watchdog fires; a loaded machine may delay that by seconds, and ending the session first would hide the landing
CONTROLLER_DEATH_GRACE_S = 15.0
SETTLE_S = 0.5       # then the time for what is on its way (the last blocks and events)
RECORDER_CATCH_UP_S = 10.0  # at the end, the recorder's time to record the last blocks (its status says)
RECORDER_STATUS_S = 0.25  # its status period here: how soon it says so


class ProcessesLayout(Layout):
    """Every node its own process (:class:`~ambid_nodes.running.layout.Layout`); :meth:`run` raises
    :class:`~ambid_nodes.running.plan.NodeDied` if a node died before the run was over."""

    kind = "processes"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.plant_name = "hardware_bridge" if self.cfg.hardware else "plant_sim"
        self.bar = ProgressBar(self.cfg.progress)

    def run(self) -> dict:
        try:
            return super().run()
        except NodeDied as died:
            if not self.loop_only:
                raise
            return self.loop_summary(died.figures)   # the loop alone: its figures up to the death, and the death

    # --- the steps ---------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def opened(self):
        rig = self.plan.rig
        with supervised(self.cfg.namespace, self.session["session"], rig.backup_clearance_m, self.total // 2,
                        int(round(0.5 * self.fs))) as (self.executor, self.sup, self.watch):
            self.context = self.watch.context
            try:
                yield
            except NodeGone as died:
                self.bar.close()
                raise self.node_died(died.death) from None

    def start_graph(self) -> None:
        cfg, sup, session, rig_param = self.cfg, self.sup, self.session, self.rig_param
        if self.loop_only:
            sup.start(self.plant_name, self.plant_parameters(), finishes=True)
            return
        cfg.out_dir.mkdir(parents=True, exist_ok=True)
        sup.start("recorder", {"output": str(self.mcap_path), "overwrite": True, "status_period_s": RECORDER_STATUS_S,
                               **session, "session_facts": json.dumps({"session": "identify",
                                                                       "config": config_json(cfg)})})
        sup.start(self.plant_name, self.plant_parameters(), finishes=True)
        sup.start("excitation_generator", {"start_margin": self.start_index, **rig_param, **session})
        sup.start("frf_consumer", {"estimator": cfg.estimator, **session})

    def wait_readers(self) -> None:
        """The recorder, the consumer and the generator (and a live view) listen to the measurement before the
        loop starts, and the watch hears the plant (the loop alone: the watch hears every block from the first
        before the controller joins)."""
        watch = self.watch
        if self.loop_only:
            self.spin_until(watch.hears_the_plant, START_TIMEOUT_S, f"{self.plant_name}'s measurement")
            return
        # each by name: another listener on the topic (a ros2 topic echo, a test's) stands in for none of them
        announce_live(self.live)
        listeners = self.measurement_listeners()
        self.spin_until(lambda: not watch.subscribed(watch.measurement, listeners) and watch.hears_the_plant(),
                        START_TIMEOUT_S, "the recorder, the consumer and the generator to subscribe"
                        + (" (and the live view)" if self.live is not None else ""))

    def start_experiment(self):
        """The experiment placed through the generator's service; asked again while the generator has not heard
        the plant yet (it refuses then, naming it). Then the controller starts (the target starts by itself)."""
        from ambid_msgs.srv import StartExperiment

        if self.loop_only:
            self.start_controller()
            return None
        client = self.watch.create_client(StartExperiment, "start_experiment")
        self.spin_until(client.service_is_ready, START_TIMEOUT_S, "the start_experiment service")
        end = time.monotonic() + START_TIMEOUT_S
        while True:
            future = client.call_async(StartExperiment.Request(start_index=self.start_index,
                                                               design_json=json.dumps(self.plan.design.to_dict())))
            self.spin_until(future.done, 30, "the start_experiment answer")
            answer = future.result()
            if answer.accepted:
                break
            if not answer.message.startswith("no plant/description") or time.monotonic() > end:
                raise ValueError(f"identify: the excitation generator refused the experiment: {answer.message}")
            pause = time.monotonic() + 0.2
            while time.monotonic() < pause:
                spin(self.executor, self.watch, 0.05)
        self.wait_live_design(answer)
        self.start_controller()
        return answer

    def run_loop(self, answer) -> dict:
        """Until the plant (or the bridge) finishes, or a node dies; the plant's summary."""
        sup, watch, bar, total, fs = self.sup, self.watch, self.bar, self.total, self.fs

        def done() -> bool:
            self.show_progress(bar, watch.progress)   # the bar shows at most 4 lines a second
            return sup.exited(self.plant_name)

        death = supervise(self.executor, sup, watch, done)
        if death is not None:
            raise NodeGone(death)
        bar.show(1.0, "simulation done, closing the recording", force=True)
        bar.close()
        plant_summary = sup.nodes[self.plant_name].summary
        if plant_summary is None:
            raise RuntimeError(f"{self.plant_name} exited with code {sup.nodes[self.plant_name].proc.returncode} "
                               "without a summary")
        if self.cfg.hardware:
            plant_summary = hardware_summary(plant_summary, total, fs, time.perf_counter() - self.wall0)
        if not plant_summary.get("failure") and not self.loop_only:
            self.spin_until(lambda: watch.event("frf_done") is not None or watch.event("no_estimate") is not None,
                            60, "the final FRF estimate")
        return plant_summary

    def stop(self, plant_summary: dict, answer) -> tuple[dict, dict]:
        watch = self.watch
        rec = close_recording(self.sup, self.executor, watch, self.mcap_path)
        failure = plant_summary.get("failure")
        if failure:  # the run stopped short, no estimate will come: the recording kept, say why
            raise RuntimeError(f"the plant ended the session failed ({failure['code']}): {failure['text']}; "
                               f"the recording so far is in {self.mcap_path}")
        frf = watch.event("frf_done")
        if frf is None:
            raise RuntimeError(f"the FRF consumer ended without an estimate ({watch.event('no_estimate').text}); "
                               f"the recording is in {self.mcap_path}")
        return rec, json.loads(frf.text)

    def words(self) -> str:
        return f"processes, hardware bridge to {self.cfg.hardware}" if self.cfg.hardware else "processes"

    # --- helpers -----------------------------------------------------------------------------------------
    def plant_parameters(self) -> dict:
        """plant_sim's parameters for the session's samples, or the bridge's (the target waits for the
        experiment and stops after the session's samples)."""
        cfg = self.cfg
        if cfg.hardware:
            return {**bridge_parameters(cfg), "start_with_experiment": not self.loop_only,
                    "autostart": self.loop_only, "stop_after_samples": self.total, **self.rig_param, **self.session}
        # the loop waits until the plant's own writer is matched with every reader the run waits for (the
        # graph showing a subscription by name is not yet the plant's writer matched with it); only plant_sim's
        # process sees its writer's matches (the composed layout, holding the writer, counts them itself); by name
        # too, since another listener (a monitor, a test's) matched first would make up the count
        named = [] if self.loop_only else self.measurement_listeners()
        readers = len(named) + (not self.loop_only)   # + the watch
        return {"sim_seconds": self.sim_seconds, "seed": cfg.seed, "nonlinear_magnets": cfg.nonlinear_magnets,
                "measurement_readers": readers, **({"measurement_reader_nodes": named} if named else {}),
                **self.rig_param, **self.session}

    def measurement_listeners(self) -> list[str]:
        """The session's nodes that listen to the measurement from its first block, by name."""
        return ["recorder", "frf_consumer", "excitation_generator"] + ["live_view"] * (self.live is not None)

    def start_controller(self) -> None:
        """The controller joins (a target runs its own): the loop starts."""
        if not self.cfg.hardware:
            self.sup.start("position_controller", {**self.rig_param, "controller": self.cfg.controller,
                                                   **self.session})

    def spin_until(self, pred, timeout_s: float, what: str) -> None:
        wait_for(self.executor, self.sup, self.watch, pred, timeout_s, what)

    def node_died(self, death) -> NodeDied:
        """The run's end after ``death``: the nodes stopped in order, the figures up to there, the line's facts."""
        sup = self.sup
        plant_summary = sup.nodes[self.plant_name].summary if self.plant_name in sup.nodes else None
        rec = {} if self.loop_only else close_recording(sup, self.executor, self.watch, self.mcap_path)
        recorded = rec.get("block_end", {}).get(self.watch.measurement)
        summary = died_summary(death, plant_summary, self.watch, self.plan.rig.dt, time.perf_counter() - self.wall0,
                               recorded)
        complete = bool(rec.get("complete", rec.get("state") == "done"))
        return NodeDied(summary["death"], str(self.mcap_path), complete, rec.get("messages"), summary)


def close_recording(sup: Supervisor, executor, watch, mcap_path) -> dict:
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
    except (OSError, ValueError) as exc:
        return {"messages": None, "complete": False, "error": str(exc)}
    # the event is often never sent (a recorder closing on SIGTERM has no ROS context left): the measurement's
    # end as recorded, from the file's block headers, as the event would have said it
    try:
        end = sample_index_report(mcap_path, [watch.measurement])[watch.measurement]["end_index"] or 0
    except (OSError, ValueError, KeyError):
        return {"messages": scan.message_count, "complete": scan.complete}
    return {"messages": scan.message_count, "complete": scan.complete, "block_end": {watch.measurement: end}}


def died_summary(death, summary: dict | None, watch, dt: float, wall_s: float, recorded: int | None = None) -> dict:
    """The run's figures where ``death`` ended it: the plant's own where it ended its run (its levitation is
    judged up to where the loop stopped), else the end of what the recording holds (``recorded``: its
    measurement's end index; a source stopped while sending a block may have reached the recorder with it and not
    the watch, or the other way round: a writer sends to each reader in turn), else what the watch heard."""
    if summary is None:
        k = watch.progress if recorded is None else recorded
        figures = watch.figures("plant_sim")
        summary = {**watch.monitor.figures(), "samples": k, "simulated_s": k * dt, "wall_s": wall_s,
                   "samples_per_wall_s": k / wall_s if wall_s > 0 else 0.0, "state": "failed", "failure": None,
                   "messages_rejected": figures.get("messages_rejected", 0),
                   "messages_received": figures.get("messages_received", 0)}
    failure = summary.get("failure") or {}
    finished = summary.get("state") == "done"
    k = failure.get("sample_index", summary.get("samples", watch.progress))
    summary = {**summary, "state": "failed"}
    summary["death"] = {"node": death.node, "how": death.how, "sample_index": int(k), "simulated_s": k * dt,
                        "consequence": consequence(death.node, failure, finished)}
    return summary


@contextlib.contextmanager
def supervised(namespace: str, session: int, clearance_m: float, settle_samples: int, after_lift_off: int):
    """``(executor, supervisor, watch)``: a supervisor of a session's node processes on this process's domain and
    the session's watch (``ambid_nodes.watch.SessionWatch``: the levitation judged as plant_sim judges it), spun
    by one executor; at the end every node is stopped and ROS shut down, whatever happened."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=session_domain_id())
    executor = EventsExecutor(context=context)
    sup = Supervisor(namespace, dict(os.environ, ROS_DOMAIN_ID=str(session_domain_id())))
    watch = None
    try:
        watch = SessionWatch(session, clearance_m, settle_samples, after_lift_off, namespace=namespace,
                             context=context)
        executor.add_node(watch)
        yield executor, sup, watch
    finally:
        sup.stop_all()
        executor.shutdown()
        if watch is not None:
            watch.destroy_node()
        rclpy.shutdown(context=context)


def supervise(executor, sup: Supervisor, watch, done, grace_s: float = DEATH_GRACE_S,
              controller_grace_s: float = CONTROLLER_DEATH_GRACE_S) -> Death | None:
    """Spin ``executor`` (the watch's) until ``done()`` or a node died; after a death, give the plant up to
    ``grace_s`` to end its run by itself (it names the exact sample where the loop stopped; after the
    position controller's death, which its watchdog always answers, up to ``controller_grace_s``), then return
    the death. None: the run ended as it should."""
    death = None
    while not done():
        spin(executor, watch)
        death = sup.check()
        if death is not None:
            break
    if death is None:
        return None
    plant = next((n for n in ("plant_sim", "hardware_bridge") if n in sup.nodes), None)
    if plant is not None and death.node != plant:
        end = time.monotonic() + (controller_grace_s if death.node == "position_controller" else grace_s)
        while time.monotonic() < end and not sup.exited(plant):
            spin(executor, watch)
    end = time.monotonic() + SETTLE_S  # the blocks and events already on their way
    while time.monotonic() < end:
        spin(executor, watch)
    return death


def wait_for(executor, sup: Supervisor, node, predicate, timeout_s: float, what: str) -> None:
    """Spin until ``predicate()``; RuntimeError naming ``what`` after ``timeout_s``, NodeGone if a node died
    meanwhile, KeyboardInterrupt if the context was shut down."""
    end = time.monotonic() + timeout_s
    while not predicate():
        death = sup.check()
        if death is not None:
            raise NodeGone(death)
        if time.monotonic() > end:
            raise RuntimeError(f"timed out after {timeout_s:g} s waiting for {what}")
        spin(executor, node, 0.05)


class NodeGone(Exception):
    """A node died while the run was being set up (``death``: :class:`Death`)."""

    def __init__(self, death: Death) -> None:
        super().__init__(f"{death.node} {death.how}")
        self.death = death


def spin(executor, node, timeout_s: float = POLL_S) -> None:
    """One turn of ``executor``; KeyboardInterrupt once ``node``'s context is shut down (rclpy's SIGINT and
    SIGTERM handlers do that instead of raising), so ^C ends a supervised run, its nodes stopped in order."""
    if not node.context.ok():
        raise KeyboardInterrupt
    executor.spin_once(timeout_sec=timeout_s)
