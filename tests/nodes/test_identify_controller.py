"""A rig file carrying ``controller:`` (a controller file of the user's) runs through ``ambid identify``, and the
summary, the headline and the report say which controller ran."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from ambid.control.pid import PidParameters, pid_controller
from ambid.plant.rig import make_rig

REPO = Path(__file__).resolve().parents[2]


def test_identify_runs_the_rig_files_controller(ros_env, tmp_path):
    rig = make_rig()
    # the user's controller: a PID of other gains, as a discrete state space in a .mat file beside the rig file
    model = pid_controller(PidParameters(kp_a_per_m=14_000.0, td_s=1.7e-3), rig.dt)
    from scipy import io as sio

    sio.savemat(tmp_path / "site_controller.mat", {"A": model.a, "B": model.b, "C": model.c, "D": model.d,
                                                    "Ts": rig.dt})
    (tmp_path / "rig.yaml").write_text("name: site\ncontroller: site_controller.mat\n")
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "identify", "--rig", str(tmp_path / "rig.yaml"),
                           "--out", str(out), "--band", "20", "400", "--resolution", "20", "--periods", "2",
                           "--realisations", "1", "--transient-periods", "1", "--no-progress"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    ctrl = summary["controller"]
    assert ctrl["kind"] == "file" and ctrl["parameters"]["file"] == str((tmp_path / "site_controller.mat").resolve())
    assert ctrl["n_states"] == model.n_states and ctrl["delay_samples"] == 1
    assert f"controller: file {(tmp_path / 'site_controller.mat').resolve()}" in proc.stdout
    page = (out / "report" / "index.html").read_text()
    assert "site_controller.mat" in page
    # the loop ran that controller: the FRF error figure is the usual one (a stable, identified loop)
    assert summary["frf_error"]["median"] < 0.05
    assert os.path.getsize(out / "session.mcap") > 0
    assert np.isfinite(summary["fit"]["chi2_per_dof"])


def test_the_headline_zone_is_the_loops_not_the_lines(ros_env, tmp_path):
    """A badly tuned PID (issue 34): its sensitivity peaks at ~58 Hz, between excited lines 20 Hz apart; the
    headline's zone is that of the worst peak over the lines and the fitted model between them, and says where
    it came from (the true loop's peak is 4.87, zone C)."""
    (tmp_path / "rig.yaml").write_text("controller: {kind: pid, kp_a_per_m: 20000, td_s: 0.8e-3}\n")
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "identify", "--rig", str(tmp_path / "rig.yaml"),
                           "--out", str(out), "--band", "20", "400", "--resolution", "20", "--periods", "2",
                           "--realisations", "1", "--transient-periods", "1", "--no-progress"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    loop = json.loads((out / "summary.json").read_text())["sensitivity"]["loop"]
    assert loop["iso_zone"] == "C" and 54 < loop["peak_hz"] < 62 and loop["source"].startswith("the fitted model")
    head = next(ln for ln in proc.stdout.splitlines() if "loop sensitivity peak" in ln)
    assert "ISO 14839-3 zone C" in head and "from the fitted model between the lines" in head
