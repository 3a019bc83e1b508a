"""A rig file carrying ``controller:`` (a controller file of the user's) runs through ``ambid identify``, and the
summary, the headline and the report say which controller ran. The controller is issue 34's badly tuned PID
(kp 20000 A/m, td 0.8 ms): its sensitivity peaks near 58 Hz, between the excited lines, and the headline's ISO
zone is the loop's (the worst over the lines and the fitted model between them, the true loop's 4.87: zone C),
not the lines' (zone B here)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from ambid.background import wait
from ambid.control.pid import PidParameters, pid_controller
from ambid.plant.rig import make_rig

REPO = Path(__file__).resolve().parents[2]


def test_identify_runs_the_rig_files_controller(ros_env, tmp_path):
    rig = make_rig()
    # the user's controller: a badly tuned PID, as a discrete state space in a .mat file beside the rig file
    model = pid_controller(PidParameters(kp_a_per_m=20_000.0, td_s=0.8e-3), rig.dt)
    from scipy import io as sio

    sio.savemat(tmp_path / "site_controller.mat", {"A": model.a, "B": model.b, "C": model.c, "D": model.d,
                                                    "Ts": rig.dt})
    (tmp_path / "rig.yaml").write_text("name: site\ncontroller: site_controller.mat\n")
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "identify", "--rig", str(tmp_path / "rig.yaml"),
                           "--out", str(out), "--band", "20", "400", "--resolution", "5", "--periods", "4",
                           "--realisations", "2", "--transient-periods", "1", "--no-progress"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    ctrl = summary["controller"]
    assert ctrl["kind"] == "file" and ctrl["parameters"]["file"] == str((tmp_path / "site_controller.mat").resolve())
    assert ctrl["n_states"] == model.n_states and ctrl["delay_samples"] == 1
    assert f"controller: file {(tmp_path / 'site_controller.mat').resolve()}" in proc.stdout
    # the report is written by a process of its own after the headline: there once its status says done
    assert wait(out / "report" / "status.json")["state"] == "done"
    page = (out / "report" / "index.html").read_text()
    assert "site_controller.mat" in page
    # the loop ran that controller: the FRF error figure is the usual one (a stable, identified loop)
    assert summary["frf_error"]["median"] < 0.05
    assert os.path.getsize(out / "session.mcap") > 0
    assert np.isfinite(summary["fit"]["chi2_per_dof"])
    # the headline's zone is the loop's, with its frequency and where it came from
    loop = summary["sensitivity"]["loop"]
    assert loop["iso_zone"] == "C" and 54 < loop["peak_hz"] < 62 and loop["source"].startswith("the fitted model")
    assert summary["sensitivity"]["iso_zone"] != "C"          # the lines alone miss the peak
    head = next(ln for ln in proc.stdout.splitlines() if "loop sensitivity peak" in ln)
    assert "ISO 14839-3 zone C" in head and "from the fitted model between the lines" in head
    # the zone's confidence: from the data's uncertainty, most of it on the true loop's zone (4.87: C)
    probs = loop["zone_probabilities"]
    assert abs(sum(probs.values()) - 1.0) < 1e-9 and max(probs, key=probs.get) == "C"
    assert any(ln.strip().startswith("zone probabilities A ") for ln in proc.stdout.splitlines())
