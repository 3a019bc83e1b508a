"""The live view's cost on the loop, and how soon identify's results follow the last period.

* :func:`live_figures`: an identify session (composed, recorder and consumer
  included) with the live view and a Foxglove client connected, against the
  same session without a live view, rounds interleaved (the order
  alternating): the plant's simulated samples per wall second, with over
  without. The client (:mod:`ambid_cli.bench.foxglove_client`) runs in a
  process and session of its own and subscribes to every channel, as the
  Foxglove app would with the layout open.
* :func:`analysis_figures`: a whole ``identify`` (:func:`ambid_nodes.running.identify.run_identify`):
  wall seconds from the consumer's final FRF (the last period measured) to
  the headline and to the report; beside it, the analysis of the same
  recording as it was done before (``identify_session`` on the file, in this
  process, after the session), with where its time goes.
"""

from __future__ import annotations

import json
import os
import select
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _wait_connected(client: subprocess.Popen, timeout_s: float = 60.0) -> None:
    """Until the client says its connection is open: a session started before it would end, at --quick sizes
    on a loaded machine, before a client still starting had connected (0 messages)."""
    from ambid_cli.bench.foxglove_client import CONNECTED

    ready, _, _ = select.select([client.stdout], [], [], timeout_s)
    line = client.stdout.readline().strip() if ready else ""
    if line != CONNECTED:
        raise RuntimeError(f"the Foxglove client did not connect to the live view within {timeout_s:g} s "
                           f"(it said {line!r})")


def _session(out_dir: Path, overrides: dict, live: bool) -> dict:
    from ambid.excitation.spec import DesignSpec

    from ambid_nodes.running.domain import session_domain_id
    from ambid_nodes.live_view import LiveProcess
    from ambid_nodes.running.plan import SessionConfig
    from ambid_nodes.running.run import run_session

    cfg = SessionConfig(out_dir=out_dir, progress=False, experiment=DesignSpec(**overrides))
    proc = client = run = None
    cpu: dict[str, float | None] = {}
    figures, got = {}, {}
    try:
        if live:
            proc = LiveProcess(0, "127.0.0.1", cfg.namespace, cfg.estimator, session_domain_id())
            url = proc.wait_ready()
            # a session of its own, as the Foxglove app on a desktop (or another machine) has: in the bench's
            # session it would share the loop's scheduling group, which no real viewer does
            client = subprocess.Popen([sys.executable, "-m", "ambid_cli.bench.foxglove_client", url],
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                      start_new_session=True)
            _wait_connected(client)
        cpu["session0"] = time.process_time()
        run = run_session(cfg, live=proc)
        cpu["session"] = time.process_time() - cpu.pop("session0")
    finally:
        figures = proc.stop() if proc is not None else {}
        if client is not None:
            try:
                out, _ = client.communicate(timeout=30)
                got = json.loads(out.strip().splitlines()[-1]) if out.strip() else {}
            except (subprocess.TimeoutExpired, ValueError):
                client.kill()
    if live:
        # what the live view (nicer than the loop) did after the loop is its cost too: its CPU and the client's
        # are counted until they exit
        cpu.update(live=figures.get("cpu_s"), client=got.get("cpu_s"), live_caught_up=run.get("live_caught_up"))
    plant = run["plant"]
    if plant.get("state") != "done":
        raise RuntimeError(f"the session ended in state {plant.get('state')!r}")
    return {"loop_samples_per_s": plant["samples_per_wall_s"], "session_samples_per_s": run["samples_per_wall_s"],
            "wall_s": run["wall_s"], "samples": plant["samples"], "live": figures, "cpu_s": cpu,
            "client_messages": got.get("total"), "client_channels": len(got.get("channels", []))}


