"""docs/campaign.md's cluster: a Dask scheduler and two workers started exactly as the doc tells a cluster's
owner (each in a shell that sourced ambid's set-up), a campaign run on them with the doc's command, its
printed table as the doc shows it, and its result equal to the local cluster's for the same options.

The local campaign is also ``ambid campaign``'s own test on the spinning rig (one campaign of the same two speeds
and options, run once for both): the first bending mode's forward and backward whirl identified within 0.5 % of
the true rig's with the right direction; a campaign continued in its folder runs only the speeds it lacks; other
settings in the same folder are refused."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
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


def _campaign(out: Path, *speeds: str, extra=()) -> subprocess.CompletedProcess:
    # its sessions' domains 223..230: test_validate_command's are 215..222 (the two may run at once)
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", "campaign", "--speeds-rpm", *speeds,
                           "--domain-base", "223",
                           "--rig", str(REPO / "rigs" / "spinning.yaml"), "--out", str(out), "--realisations", "1",
                           "--no-progress", *(extra or ("--resolution", "10"))],
                          env=dict(os.environ), cwd=REPO, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def local_campaign(tmp_path_factory) -> dict:
    """The doc's campaign (0 and 12000 rpm, one realisation, 10 Hz lines, the spinning rig) on the local cluster:
    12000 rpm first, then continued in its folder with both speeds."""
    out = tmp_path_factory.mktemp("local") / "campaign"
    first = _campaign(out, "12000")
    assert first.returncode == 0, first.stderr[-2000:]
    mcap_12k = out / "rpm_12000" / "session.mcap"
    stamp = mcap_12k.stat().st_mtime_ns
    proc = _campaign(out, "0", "12000")
    assert proc.returncode == 0, proc.stderr[-2000:]
    return dict(out=out, proc=proc, kept=mcap_12k.stat().st_mtime_ns == stamp)


def test_campaign_identifies_the_whirl_and_continues_where_it_stopped(local_campaign):
    out, proc = local_campaign["out"], local_campaign["proc"]
    # continued with one more speed: 12000 rpm is kept as it was, 0 rpm runs
    assert "12000 rpm: done before, kept" in proc.stderr and local_campaign["kept"]
    camp = json.loads((out / "campbell.json").read_text())
    assert [r["speed_rpm"] for r in camp["speeds"]] == [0.0, 12000.0]
    still, spin = (r["first_bending"] for r in camp["speeds"])
    assert still["true"]["whirl"] == still["identified"]["whirl"] == "standing"
    assert spin["true"]["whirl"] == spin["identified"]["whirl"] == "split"
    for fb in (still, spin):
        assert abs(fb["backward_error"]) < 0.005 and abs(fb["forward_error"]) < 0.005
    # the true split at 12,000 rpm is real: backward below forward by several Hz
    assert spin["true"]["forward_hz"] - spin["true"]["backward_hz"] > 5.0
    assert spin["identified"]["forward_hz"] - spin["identified"]["backward_hz"] > 5.0
    assert camp["first_bending_whirl_right"] is True and camp["first_bending_max_error"] < 0.005
    # every identified first-bending frequency carries identify's 95 % interval, and the campaign counts how
    # often those hold the true rig's (2 speeds x 2 whirls)
    for fb in (still, spin):
        for side in ("backward", "forward"):
            lo, hi = fb["identified"][f"{side}_hz_ci95"]
            assert lo < fb["identified"][f"{side}_hz"] < hi and fb[f"{side}_covered"] in (True, False)
    held, n = camp["first_bending_ci_covered"]
    assert n == 4 and f"hold the true frequency {held} of 4 times" in proc.stdout
    # the critical speeds lie where the predicted branches cross 1X
    for c in camp["critical_speeds"]:
        assert abs(c["freq_hz"] - c["speed_rpm"] / 60.0) < 1e-9
    assert (out / "report" / "campbell.png").stat().st_size > 10_000
    assert "| 12000 |" in proc.stdout


def _first_bending(out: Path) -> list[dict]:
    camp = json.loads((out / "campbell.json").read_text())
    return [(r["speed_rpm"], r["first_bending"]["identified"]) for r in camp["speeds"]]


def test_campaign_on_a_cluster_started_as_the_doc_says(local_campaign, tmp_path):
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
    # the same options on the local cluster give the same campaign: its folder's settings (rig, controller, band,
    # resolution, realisations, seed) and speeds are the doc's command's, and its first bending mode is the same
    cluster, local = wd / "campaign_cluster", local_campaign["out"]
    assert json.loads((cluster / "campaign.json").read_text()) == json.loads((local / "campaign.json").read_text())
    assert _first_bending(cluster) == _first_bending(local)


def test_a_campaign_folder_refuses_other_settings(local_campaign):
    # the same folder with other settings is refused, nothing run
    proc = _campaign(local_campaign["out"], "0", extra=("--resolution", "20"))
    assert proc.returncode == 2 and "other settings" in proc.stderr
