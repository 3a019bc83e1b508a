"""The core's wheel carries what its API needs: built from ``ambid_core/`` alone, installed with nothing of ROS
(no sourced workspace, no AMENT_PREFIX_PATH), it runs the library example of docs/python.md and README.md
(``pip install ./ambid_core``, then ``python docs/examples/offline_identification.py``) and prints what
docs/python.md shows. Its dependencies (numpy, scipy, ...) are the suite's, behind the wheel on the path."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

from doc_blocks import REPO, mismatch, parse

EXAMPLE = "docs/examples/offline_identification.py"


def _no_ros_env(site: Path) -> dict[str, str]:
    keep = {k: os.environ[k] for k in ("PATH", "HOME", "LANG", "TMPDIR") if k in os.environ}
    deps = sysconfig.get_paths()["purelib"]
    return dict(keep, PYTHONPATH=f"{site}{os.pathsep}{deps}", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                PYTHONNOUSERSITE="1")


def test_the_core_wheel_carries_the_messages_and_runs_the_example(tmp_path):
    # the sources as a clone has them, outside the checkout (the wheel's build writes build/ beside them)
    src = tmp_path / "src"
    shutil.copytree(REPO / "ambid_core", src / "ambid_core", symlinks=True,
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    shutil.copytree(REPO / "ambid_msgs" / "msg", src / "ambid_msgs" / "msg")
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(wheels),
                    str(src / "ambid_core")], check=True, capture_output=True, text=True, timeout=600)
    (wheel,) = wheels.glob("ambid-*.whl")
    # every definition of ambid_msgs, byte for byte, and the one of ROS it nests (builtin_interfaces/Time)
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        for msg in sorted((REPO / "ambid_msgs" / "msg").glob("*.msg")):
            inside = f"ambid/interfaces/share/ambid_msgs/msg/{msg.name}"
            assert inside in names, f"the wheel lacks {inside}"
            assert z.read(inside) == msg.read_bytes()
        assert "ambid/interfaces/share/builtin_interfaces/msg/Time.msg" in names

    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
                   check=True, capture_output=True, text=True, timeout=600)
    env = _no_ros_env(site)
    run = tmp_path / "run"
    run.mkdir()
    where = subprocess.run([sys.executable, "-c", "import ambid, os; print(ambid.__file__); "
                            "print(os.environ.get('AMENT_PREFIX_PATH', ''))"],
                           cwd=run, env=env, capture_output=True, text=True, check=True)
    assert where.stdout.splitlines() == [str(site / "ambid" / "__init__.py"), ""]

    # the doc's command, run where the wheel is the only ambid
    (block,) = [b for b in parse(REPO / "docs" / "python.md") if EXAMPLE in b.text]
    cmd = block.text.split("#")[0].split()
    assert cmd[:2] == ["python", EXAMPLE]
    out = tmp_path / "example"
    proc = subprocess.run([sys.executable, str(REPO / EXAMPLE), str(out)], cwd=run, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (out / "rig.mcap").stat().st_size > 0
    # what docs/python.md shows under the command, with its folder (cmd[2]) where the test wrote it
    shown = next(b for b in parse(REPO / "docs" / "python.md") if b.line > block.line)
    expected = [ln.replace(cmd[2], str(out)) for ln in shown.text.splitlines()]
    assert mismatch(expected, proc.stdout) is None, mismatch(expected, proc.stdout)
    # README.md's and docs/python.md's install line is what this test built
    for doc in ("README.md", "docs/python.md"):
        assert "pip install ./ambid_core" in (REPO / doc).read_text()
