"""docs/campaign.md's cluster: a Dask scheduler and two workers started exactly as the doc tells a cluster's
owner (each in a shell that sourced ambid's set-up), a campaign run on them with the doc's command, its
printed table as the doc shows it, and its result equal to the local cluster's for the same options."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

from doc_blocks import REPO, checkout_paths, commands, mismatch, parse

DOC = REPO / "docs" / "campaign.md"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cluster_blocks():
    blocks = [b for b in parse(DOC) if b.markers.get("run by") == "tests/docs/test_dask_cluster.py"]
    table, scheduler, workers, campaign = blocks
    assert "dask scheduler" in scheduler.text and "dask worker" in workers.text and "--scheduler" in campaign.text
    return table, scheduler, workers, campaign


#: the sessions' ROS domains 231 and 232 (workers 0 and 1): tests/nodes' campaign and validate hold 215..230
#: and may run at the same time under pytest-xdist
DOMAIN_BASE = ("--domain-base", "231")


def _script(block, port: int) -> str:
    # the doc's host and port are the only things changed (this host, a port free now), and the campaign's
    # ROS domains named so they stay clear of the suite's other Dask sessions
    script = checkout_paths("\n".join(commands(block))).replace("SCHEDULER_HOST", "127.0.0.1").replace(
        "8786", str(port))
    return script + (" " + " ".join(DOMAIN_BASE) if "--scheduler" in script else "")


def _start(script: str, cwd: Path, log: Path) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k in ("PATH", "HOME", "LANG", "TMPDIR", "USER")}
    env["PATH"] = ":".join(p for p in env.get("PATH", "").split(":") if "/.venv/" not in p)  # a fresh shell
    return subprocess.Popen(["bash", "-e", "-c", script], cwd=cwd, env=env, stdout=log.open("w"),
                            stderr=subprocess.STDOUT, start_new_session=True)


def _workers_ready(port: int, n: int, deadline: float) -> None:
    from dask.distributed import Client

    while time.monotonic() < deadline:
        try:
            with Client(f"tcp://127.0.0.1:{port}", timeout="5s") as c:
                if len(c.scheduler_info()["workers"]) >= n:
                    return
        except OSError:
            pass
        time.sleep(1.0)
    raise AssertionError(f"{n} workers never joined the scheduler on port {port}")


def _first_bending(out: Path) -> list[dict]:
    camp = json.loads((out / "campbell.json").read_text())
    return [(r["speed_rpm"], r["first_bending"]["identified"]) for r in camp["speeds"]]


def test_campaign_on_a_cluster_started_as_the_doc_says(tmp_path):
    ros_env = dict(os.environ)
    table, scheduler, workers, campaign = _cluster_blocks()
    port = _free_port()
    wd = tmp_path / "host"
    wd.mkdir()
    (wd / "rigs").symlink_to(REPO / "rigs")
    procs = []
    try:
        procs.append(_start(_script(scheduler, port), wd, tmp_path / "scheduler.log"))
        procs.append(_start(_script(workers, port), wd, tmp_path / "workers.log"))
        _workers_ready(port, 2, time.monotonic() + 300)
        run = subprocess.run(["bash", "-e", "-c", _script(campaign, port)], cwd=wd, env=ros_env,
                             capture_output=True, text=True, timeout=900)
        logs = "".join(p.read_text()[-2000:] for p in (tmp_path / "scheduler.log", tmp_path / "workers.log"))
        assert run.returncode == 0, run.stderr[-3000:] + logs
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGTERM)
                p.wait(timeout=30)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                os.killpg(p.pid, signal.SIGKILL)
    # the table and verdict docs/campaign.md shows
    assert mismatch(table.text.splitlines(), run.stdout) is None, mismatch(table.text.splitlines(), run.stdout)
    # both sessions ran on the cluster's workers, not on a local cluster of this process
    worker_log = (tmp_path / "workers.log").read_text()
    assert "Registered to" in worker_log
    # the same options on the local cluster give the same campaign
    cmd = commands(campaign)[0]
    local_cmd = (cmd.split(" --scheduler")[0].replace("campaign_cluster", "campaign_local") + " --jobs 2 "
                 + " ".join(DOMAIN_BASE))
    local = subprocess.run(["bash", "-e", "-c", checkout_paths(local_cmd)], cwd=wd, env=ros_env,
                           capture_output=True, text=True, timeout=900)
    assert local.returncode == 0, local.stderr[-3000:]
    assert _first_bending(wd / "campaign_cluster") == _first_bending(wd / "campaign_local")