def live_figures(work: Path, overrides: dict, repeats: int) -> dict:
    """Loop rate of an identify session with the live view and a client against without, ``repeats`` rounds.

    Returns:
        dict with ``ratio`` (median over rounds of with / without, the plant's samples per wall second),
        ``session_ratio`` (the same of the whole session's rate), ``live_and_client_cpu_share`` (the CPU the
        live view's and the client's processes took from listening and connecting until they exit, catching
        up after the loop included, over the session process's: the load they add, less sensitive to the
        machine's other jobs than the rates), medians of each rate, and the rounds.
    """
    rounds = []
    for r in range(repeats):
        res = {"load_avg_1min": os.getloadavg()[0]}
        for which in (("without", "with") if r % 2 == 0 else ("with", "without")):
            res[which] = _session(work / f"live_{r}_{which}", overrides, which == "with")
        res["ratio"] = res["with"]["loop_samples_per_s"] / res["without"]["loop_samples_per_s"]
        res["session_ratio"] = res["with"]["session_samples_per_s"] / res["without"]["session_samples_per_s"]
        rounds.append(res)
    med = statistics.median
    shares = [(x["with"]["cpu_s"].get("live") or 0.0) + (x["with"]["cpu_s"].get("client") or 0.0)
              for x in rounds]
    cpu_share = med(s / x["with"]["cpu_s"]["session"] for s, x in zip(shares, rounds))
    return {"ratio": med(x["ratio"] for x in rounds), "session_ratio": med(x["session_ratio"] for x in rounds),
            "live_and_client_cpu_share": cpu_share,
            "with_samples_per_s": med(x["with"]["loop_samples_per_s"] for x in rounds),
            "without_samples_per_s": med(x["without"]["loop_samples_per_s"] for x in rounds),
            "client_messages": med(x["with"]["client_messages"] or 0 for x in rounds),
            "dropped_frames": max(x["with"]["live"].get("dropped_frames", 0) for x in rounds),
            "lost_blocks": max(x["with"]["live"].get("lost_blocks", 0) for x in rounds),
            "rounds": rounds}


def analysis_figures(work: Path, overrides: dict) -> dict:
    """How soon a whole identify's results follow its last period, and the analysis as it was before.

    Returns:
        dict with ``headline_after_last_period_s`` and ``report_after_last_period_s`` (wall, from the
        consumer's final FRF), the worker's timing notes, ``before_s`` (identify_session on the recording,
        in this process: the old path, whose time all came after the session) with its ``before_parts_s``.
    """
    from ambid.excitation.spec import DesignSpec
    from ambid.identification import model_fit, pipeline, report
    from ambid.jsonable import to_jsonable

    from ambid_nodes.running.identify import run_identify
    from ambid_nodes.running.plan import SessionConfig

    out = work / "analysis"
    cfg = SessionConfig(out_dir=out, progress=False, experiment=DesignSpec(**overrides))
    shown = {}
    summary = run_identify(cfg, on_headline=lambda s: shown.setdefault("summary", s))
    timing = dict(summary.analysis_timing)
    # before: the recording analysed after the session, in this process, where its time goes
    parts: dict[str, float] = {}
    originals = {}
    for module, name, label in ((pipeline, "read_session_inputs", "read_session_inputs"),
                                (pipeline, "reference_models", "reference_models"),
                                (model_fit, "stabilisation_diagram", "stabilisation_diagram"),
                                (model_fit, "fit_common_denominator", "fit_common_denominator"),
                                (pipeline, "update_rig", "_update"), (report, "write_report", "write_report")):
        originals[module, name] = fn = getattr(module, name)

        def timed(*a, _fn=fn, _name=label, **k):
            t = time.perf_counter()
            try:
                return _fn(*a, **k)
            finally:
                parts[_name] = parts.get(_name, 0.0) + time.perf_counter() - t
        setattr(module, name, timed)
    try:
        t0 = time.perf_counter()
        before = pipeline.identify_session(summary.recording.path, work / "analysis_before", estimator=cfg.estimator)
        before_s = time.perf_counter() - t0
    finally:
        for (module, name), fn in originals.items():
            setattr(module, name, fn)
    early = shown["summary"].identification if "summary" in shown else None
    same = early is not None and all(to_jsonable(getattr(before, k)) == to_jsonable(getattr(early, k))
                                     for k in ("frf_error", "fit", "update", "sensitivity", "noise", "modes_vs_true"))
    return {**timing, "before_s": before_s, "before_parts_s": parts, "same_numbers": same,
            "state": summary.state, "session_samples_per_s": summary.simulated_samples_per_wall_s}
