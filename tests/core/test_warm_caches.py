"""``ambid setup`` fills the caches the first identify would fill (ambid_cli.warm_caches): after it, a new
process builds the session's plant, controller and loop kernels from the numba cache without compiling,
and identify's default experiment from the design cache, the same design as a fresh one."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba")
ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import json, numba
import ambid_nodes.loop_kernels as lk
from ambid.plant import step_kernel as pk
from ambid.control import step_kernel as ck
from ambid.control.kinds import checked_design
from ambid.control.stepper import ControllerStepper
from ambid.excitation import multisine
from ambid.excitation.spec import DesignSpec
from ambid.plant.rig import make_rig
from ambid.plant.simulator import PlantSimulator

rig = make_rig()
PlantSimulator(rig, seed=3, nonlinear_magnets=False)   # not the arguments warm_caches used
d = checked_design("pid", rig)
ControllerStepper(d.model, d.current_limit_a)
def not_again(*args):
    raise AssertionError("designed again")
multisine._optimise = not_again
design = DesignSpec().build(float(rig.sample_rate_hz), float(rig.rotor_speed_rpm), rig.layout.inputs)
entry = {"plant_step_with": pk.plant_step_with, "statespace_step": ck.statespace_step}
print(json.dumps({"misses": {k: sum(f.stats.cache_misses.values()) for k, f in entry.items()},
                  "hits": {k: sum(f.stats.cache_hits.values()) for k, f in entry.items()},
                  "cfunc_hits": [lk.plant_kernel.cache_hits, lk.controller_kernel.cache_hits],
                  "design": design.to_dict()["phasors"]}))
"""


def test_setup_fills_the_caches_the_first_run_reads(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), AMBID_CACHE_DIR=str(tmp_path / "ambid"),
               PYTHONPATH=os.pathsep.join(str(ROOT / d) for d in ("ambid_core", "ambid_nodes", "ambid_cli")))
    warm = subprocess.run([sys.executable, "-m", "ambid_cli.warm_caches"], capture_output=True, text=True,
                          timeout=600, env=env, cwd=tmp_path)
    assert warm.returncode == 0, warm.stderr
    said = warm.stderr.splitlines()
    assert said[0].startswith("ambid setup: compiling the per-sample kernels") and "caches filled" in said[-1]
    assert len(list((tmp_path / "ambid" / "crest_phases").glob("*.npy"))) == 3 * 4  # M = 3 realisations x 4 inputs
    probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=600, env=env,
                           cwd=ROOT)
    assert probe.returncode == 0, probe.stderr
    got = json.loads(probe.stdout.strip().splitlines()[-1])
    assert got["misses"] == {"plant_step_with": 0, "statespace_step": 0}
    assert got["hits"] == {"plant_step_with": 1, "statespace_step": 1}
    assert got["cfunc_hits"] == [1, 1]
    # the cached default design equals one designed without any cache
    fresh = subprocess.run([sys.executable, "-c", PROBE.replace("multisine._optimise = not_again", "")],
                           capture_output=True, text=True, timeout=600, cwd=ROOT,
                           env=dict(env, AMBID_CACHE_DIR="off"))
    assert fresh.returncode == 0, fresh.stderr
    assert json.loads(fresh.stdout.strip().splitlines()[-1])["design"] == got["design"]
