"""The five-axis rig (rigs/five_axis.yaml) on the graph: ``ambid graph --processes`` levitates the rotor on
all five axes, and ``ambid identify --rig rigs/five_axis.yaml`` (identify's default experiment: a five-input
orthogonal multisine) measures the 5 x 5 FRF within 2 % (median) of the true rig's and fits it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from ambid.channels import FIVE_AXIS
from ambid.plant.rig import load_rig

ROOT = Path(__file__).resolve().parents[2]
RIG_FILE = ROOT / "rigs" / "five_axis.yaml"


def _cli(env, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", *args], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_graph_processes_levitates_the_five_axis_rotor(ros_env):
    out = _cli(ros_env, "graph", "--processes", "--rig", str(RIG_FILE), "--sim-seconds", "0.3", timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "axes a_x b_x a_y b_y z" in out.stdout and "over 5 axes" in out.stdout, out.stdout
    assert "rotor levitated" in out.stdout and "rejected messages: 0" in out.stdout


def test_identify_measures_the_five_by_five_frf(ros_env, tmp_path):
    out = _cli(ros_env, "identify", "--rig", str(RIG_FILE), "--out", str(tmp_path), "--no-progress",
               "--no-report")
    assert out.returncode == 0, out.stdout + out.stderr[-3000:]
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["levitated"] and s["simulated"]
    assert s["inputs"] == list(FIVE_AXIS.inputs) and s["outputs"] == list(FIVE_AXIS.outputs)
    assert s["excitation"]["n_experiments"] == 5 and s["excitation"]["mimo"] == "orthogonal"
    frf = np.load(tmp_path / "frf.npz")["frf"]
    assert frf.shape[1:] == (5, 5)
    # against the true rig's sampled small-signal model (ambid.plant.true_rig, not the fit)
    print(f"five-axis identify: FRF error median {100 * s['frf_error']['median']:.2f} %, worst "
          f"{100 * s['frf_error']['worst']:.2f} %; modes {[round(m['freq_hz'], 1) for m in s['fit']['modes']]}")
    assert s["frf_error"]["median"] <= 0.02
    assert s["modes_vs_true"] and s["max_mode_freq_error"] < 0.01
    # the axial axis is its own: its noise through the loop, its magnet updated near the true one
    assert len(s["noise"]["output_noise_std_m"]) == 5
    rig = load_rig(RIG_FILE)
    params = s["update"]["parameters"]
    for name in ("axial_ki_n_per_a", "axial_ks_n_per_m"):
        true = rig.derived()[f"axial_true_{name[len('axial_'):]}"]
        assert abs(params[name]["value"] / true - 1) < 0.03, (name, params[name]["value"], true)
