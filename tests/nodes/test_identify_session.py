"""One short ``ambid identify`` session, and what must hold of it:

- ``ambid design --out D`` with the same experiment options writes the very design identify ran and recorded
  (with no options both are ``DesignSpec()``, tests/core/test_design_command.py), so the preview is the
  experiment.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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
    run = _cli(ros_env_module, "identify", "--out", str(out), "--no-progress", *SHORT)
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
