"""Issue 9, points 6 and 7: bad rig and parameter files are refused naming the field and its range,
without a traceback; nodes keep DDS discovery on this host unless the user opens it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_bad_rig_file_through_ambid_graph_names_the_field_and_range(ros_env, tmp_path):
    rig = tmp_path / "bad_rig.yaml"
    rig.write_text("name: bad\nbias_current_a: -3.0\n")
    out = subprocess.run([sys.executable, "-m", "ambid_cli.cli", "graph", "--processes", "--rig", str(rig),
                          "--sim-seconds", "0.1"], env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=120)
    text = out.stdout + out.stderr
    assert out.returncode == 2  # refused before any node starts
    assert "bias_current_a = -3" in text and "allowed range [0.01, 100] A" in text, text
    assert f"rig file {rig}" in text
    assert "Traceback" not in text, text
    # the node itself refuses it too, naming its parameter
    node = subprocess.run([sys.executable, "-m", "ambid_nodes.plant_sim", "--ros-args", "-p", f"rig_file:={rig}"],
                          env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert node.returncode == 2 and "parameter 'rig_file'" in node.stderr and "bias_current_a = -3" in node.stderr
    assert "Traceback" not in node.stderr


def test_bad_parameter_file_names_the_field_and_range(ros_env, tmp_path):
    params = tmp_path / "controller.yaml"
    params.write_text("/**:\n  ros__parameters:\n    plant_timeout_s: 0.0\n")
    out = subprocess.run([sys.executable, "-m", "ambid_nodes.position_controller", "--ros-args", "--params-file",
                          str(params)], env=ros_env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert "'plant_timeout_s' is invalid (allowed range [0.01, 3600.0] s)" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr


def _environ(pid: int) -> dict[str, str]:
    with open(f"/proc/{pid}/environ", "rb") as f:
        items = f.read().split(b"\0")
    return dict(i.decode(errors="replace").split("=", 1) for i in items if b"=" in i)


def test_nodes_keep_discovery_on_localhost_unless_opened(ros_env):
    base = {k: v for k, v in ros_env.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}
    via_ambid = ["bash", "-c", f"source '{REPO}/launch_scripts/setup/setup.sh' && ambid_activate && "
                 "exec python -m ambid_cli.cli node position_controller --ros-args -r __ns:=/net_{0}"]
    runs = {
        # what `ambid node ...` does after its set-up: the environment of ambid_activate
        "ambid": (via_ambid[:2] + [via_ambid[2].format("ambid")], base, "LOCALHOST"),
        "ambid_opened": (via_ambid[:2] + [via_ambid[2].format("opened")],
                         dict(base, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET"), "SUBNET"),
        # started by hand without the variable: the node's own default
        "bare": ([sys.executable, "-m", "ambid_nodes.position_controller", "--ros-args", "-r", "__ns:=/net_bare"],
                 base, "LOCALHOST"),
    }
    procs = {name: subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                    start_new_session=True) for name, (cmd, env, _) in runs.items()}
    try:
        lines = {}
        for name, p in procs.items():
            deadline = time.monotonic() + 90
            for line in p.stdout:
                if "networking:" in line:
                    lines[name] = line
                    break
                assert time.monotonic() < deadline, f"{name}: no networking line"
        for name, (_, _, want) in runs.items():
            assert f"discovery range {want}" in lines[name], (name, lines[name])
            assert f"ROS_DOMAIN_ID={ros_env['ROS_DOMAIN_ID']}" in lines[name]
        # the process itself (after ambid's exec chain) was given the variable by ambid_activate
        assert _environ(procs["ambid"].pid).get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST"
        assert _environ(procs["ambid_opened"].pid).get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "SUBNET"
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in _environ(procs["bare"].pid)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs.values():
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_a_node_stopped_while_it_starts_exits_quietly(ros_env):
    """SIGTERM during start-up (the graph runner stopping a controller whose plant refused its rig) leaves
    no traceback, whether it lands during the imports, while the node is built or once it runs."""
    for delay in (0.3, 1.0, 2.0, 3.0):
        p = subprocess.Popen([sys.executable, "-m", "ambid_nodes.position_controller"], env=ros_env, cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(delay)
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=60)
        assert "Traceback" not in out + err, (delay, err)
        assert p.returncode in (0, 130, -signal.SIGTERM), (delay, p.returncode, err)
