"""``ambid identify --live PORT`` with a Foxglove WebSocket client connected while it runs.

The client (ambid_cli.bench.foxglove_client: the protocol over the ``websockets`` package, as the Foxglove
app speaks it) subscribes to every channel the live view advertises and decodes every message. Checked: the
channels of the live FRF (one per entry of the 4 x 4 matrix), the time signals, an orbit per bearing, the
levels, the progress, the nodes' status and the events are advertised and send messages; the live FRF's
last estimate is the session's final FRF (frf.npz) bit for bit; and the same session without a live view
gives identical results.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from ambid.channels import RADIAL

from ambid_cli.bench.foxglove_client import follow

REPO = Path(__file__).resolve().parents[2]
SHORT = ["--band", "20", "400", "--resolution", "20", "--periods", "2", "--realisations", "2",
         "--transient-periods", "1", "--seed", "4", "--no-progress", "--no-report"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _identify(env, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "ambid_cli.cli", "identify", "--out", str(out), *SHORT, *extra],
                            env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, ros_env_module):
    root = tmp_path_factory.mktemp("live")
    port = _free_port()
    got: dict = {"channels": [], "messages": {}}

    def on_message(topic, t_ns, msg):
        got["messages"].setdefault(topic, []).append(msg)

    proc = _identify(ros_env_module, root / "live", "--live", str(port))
    client = threading.Thread(target=lambda: asyncio.run(follow(f"ws://127.0.0.1:{port}", on_message, 300.0,
                                                                got["channels"].extend)))
    client.start()
    out, err = proc.communicate(timeout=900)
    client.join(60)
    assert proc.returncode == 0, err[-3000:]
    plain = _identify(ros_env_module, root / "plain")
    p_out, p_err = plain.communicate(timeout=900)
    assert plain.returncode == 0, p_err[-3000:]
    return dict(root=root, got=got, stdout=out, plain_stdout=p_out)


def test_the_client_gets_every_channel_of_the_live_view(sessions):
    got = sessions["got"]
    topics = {c["topic"] for c in got["channels"]}
    frf = {f"/amb/live/frf/{o}/{i}" for o in RADIAL.outputs for i in RADIAL.inputs}
    wanted = frf | {"/amb/live/signals", "/amb/live/orbit/a", "/amb/live/orbit/b", "/amb/live/progress",
                    "/amb/live/status/frf_consumer", "/amb/live/events"} | {f"/amb/live/levels/{o}" for o in RADIAL.outputs}
    assert wanted <= topics, wanted - topics
    live = json.loads((sessions["root"] / "live" / "summary.json").read_text())["live"]
    for topic in wanted:
        assert got["messages"].get(topic), f"no message on {topic}; the live view's figures: {live}"
    sig = got["messages"]["/amb/live/signals"]
    # at most display_rate_hz (30) a wall second: the session runs faster than real time, a viewer draws ~30
    assert set(RADIAL.outputs) | set(RADIAL.inputs) <= set(sig[-1]) and len(sig) >= 2
    assert [m["t_s"] for m in sig] == sorted(m["t_s"] for m in sig) and live["frames_thinned"] > 0
    orbit = got["messages"]["/amb/live/orbit/b"][-1]
    assert (orbit["x_channel"], orbit["y_channel"]) == ("y_b_x", "y_b_y") and len(orbit["x_m"]) == len(orbit["y_m"])
    assert any(e["level"] == 2 and "frf_done" in e["message"] for e in got["messages"]["/amb/live/events"])
    progress = got["messages"]["/amb/live/progress"][-1]
    assert progress["finished"] and progress["lost_blocks"] == 0 and progress["dropped_frames"] == 0, progress
    assert progress["frf_gaps"] == 0 and progress["periods_done"] == progress["periods"], progress


def test_the_live_frf_ends_as_the_sessions_frf(sessions):
    saved = np.load(sessions["root"] / "live" / "frf.npz")
    for i, out in enumerate(RADIAL.outputs):
        for j, inp in enumerate(RADIAL.inputs):
            final = [m for m in sessions["got"]["messages"][f"/amb/live/frf/{out}/{inp}"] if m["complete"]]
            assert final, f"no complete estimate of {out}/{inp}"
            m = final[-1]
            np.testing.assert_array_equal(m["freq_hz"], saved["freq_hz"])
            np.testing.assert_array_equal(np.array(m["real"]) + 1j * np.array(m["imag"]), saved["frf"][:, i, j])
            assert m["records"] == 4 and m["realisations"] == 2   # P = 2 periods in M = 2 realisations
    # the estimates came while it ran (one after every block that completed a record), and the client got each
    live = json.loads((sessions["root"] / "live" / "summary.json").read_text())["live"]
    counts = [len(v) for k, v in sessions["got"]["messages"].items() if k.startswith("/amb/live/frf/")]
    assert live["estimates"] >= 2 and min(counts) >= live["estimates"], (live["estimates"], counts)


def test_results_are_identical_with_and_without_the_live_view(sessions):
    root = sessions["root"]
    a = json.loads((root / "live" / "identification.json").read_text())
    b = json.loads((root / "plain" / "identification.json").read_text())
    for key in ("frf_error", "noise", "fit", "modes_vs_true", "update", "sensitivity"):
        assert a[key] == b[key], key
    fa, fb = np.load(root / "live" / "frf.npz"), np.load(root / "plain" / "frf.npz")
    for key in fa.files:
        np.testing.assert_array_equal(fa[key], fb[key], err_msg=key)
    summary = json.loads((root / "live" / "summary.json").read_text())
    assert summary["live"]["clients"] >= 1 and summary["live"]["frames_sent"] > 0
    assert summary["live"]["dropped_frames"] == 0 and summary["live"]["lost_blocks"] == 0
    assert "live view:" in sessions["stdout"] and "results" in sessions["stdout"]


def test_graph_live_shows_signals_orbits_and_status(tmp_path, ros_env_module):
    """A client that connects once the live view listens (here: while a long graph runs, however loaded the
    machine) gets the signals and an orbit per bearing on the session's own clock; ^C ends the graph with the live
    view's figures. ``--live 0``: the graph says the port it got (no port picked here that another socket could
    take meanwhile)."""
    got: dict = {"channels": [], "messages": {}}
    run = subprocess.Popen([sys.executable, "-m", "ambid_cli.cli", "graph", "--sim-seconds", "3000", "--live", "0"],
                           env=ros_env_module, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, start_new_session=True)
    lines: dict[str, list[str]] = {"out": [], "err": []}
    readers = [threading.Thread(target=lambda k=k, f=f: lines[k].extend(f), daemon=True)
               for k, f in (("out", run.stdout), ("err", run.stderr))]
    for r in readers:
        r.start()
    topics = ("/amb/live/signals", "/amb/live/orbit/a", "/amb/live/orbit/b")
    client = None
    try:
        end = time.monotonic() + 300
        url = None
        while url is None and time.monotonic() < end and run.poll() is None:
            url = next((ln.split("live view on ")[1].split()[0] for ln in list(lines["out"])
                        if "live view on ws://" in ln), None)
            time.sleep(0.1)
        if url is not None:
            client = threading.Thread(target=lambda: asyncio.run(follow(
                url, lambda topic, t, msg: got["messages"].setdefault(topic, []).append(msg), 60.0,
                got["channels"].extend)))
            client.start()
        while time.monotonic() < end and run.poll() is None and not (
                all(got["messages"].get(t) for t in topics) and len(got["messages"]["/amb/live/signals"]) > 20):
            time.sleep(0.2)
        if run.poll() is not None or url is None:
            run.kill()
            run.wait()
            pytest.fail(f"the graph ended (exit code {run.returncode}) before the client heard it (url {url}): "
                        f"{ {t: len(got['messages'].get(t, [])) for t in topics} }; "
                        f"{''.join(lines['out'])[-1500:]} {''.join(lines['err'])[-2500:]}")
        os.killpg(run.pid, signal.SIGINT)   # ^C, as a user ends it
        run.wait(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait()
    for r in readers:
        r.join(10)
    if client is not None:
        client.join(60)
    out, err = "".join(lines["out"]), "".join(lines["err"])
    assert run.returncode == 130, err[-3000:]   # interrupted, as ^C says
    assert "interrupted; every node stopped" in err
    assert "live view:" in out and "blocks lost" in out
    for topic in topics:
        assert got["messages"].get(topic), f"no message on {topic}"
    assert not any("/frf/" in c["topic"] for c in got["channels"])   # no experiment, no FRF
    t = [m["t_s"] for m in got["messages"]["/amb/live/signals"]]
    assert t == sorted(t) and t[-1] > t[0]   # the session's own clock


def test_identify_processes_live_view_sees_the_whole_experiment(tmp_path, ros_env_module):
    """With ``--processes`` the loop starts only once the live view (a process of its own) has the design: it
    takes every block of the experiment, every period in its live FRF, no gap, and finishes with the session."""
    run = _identify(ros_env_module, tmp_path / "p", "--processes", "--live", "0")
    out, err = run.communicate(timeout=900)
    assert run.returncode == 0, err[-3000:]
    s = json.loads((tmp_path / "p" / "summary.json").read_text())
    live = s["live"]
    assert live["finished"] and live["periods_done"] == live["periods"] > 0, live
    assert live["lost_blocks"] == 0 and live["frf_gaps"] == 0 and live["rejected_blocks"] == 0, live
    assert live["estimates"] >= 2 and live["records"] == 4 and not live["problems"], live
    assert s["layout"] == "processes" and "live view:" in out


@pytest.mark.parametrize("kind", ["composed", "processes", "hardware"])
def test_a_live_view_without_the_design_costs_a_line_not_the_session(kind, capsys):
    """Every layout waits for the live view's design the one way (docs/live.md): up to 60 s, then one line and the
    session runs on (a viewer never stops the session it shows)."""
    from types import SimpleNamespace

    from ambid_nodes.running.composed import ComposedLayout
    from ambid_nodes.running.hardware import HardwareLayout
    from ambid_nodes.running.processes import ProcessesLayout

    asked = []

    class NeverGetsIt:   # a live view whose design never comes: LiveProcess.wait_design's timeout
        def wait_design(self, experiment_id: str, timeout_s: float) -> None:
            asked.append(timeout_s)
            raise RuntimeError(f"the live view did not get the design of {experiment_id} within {timeout_s:g} s")

    cls = {"composed": ComposedLayout, "processes": ProcessesLayout, "hardware": HardwareLayout}[kind]
    layout = cls.__new__(cls)   # the step alone: no graph, no plan
    layout.live = NeverGetsIt()
    layout.wait_live_design(SimpleNamespace(experiment_id="exp-1"))   # returns: the session goes on
    err = capsys.readouterr().err.strip().splitlines()
    assert asked == [60.0]
    assert err == ["ambid: the live view did not get the design of exp-1 within 60 s; it shows what it gets"]
    layout.live = None
    layout.wait_live_design(SimpleNamespace(experiment_id="exp-2"))   # no live view: nothing to wait for
    assert asked == [60.0] and not capsys.readouterr().err
