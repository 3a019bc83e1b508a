"""The one entry to running a session: :func:`run_session` picks its layout and runs it.

``ambid identify``, ``campaign``, ``validate``, ``commission``, ``tune``'s coverage and the benches all run
their sessions through here (``ambid graph`` runs the loop alone, through the same layouts).
"""

from __future__ import annotations

from typing import Callable

from ambid_nodes.running.composed import ComposedLayout
from ambid_nodes.running.hardware import HardwareLayout
from ambid_nodes.running.layout import Layout
from ambid_nodes.running.plan import SessionConfig, SessionPlan, plan_session
from ambid_nodes.running.processes import ProcessesLayout


def layout_for(cfg: SessionConfig, plan: SessionPlan, report_foreign: Callable[[dict], None] | None = None,
               live=None, early=None) -> Layout:
    """The layout ``cfg`` asks for: processes (``cfg.processes``, with the bridge where ``cfg.hardware``
    names a target), hardware (``cfg.hardware``), else composed. ``early`` (an
    :class:`ambid.identification.early.EarlyAnalysis`) is fed by the layouts in this process only."""
    if cfg.processes:
        return ProcessesLayout(cfg, plan, report_foreign, live)
    kind = HardwareLayout if cfg.hardware else ComposedLayout
    return kind(cfg, plan, report_foreign, live, early=early)


def run_session(cfg: SessionConfig, plan: SessionPlan | None = None,
                report_foreign: Callable[[dict], None] | None = None, live=None, early=None) -> dict:
    """Run the session ``cfg`` on the graph; the run's facts (:func:`ambid_nodes.running.plan.run_facts`,
    no offline analysis).

    ``plan`` (default :func:`~ambid_nodes.running.plan.plan_session`) is what the nodes run: one rig, one
    controller, one design. ``report_foreign`` is told the foreign publishers found on the rig's topics
    before anything starts; ``live`` (a started :class:`ambid_nodes.live_view.LiveProcess`) sees the whole
    experiment; ``early`` see :func:`layout_for`.
    """
    return layout_for(cfg, plan_session(cfg) if plan is None else plan, report_foreign, live, early).run()
