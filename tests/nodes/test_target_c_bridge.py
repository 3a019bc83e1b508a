"""The C reference target behind the real hardware bridge, over loopback: `ambid graph --hardware` levitates,
and `ambid identify --hardware` records a session and identifies the C target's plant as accurately as the
simulated rig at the same noise."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from ambid.excitation.spec import DesignSpec
from ambid.hardware.target_model import rig_target_model, write_target_model
from ambid.plant.rig import make_rig

from ambid_nodes.session import SessionConfig, session_samples
from udp_port import free_port

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / "ros_ws" / "install" / "target_c" / "ambp_udp_target"
SMALL = ["--resolution", "10", "--periods", "2", "--realisations", "1", "--transient-periods", "1", "--no-progress"]


def start_target(model: Path, *args: str) -> tuple[subprocess.Popen, str, int]:
    assert BIN.is_file(), f"{BIN} is missing: run './launch_scripts/ambid setup' (it compiles the C target)"
    tp, lp = free_port(), free_port()
    proc = subprocess.Popen([str(BIN), "--model", str(model), "--bind", f"127.0.0.1:{tp}",
                             "--bridge", f"127.0.0.1:{lp}", "--linger", "0.3", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, f"127.0.0.1:{tp}", lp


def start_identify_target(model: Path, rig=None) -> tuple[subprocess.Popen, str, int, int]:
    """The C target free-running while it waits for the excitation (deterministic and fast), stopping where an
    identify session of SMALL on ``rig`` (default the default rig) does: (process, address, bridge port,
    the session's samples)."""
    rig = make_rig() if rig is None else rig
    fs = 1 / rig.dt
    spec = DesignSpec(resolution_hz=10, n_periods=2, n_realisations=1, n_transient_periods=1)
    _, total = session_samples(SessionConfig(experiment=spec).design(fs, inputs=rig.layout.inputs), fs)
    return (*start_target(model, "--pace", "0", "--hold-for-excitation", "--samples", str(total), "--seed", "7"),
            total)


def identify_on_target(model: Path, out: Path, rig=None, *extra: str) -> int:
    """``ambid identify --hardware`` (SMALL, ``extra`` arguments) against the C target running ``model``, held
    for the excitation (:func:`start_identify_target`): both must end as planned; returns the session's
    samples."""
    proc, target, local, total = start_identify_target(model, rig)
    try:
        hw = cli("identify", "--hardware", target, "--local-port", str(local), "--true-model", str(model),
                 "--out", str(out), *extra, *SMALL)
        s = target_summary(proc)
    finally:
        proc.kill()
    assert hw.returncode == 0, hw.stdout + hw.stderr
    assert s["state"] == "done" and s["samples"] == total and s["late_excitation_samples"] == 0
    return total


def target_summary(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=30)
    line = next((ln for ln in out.splitlines() if ln.startswith("RT_TARGET_SUMMARY ")), None)
    assert line, err
    return json.loads(line.split(" ", 1)[1])


def cli(*args: str) -> subprocess.CompletedProcess:
    """``ambid ARGS`` on a ROS domain of its own (localhost only): no other test's or user's session hears it."""
    from conftest import next_domain_id

    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", *args], capture_output=True, text=True,
                          timeout=240, cwd=ROOT, env=env)


def test_graph_hardware_levitates_against_the_c_target(tmp_path):
    model = tmp_path / "rig.txt"
    write_target_model(model, rig_target_model())
    # paced on absolute deadlines as on a rig, at a quarter of real time: a loaded 2-core machine keeps up with
    # it, so a lost sample is the bridge's fault, not the test machine's (real time is a bench figure)
    proc, target, local = start_target(model, "--pace", "4")
    try:
        p = cli("graph", "--hardware", target, "--local-port", str(local), "--sim-seconds", "0.5")
        s = target_summary(proc)
    finally:
        proc.kill()
    assert p.returncode == 0, p.stdout + p.stderr
    assert "rotor levitated" in p.stdout and "lost 0 samples in 0 gaps" in p.stdout, p.stdout
    assert "target state done" in p.stdout, p.stdout  # told to STOP once the samples were in
    assert s["state"] == "done" and s["samples"] >= 5000 and proc.returncode == 0
    print(f"C target under the bridge: {s['samples_per_wall_s']:.0f} samples/s of {s['commanded_samples_per_s']:.0f}"
          f" commanded, {s['late_samples']} late samples (max {s['max_late_us']:.0f} us), {s['overruns']} overruns")


