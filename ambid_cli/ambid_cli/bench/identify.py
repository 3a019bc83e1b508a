"""Real-time factor of a full ``identify`` session: every node of the graph composed, recorder included.

Runs the session runner of ``ambid identify`` (:func:`ambid_nodes.running.run.run_session`)
as it is, on its default experiment unless told otherwise; the offline
identification after the recording is not part of this figure.
"""

from __future__ import annotations

import os
from pathlib import Path

from ambid.excitation.spec import DesignSpec


def identify_figures(out_dir: str | os.PathLike, overrides: dict | None = None) -> dict:
    """Run one composed identify session and time it.

    Args:
        out_dir: directory for the session's recording.
        overrides: DesignSpec fields to change (e.g. a shorter experiment); None = the default session.

    Returns:
        dict with ``available`` (False, with ``reason``, when the session runner is missing),
        ``simulated_s``, ``wall_s`` (the whole session: set-up, discovery, loop, closing the recording),
        ``real_time_factor`` (simulated_s / wall_s), ``loop_real_time_factor`` (the plant's own rate over
        the sample rate, loop only), ``samples``, ``state``, ``levitated``.
    """
    try:
        from ambid_nodes.running.plan import SessionConfig
        from ambid_nodes.running.run import run_session
    except ImportError as exc:
        return {"available": False, "reason": f"the identify session runner cannot be imported: {exc}"}
    cfg = SessionConfig(out_dir=Path(out_dir), progress=False, experiment=DesignSpec(**(overrides or {})))
    run = run_session(cfg)
    plant = run["plant"]
    fs = plant["samples"] / plant["simulated_s"]
    return {
        "available": True,
        "config": {k: v for k, v in (overrides or {}).items()},
        "samples": plant["samples"],
        "simulated_s": run["simulated_s"],
        "wall_s": run["wall_s"],
        "real_time_factor": run["simulated_s"] / run["wall_s"],
        "loop_samples_per_wall_s": plant["samples_per_wall_s"],
        "loop_real_time_factor": plant["samples_per_wall_s"] / fs,
        "state": plant["state"],
        "levitated": plant.get("levitated"),
    }
