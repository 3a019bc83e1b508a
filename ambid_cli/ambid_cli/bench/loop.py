"""Lock-step loop throughput of plant_sim + position_controller beside the bare ping-pong.

Each round runs, per layout, the bare ping-pong and the real loop with the
same number of samples back to back (the order alternating between rounds),
so the ratio of the two is measured under the same load; the machine is
shared, the ratios are the figures to trust, the absolute rates vary with
the load average.
"""

from __future__ import annotations

import os
import statistics
import time

from ambid.excitation.spec import DesignSpec
from ambid.plant.rig import make_rig
from ambid.session_id import new_session_id

from ambid_cli.bench.pingpong import run_pingpong_composed, run_pingpong_processes

from ambid_nodes.running.domain import session_domain_id
from ambid_nodes.running.plan import SessionConfig
from ambid_nodes.running.run import run_session

LAYOUTS = ("composed", "processes")


def _ours(layout: str, sim_seconds: float, controller: str = "") -> dict:
    # a session, as identify and graph run: the loop pump checks each message's publisher GID
    cfg = SessionConfig(loop_seconds=sim_seconds, controller=controller, session=new_session_id(),
                        experiment=DesignSpec(seed=0),
                        nonlinear_magnets=False, progress=False, processes=layout == "processes")
    cpu0 = time.process_time()
    s = run_session(cfg)
    if s.get("state") != "done":
        raise RuntimeError(f"the {layout} loop ended in state {s.get('state')!r}: {s}")
    out = {k: s[k] for k in ("samples", "wall_s", "samples_per_wall_s")}
    if layout == "composed":  # this process's CPU, node set-up included (see _short_run_cpu)
        out["cpu_s_with_setup"] = time.process_time() - cpu0
    return out


def _short_run_cpu() -> tuple[float, int]:
    """(CPU time [s], samples) of a composed run of 0.01 s: mostly the set-up (nodes, stability check)."""
    cpu0 = time.process_time()
    s = run_session(SessionConfig(loop_seconds=0.01, session=new_session_id(), experiment=DesignSpec(seed=0),
                                  nonlinear_magnets=False, progress=False))
    return time.process_time() - cpu0, s["samples"]


def _bare(layout: str, n_samples: int) -> dict:
    run = run_pingpong_composed if layout == "composed" else run_pingpong_processes
    s = run(n_samples, session_domain_id())
    return {k: s[k] for k in ("samples", "wall_s", "samples_per_wall_s", "cpu_s") if k in s}


def loop_figures(sim_seconds: float = 2.0, repeats: int = 3, layouts: tuple[str, ...] = LAYOUTS,
                 user_controller: str = "") -> dict:
    """Simulated samples per wall second of the loop and of the bare ping-pong, per layout.

    Args:
        sim_seconds: simulated time per run [s], >= 0.05 (samples = sim_seconds / dt of the default rig).
        repeats: rounds; each round runs bare and ours once per layout, adjacent in time.
        layouts: any of ``"composed"``, ``"processes"``.
        user_controller: a controller file; composed, each round also runs the loop with it
            (``user_samples_per_s``, ``user_ratio`` against the same round's ping-pong).

    Returns:
        dict layout -> {``ours_samples_per_s`` (median), ``bare_samples_per_s`` (median),
        ``ratio`` (median over rounds of ours / bare in that round), ``rounds`` (each run's
        figures and the 1-minute load average)}, plus ``samples`` per run. Composed, also
        ``cpu_ratio``: bare over ours in CPU time per sample (this process, all threads; ours less
        a 100-sample run's, i.e. the set-up), less sensitive to the machine's load than the rates.
    """
    if sim_seconds < 0.05 or repeats < 1:
        raise ValueError(f"loop_figures: sim_seconds must be >= 0.05 and repeats >= 1, got {sim_seconds}, {repeats}")
    unknown = set(layouts) - set(LAYOUTS)
    if unknown:
        raise ValueError(f"loop_figures: unknown layouts {sorted(unknown)}; use {LAYOUTS}")
    n = int(round(sim_seconds / make_rig().dt))
    out: dict = {"samples": n, "sim_seconds": sim_seconds}
    rounds: dict[str, list] = {layout: [] for layout in layouts}
    for r in range(repeats):
        for layout in layouts:
            order = ("bare", "ours") if r % 2 == 0 else ("ours", "bare")
            res = {"load_avg_1min": os.getloadavg()[0]}
            for which in order:
                res[which] = _bare(layout, n) if which == "bare" else _ours(layout, sim_seconds)
            res["ratio"] = res["ours"]["samples_per_wall_s"] / res["bare"]["samples_per_wall_s"]
            if layout == "composed" and user_controller:
                res["user"] = _ours(layout, sim_seconds, user_controller)
                res["user_ratio"] = res["user"]["samples_per_wall_s"] / res["bare"]["samples_per_wall_s"]
            if layout == "composed":
                cpu_short, n_short = _short_run_cpu()
                res["ours"]["cpu_us_per_sample"] = 1e6 * max(res["ours"]["cpu_s_with_setup"] - cpu_short,
                                                             1e-6) / (n - n_short)
                res["bare"]["cpu_us_per_sample"] = 1e6 * res["bare"]["cpu_s"] / n
                res["cpu_ratio"] = res["bare"]["cpu_us_per_sample"] / max(res["ours"]["cpu_us_per_sample"], 1e-9)
            rounds[layout].append(res)
    for layout, rs in rounds.items():
        out[layout] = {
            "ours_samples_per_s": statistics.median(x["ours"]["samples_per_wall_s"] for x in rs),
            "bare_samples_per_s": statistics.median(x["bare"]["samples_per_wall_s"] for x in rs),
            "ratio": statistics.median(x["ratio"] for x in rs),
            "rounds": rs,
        }
        if layout == "composed" and user_controller:
            out[layout].update(user_samples_per_s=statistics.median(x["user"]["samples_per_wall_s"] for x in rs),
                               user_ratio=statistics.median(x["user_ratio"] for x in rs))
        if layout == "composed":
            out[layout].update(
                ours_cpu_us_per_sample=statistics.median(x["ours"]["cpu_us_per_sample"] for x in rs),
                bare_cpu_us_per_sample=statistics.median(x["bare"]["cpu_us_per_sample"] for x in rs),
                cpu_ratio=statistics.median(x["cpu_ratio"] for x in rs))
    return out
