"""``ambid identify`` on rigs/ideal.yaml: its sensors' 1 MHz bandwidth leaves the FRF unchanged, so the update
fixes it at its start value with a note instead of failing, and the magnets' slopes come back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_identify_on_the_ideal_rig_fixes_what_the_data_cannot_tell(ros_env, tmp_path):
    out = tmp_path / "run"
    rig = str(REPO / "rigs" / "ideal.yaml")
    proc = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "identify", "--rig", rig, "--out", str(out),
                           "--resolution", "10", "--periods", "2", "--realisations", "2", "--transient-periods", "2",
                           "--no-progress"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    params = summary["update"]["parameters"]
    assert not params["sensor_bandwidth_hz"]["free"] and params["sensor_bandwidth_hz"]["value"] == 1.0e6
    assert any(n.startswith("sensor_bandwidth_hz fixed at its start value") for n in summary["notes"])
    assert not any("model updating failed" in n for n in summary["notes"])
    for name in ("ki_n_per_a", "ks_n_per_m"):
        assert params[name]["free"] and abs(params[name]["error"]) < 0.01, (name, params[name])
    assert "updated ki_n_per_a" in proc.stdout
