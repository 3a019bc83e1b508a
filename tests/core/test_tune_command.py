"""ambid tune on a run's folder, in-process and without ROS: a short simulated session fitted by ``ambid fit``
is tuned end to end (controller.npz that --controller reads, tune.json with the prediction and the zones, the
report), and every bad run folder or option gets one line naming the problem and the fix, exit code 2."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from ambid.channels import RADIAL
from ambid.control.closed_loop import close_loop, loop_robustness
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.user_controller import load_controller
from ambid.excitation import design_multisine
from ambid.fit.model_update import physical_discrete
from ambid.plant.rig import make_rig
from ambid_cli import cli
from session_testbench import design_message, plant_message, simulate_closed_loop, write_session

RIG = make_rig()
FIX = re.compile(r"\b(give|run|record|check|create|leave out|make|use)\b")


def _run(argv, capsys):
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return code, out


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A simulated session (the default PID, two realisations of a MIMO multisine) and its ambid fit output."""
    d = tmp_path_factory.mktemp("tune")
    design = design_multisine((10.0, 1000.0), 10.0, RIG.sample_rate_hz, list(RADIAL.inputs), 0.4, n_periods=3,
                              n_realisations=2, seed=5)
    names, x = simulate_closed_loop(RIG, design, design.total_samples, post_samples=100, seed=6)
    session = d / "session.mcap"
    write_session(session, [(k, x[k:k + 1000]) for k in range(0, len(x), 1000)], names,
                  [(0, design_message(design, design.total_samples))], RIG.dt, plant=plant_message(RIG))
    code = cli.main(["fit", str(session), "--out", str(d / "run"), "--no-report"])   # the rig from the session
    assert code == 0
    return d


def test_tune_writes_a_controller_that_holds_the_updated_plant_and_its_prediction(run, capsys):
    out = run / "tuned"
    code, printed = _run(["tune", str(run / "run"), "--out", str(out), "--kind", "structured", "--checks", "8",
                          "--samples", "8", "--evaluations", "120", "--quiet"], capsys)
    assert code == 0, printed.err
    doc = json.loads((out / "tune.json").read_text())
    lo, hi = doc["predicted_peak"]["ci95"]
    assert lo <= doc["predicted_peak"]["value"] <= hi and abs(sum(doc["zones"].values()) - 1) < 1e-9
    assert doc["kind"] in ("structured", "running") and doc["stable_on"]["share"] == 1.0
    assert "predicted input sensitivity peak" in printed.out and (out / "report" / "index.html").is_file()
    # the file --controller takes, stable with the run's updated model
    k = load_controller(out / "controller.npz", RIG.dt, layout=RIG.layout)
    summary = json.loads((run / "run" / "identification.json").read_text())
    params = {n: v["value"] for n, v in summary["update"]["parameters"].items()}
    assert np.all(np.abs(close_loop(physical_discrete(RIG.rotor_model(), params, RIG.dt), k).poles()) < 1)
    # the session records no controller: no "running" candidate; the PID that ran is beaten on the updated model
    assert [c["kind"] for c in doc["candidates"]] == ["structured"]
    plant = physical_discrete(RIG.rotor_model(), params, RIG.dt)
    pid = loop_robustness(plant, pid_controller(PidParameters(), RIG.dt, RIG.layout)).sensitivity_peak.max()
    assert loop_robustness(plant, k).sensitivity_peak.max() < pid


def test_bad_run_folders_are_refused_in_one_line(run, capsys, tmp_path):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "empty").mkdir()
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("frf.npz", "model.npz"):
        (broken / name).write_bytes((run / "run" / name).read_bytes())
    (broken / "identification.json").write_bytes(np.random.default_rng(1).bytes(300))
    cases = [(tmp_path / "missing", "is not a folder"), (tmp_path / "afile", "is not a folder"),
             (tmp_path / "empty", "has no identification.json"), (broken, "cannot be read")]
    for folder, why in cases:
        code, printed = _run(["tune", str(folder), "--out", str(tmp_path / "o")], capsys)
        lines = [ln for ln in printed.err.splitlines() if ln.strip()]
        assert code == 2 and len(lines) == 1 and lines[0].startswith("ambid tune: ") and why in lines[0], printed.err
        assert FIX.search(lines[0])
        assert not (tmp_path / "o").exists()
    code, printed = _run(["tune", str(run / "run"), "--out", str(tmp_path / "o"), "--rig", str(tmp_path / "nope.yaml")],
                         capsys)
    assert code == 2 and "does not exist" in printed.err
    code, printed = _run(["tune", str(run / "run"), "--out", str(tmp_path / "o"), "--kind", "lqr"], capsys)
    assert code == 2 and "--kind" in printed.err
