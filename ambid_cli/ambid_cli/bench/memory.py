"""Peak memory of a session and of one six times longer, each in a fresh child process.

Two kinds of session:

* offline: :func:`ambid.frf.offline.frf_from_session` on a simulated session
  file (:func:`ambid_cli.bench.offline.write_simulated_session`) of the
  experiment alone with M and 6 M realisations: exactly six times longer;
* live: the composed ``identify`` session (every node in one process,
  recorder and FRF consumer included) with M and 6 M realisations; the
  lift-off before the experiment is the same in both, so the whole session
  is less than six times longer (both durations are reported).

The peak is the child's high-water resident size (``VmHWM``); ``baseline_mb`` is its resident size
after the imports, before the work, so ``growth_mb`` is what the session added.
As a child: ``python -m ambid_cli.bench.memory offline FILE`` or
``python -m ambid_cli.bench.memory live OUT_DIR '{DesignSpec overrides}'``,
printing one JSON line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


def _status_mb(key: str) -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024  # kB
    raise RuntimeError(f"no {key} in /proc/self/status")


def _rss_mb() -> float:
    return _status_mb("VmRSS")


def _peak_mb() -> float:
    # VmHWM, not ru_maxrss: Linux carries ru_maxrss over exec, so a child would report the
    # (larger) resident size of the bench process it was forked from
    return _status_mb("VmHWM")


def _child(argv: list[str]) -> dict:
    kind = argv[0]
    if kind == "offline":
        from ambid.frf.offline import frf_from_session

        base = _rss_mb()
        frf_from_session(argv[1])
        return {"baseline_mb": base, "peak_mb": _peak_mb()}
    if kind == "live":
        import importlib

        from ambid.excitation.spec import DesignSpec
        from ambid_nodes.running.plan import SessionConfig
        from ambid_nodes.running.run import run_session

        for node in ("excitation_generator", "frf_consumer", "plant_sim", "position_controller", "recorder"):
            importlib.import_module(f"ambid_nodes.{node}")  # imported before the baseline, as the offline child
        base = _rss_mb()
        run = run_session(SessionConfig(out_dir=Path(argv[1]), progress=False,
                                                 experiment=DesignSpec(**json.loads(argv[2]))))
        return {"baseline_mb": base, "peak_mb": _peak_mb(), "simulated_s": run["simulated_s"],
                "wall_s": run["wall_s"], "state": run["plant"]["state"]}
    raise ValueError(f"unknown child kind {kind!r}; use offline or live")


def _start_child(args: tuple[str, ...], domain_id: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "ambid_cli.bench.memory", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, ROS_DOMAIN_ID=str(domain_id)))


def _child_result(proc: subprocess.Popen, timeout_s: float = 900.0) -> dict:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    lines = [line for line in out.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"memory child {proc.args[3:]} failed (exit {proc.returncode}): {err[-2000:]}")
    res = json.loads(lines[-1])
    res["growth_mb"] = res["peak_mb"] - res["baseline_mb"]
    return res


def _compare(short: dict, long: dict) -> dict:
    return {"short": short, "long": long, "peak_ratio": long["peak_mb"] / short["peak_mb"],
            "growth_ratio": (long["growth_mb"] / short["growth_mb"]) if short["growth_mb"] > 0 else None,
            "length_ratio": long["simulated_s"] / short["simulated_s"]}


def memory_figures(work_dir: str | os.PathLike, design_kwargs: dict, live_overrides: dict,
                   factor: int = 6) -> dict:
    """Peak memory of the offline FRF and of a live identify session, each short and factor x longer.

    The four children run side by side (a peak resident size does not depend on the CPU share),
    the live ones each on its own DDS domain.

    Args:
        work_dir: directory for the session files (the offline ones are deleted after use).
        design_kwargs: :func:`ambid_cli.bench.offline.make_design` overrides of the short offline session.
        live_overrides: ``DesignSpec`` overrides of the short live session.
        factor: length factor of the long sessions (their realisations M x factor).

    Returns:
        dict with ``offline`` and ``live``, each {``short``, ``long`` (``baseline_mb``, ``peak_mb``,
        ``growth_mb``, ``simulated_s``, ...), ``peak_ratio``, ``growth_ratio``, ``length_ratio``};
        ``live`` is {``available``: False, ``reason``} when the session runner is missing.
    """
    from ambid_cli.bench.offline import make_design, write_simulated_session
    from ambid_nodes.running.domain import session_domain_id

    work_dir = Path(work_dir)
    try:
        import ambid_nodes.running.run  # noqa: F401
        live_reason = None
    except ImportError as exc:
        live_reason = f"the identify session runner cannot be imported: {exc}"
    m_off = int(make_design(**design_kwargs).n_realisations)
    m_live = int(live_overrides.get("n_realisations", 1))
    info, paths = {}, {}
    for label, m in (("short", m_off), ("long", factor * m_off)):
        paths[label] = work_dir / f"memory_{label}.mcap"
        # the experiment only, no lead-in or tail: the long session is exactly factor x longer
        info[label] = write_simulated_session(paths[label], make_design(**{**design_kwargs, "n_realisations": m}),
                                              start_index=0, tail_samples=0)
    d = session_domain_id()
    procs = {("offline", label): _start_child(("offline", str(paths[label])), d) for label in paths}
    if live_reason is None:
        for i, (label, m) in enumerate((("short", m_live), ("long", factor * m_live))):
            args = ("live", str(work_dir / f"live_{label}"), json.dumps({**live_overrides, "n_realisations": m}))
            procs["live", label] = _start_child(args, d + 1 + i if d < 231 else d - 1 - i)
    try:
        runs = {key: _child_result(p) for key, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    for label, path in paths.items():
        runs["offline", label].update(simulated_s=info[label]["simulated_s"], file_bytes=info[label]["file_bytes"])
        path.unlink()
    out = {"offline": _compare(runs["offline", "short"], runs["offline", "long"])}
    if live_reason is None:
        out["live"] = {"available": True, "config": live_overrides,
                       **_compare(runs["live", "short"], runs["live", "long"])}
    else:
        out["live"] = {"available": False, "reason": live_reason}
    return out


if __name__ == "__main__":
    print(json.dumps(_child(sys.argv[1:])), flush=True)
