"""One way to run a session: the :class:`Layout` interface, and what every layout shares.

A session's nodes run in one of three layouts, each a :class:`Layout`:

- composed (:class:`ambid_nodes.running.composed.ComposedLayout`): every node in this process, one executor;
- hardware (:class:`ambid_nodes.running.hardware.HardwareLayout`): composed, with the bridge to a real-time
  target in place of plant_sim and the position controller (the target runs the fast loop);
- processes (:class:`ambid_nodes.running.processes.ProcessesLayout`): every node its own process, supervised.

:meth:`Layout.run` is the walk of a session, written once: open the graph's context, name the foreign
publishers already there (:func:`preflight`), start the nodes, wait until every reader is matched, place
the experiment through the generator's ``start_experiment`` and start the loop, run it to its end, stop
the nodes and close the recording, and return the run's facts (:func:`ambid_nodes.running.plan.run_facts`).
A layout says only how each step is done where its nodes live. :func:`ambid_nodes.running.run.run_session`
picks the layout of a :class:`~ambid_nodes.running.plan.SessionConfig`.
"""

from __future__ import annotations

import contextlib
import sys
import time
from abc import ABC, abstractmethod
from typing import Callable

from ambid.session_id import new_session_id

from ambid_nodes.running.domain import session_domain_id
from ambid_nodes.running.plan import SessionConfig, SessionPlan, run_facts, session_samples


