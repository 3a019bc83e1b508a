"""The closed loop stepped in plain Python: the plant simulator and the controller stepper the nodes run.

The order is ``ambid_nodes.plant_sim``'s: y[k] = output, ic[k] = controller(y[k]), u[k] = ic[k] + r[k],
step. :func:`levitate` lifts the rotor off and lets it settle; :func:`run_loop` runs one experiment from a
copy of that state, so experiments started from one :class:`LoopStart` see the same sensor noise (common
random numbers). Offline checks and comparisons use it where a whole ROS graph would only add time.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np

from ambid.channels import Layout
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.rig import Rig
from ambid.plant.simulator import PlantSimulator
from ambid.statespace import StateSpace

__all__ = ["LoopStart", "LoopRecord", "levitate", "run_loop"]

@dataclass(frozen=True)
class LoopStart:
    """A levitated, settled plant and controller every experiment is copied from.

    Copies include the noise generator's state: every experiment sees the
    same sensor-noise sequence (common random numbers, so the methods differ
    by their excitation only).

    Attributes
    ----------
    sim
        the plant simulator (experiments deep-copy it).
    ctl
        the controller stepper (likewise).
    liftoff_s
        simulated time spent lifting off and settling [s].
    nonlinear_magnets
        whether the plant uses eq. 2.14.
    """

    sim: PlantSimulator
    ctl: ControllerStepper
    liftoff_s: float
    nonlinear_magnets: bool


@dataclass(frozen=True)
class LoopRecord:
    """What one experiment measured.

    Attributes
    ----------
    y
        (n, na) sensor displacements [m].
    u
        (n, na) current references u = ic + r [A] (before the amplifier limit).
    r
        (n, na) excitation [A].
    n_clipped
        samples where the amplifiers saturated.
    n_contact
        samples where the rotor touched the backup bearings.
    wall_s
        wall time of the loop [s].
    layout
        the rig's axes, the columns' order.
    """

    y: np.ndarray
    u: np.ndarray
    r: np.ndarray
    n_clipped: int
    n_contact: int
    wall_s: float
    layout: Layout

    def columns(self) -> np.ndarray:
        """(n, 3 na) [y, u, r], the column order of an :class:`ambid.frf.streaming.FrfStream`."""
        return np.hstack([self.y, self.u, self.r])


def levitate(rig: Rig, seed: int = 0, nonlinear_magnets: bool = False, liftoff_s: float = 0.5,
             controller: tuple[StateSpace, float] | None = None) -> LoopStart:
    """Lift the rotor off its backup bearings under the default PID (or ``controller``) and let it settle.

    Parameters
    ----------
    rig
        rig parameters.
    seed
        sensor-noise seed.
    nonlinear_magnets
        use the full magnet law (eq. 2.14).
    liftoff_s
        simulated time [s], > 0.
    controller
        (discrete controller y -> ic, its current limit [A]); None: the default PID.

    Raises
    ------
    ValueError
        if the rotor touches the retainer in the second half of that time.
    """
    if not (math.isfinite(liftoff_s) and liftoff_s > 0):
        raise ValueError(f"liftoff_s must be finite and > 0, got {liftoff_s!r}")
    sim = PlantSimulator(rig, seed=seed, nonlinear_magnets=nonlinear_magnets)
    if controller is None:
        pid = PidParameters()
        controller = (pid_controller(pid, rig.dt, rig.layout), pid.current_limit_a)
    ctl = ControllerStepper(*controller)
    n = int(round(liftoff_s / rig.dt))
    for k in range(n):
        _, contact = sim.step(ctl.step(sim.output()))
        if contact and k >= n // 2:
            raise ValueError(f"levitate: the rotor still touches the backup bearings after {k * rig.dt:.3f} s; "
                             "lengthen liftoff_s or check the rig and controller")
    return LoopStart(sim, ctl, float(liftoff_s), bool(nonlinear_magnets))


def run_loop(start: LoopStart, r: np.ndarray) -> LoopRecord:
    """Run one experiment from a copy of ``start``, sample by sample in the plant_sim order.

    Parameters
    ----------
    start
        the levitated state (not modified).
    r
        (n, na) excitation [A] added to the control currents, in the rig layout's order.

    Returns
    -------
    :class:`LoopRecord`.
    """
    r = np.asarray(r, dtype=float)
    layout = start.sim.layout
    na = len(layout)
    if r.ndim != 2 or r.shape[1] != na or not np.all(np.isfinite(r)):
        raise ValueError(f"run_loop: r must be finite with shape (n, {na}) [A], got shape {r.shape}")
    sim, ctl = copy.deepcopy(start.sim), copy.deepcopy(start.ctl)
    n = r.shape[0]
    ys: list = [None] * n
    us: list = [None] * n
    output, control, step = sim.output, ctl.step, sim.step
    n_clip = n_contact = 0
    t0 = time.perf_counter()
    for k, rk in enumerate(r.tolist()):
        y = output()
        ic = control(y)
        u = [a + b for a, b in zip(ic, rk)]
        clipped, contact = step(u)
        ys[k] = y
        us[k] = u
        n_clip += clipped
        n_contact += contact
    wall = time.perf_counter() - t0
    y_arr = np.array(ys, dtype=float).reshape(n, na)
    u_arr = np.array(us, dtype=float).reshape(n, na)
    return LoopRecord(y_arr, u_arr, r, int(n_clip), int(n_contact), wall, layout)
