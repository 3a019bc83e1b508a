"""``ambid identify`` on rigs/ideal.yaml: its sensors' 1 MHz bandwidth leaves the FRF unchanged; the update keeps
it free with its tolerance's width (the prior dominates it, and the summary says so) instead of failing or
freezing it, and the magnets' slopes come back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_identify_on_the_ideal_rig_keeps_what_the_data_cannot_tell_at_its_prior(ros_env, tmp_path):
    out = tmp_path / "run"
    rig = str(REPO / "rigs" / "ideal.yaml")
    proc = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "identify", "--rig", rig, "--out", str(out),
                           "--resolution", "10", "--periods", "2", "--realisations", "2", "--transient-periods", "2",
                           "--no-progress", "--no-report"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    params = summary["update"]["parameters"]
    sensor = params["sensor_bandwidth_hz"]
    assert sensor["free"] and sensor["prior_dominated"] and sensor["prior_ratio"] > 0.95
    assert sensor["ci95"][0] < 1.0e6 < sensor["ci95"][1]
    assert "sensor_bandwidth_hz" in summary["update"]["prior_dominated"]
    assert any("the data tell little about" in n and "sensor_bandwidth_hz" in n for n in summary["notes"])
    assert not any("model updating failed" in n or "fixed at" in n for n in summary["notes"])
    for name in ("ki_n_per_a", "ks_n_per_m"):
        assert params[name]["free"] and abs(params[name]["error"]) < 0.01, (name, params[name])
    assert "updated ki_n_per_a" in proc.stdout