class Layout(ABC):
    """Where a session's nodes run; :meth:`run` runs the session.

    Parameters
    ----------
    cfg : SessionConfig
        What to run.
    plan : SessionPlan
        The rig, the controller and the design, decided once (:func:`ambid_nodes.running.plan.plan_session`).
    report_foreign : callable, optional
        Told ``{topic: [publishers]}`` found on the session's topics before anything starts.
    live : ambid_nodes.live_view.LiveProcess, optional
        A started live view: the experiment starts once it listens, so it shows the whole experiment.
    """

    executor = None  # set by opened(): the executor the layout spins
    context = None   # and its rclpy context
    foreign: dict = {}  # the foreign publishers preflight found

    def __init__(self, cfg: SessionConfig, plan: SessionPlan, report_foreign: Callable[[dict], None] | None = None,
                 live=None) -> None:
        self.cfg, self.plan, self.report_foreign, self.live = cfg, plan, report_foreign, live
        self.fs = plan.rig.sample_rate_hz
        self.start_index, self.total = session_samples(plan.design, self.fs, cfg.loop_seconds)
        self.loop_only = plan.design is None   # the loop alone (ambid graph): no recorder, experiment, estimate
        self.sim_seconds = cfg.loop_seconds or self.total / self.fs   # the plant's run
        self.mcap_path = cfg.out_dir / "session.mcap"
        self.session = {"session": cfg.session or new_session_id()}  # every session has an id, given or fresh
        # said, not parsed again: a composed node gets plan.rig, a process parses the file once
        self.rig_param = {"rig_file": cfg.rig_file} if cfg.rig_file else {}
        self.wall0 = time.perf_counter()

    def run(self) -> dict:
        """Run the session; the run's facts (:func:`ambid_nodes.running.plan.run_facts`; no offline analysis).

        RuntimeError or ValueError names what went wrong (a timeout, a refused experiment, a failed run: the
        recording so far is kept); the processes layout raises
        :class:`ambid_nodes.running.plan.NodeDied` when a node died before the run was over.
        KeyboardInterrupt once the context is shut down (^C, SIGTERM): every node is stopped.

        The loop alone (``cfg.loop_seconds``, ``ambid graph``) returns the plant's summary with ``layout`` and
        ``foreign_publishers`` instead (where a node died, the figures up to there and ``death``).
        """
        with self.opened():
            self.foreign = preflight(self.executor, self.cfg.namespace, self.context, self.report_foreign)
            self.start_graph()
            self.wait_readers()
            answer = self.start_experiment()
            plant_summary = self.run_loop(answer)
            if answer is None:   # the loop alone: the plant's summary is the run's
                return self.loop_summary(plant_summary)
            recorder, estimate = self.stop(plant_summary, answer)
            facts = run_facts(answer, plant_summary, recorder, live_figures(estimate),
                              time.perf_counter() - self.wall0, self.words(), self.plan.design, self.mcap_path,
                              self.foreign, self.final_estimate_at(answer))
            if self.live is not None:
                # the live view runs nicer than the loop: on a busy machine it may still be behind. The loop is
                # over, so it catches up now, while the writers live to send it what it has not received
                facts["live_caught_up"] = self.live.wait_finished(answer.experiment_id, LIVE_CATCH_UP_S)
            return facts

    @abstractmethod
    def opened(self) -> contextlib.AbstractContextManager:
        """A context in which ``executor`` and ``context`` are ready; leaving it stops every node."""

    @abstractmethod
    def start_graph(self) -> None:
        """Start the recorder, the plant (or the bridge), the generator and the consumer (the plant alone where
        the loop runs alone)."""

    @abstractmethod
    def wait_readers(self) -> None:
        """Return once every reader of the measurement and of the design is matched (a live view's too)."""

    @abstractmethod
    def start_experiment(self):
        """Place the experiment through the generator's service and start the loop; the service's answer
        (None where the loop runs alone: it is started)."""

    @abstractmethod
    def run_loop(self, answer) -> dict:
        """Run until the plant's run ends, showing progress; the plant's summary (plant_sim's terms)."""

    @abstractmethod
    def stop(self, plant_summary: dict, answer) -> tuple[dict, dict]:
        """Stop the nodes, the recorder last; (the recorder's facts, the consumer's final figures)."""

    @abstractmethod
    def words(self) -> str:
        """How the session ran, for its summary (``composed``, ``processes``, ``hardware bridge to ...``)."""

    def show_progress(self, bar, k: int, extra: str = "") -> None:
        """The progress line at sample ``k``: simulated time, the rate, and ``extra`` (the consumer's words)."""
        total, fs = self.total, self.fs
        rate = k / max(time.perf_counter() - self.wall0, 1e-9)
        bar.show(k / total, f"sim {k / fs:6.2f}/{total / fs:.2f} s  {rate / 1000:5.1f}k samples/s{extra}")

    def wait_live_design(self, answer) -> None:
        """With a live view: wait until it has the experiment's design, so it shows the experiment from its first
        sample (the design reaches a late reader on request, after the blocks streaming in ahead of it when the
        live view, nicer than the loop, is slow to answer: it would have had no live FRF). Tolerant: a live view
        without the design after ``LIVE_DESIGN_S`` gets one line on stderr and the session runs (a viewer never
        stops the session it shows; it shows what it gets)."""
        if self.live is None:
            return
        try:
            self.live.wait_design(answer.experiment_id, LIVE_DESIGN_S)
        except RuntimeError as exc:
            print(f"ambid: {exc}; it shows what it gets", file=sys.stderr, flush=True)

    def loop_summary(self, plant_summary: dict) -> dict:
        """The run's summary where the loop ran alone: the plant's, how it ran and the foreign publishers."""
        return {**plant_summary, "layout": self.words(), "foreign_publishers": self.foreign}

    def final_estimate_at(self, answer) -> float | None:
        """When the consumer had the final FRF (time.perf_counter), where this process knows it."""
        return None


def live_figures(f: dict) -> dict:
    """The FRF consumer's final figures (its ``frf_done`` event) as a session's summary gives them."""
    return {"relative_noise_std": f.get("relative_noise_std"), "periods": f.get("periods_used"),
            "realisations": f.get("realisations_used"), "iso_zone": f.get("iso_zone"),
            "sensitivity_peak": f.get("sensitivity_peak")}


