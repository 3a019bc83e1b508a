"""One short ``ambid identify`` session, and what must hold of it:

- ``ambid design --out D`` with the same experiment options writes the very design identify ran and recorded
  (with no options both are ``DesignSpec()``, tests/core/test_design_command.py), so the preview is the
  experiment;
- in a fresh venv of the machine's Python 3.11 without ROS, ``pip install ./ambid_core`` and then
  ``ambid.read_session``, ``estimate_frf``, ``fit_model`` give identify's modes, and rclpy is neither installed
  nor imported.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ambid.excitation import ExcitationDesign
from ambid.frf.offline import session_designs

REPO = Path(__file__).resolve().parents[2]
# identify's experiment, shortened: every other term is the default the commands share
SHORT = ["--band", "20", "400", "--resolution", "20", "--periods", "2", "--realisations", "2",
         "--transient-periods", "1", "--seed", "4"]


def _cli(env, *args, timeout=600):
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", *args], env=env, cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def identified(tmp_path_factory, ros_env_module):
    out = tmp_path_factory.mktemp("identify")
    run = _cli(ros_env_module, "identify", "--out", str(out), "--no-progress", "--no-report", *SHORT)
    assert run.returncode == 0, run.stderr[-3000:]
    return out


def test_design_writes_the_design_identify_records(identified, tmp_path, ros_env_module):
    preview = _cli(ros_env_module, "design", "--out", str(tmp_path), "--no-plan", "--no-figure", *SHORT)
    assert preview.returncode == 0, preview.stderr
    written = ExcitationDesign.from_dict(json.loads((tmp_path / "design.json").read_text()))
    (entry,) = session_designs(identified / "session.mcap")
    recorded = entry["design"]
    assert written == recorded
    assert recorded.options["phases"] == "crest_optimised" and recorded.peak_a.max() == pytest.approx(0.4)


FRESH = """
import importlib.util, json, sys
import ambid
s = ambid.read_session(sys.argv[1])
frf = ambid.estimate_frf(s)
m = ambid.fit_model(frf)
print(json.dumps({"modes": [[x.freq_hz, x.damping, list(x.freq_hz_ci95 or []), list(x.damping_ci95 or [])]
                            for x in m.modes],
                  "order": m.order, "rclpy_installed": importlib.util.find_spec("rclpy") is not None,
                  "ros_imported": sorted(n for n in sys.modules if n.split(".")[0] in ("rclpy", "ambid_msgs",
                                                                                    "ambid_nodes", "ambid_cli")),
                  "ambid": ambid.__file__}))
"""


def _clean_env(tmp: Path) -> dict:
    """The environment of a user's shell without ROS: no PYTHONPATH, no ROS or ament variables; pip's
    index, proxy and cache settings kept (the set-up needed the same)."""
    keep = ("PATH", "HOME", "LANG", "LC_ALL", "TMPDIR", "http_proxy", "https_proxy", "HTTP_PROXY", "HTTPS_PROXY",
            "no_proxy", "NO_PROXY", "XDG_CACHE_HOME")
    env = {k: v for k, v in os.environ.items() if k in keep or k.startswith("PIP_")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if ".venv" not in p and "ros" not in p.lower())
    return env


def test_the_core_installs_without_ros_and_gives_identifys_modes(identified, tmp_path):
    # the machine's Python 3.11 (the venv's base interpreter), in a venv of its own: no ROS on any path
    base = getattr(sys, "_base_executable", sys.executable)
    env = _clean_env(tmp_path)
    venv = tmp_path / "venv"
    subprocess.run([base, "-m", "venv", str(venv)], check=True, env=env, timeout=300)
    py = str(venv / "bin" / "python")
    # a copy, so the build leaves nothing in the work tree; the pins of the set-up, from pip's cache
    src = shutil.copytree(REPO / "ambid_core", tmp_path / "ambid_core",
                          ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    pins = str(REPO / "launch_scripts" / "setup" / "constraints.txt")
    # --no-compile: what is checked is that the core and its pinned dependencies install and run; byte-compiling
    # every module of scipy, numba, ... took 25 of pip's 38 s on a loaded machine, and the run below compiles the
    # few it imports (2 s)
    pip = [py, "-m", "pip", "install", "--disable-pip-version-check", "--no-compile", "-q", "-c", pins]
    for args in (["wheel"], ["--no-build-isolation", str(src)]):
        run = subprocess.run(pip + args, env=env, capture_output=True, text=True, timeout=900)
        assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    run = subprocess.run([py, "-c", FRESH, str(identified / "session.mcap")], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert not got["rclpy_installed"] and got["ros_imported"] == []
    assert got["ambid"].startswith(str(venv))  # the installed distribution, not the work tree
    summary = json.loads((identified / "summary.json").read_text())
    rows = summary["fit"]["modes"]
    assert got["order"] == summary["fit"]["order"] and len(got["modes"]) == len(rows) > 0
    for (freq, damping, freq_ci, damping_ci), row in zip(got["modes"], rows):
        np.testing.assert_allclose([freq, damping, *freq_ci, *damping_ci],
                                   [row["freq_hz"], row["damping"], *row["freq_hz_ci95"], *row["damping_ci95"]],
                                   rtol=1e-9, atol=0)