def test_identify_hardware_gives_the_c_target_the_accuracy_of_the_simulated_rig(tmp_path):
    model = tmp_path / "rig.txt"
    write_target_model(model, rig_target_model())
    sim = cli("identify", "--out", str(tmp_path / "sim"), "--linear-magnets", *SMALL)
    assert sim.returncode == 0, sim.stdout + sim.stderr
    total = identify_on_target(model, tmp_path / "hw")
    a = json.loads((tmp_path / "sim" / "summary.json").read_text())
    b = json.loads((tmp_path / "hw" / "summary.json").read_text())
    assert b["layout"].startswith("hardware bridge") and b["frf_error"]["reference"] == "the given plant model"
    ea, eb = a["frf_error"], b["frf_error"]
    print(f"FRF error, simulated rig: median {100 * ea['median']:.2f} %, worst {100 * ea['worst']:.2f} %; "
          f"C target: median {100 * eb['median']:.2f} %, worst {100 * eb['worst']:.2f} %")
    # the same accuracy at the same noise: the median over ~100 lines within 25 %, the worst line within 1.6x
    assert 0.8 < eb["median"] / ea["median"] < 1.25
    assert 1 / 1.6 < eb["worst"] / ea["worst"] < 1.6
    assert b["max_mode_freq_error"] < 0.01 and b["modes_vs_true"]
    # the Python target serves the simulated rig itself (same seed): over the same bridge path the figures
    # are the simulated session's to the last bit, so the C target's differ by its noise realisation only
    tp, lp = free_port(), free_port()
    py_target = subprocess.Popen([sys.executable, "-m", "ambid.hardware.rt_target", "--bind", f"127.0.0.1:{tp}",
                                  "--bridge", f"127.0.0.1:{lp}", "--pace", "0", "--hold-for-excitation",
                                  "--samples", str(total), "--seed", "1", "--linger", "0.3"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT / "ambid_core")
    try:
        py = cli("identify", "--hardware", f"127.0.0.1:{tp}", "--local-port", str(lp), "--true-model", str(model),
                 "--out", str(tmp_path / "py"), *SMALL)
        py_target.communicate(timeout=30)
    finally:
        py_target.kill()
    assert py.returncode == 0, py.stdout + py.stderr
    ep = json.loads((tmp_path / "py" / "summary.json").read_text())["frf_error"]
    assert ep["median"] == ea["median"] and ep["worst"] == ea["worst"]
    # recorded as any session: every sample's measurement, read back by the offline FRF above
    assert Path(b["recording"]["path"]).is_file() and b["recording"]["complete"]
    assert b["state"] == "done" and b["simulated_time_s"] == total / (1 / make_rig().dt)
    assert np.isfinite(b["noise"]["relative_frf_noise_std"])


def test_the_c_target_runs_the_five_axis_model_over_the_bridge(tmp_path):
    """rigs/five_axis.yaml's model in the C target: protocol version 2 carries its five axes (y, u, ic, r of
    a_x b_x a_y b_y z); the graph levitates on all five and identify measures the 5 x 5 FRF of the model the
    target runs."""
    rig_file = ROOT / "rigs" / "five_axis.yaml"
    from ambid.plant.rig import load_rig

    rig = load_rig(rig_file)
    model = tmp_path / "five.txt"
    write_target_model(model, rig_target_model(rig))
    assert "axes 5 a_x b_x a_y b_y z" in model.read_text()
    # paced on absolute deadlines as on a rig, at a quarter of real time: a loaded 2-core machine keeps up with
    # it, so a lost sample is the bridge's fault, not the test machine's (real time is a bench figure)
    proc, target, local = start_target(model, "--pace", "4")
    try:
        p = cli("graph", "--hardware", target, "--local-port", str(local), "--rig", str(rig_file),
                "--sim-seconds", "0.5")
        s = target_summary(proc)
    finally:
        proc.kill()
    assert p.returncode == 0, p.stdout + p.stderr
    assert "rotor levitated" in p.stdout and "lost 0 samples in 0 gaps" in p.stdout, p.stdout
    assert s["state"] == "done" and s["samples"] >= 5000 and s["rx_rejected_by_reason"]["content"] == 0
    # identify over the bridge: the 5 x 5 FRF against the model the target runs
    identify_on_target(model, tmp_path / "hw", rig, "--rig", str(rig_file))
    b = json.loads((tmp_path / "hw" / "summary.json").read_text())
    assert b["inputs"] == list(rig.layout.inputs) and b["outputs"] == list(rig.layout.outputs)
    print(f"five-axis C target: FRF error median {100 * b['frf_error']['median']:.2f} %, worst "
          f"{100 * b['frf_error']['worst']:.2f} %, modes {[round(m['freq_hz'], 1) for m in b['fit']['modes']]}")
    assert b["frf_error"]["median"] < 0.05 and b["max_mode_freq_error"] < 0.01