def start_live(cfg: SessionConfig):
    """The live view of ``cfg`` (``live_port``) as a process of its own, started; None without one."""
    if cfg.live_port is None:
        return None
    from ambid_nodes.live_view import LiveProcess

    return LiveProcess(cfg.live_port, cfg.live_host, cfg.namespace, cfg.estimator, session_domain_id(),
                       cfg.session or 0)


#: the most wall seconds a session waits, before its loop, for its live view to have the experiment's design
LIVE_DESIGN_S = 60.0
#: the most wall seconds a session waits, after its loop, for its live view to show the experiment's end
LIVE_CATCH_UP_S = 10.0


def announce_live(live) -> int:
    """Wait for a live view to listen and say where it is; how many readers it adds (0 without one)."""
    if live is None:
        return 0
    print(f"ambid: live view on {live.wait_ready()} (docs/live.md)", file=sys.stderr, flush=True)
    return 1


def preflight(executor, namespace: str, context, report: Callable[[dict], None] | None = None) -> dict[str, list[str]]:
    """{topic: [publishers named]} already on the rig's topics before its session starts (a rig next door, a
    replayed recording, a script left running), found in the session's own ``context`` before any of its nodes
    exists: a listener waits for discovery to settle and for the graph to know each publisher's node
    (:func:`wait_for_discovery`, 1-5 s, up to 10 s while a node's name lags its publisher), so the session's
    participant knows them from then on and its nodes hear them from their first message. The session runs
    unaffected by them (every node acts only on its session's messages); ``report(found)`` names them at
    once (the command's one line). Without ``report`` (a study's sessions: campaign, validate, bench) nobody
    asks: no wait, {}."""
    if report is None:
        return {}
    import rclpy

    from ambid_nodes.identity import endpoint_node, unnamed_endpoint
    from ambid_nodes.watch import SESSION_TOPICS

    probe = rclpy.create_node("session_preflight", namespace=namespace, context=context)
    executor.add_node(probe)
    topics = [probe.resolve_topic_name(t) for t in SESSION_TOPICS]

    def publishers() -> dict[str, list]:  # nothing of the session publishes yet: every publisher there is foreign
        return {t: infos for t in topics if (infos := probe.get_publishers_info_by_topic(t))}

    try:
        wait_for_discovery(executor, probe, named=lambda: all(endpoint_node(i) for infos in publishers().values()
                                                              for i in infos))
        found = {t: sorted({endpoint_node(i) or unnamed_endpoint(i) for i in infos})
                 for t, infos in publishers().items()}
    finally:
        executor.remove_node(probe)
        probe.destroy_node()
    report(found)
    return found


def wait_for_discovery(executor, node, least_s: float = 1.0, most_s: float = 5.0, still_s: float = 1.0,
                       named: Callable[[], bool] | None = None, name_s: float = 5.0) -> None:
    """Spin at least ``least_s``, then until the graph ``node`` sees has not changed for ``still_s`` (at most
    ``most_s`` in all): participants already on the domain are discovered within a fraction of a second on
    one host, later on a loaded one (a node's name and its publishers come a while after its participant: the
    graph compared is the nodes and the topics with their types, so late endpoints count as a change).
    ``named()``: the graph knows the node of every endpoint that matters; rmw's node names travel apart from
    the endpoints and can lag them by more than ``still_s`` on a loaded machine (the preflight's line then named
    "_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_"), so while it is False the wait goes on, up to ``name_s``
    beyond ``most_s``; an endpoint still without its node is then named by its GID (identity.UNNAMED)."""
    start = time.monotonic()
    seen, since = None, start
    while time.monotonic() - start < most_s + (name_s if named is not None else 0.0):
        executor.spin_once(timeout_sec=0.05)
        now = (frozenset(node.get_node_names_and_namespaces()),
               frozenset((t, tuple(types)) for t, types in node.get_topic_names_and_types()))
        if now != seen:
            seen, since = now, time.monotonic()
        elapsed = time.monotonic() - start
        settled = elapsed >= most_s or (elapsed >= least_s and time.monotonic() - since >= still_s)
        if settled and (named is None or named()):
            return
