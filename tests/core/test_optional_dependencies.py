"""The core without its optional dependencies: numba (the simulator and controllers run as plain Python and give
the same numbers) and matplotlib (reading a session, the FRF and the fit do not need it)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
BLOCK = """
import sys
class _Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {blocked!r}:
            raise ImportError(name + " is not installed here")
sys.meta_path.insert(0, _Block())
"""
LOOP = """
import json, sys
import numpy as np
from ambid.compiled import HAVE_NUMBA
from ambid.control.kinds import design_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.rig import make_rig
from ambid.plant.simulator import PlantSimulator

rig = make_rig()
sim = PlantSimulator(rig, seed=3, nonlinear_magnets=True)
ctrl = design_controller("pid", rig)
stepper = ControllerStepper(ctrl.model, ctrl.current_limit_a)
y, rows = sim.output(), []
for k in range(400):
    ic = stepper.step(y)
    out = sim.step_output(ic[0] + 0.2 * np.sin(0.06 * k), ic[1], ic[2], ic[3])
    y = out[:4]
    rows.append([float(v) for v in out[:4]] + [float(v) for v in ic])
print(json.dumps({"numba": HAVE_NUMBA, "imported": "numba" in sys.modules, "rows": rows}))
"""


def _run(code: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "ambid_core"))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_the_simulator_and_controller_without_numba_give_the_same_numbers():
    fast = _run(LOOP)
    plain = _run(BLOCK.format(blocked={"numba"}) + LOOP)
    assert fast["numba"] and not plain["numba"] and not plain["imported"]
    # levitated, excited, nonlinear magnets: every displacement and current bit for bit
    assert np.array_equal(np.array(plain["rows"]), np.array(fast["rows"]))


def test_reading_the_frf_and_the_fit_need_no_matplotlib(tmp_path):
    code = BLOCK.format(blocked={"matplotlib", "numba"}) + """
import json, sys
import ambid.recording, ambid.frf.offline, ambid.fit, ambid.fit.order_selection, ambid.identification
print(json.dumps({"matplotlib": "matplotlib" in sys.modules}))
"""
    assert _run(code) == {"matplotlib": False}
