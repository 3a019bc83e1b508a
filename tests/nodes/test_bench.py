"""ambid bench --quick: every section runs and reports its figures (a smoke test, nothing is timed)."""

from __future__ import annotations

import argparse
import json
import math

from ambid_cli.commands import bench


def test_quick_bench_reports_every_figure_as_a_positive_number(ros, tmp_path, capfd, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros.domain_id))  # the bench's graphs on the test's own domain
    out = tmp_path / "bench.json"
    page = tmp_path / "results.md"
    args = argparse.Namespace(json=str(out), loop_seconds=None, repeats=None, fit_lines=None, skip="", quick=True,
                              work_dir=str(tmp_path / "work"), results=str(page))
    code = bench.run(args)
    text = capfd.readouterr().out  # capfd: rclpy's EventsExecutor needs a real stderr (faulthandler)
    report = json.loads(out.read_text())
    assert report["errors"] == {}, report["errors"]
    assert code in (0, 1)  # 1: a target missed, which tiny sizes on a shared machine may well do
    assert set(report["sections"]) == set(bench.SECTIONS)
    for name in bench.SECTIONS:
        section = report["sections"][name]
        assert section["wall_s"] > 0 and len(section["load_average_1min"]) == 2
    names = [f["name"] for f in report["figures"]]
    assert len(names) == len(set(names)) >= 16
    for f in report["figures"]:
        assert isinstance(f["value"], (int, float)) and math.isfinite(f["value"]), f
        assert f["value"] >= 0 if f["unit"] == "count" else f["value"] > 0, f  # a count (overruns) may be 0
        assert f["pass"] in ((True, False) if f["target"] else (None,)), f
        assert f["name"] in text  # the table shows it
        assert f"| {f['name']} |" in page.read_text()  # and the results page, written by the bench
    # the loop ran ours and bare in both layouts with the same sample count
    loop = report["sections"]["loop"]
    for layout in ("composed", "processes"):
        (r,) = loop[layout]["rounds"]
        assert r["ours"]["samples"] == r["bare"]["samples"] == loop["samples"] == 2000
        assert math.isclose(loop[layout]["ratio"], r["ours"]["samples_per_wall_s"] / r["bare"]["samples_per_wall_s"])
    assert report["sections"]["identify"]["state"] == "done"
    # the commands as typed at a terminal: each answered before it ended, identify's split adds up
    cmds = report["sections"]["commands"]
    assert 0 < cmds["fit"]["to_figures_s"] < cmds["fit"]["wall_s"]
    ident = cmds["identify"]
    assert 0 < ident["setup_s"] + ident["session_s"] <= ident["headline_s"] <= ident["wall_s"]
    assert 0 < ident["longest_silence_s"] < ident["wall_s"]
    # what follows the answer, from a process of its own: design's figure, identify's report, each done
    assert cmds["design"]["figure_own_s"] > 0 and cmds["design"]["figure_s"] >= cmds["design"]["wall_s"]
    assert ident["report_own_s"] > 0
    mem = report["sections"]["memory"]
    assert math.isclose(mem["offline"]["length_ratio"], bench.FACTOR) and mem["live"]["length_ratio"] > 1.5
    assert len(report["machine"]["load_average_start"]) == 3
    # the link: the C target's cost per datagram, sealed (version 3) above unauthenticated (version 2), and its
    # real-time runs under the bridge at both versions, every sample published
    link = report["sections"]["link"]
    assert link["cost"]["v3"]["encode_measurement_ns"] > link["cost"]["v2"]["encode_measurement_ns"]
    assert link["cost"]["v3"]["measurement_bytes"] == link["cost"]["v2"]["measurement_bytes"] + 24
    # the Python side packs and opens the same datagrams, byte for byte as long
    for v in ("v2", "v3"):
        assert {k: link["python_cost"][v][k] for k in ("measurement_bytes", "excitation_bytes")} == \
            {k: link["cost"][v][k] for k in ("measurement_bytes", "excitation_bytes")}
    for v, run in link["runs"].items():
        assert run["bridge"]["protocol_version"] == int(v) and run["bridge"]["authenticated"] == (int(v) == 3)
        assert run["target"]["state"] == "done" and run["bridge"]["missing_samples"] == 0
